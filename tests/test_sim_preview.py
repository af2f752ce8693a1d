"""`vtlearn preview` writes a PNG grid for a generated dataset."""

from vtlearn.cli import main
from vtlearn.sim_data.fixtures import make_tiny_dataset


def test_preview_png(tmp_path):
    import matplotlib.image as mpimg

    d = make_tiny_dataset("reconstruction", tmp_path / "ds")
    out = tmp_path / "p.png"
    assert main(["preview", str(d), "--out", str(out), "--max-categories", "2"]) == 0
    img = mpimg.imread(out)
    assert img.shape[0] > 300 and img.shape[1] > 600  # 2 rows x 4 columns of panels
    assert img[..., :3].std() > 0.05  # not a blank canvas
