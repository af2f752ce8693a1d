"""Real-dataset loaders: ShapeNet / ModelNet / category folders / pybullet_data; broken meshes skipped
with a reason."""

import logging

import numpy as np
import trimesh

from vtlearn.sim_data.loaders import check_mesh, scan_mesh_folder, scan_pybullet_data
from vtlearn.sim_data.writer import GenConfig, generate_dataset


def _box(path, extents=(1, 2, 3)):
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=extents).export(path)


def test_shapenet_layout(tmp_path):
    _box(tmp_path / "02876657" / "abc" / "models" / "model_normalized.obj")
    _box(tmp_path / "99999999" / "def" / "models" / "model_normalized.obj")
    items = scan_mesh_folder(tmp_path)
    assert [i["category"] for i in items] == ["bottle", "99999999"]


def test_modelnet_layout(tmp_path):
    _box(tmp_path / "cup" / "train" / "cup_0001.off")
    _box(tmp_path / "cup" / "test" / "cup_0002.off")
    items = scan_mesh_folder(tmp_path)
    assert len(items) == 2 and {i["category"] for i in items} == {"cup"}


def test_category_folders_skip_broken_and_non_manifold(tmp_path, caplog):
    _box(tmp_path / "box" / "good.obj")
    (tmp_path / "box" / "broken.obj").write_text("this is not a mesh\n")
    # three triangles sharing the edge (0, 1): non-manifold
    fin = trimesh.Trimesh(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]],
        [[0, 1, 2], [1, 0, 3], [0, 1, 4]],
        process=False,
    )
    fin.export(tmp_path / "box" / "fin.obj")
    with caplog.at_level(logging.WARNING):
        items = scan_mesh_folder(tmp_path)
    assert [i["file"].split("/")[-1] for i in items] == ["good.obj"]
    assert "non-manifold" in caplog.text and "broken.obj" in caplog.text
    assert check_mesh(tmp_path / "box" / "fin.obj")[1].startswith("non-manifold")


def test_pybullet_data_meshes():
    items = scan_pybullet_data(random_objects=3)
    cats = [i["category"] for i in items]
    assert {"bunny", "duck", "teddy", "mug"} <= set(cats) and cats.count("random_object") == 3
    mesh, reason = check_mesh(items[0]["file"])
    assert reason is None and len(mesh.faces) > 100


def test_gen_data_from_mesh_folder(tmp_path):
    for cat, ext in (("tall", (0.05, 0.05, 0.2)), ("flat", (0.2, 0.2, 0.03))):
        for i in range(3):
            _box(tmp_path / "meshes" / cat / f"{i}.obj", np.asarray(ext) * (1 + 0.1 * i))
    cfg = GenConfig(
        kind="reconstruction",
        categories=["tall", "flat"],
        per_category=3,
        touches=8,
        pinches=2,
        mesh_source=str(tmp_path / "meshes"),
    )
    m = generate_dataset(cfg, tmp_path / "out", progress=False)
    assert m["class_names"] == ["tall", "flat"] and sum(s["instances"] for s in m["splits"].values()) == 6
