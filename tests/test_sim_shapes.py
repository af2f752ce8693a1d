"""Procedural shapes: every category, canonical frame, watertightness, determinism, gen-shapes CLI."""

import json

import numpy as np
import pytest

from vtlearn.sim_data.shapes import CATEGORIES, generate_shape, instance_seed, write_shapes


@pytest.mark.parametrize("category", CATEGORIES)
def test_category_canonical_watertight(category):
    mesh, rec = generate_shape(category, seed=3, sections=24)
    assert rec.category == category and rec.watertight and mesh.is_watertight
    lo, hi = mesh.bounds
    np.testing.assert_allclose((lo + hi) / 2, 0, atol=1e-9)  # centred
    assert np.isclose(np.max(hi - lo), 1.0)  # unit cube
    np.testing.assert_allclose(mesh.extents * rec.scale_m, rec.size_m, rtol=1e-9)
    assert 0.02 < max(rec.size_m) < 0.35  # household objects, metres
    # every part is a closed, outward-oriented solid
    assert all(part.volume > 0 for part in mesh.split(only_watertight=False))


def test_same_seed_same_mesh_and_instances_differ():
    a, ra = generate_shape("mug", 11)
    b, rb = generate_shape("mug", 11)
    c, rc = generate_shape("mug", 12)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces) and ra == rb
    assert rc.params != ra.params
    # instance parameters spread widely: heights of 20 bottles span > 5 cm
    heights = [generate_shape("bottle", instance_seed(0, "bottle", i))[1].size_m[2] for i in range(20)]
    assert max(heights) - min(heights) > 0.05


def test_handles_make_mugs_asymmetric():
    mesh, _ = generate_shape("mug", 0)
    assert mesh.bounds[1, 0] - mesh.bounds[0, 0] > mesh.bounds[1, 1] - mesh.bounds[0, 1] + 0.1


def test_bad_input():
    with pytest.raises(ValueError, match="category"):
        generate_shape("teapot", 0)
    with pytest.raises(ValueError, match="sections"):
        generate_shape("can", 0, sections=3)


def test_gen_shapes_cli(tmp_path):
    from vtlearn.cli import main
    from vtlearn.io import read_mesh

    assert main(["gen-shapes", "--out", str(tmp_path), "--categories", "can,box", "--per-category", "2"]) == 0
    objs = sorted(tmp_path.rglob("*.obj"))
    assert len(objs) == 4
    rec = json.loads(objs[0].with_suffix(".json").read_text())
    assert {"category", "seed", "params", "size_m", "scale_m", "transparent"} <= set(rec)
    mesh = read_mesh(objs[0])
    assert np.isclose(mesh.extents.max(), 1.0, atol=1e-5)
    recs = write_shapes(tmp_path / "again", ["can", "box"], 2, seed=0, progress=False)
    on_disk = {p.stem: json.loads(p.with_suffix(".json").read_text())["params"] for p in objs}
    assert {r["name"]: r["params"] for r in recs} == on_disk
