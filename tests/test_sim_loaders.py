"""Real-dataset loaders: ShapeNet / ModelNet / category folders / pybullet_data; broken meshes skipped
with a reason."""

import json
import logging

import numpy as np
import pytest
import trimesh

from vtlearn.sim_data.loaders import check_mesh, load_mesh_item, scan_mesh_folder, scan_pybullet_data
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


# ------------------------------------------------------------------ real layouts (ShapeNet, ModelNet quirks)
def _tall(path, scale=1.0, up="y", double_sided=False):
    """A 1 x 1 x 4 box, long along ``up`` (ShapeNet files are y-up), at ``scale`` units."""
    path.parent.mkdir(parents=True, exist_ok=True)
    m = trimesh.creation.box(extents=(1, 4, 1) if up == "y" else (1, 1, 4))
    v, f = m.vertices * scale, m.faces
    if double_sided:  # ShapeNet often stores each face once per winding
        f = np.vstack([f, f[:, ::-1]])
    trimesh.Trimesh(v, f, process=False).export(path)


def test_shapenet_v2_taxonomy_names_and_z_up(tmp_path):
    """Synsets missing from the built-in table take their taxonomy.json name; y-up files are turned z-up."""
    root = tmp_path / "ShapeNetCore.v2"
    root.mkdir()
    (root / "taxonomy.json").write_text(json.dumps([
        {"synsetId": "99990000", "name": "toy robot,robot", "children": [], "numInstances": 1},
        {"synsetId": "02876657", "name": "bottle", "children": [], "numInstances": 1}]))
    _tall(root / "99990000" / "a1" / "models" / "model_normalized.obj", double_sided=True)
    _tall(root / "02691156" / "b2" / "models" / "model_normalized.obj")
    (root / "02773838").mkdir()  # an empty synset folder
    items = scan_mesh_folder(root)
    assert sorted(i["category"] for i in items) == ["airplane", "toy_robot"]
    for it in items:  # the duplicate-winding faces are not "non-manifold"; the long y axis is now z
        mesh = load_mesh_item(it)
        assert np.allclose(mesh.extents, [0.25, 0.25, 1.0])


def test_shapenet_v1_layout(tmp_path):
    _tall(tmp_path / "03797390" / "m1" / "model.obj")
    items = scan_mesh_folder(tmp_path)
    assert [i["category"] for i in items] == ["mug"]
    assert np.allclose(load_mesh_item(items[0]).extents, [0.25, 0.25, 1.0])


def test_modelnet_off_header_quirk_hidden_files_and_odd_scales(tmp_path, caplog):
    """ModelNet's 'OFF<counts>' first line reads; macOS '._*' copies are ignored, not warned about; meshes
    in mm or at 1e-9 / 1e20 scale give the same canonical mesh (trimesh's absolute merge tolerance once
    collapsed tiny ones and overflowed on huge ones, both reported as 'zero surface area')."""
    box = trimesh.creation.box(extents=(1, 2, 4))
    d = tmp_path / "chair" / "train"
    d.mkdir(parents=True)
    for k, scale in enumerate((1.0, 1e3, 1e-9, 1e20)):
        body = [f"{len(box.vertices)} {len(box.faces)} 0"] + [" ".join(repr(float(x)) for x in v * scale)
                                                              for v in box.vertices]
        body += ["3 " + " ".join(map(str, f)) for f in box.faces]
        (d / f"chair_{k:04d}.off").write_text("OFF" + "\n".join(body) + "\n")
    (d / "._chair_0000.off").write_bytes(b"\x00\x05\x16\x07 AppleDouble")
    with caplog.at_level(logging.WARNING):
        items = scan_mesh_folder(tmp_path)
    assert len(items) == 4 and not caplog.text
    for it in items:
        assert np.allclose(load_mesh_item(it).extents, [0.25, 0.5, 1.0])


def test_skipped_meshes_are_counted_and_scan_reads_only_what_it_needs(tmp_path, caplog, capsys):
    for k in range(3):
        _tall(tmp_path / "can" / "train" / f"can_{k:04d}.off", up="z")
    (tmp_path / "can" / "train" / "can_0009.off").write_text("OFF\n0 0 0\n")
    (tmp_path / "can" / "train" / "can_0010.off").write_text("garbage")
    _tall(tmp_path / "cup" / "train" / "cup_0001.off", up="z")
    with caplog.at_level(logging.WARNING):
        assert len(scan_mesh_folder(tmp_path)) == 4
    assert "skipped 2 of 6 meshes" in caplog.text and "can/train/can_0009.off" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):  # two usable cans are found before the broken files are read
        items = scan_mesh_folder(tmp_path, categories=["can"], per_category=2, progress=True)
    assert [i["file"][-12:] for i in items] == ["can_0000.off", "can_0001.off"] and not caplog.text
    assert "checking meshes" in capsys.readouterr().err


def _two_category_folder(root, n=3):
    for cat, ext in (("tall", (0.05, 0.05, 0.2)), ("flat", (0.2, 0.2, 0.03))):
        for i in range(n):
            _box(root / cat / f"{i}.obj", np.asarray(ext) * (1 + 0.1 * i))


def test_gen_data_from_meshes_takes_every_category_and_records_each_instance_file(tmp_path):
    _two_category_folder(tmp_path / "meshes")
    cfg = GenConfig(kind="reconstruction", categories=None, per_category=3, touches=4, pinches=1,
                    mesh_source=str(tmp_path / "meshes"))
    m = generate_dataset(cfg, tmp_path / "out", progress=False)
    assert m["class_names"] == ["flat", "tall"] and m["config"]["categories"] == ["flat", "tall"]
    rows = json.loads((tmp_path / "out" / "meshes.json").read_text())["instances"]
    assert sorted(r["file"] for r in rows) == \
        sorted(f"{c}/{i}.obj" for c in ("flat", "tall") for i in range(3))
    assert len({r["instance"] for r in rows}) == 6  # each file is one instance, in one split
    assert {(r["category"], r["split"]) for r in rows} == {(c, s) for c in ("flat", "tall")
                                                           for s in ("train", "val", "test")}


def test_resuming_after_the_mesh_folder_changed_is_refused(tmp_path):
    """Finished shards hold the old plan's instances: resuming on a changed folder could put one mesh in
    two splits, so it is refused, naming mesh_source."""
    _two_category_folder(tmp_path / "meshes", n=4)
    cfg = GenConfig(kind="reconstruction", categories=["tall", "flat"], per_category=4, shard_size=1,
                    touches=4, pinches=1, mesh_source=str(tmp_path / "meshes"))
    assert generate_dataset(cfg, tmp_path / "out", progress=False, max_shards=2) == {}
    _box(tmp_path / "meshes" / "tall" / "00.obj", (0.05, 0.06, 0.2))  # sorts first: shifts the plan
    with pytest.raises(ValueError, match=r"mesh_source: the usable meshes in .* are not those"):
        generate_dataset(cfg, tmp_path / "out", progress=False)
    (tmp_path / "meshes" / "tall" / "00.obj").unlink()
    assert generate_dataset(cfg, tmp_path / "out", progress=False)["splits"]["train"]["instances"] > 0


def test_each_instance_maps_back_to_the_mesh_it_was_made_from(tmp_path):
    """`vtlearn preview` draws an instance's mesh from planned_instances: it must be the file generation used
    for that instance (a replay of the split permutation over meshes.json's rows drew other files)."""
    from vtlearn.sim_data.writer import _usable_meshes, plan_instances, planned_instances

    _two_category_folder(tmp_path / "meshes", n=8)
    cfg = GenConfig(kind="reconstruction", categories=None, per_category=8, touches=4, pinches=1,
                    mesh_source=str(tmp_path / "meshes"))
    m = generate_dataset(cfg, tmp_path / "out", progress=False)
    made_with = GenConfig(**m["config"])
    used = {it["instance"]: it["file"] for split in plan_instances(*_usable_meshes(made_with, False)).values()
            for it in split}
    got = planned_instances(tmp_path / "out", made_with)
    assert len(used) == 16 and {i: it["file"] for i, it in got.items()} == used


def test_resuming_a_mesh_dataset_made_before_meshes_json_is_refused(tmp_path):
    """Shards made before meshes.json were read with the older mesh reading (other usable meshes, y-up), so
    a resume could mix plans: refused, naming out_dir."""
    _two_category_folder(tmp_path / "meshes", n=4)
    cfg = GenConfig(kind="reconstruction", categories=["tall", "flat"], per_category=4, shard_size=1,
                    touches=4, pinches=1, mesh_source=str(tmp_path / "meshes"))
    assert generate_dataset(cfg, tmp_path / "out", progress=False, max_shards=2) == {}
    (tmp_path / "out" / "meshes.json").unlink()  # as an older vtlearn left it
    with pytest.raises(ValueError, match=r"out_dir: .* holds shards made from .* before vtlearn recorded"):
        generate_dataset(cfg, tmp_path / "out", progress=False)


# ------------------------------------------------------------------ --keep-split: ModelNet's own split
def _modelnet(root, cats=("cup", "vase"), n_train=6, n_test=3):
    """A ModelNet-like tree: ``<cat>/train/<cat>_0001.off`` ... then ``<cat>/test/...``, numbered on."""
    for c, cat in enumerate(cats):
        k = 0
        for split, n in (("train", n_train), ("test", n_test)):
            for i in range(n):
                k += 1
                _box(root / cat / split / f"{cat}_{k:04d}.off", (1 + 0.1 * i, 2 + c, 3))
    return root


def _plan_files(cfg):
    """Split -> the mesh files (relative to mesh_source) that generation would make its instances from."""
    from pathlib import Path

    from vtlearn.sim_data.writer import _usable_meshes, plan_instances

    plan = plan_instances(*_usable_meshes(cfg, False))
    return {s: [str(Path(it["file"]).relative_to(cfg.mesh_source)) for it in v] for s, v in plan.items()}


def test_modelnet_items_record_the_folder_they_came_from(tmp_path):
    _modelnet(tmp_path / "mn", cats=("cup",), n_train=2, n_test=1)
    items = scan_mesh_folder(tmp_path / "mn")
    assert [(i["file"].split("/")[-2], i["source_split"]) for i in items] == \
        [("test", "test"), ("train", "train"), ("train", "train")]
    _two_category_folder(tmp_path / "folders", n=1)  # layouts without a split of their own record none
    assert all("source_split" not in i for i in scan_mesh_folder(tmp_path / "folders"))
    with pytest.raises(ValueError, match="by_source_split: the meshes of .* have no train/test split"):
        scan_mesh_folder(tmp_path / "folders", per_category=1, by_source_split=True)


def test_without_keep_split_modelnet_meshes_are_split_as_before(tmp_path):
    """The default ignores ModelNet's folders (test meshes land in train): the plan of the version before
    --keep-split, hard-coded, so that recording the source folder in the items changes no split."""
    cfg = GenConfig(categories=None, per_category=9, mesh_source=str(_modelnet(tmp_path / "mn")))
    files = _plan_files(cfg)
    assert files["val"] == ["cup/train/cup_0004.off", "vase/train/vase_0006.off"]
    assert files["test"] == ["cup/train/cup_0001.off", "vase/train/vase_0005.off"]
    assert len(files["train"]) == 14 and "cup/test/cup_0007.off" in files["train"]


def test_keep_split_puts_every_test_folder_mesh_in_test_and_takes_val_from_train_meshes(tmp_path):
    root = _modelnet(tmp_path / "mn")
    every = {str(p.relative_to(root)) for p in root.glob("*/*/*.off")}
    test_folder = {f for f in every if "/test/" in f}
    cfg = GenConfig(categories=None, per_category=10, mesh_source=str(root), keep_split=True)
    files = _plan_files(cfg)
    assert set(files["test"]) == test_folder and len(files["test"]) == 6
    assert set(files["train"]) | set(files["val"]) == every - test_folder
    assert not set(files["train"]) & set(files["val"])
    # each category's 6 train meshes split 0.7:0.15 into train and val
    assert sorted(f.split("/")[0] for f in files["val"]) == ["cup", "vase"]
    assert _plan_files(cfg) == files  # seeded: the same plan again
    other = _plan_files(GenConfig(categories=None, per_category=10, mesh_source=str(root), keep_split=True,
                                  seed=1))
    assert other["test"] == files["test"] and set(other["val"]) <= every - test_folder


def test_keep_split_caps_each_folder_at_per_category_and_allows_no_val(tmp_path):
    root = _modelnet(tmp_path / "mn", cats=("cup",))
    files = _plan_files(GenConfig(categories=None, per_category=2, mesh_source=str(root), keep_split=True))
    assert files["test"] == ["cup/test/cup_0007.off", "cup/test/cup_0008.off"]  # the first 2 of each folder
    assert sorted(files["train"] + files["val"]) == ["cup/train/cup_0001.off", "cup/train/cup_0002.off"]
    assert len(files["val"]) == 1
    files = _plan_files(GenConfig(categories=None, per_category=10, mesh_source=str(root), keep_split=True,
                                  split_fractions=[0.85, 0.0, 0.15]))
    assert files["val"] == [] and len(files["train"]) == 6 and len(files["test"]) == 3


def test_keep_split_dataset_records_source_splits_and_is_resumed_only_with_the_flag(tmp_path):
    from vtlearn.sim_data.writer import planned_instances

    root = _modelnet(tmp_path / "mn", cats=("cup",), n_train=1, n_test=1)
    cfg = GenConfig(kind="reconstruction", categories=None, per_category=5, touches=4, pinches=1,
                    split_fractions=[1.0, 0.0, 0.0], mesh_source=str(root), keep_split=True)
    m = generate_dataset(cfg, tmp_path / "out", progress=False)
    assert [m["splits"][s]["instances"] for s in ("train", "val", "test")] == [1, 0, 1]
    rows = json.loads((tmp_path / "out" / "meshes.json").read_text())["instances"]
    assert sorted((r["split"], r["source_split"], r["file"]) for r in rows) == [
        ("test", "test", "cup/test/cup_0002.off"), ("train", "train", "cup/train/cup_0001.off")]
    made_with = GenConfig(**m["config"])  # `vtlearn preview` maps each instance back to its file
    assert {i: it["file"] for i, it in planned_instances(tmp_path / "out", made_with).items()} == \
        {r["instance"]: str(root / r["file"]) for r in rows}
    assert generate_dataset(cfg, tmp_path / "out", progress=False) == m  # resumes: nothing to redo
    cfg.keep_split = False
    with pytest.raises(ValueError, match="out_dir: .*keep_split: true in the folder, false asked"):
        generate_dataset(cfg, tmp_path / "out", progress=False)


def test_modelnet_folders_made_before_keep_split_still_resume(tmp_path):
    """Their config.json has no keep_split key and their meshes.json rows no source_split."""
    root = _modelnet(tmp_path / "mn", cats=("cup",), n_train=3, n_test=1)
    cfg = GenConfig(kind="reconstruction", categories=None, per_category=4, mesh_source=str(root))
    out = tmp_path / "out"
    assert generate_dataset(cfg, out, progress=False, max_shards=0) == {}
    rows = json.loads((out / "meshes.json").read_text())["instances"]
    assert len(rows) == 4 and all("source_split" not in r for r in rows)
    old = json.loads((out / "config.json").read_text())
    del old["keep_split"]
    (out / "config.json").write_text(json.dumps(old))
    assert generate_dataset(cfg, out, progress=False, max_shards=0) == {}


def test_keep_split_refusals_name_the_flag(tmp_path, capsys):
    from vtlearn.cli import main

    with pytest.raises(ValueError, match="keep_split: .* procedural shapes have none"):
        GenConfig(keep_split=True)
    with pytest.raises(ValueError, match="keep_split: .* both 0"):
        GenConfig(mesh_source=str(tmp_path), keep_split=True, split_fractions=[0.0, 0.0, 1.0])

    def refused(*flags):
        argv = ["gen-data", "reconstruction", "--out", str(tmp_path / "out"), "--keep-split", *flags]
        assert main(argv) == 2
        err = capsys.readouterr().err.splitlines()[-1]  # after the mesh check's warnings and progress bar
        assert err.startswith("vtlearn: error: --keep-split: "), err
        return err

    refused()  # procedural shapes
    _two_category_folder(tmp_path / "folders", n=3)
    assert "have no train/test split of their own" in refused("--meshes", str(tmp_path / "folders"))
    assert "have no train/test split" in refused("--meshes", "pybullet_data", "--categories", "bunny")
    root = _modelnet(tmp_path / "mn", cats=("cup", "vase"), n_train=3, n_test=1)
    for f in (root / "cup" / "test").glob("*.off"):
        f.unlink()
    assert "has no test meshes of 'cup'" in refused("--meshes", str(root))
    for f in (root / "vase" / "train").glob("*.off"):
        f.unlink()
    assert "has no train meshes of 'vase'" in refused("--meshes", str(root), "--categories", "vase")
    # meshes there but unusable: found once they are read
    root = _modelnet(tmp_path / "mn2", cats=("cup",), n_train=2, n_test=1)
    (root / "cup" / "train" / "cup_0002.off").write_text("garbage")
    err = refused("--meshes", str(root))
    assert "only 1 usable train mesh(es) of 'cup'" in err and "leave split 'val' with none" in err
    (root / "cup" / "test" / "cup_0003.off").write_text("garbage")
    assert "no usable test meshes of 'cup'" in refused("--meshes", str(root), "--splits", "1,0,0")
    assert not list((tmp_path / "out").glob("*.npz"))
