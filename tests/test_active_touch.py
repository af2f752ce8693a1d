"""Tests for vtlearn.classical.active_touch (thesis 4.2.4, Algorithm 1, eq. 4.24-4.25)."""

import json
import os

import numpy as np
import pytest
import trimesh

from vtlearn.classical.active_touch import (
    ActionSampler,
    MeshRaycaster,
    lookahead_information_gain,
    select_action,
    simulate_touches,
)
from vtlearn.classical.tiqf import SequentialTIQF, _quat_to_matrix, gaussian_kl, tiqf_update

os.environ.setdefault("WANDB_MODE", "disabled")


def _pose(rng, trans=0.1):
    q = rng.normal(size=4)
    T = np.eye(4)
    T[:3, :3] = _quat_to_matrix(q / np.linalg.norm(q))
    T[:3, 3] = rng.uniform(-trans, trans, 3)
    return T


def test_raycaster_hits_box_faces():
    box = trimesh.creation.box(extents=[0.2, 0.1, 0.1])
    caster = MeshRaycaster(box)
    T = _pose(np.random.default_rng(0))
    origins = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]) @ T[:3, :3].T + T[:3, 3]
    dirs = -np.eye(3) @ T[:3, :3].T
    hits, ok = caster.cast(origins, dirs, T)
    assert ok.all()
    expected = np.array([[0.1, 0, 0], [0, 0.05, 0], [0, 0, 0.05]]) @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(hits, expected, atol=1e-6)
    _, ok = caster.cast(origins, -dirs, T)  # pointing away
    assert not ok.any()


def test_action_sampler_on_box_faces_pointing_inwards():
    lo, hi = np.array([-0.1, -0.05, -0.05]), np.array([0.1, 0.05, 0.05])
    sampler = ActionSampler(lo, hi, margin=0.0, faces=("+x", "-x", "+y", "-y", "+z"))
    o, d = sampler.sample(500, np.eye(4), 0)
    on_face = np.isclose(o, hi) | np.isclose(o, lo)
    assert on_face.any(axis=1).all()
    # no action from the bottom face (it would point up, +z)
    assert not (d[:, 2] > 0.5).any()
    assert (d[:, 2] < -0.5).any() and (np.abs(d[:, 0]) > 0.5).any()
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    # inwards: moving along d from the start point goes towards the box centre
    assert np.all(np.einsum("nd,nd->n", d, -o) > 0)
    with pytest.raises(ValueError, match="n"):
        sampler.sample(0, np.eye(4), 0)


def test_lookahead_gain_matches_per_candidate_naive_update():
    rng = np.random.default_rng(1)
    s = rng.normal(size=(6, 3))
    o = rng.normal(size=(6, 3))
    x = np.array([0.9, 0.1, -0.3, 0.2])
    x /= np.linalg.norm(x)
    P = 0.2 * np.eye(4)
    z_hat, o_hat = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    gain = lookahead_information_gain(x, P, s, o, z_hat, o_hat, rho=0.05)
    for c in range(5):
        # naive: the pairs (i, new) for every measured i, one literal update, then the KL
        x_c, P_c = tiqf_update(x, P, z_hat[c] - s, o_hat[c] - o, 0.05)
        np.testing.assert_allclose(gain[c], gaussian_kl(x_c, P_c, x, P), rtol=1e-6, atol=1e-9)
    assert np.all(gain >= 0)


def test_select_action_random_first_then_by_gain():
    rng = np.random.default_rng(2)
    mesh = trimesh.creation.box(extents=[0.2, 0.1, 0.05])
    model = trimesh.sample.sample_surface(mesh, 500, seed=0)[0]
    caster = MeshRaycaster(mesh)
    sampler = ActionSampler(*mesh.bounds)
    filt = SequentialTIQF(model, T_init=np.eye(4))
    _, _, order = select_action(filt, caster, sampler, 20, rng)
    assert sorted(order.tolist()) == list(range(20))
    filt.add(model[:5])
    origins, dirs, order = select_action(filt, caster, sampler, 50, rng)
    z, hit = caster.cast(origins, dirs, filt.T_scene_model)
    gain = lookahead_information_gain(
        filt.x, filt.P, filt.scene, filt.correspondences(), z[hit], filt.correspondences(z[hit]), filt.rho
    )
    # the first candidate is a hit with the largest gain
    assert hit[order[0]]
    assert np.isclose(
        gain.max(),
        lookahead_information_gain(
            filt.x,
            filt.P,
            filt.scene,
            filt.correspondences(),
            z[order[:1]],
            filt.correspondences(z[order[:1]]),
            filt.rho,
        )[0],
    )


def test_simulate_touches_reduces_error_noiseless():
    rng = np.random.default_rng(3)
    mesh = trimesh.creation.box(extents=[0.2, 0.12, 0.06])
    T_gt = _pose(rng)
    T_init = T_gt.copy()
    T_init[:3, 3] += [0.01, -0.01, 0.005]
    axis_angle = 0.1
    T_init[:3, :3] = T_gt[:3, :3] @ _quat_to_matrix(
        np.array([np.cos(axis_angle / 2), 0, 0, np.sin(axis_angle / 2)])
    )
    tr = simulate_touches(mesh, T_gt, T_init, n_touches=15, n_candidates=30, noise=0.0, seed=0)
    assert tr.contacts == 15 and tr.attempts >= 15
    assert tr.trans_err[-1] < 0.005 and tr.rot_err_deg[-1] < 3.0
    for active in (True, False):
        a = simulate_touches(mesh, T_gt, T_init, n_touches=4, n_candidates=10, active=active, seed=5)
        b = simulate_touches(mesh, T_gt, T_init, n_touches=4, n_candidates=10, active=active, seed=5)
        np.testing.assert_array_equal(a.trans_err, b.trans_err)


def test_simulate_touches_rejects_bad_pose():
    mesh = trimesh.creation.box()
    with pytest.raises(ValueError, match="T_gt"):
        simulate_touches(mesh, np.zeros((4, 4)), np.eye(4))
    with pytest.raises(ValueError, match="mesh"):
        MeshRaycaster(trimesh.Trimesh())


def test_bench_active_touch_tiny(tmp_path, capsys):
    from vtlearn.cli import main

    out = tmp_path / "at.json"
    code = main(
        [
            "bench",
            "active-touch",
            "--candidates",
            "10",
            "--faces",
            "500",
            "--repeats",
            "1",
            "--trials",
            "1",
            "--touches",
            "4",
            "--json",
            str(out),
        ]
    )
    assert code == 0
    res = json.loads(out.read_text())
    assert res["lookahead_rows"][0]["candidates"] == 10
    assert len(res["curves_rmse"]["active"]["trans_m"]) == 4
    # 500 faces is not a row of Table 4.1, so there is no thesis time to compare with
    row = res["lookahead_rows"][0]
    assert row["thesis_s"] is None and row["speedup_vs_thesis"] is None
    last = res["curve_rows"][-1]
    assert last["touches"] == 4
    for name in ("active", "active_entropy"):
        assert last[f"{name}_over_random_trans"] == pytest.approx(
            last[f"{name}_trans_rmse_mm"] / last["random_trans_rmse_mm"])
        assert last[f"{name}_over_random_rot"] == pytest.approx(
            last[f"{name}_rot_rmse_deg"] / last["random_rot_rmse_deg"])
    assert out.with_suffix(".png").exists()
    assert "look-ahead" in capsys.readouterr().out


def test_entropy_criterion_is_half_logdet_ratio():
    rng = np.random.default_rng(9)
    s, o = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    x = np.array([1.0, 0, 0, 0])
    P = 0.3 * np.eye(4)
    z, oz = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    g = lookahead_information_gain(x, P, s, o, z, oz, 0.1, criterion="entropy")
    for c in range(3):
        _, P_c = tiqf_update(x, P, z[c] - s, oz[c] - o, 0.1)
        np.testing.assert_allclose(g[c], 0.5 * np.log(np.linalg.det(P) / np.linalg.det(P_c)), rtol=1e-6)
    with pytest.raises(ValueError, match="criterion"):
        lookahead_information_gain(x, P, s, o, z, oz, 0.1, criterion="nope")


def test_simulate_touches_gives_up_when_no_ray_can_reach_the_object():
    # The candidates start on the box at the estimate and run along the box axes; with the estimate 1 m
    # away on the diagonal, no axis-aligned ray from it meets the object, so no contact is possible.
    mesh = trimesh.creation.box(extents=[0.06, 0.08, 0.1])
    T_init = np.eye(4)
    T_init[:3, 3] = [1.0, 1.0, 1.0]
    with pytest.raises(ValueError, match="T_init: no candidate ray reached the object"):
        simulate_touches(mesh, np.eye(4), T_init, n_touches=2, n_candidates=5, max_rounds=4, seed=0)


def test_active_touch_input_is_named():
    box = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(ValueError, match="mesh: degenerate"):
        simulate_touches(flat, np.eye(4), np.eye(4), n_touches=2)  # no ray could ever hit it
    with pytest.raises(ValueError, match="mesh: degenerate"):
        MeshRaycaster(flat)
    for kw, name in ((dict(n_touches=0), "n_touches"), (dict(noise=np.nan), "noise"),
                     (dict(n_candidates=0), "n_candidates"), (dict(criterion="kl2"), "criterion")):
        with pytest.raises(ValueError, match=name):
            simulate_touches(box, np.eye(4), np.eye(4), **kw)
    with pytest.raises(ValueError, match="faces"):
        ActionSampler(np.zeros(3), np.ones(3), faces=("+w",))
    with pytest.raises(ValueError, match="margin"):
        ActionSampler(np.zeros(3), np.ones(3), margin=np.nan)
    with pytest.raises(ValueError, match="hi"):
        ActionSampler(np.ones(3), np.zeros(3))
    x, P = np.array([1.0, 0, 0, 0]), np.eye(4)
    with pytest.raises(ValueError, match="scene_points"):
        lookahead_information_gain(x, P, np.zeros((0, 3)), np.zeros((0, 3)), np.ones((2, 3)), np.ones((2, 3)),
                                   0.01)
    with pytest.raises(ValueError, match="o_hat"):
        lookahead_information_gain(x, P, np.ones((3, 3)), np.ones((3, 3)), np.ones((2, 3)), np.ones((1, 3)),
                                   0.01)


@pytest.mark.parametrize("kw, name", [
    (dict(init_rot_deg=np.nan), "init_rot_deg"),
    (dict(init_trans=-0.01), "init_trans"),
    (dict(trials=0), "trials"),
    (dict(candidates=()), "candidates"),
    (dict(faces=(3,)), "faces"),
])
def test_active_touch_benchmark_checks_arguments_before_work(kw, name):
    from vtlearn.classical.active_touch import run_active_touch_benchmark

    args = dict(candidates=(5,), faces=(100,), repeats=1, trials=1, touches=3) | kw
    with pytest.raises(ValueError, match=name):
        run_active_touch_benchmark(**args)


def test_active_touch_benchmark_names_a_missing_mesh(tmp_path):
    from vtlearn.classical.active_touch import run_active_touch_benchmark

    with pytest.raises(FileNotFoundError, match="mesh_spec"):
        run_active_touch_benchmark(candidates=(5,), faces=(100,), repeats=1, trials=1, touches=3,
                                   mesh_spec=str(tmp_path / "missing.obj"))
