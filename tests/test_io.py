import json

import numpy as np
import pytest
import trimesh

from vtlearn.io import (
    atomic_write_npz,
    read_cloud,
    read_cloud_with_normals,
    read_geometry,
    read_mesh,
    read_poses,
    write_cloud,
    write_mesh,
)


@pytest.fixture
def cloud():
    rng = np.random.default_rng(0)
    pts = rng.random((50, 3))
    nrm = rng.normal(size=(50, 3))
    return pts, nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


@pytest.mark.parametrize("suffix", [".ply", ".pcd", ".xyz", ".txt", ".csv", ".npy", ".npz"])
def test_cloud_round_trip(tmp_path, cloud, suffix):
    pts, nrm = cloud
    path = write_cloud(tmp_path / f"c{suffix}", pts, nrm)
    back, back_n = read_cloud_with_normals(path)
    text = (".ply", ".pcd", ".xyz", ".txt", ".csv")
    tol = 1e-6 if suffix in text else 0  # text/float32-free formats are exact
    np.testing.assert_allclose(back, pts, atol=max(tol, 1e-12))
    assert back_n is not None
    np.testing.assert_allclose(back_n, nrm, atol=max(tol, 1e-12))
    np.testing.assert_allclose(
        read_cloud(write_cloud(tmp_path / f"n{suffix}", pts)), pts, atol=max(tol, 1e-12)
    )


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".off"])
def test_mesh_round_trip(tmp_path, suffix):
    box = trimesh.creation.box(extents=(0.1, 0.2, 0.3))
    path = write_mesh(tmp_path / f"m{suffix}", box)
    back = read_mesh(path)
    assert back.is_watertight
    np.testing.assert_allclose(back.volume, box.volume, rtol=1e-5)
    np.testing.assert_allclose(back.bounds, box.bounds, atol=1e-6)


def test_read_geometry_samples_meshes_and_passes_clouds(tmp_path, cloud):
    path = write_mesh(tmp_path / "box.ply", trimesh.creation.box(extents=(1, 1, 1)))
    pts = read_geometry(path, n_points=300)
    assert pts.shape == (300, 3) and np.abs(pts).max() <= 0.5 + 1e-9
    np.testing.assert_allclose(read_geometry(write_cloud(tmp_path / "c.npy", cloud[0])), cloud[0])


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.ply"):
        read_cloud(tmp_path / "nope.ply")
    with pytest.raises(FileNotFoundError, match="nope.obj"):
        read_mesh(tmp_path / "nope.obj")
    bad = tmp_path / "bad.xyz"
    bad.write_text("1 2 3\n4 5\n")
    with pytest.raises(ValueError, match="bad.xyz"):
        read_cloud(bad)
    nan = tmp_path / "nan.xyz"
    nan.write_text("1 2 3\nnan 5 6\n")
    with pytest.raises(ValueError, match="NaN"):
        read_cloud(nan)
    empty = tmp_path / "empty.txt"
    empty.write_text("")
    with pytest.raises(ValueError, match="empty.txt"):
        read_cloud(empty)
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"\x00\x01 not a ply")
    with pytest.raises(ValueError, match="garbage.ply"):
        read_cloud(garbage)
    wrong = tmp_path / "wrong.npy"
    np.save(wrong, np.ones((4, 2)))
    with pytest.raises(ValueError, match=r"wrong.npy.*k >= 3 columns.*\(4, 2\)"):
        read_cloud(wrong)
    other = tmp_path / "cloud.csvx"
    other.write_text("1 2 3")
    with pytest.raises(ValueError, match="unsupported cloud format"):
        read_cloud(other)
    broken_mesh = tmp_path / "broken.obj"
    broken_mesh.write_text("v 0 0 0\nv 1 0 0\n")
    with pytest.raises(ValueError, match="broken.obj"):
        read_mesh(broken_mesh)


def test_npz_never_unpickles(tmp_path):
    path = tmp_path / "obj.npz"
    np.savez(path, points=np.array([object()], dtype=object))
    with pytest.raises(ValueError, match="obj.npz"):
        read_cloud(path)
    with pytest.raises(ValueError, match="object arrays"):
        atomic_write_npz(tmp_path / "x.npz", a=np.array([object()], dtype=object))


def test_atomic_write_npz_leaves_no_temp(tmp_path):
    out = atomic_write_npz(tmp_path / "sub" / "shard.npz", points=np.ones((3, 3)))
    assert out.exists() and [p.name for p in out.parent.iterdir()] == ["shard.npz"]
    with np.load(out, allow_pickle=False) as d:
        np.testing.assert_array_equal(d["points"], np.ones((3, 3)))


def test_write_cloud_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="points"):
        write_cloud(tmp_path / "a.ply", np.empty((0, 3)))
    with pytest.raises(ValueError, match="unsupported"):
        write_cloud(tmp_path / "a.las", np.ones((3, 3)))


def test_atomic_write_npz_is_byte_reproducible(tmp_path):
    arrays = {"b": np.arange(6.0).reshape(2, 3), "a": np.ones(4, dtype=np.int64)}
    one = atomic_write_npz(tmp_path / "one.npz", **arrays).read_bytes()
    two = atomic_write_npz(tmp_path / "two.npz", compress=True, **arrays)
    assert atomic_write_npz(tmp_path / "again.npz", **arrays).read_bytes() == one
    with np.load(two, allow_pickle=False) as d:
        np.testing.assert_array_equal(d["b"], arrays["b"])
        np.testing.assert_array_equal(d["a"], arrays["a"])


def test_atomic_path_leaves_nothing_behind_on_failure(tmp_path, monkeypatch):
    """The one atomic write of vtlearn (checkpoints, JSON, shards, figures): a failed write, or a failed
    rename, leaves neither half a file at the destination nor its temporary file."""
    import vtlearn.io as vio

    with pytest.raises(RuntimeError, match="killed"):
        with vio.atomic_path(tmp_path / "out.ckpt") as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []

    def fail(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(vio.os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        with vio.atomic_path(tmp_path / "out.ckpt") as tmp:
            tmp.write_bytes(b"whole")
    assert list(tmp_path.iterdir()) == []
    monkeypatch.undo()
    with vio.atomic_path(tmp_path / "sub" / "fig.png") as tmp:
        assert tmp.suffix == ".png" and tmp.parent == tmp_path / "sub"  # writers that infer the format
        tmp.write_bytes(b"png")
    assert [f.name for f in (tmp_path / "sub").iterdir()] == ["fig.png"]


def test_read_poses_reads_every_format_alike(tmp_path):
    """The same two poses as .npy, JSON and stacked 4x4 text blocks read back equal (pose files from robot
    logs come in all three)."""
    from scipy.spatial.transform import Rotation

    T = np.repeat(np.eye(4)[None], 2, 0)
    T[:, :3, :3] = Rotation.from_rotvec([[0.3, -0.2, 0.5], [0.0, 1.0, 0.0]]).as_matrix()
    T[:, :3, 3] = [[0.1, 0.2, 0.3], [-0.4, 0.0, 0.05]]
    np.save(tmp_path / "T.npy", T)
    (tmp_path / "T.json").write_text(json.dumps(T.tolist()))
    np.savetxt(tmp_path / "T.txt", T.reshape(-1, 4))
    for name in ("T.npy", "T.json", "T.txt"):
        np.testing.assert_allclose(read_poses(tmp_path / name, "--poses", n=2), T, atol=1e-12)
    np.save(tmp_path / "one.npy", T[0])  # a single (4, 4) pose is one pose
    np.testing.assert_allclose(read_poses(tmp_path / "one.npy", "--init", n=1), T[:1], atol=1e-12)


@pytest.mark.parametrize("content, n, what", [
    (None, None, "no file at"),
    ("", None, "holds no numbers"),
    ("1 2 3\n4 5", None, "cannot read"),
    ("1 0 0\n0 1 0\n0 0 1", None, "got shape (3, 3)"),
    ("\n".join(["1 0 0 0", "0 1 0 0", "0 0 1 0", "0 0 0 1"] * 2), 1, "need one pose as"),
    ("\n".join(["2 0 0 0", "0 2 0 0", "0 0 2 0", "0 0 0 1"]), None, "not a proper rotation"),
])
def test_read_poses_errors_name_the_argument(tmp_path, content, n, what):
    p = tmp_path / "T.txt"
    if content is not None:
        p.write_text(content)
    with pytest.raises((ValueError, FileNotFoundError)) as exc:
        read_poses(p, "--poses", n=n)
    assert str(exc.value).startswith("--poses") and what in str(exc.value)


def test_extra_columns_and_a_header_row_are_read_as_the_text_formats_are(tmp_path, cloud):
    """Scanner exports carry intensity (x y z i) and CSV headers: .npy reads like text, x y z first."""
    pts, nrm = cloud
    intensity = np.arange(len(pts), dtype=np.float64)[:, None]
    np.save(tmp_path / "xyzi.npy", np.hstack([pts, intensity]))
    np.testing.assert_array_equal(read_cloud(tmp_path / "xyzi.npy"), pts)
    np.save(tmp_path / "xyzni.npy", np.hstack([pts, nrm, intensity]))
    got_pts, got_nrm = read_cloud_with_normals(tmp_path / "xyzni.npy")
    np.testing.assert_array_equal(got_pts, pts)
    np.testing.assert_allclose(np.abs(got_nrm), np.abs(nrm), atol=1e-12)
    rows = "\n".join(",".join(f"{v:.9g}" for v in r) for r in np.hstack([pts, intensity]))
    (tmp_path / "scan.csv").write_text("x,y,z,intensity\n" + rows + "\n")
    np.testing.assert_allclose(read_cloud(tmp_path / "scan.csv"), pts, atol=1e-8)
    (tmp_path / "header_only.csv").write_text("x,y,z\n")
    with pytest.raises(ValueError, match="header_only.csv.*no data rows"):
        read_cloud(tmp_path / "header_only.csv")


@pytest.mark.parametrize("suffix", [".npy", ".npz", ".ply"])
def test_a_cloud_of_no_points_is_refused_unless_allowed(tmp_path, suffix):
    path = tmp_path / f"none{suffix}"
    if suffix == ".npy":
        np.save(path, np.zeros((0, 3)))
    elif suffix == ".npz":
        np.savez(path, points=np.zeros((0, 3)))
    else:
        path.write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                        "property float z\nend_header\n")
    with pytest.raises(ValueError) as err:
        read_cloud(path)
    msg = str(err.value)
    assert "point cloud is empty" in msg and msg.count(path.name) == 1  # the file named once
    assert read_cloud(path, allow_empty=True).shape == (0, 3)
    pts, normals = read_cloud_with_normals(path, allow_empty=True)
    assert pts.shape == (0, 3) and normals is None
