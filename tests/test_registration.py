"""Tests for vtlearn.classical.registration (unified API), sparse_icp and the registration CLI/benchmark."""

import json
import os

import numpy as np
import pytest
from scipy.spatial import cKDTree

from vtlearn.classical.registration import METHODS, RegistrationResult, available_methods, register
from vtlearn.classical.sparse_icp import kabsch, shrink_lp, sparse_icp
from vtlearn.classical.tiqf import _quat_to_matrix

os.environ.setdefault("WANDB_MODE", "disabled")


def _pose(rng, trans=0.3, rot_scale=1.0):
    w = rng.normal(size=3) * rot_scale
    q = np.concatenate([[1.0], 0.5 * w])
    q /= np.linalg.norm(q)
    T = np.eye(4)
    T[:3, :3] = _quat_to_matrix(q)
    T[:3, 3] = rng.uniform(-trans, trans, 3)
    return T


def _box_cloud(rng, n=600):
    pts = rng.uniform(-1, 1, size=(n, 3)) * [1.0, 0.6, 0.35]
    # push to the surface of the box so the shape has clear structure
    k = rng.integers(0, 3, n)
    pts[np.arange(n), k] = np.sign(pts[np.arange(n), k]) * np.array([1.0, 0.6, 0.35])[k]
    return pts


def test_kabsch_exact():
    rng = np.random.default_rng(0)
    T = _pose(rng, rot_scale=2.0)
    x = rng.normal(size=(10, 3))
    np.testing.assert_allclose(kabsch(x, x @ T[:3, :3].T + T[:3, 3]), T, atol=1e-10)


def test_shrink_lp_matches_naive_minimiser():
    rng = np.random.default_rng(1)
    h = rng.normal(size=(6, 3))
    mu, p = 3.0, 0.5
    z = shrink_lp(h, mu, p, n_fixed_point=50)
    for hi, zi in zip(h, z, strict=True):
        # naive: 1-D search along h (the minimiser is a non-negative multiple of h)
        betas = np.linspace(0, 1, 20001)
        f = (betas * np.linalg.norm(hi)) ** p + mu / 2 * ((1 - betas) * np.linalg.norm(hi)) ** 2
        best = betas[np.argmin(f)] * hi
        f_z = np.linalg.norm(zi) ** p + mu / 2 * np.linalg.norm(zi - hi) ** 2
        f_best = np.linalg.norm(best) ** p + mu / 2 * np.linalg.norm(best - hi) ** 2
        assert f_z <= f_best + 1e-6


def test_sparse_icp_noiseless_and_outliers():
    rng = np.random.default_rng(2)
    target = _box_cloud(rng, 300)
    T = _pose(rng, trans=0.1, rot_scale=0.2)
    source = (target[:100] - T[:3, 3]) @ T[:3, :3]  # target = T source
    T_est, _ = sparse_icp(source, target, max_icp=60, tol=1e-9)
    np.testing.assert_allclose(T_est, T, atol=1e-4)
    src_out = source.copy()
    src_out[:10] += rng.normal(scale=0.5, size=(10, 3))
    T_est, _ = sparse_icp(src_out, target, max_icp=60)
    assert np.abs(T_est[:3, 3] - T[:3, 3]).max() < 0.02
    with pytest.raises(ValueError, match="p"):
        sparse_icp(source, target, p=1.5)


@pytest.mark.parametrize("method", ["tiqf", "icp", "icp_plane", "sparse_icp"])
def test_local_methods_recover_small_offset(method):
    rng = np.random.default_rng(3)
    model = _box_cloud(rng)
    T = _pose(rng, trans=0.05, rot_scale=0.1)
    scene = model[:300] @ T[:3, :3].T + T[:3, 3]
    res = register(model, scene, method)
    assert isinstance(res, RegistrationResult)
    err = np.abs(res.T_scene_model - T).max()
    assert err < (1e-3 if method != "icp_plane" else 1e-2), err
    np.testing.assert_allclose(res.T_scene_model[:3, :3], res.R)
    assert res.scale.shape == (3,) and res.time > 0 and res.rmse < 0.05
    d = res.to_dict()
    assert json.loads(json.dumps(d))["method"] == method


def test_stiqf_global_from_far_pose():
    rng = np.random.default_rng(4)
    model = _box_cloud(rng, 800) * [1.0, 1.0, 1.0]
    model[:, 2] *= 1.6  # break the box's symmetries a little
    model = model[model[:, 0] > -0.5]  # and cut one end off
    T = np.eye(4)
    T[:3, :3] = _quat_to_matrix(np.array([0.2, 0.9, -0.3, 0.25]) / np.linalg.norm([0.2, 0.9, -0.3, 0.25]))
    T[:3, 3] = [3.0, -4.0, 2.0]
    scene = model[::5] @ T[:3, :3].T + T[:3, 3]
    res = register(model, scene, "stiqf", seed=1)
    pred = model @ res.R.T + res.t
    true = model @ T[:3, :3].T + T[:3, 3]
    assert cKDTree(pred).query(true)[0].mean() < 0.03


def test_feature_methods_run_on_dense_input():
    rng = np.random.default_rng(5)
    model = _box_cloud(rng, 1500)
    scene = model @ _pose(rng, trans=0.2, rot_scale=0.3)[:3, :3].T
    for method in ("ransac_fpfh", "fgr"):
        res = register(model, scene, method)
        R = res.R
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-6)
        assert np.isfinite(res.rmse)


def test_restart_wrapper_counts_and_improves():
    rng = np.random.default_rng(6)
    model = _box_cloud(rng)
    model = model[model[:, 0] > -0.6]
    T = _pose(rng, trans=0.0, rot_scale=3.0)
    scene = model[::4] @ T[:3, :3].T + T[:3, 3]
    plain = register(model, scene, "icp", seed=0)
    restarted = register(model, scene, "icp", restarts=8, seed=0)
    assert restarted.restarts == 8 and plain.restarts == 0
    assert restarted.rmse <= plain.rmse + 1e-12
    timed = register(model, scene, "icp", time_budget=0.0, seed=0)
    assert timed.restarts == 0  # the first run always happens, then the budget is spent


def test_available_methods_and_probreg_guard():
    methods = available_methods()
    assert {"tiqf", "stiqf", "icp", "icp_plane", "sparse_icp", "ransac_fpfh", "fgr"} <= set(methods)
    assert set(methods) <= set(METHODS)
    import importlib.util

    if importlib.util.find_spec("probreg") is None:
        with pytest.raises(ValueError, match="probreg"):
            register(np.random.rand(20, 3), np.random.rand(10, 3), "cpd")


@pytest.mark.parametrize("method", ["stiqf", "tiqf", "icp", "icp_plane", "sparse_icp", "ransac_fpfh", "fgr"])
@pytest.mark.parametrize(
    "scene, match",
    [
        (np.random.default_rng(0).random((2, 3)), "scene"),
        (np.array([[0.0, 0, 0], [1, 0, 0], [np.nan, 1, 0], [0, 1, 1]]), "scene"),
        (np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2], [-1, -1, -1]]), "scene"),
    ],
)
def test_every_method_rejects_bad_input(method, scene, match):
    model = np.random.default_rng(1).random((50, 3))
    with pytest.raises(ValueError, match=match):
        register(model, scene, method)


def test_register_rejects_bad_arguments():
    rng = np.random.default_rng(7)
    model, scene = rng.random((50, 3)), rng.random((10, 3))
    with pytest.raises(ValueError, match="method"):
        register(model, scene, "nope")
    with pytest.raises(ValueError, match="model"):
        register(model[:2], scene)
    with pytest.raises(ValueError, match="restarts"):
        register(model, scene, "icp", restarts=-1)
    with pytest.raises(ValueError, match="estimate_scale"):
        register(model, scene, "stiqf", estimate_scale=True, restarts=2)
    with pytest.raises(ValueError, match="T_init"):
        register(model, scene, "icp", T_init=np.zeros((4, 4)))
    with pytest.raises(ValueError, match="restarts: need an integer"):
        register(model, scene, "icp", restarts=2.5)  # was run as 3 restarts and reported as 2
    with pytest.raises(ValueError, match="time_budget"):
        register(model, scene, "icp", time_budget="1")


@pytest.mark.parametrize("method, options, named", [
    ("stiqf", {"estimate_scales": True}, "'estimate_scales'"),  # a misspelt option
    ("icp", {"estimate_scale": True}, "'estimate_scale'"),  # an option of another method
    ("fgr", {"max_iter": 10, "rho": 0.1}, "'max_iter', 'rho'"),
])
def test_register_refuses_options_the_method_does_not_take(method, options, named):
    """Before, each method picked the options it knew and dropped the rest, so a typo silently ran the
    default (``estimate_scales=True`` returned scale 1)."""
    rng = np.random.default_rng(7)
    model, scene = rng.random((50, 3)), rng.random((10, 3))
    with pytest.raises(ValueError, match=f"options: method '{method}' takes no {named}; its options are"):
        register(model, scene, method, **options)


def test_every_method_option_is_read_by_its_runner():
    """METHOD_OPTIONS is what register() accepts: each listed option must change what the method does, else
    it is accepted and silently ignored. Checked on the cheap ones: max_iter=1 stops the local methods
    after one step, so the result differs from the default's."""
    from vtlearn.classical.registration import METHOD_OPTIONS

    assert set(METHOD_OPTIONS) == set(METHODS)
    rng = np.random.default_rng(3)
    model = _box_cloud(rng, 300)
    T = _pose(rng, trans=0.1, rot_scale=0.3)
    scene = model[:150] @ T[:3, :3].T + T[:3, 3]
    for method in ("tiqf", "icp", "sparse_icp"):
        assert "max_iter" in METHOD_OPTIONS[method]
        full = register(model, scene, method, seed=0).T_scene_model
        one = register(model, scene, method, seed=0, max_iter=1).T_scene_model
        assert not np.allclose(full, one, atol=1e-6), method


def test_cli_register_json(tmp_path, capsys):
    from vtlearn.cli import main
    from vtlearn.io import write_cloud

    rng = np.random.default_rng(8)
    model = _box_cloud(rng)
    T = _pose(rng, trans=0.05, rot_scale=0.1)
    write_cloud(tmp_path / "model.ply", model)
    write_cloud(tmp_path / "scene.xyz", model[:200] @ T[:3, :3].T + T[:3, 3])
    code = main(
        [
            "register",
            "--model",
            str(tmp_path / "model.ply"),
            "--scene",
            str(tmp_path / "scene.xyz"),
            "--method",
            "tiqf",
            "--seed",
            "1",
            "--json",
        ]
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(np.array(out["T_scene_model"]), T, atol=1e-3)
    assert out["method"] == "tiqf" and out["n_scene"] == 200


def test_bench_registration_tiny(tmp_path, capsys):
    from vtlearn.cli import main

    out = tmp_path / "reg.json"
    code = main(
        [
            "bench",
            "registration",
            "--meshes",
            "bunny",
            "--trials",
            "2",
            "--sizes",
            "20",
            "--methods",
            "stiqf,tiqf",
            "--no-ablation",
            "--no-time-matched",
            "--scale-trials",
            "0",
            "--json",
            str(out),
        ]
    )
    assert code == 0
    res = json.loads(out.read_text())
    s = res["summary"]["20"]
    assert set(s) == {"stiqf", "tiqf"}
    assert s["tiqf"]["p_welch_vs_stiqf"] is None or 0 <= s["tiqf"]["p_welch_vs_stiqf"] <= 1
    assert len(res["adi_cm"]["20"]["stiqf"]) == 2
    assert out.with_suffix(".md").exists() and out.with_suffix(".png").exists()
    # each method against S-TIQF on the same trials, and S-TIQF against thesis Table 5.1 (20 points: 4.36 cm)
    assert s["tiqf"]["ratio_to_stiqf"] == pytest.approx(s["tiqf"]["mean"] / s["stiqf"]["mean"])
    assert s["stiqf"]["thesis_cm"] == 4.36 and s["tiqf"]["thesis_cm"] is None
    assert s["stiqf"]["ratio_to_thesis"] == pytest.approx(s["stiqf"]["mean"] / 4.36)
    printed = capsys.readouterr().out
    assert "| ADI mean cm |" in printed and "| x S-TIQF |" in printed and "| x thesis |" in printed
    assert f"wrote {out}" in printed


def test_bench_registration_rejects_unknown_method(tmp_path, capsys):
    from vtlearn.classical.registration_bench import run_registration_benchmark
    from vtlearn.cli import main

    with pytest.raises(ValueError, match=r"methods: unknown \['icpp'\]"):
        run_registration_benchmark(["bunny"], sizes=(20,), trials=1, methods=["stiqf", "icpp"],
                                   progress=False)
    # The space after the comma is stripped (the error names 'icpp'); the typo fails before any trial.
    js = str(tmp_path / "reg.json")
    assert main(["bench", "registration", "--meshes", "bunny", "--methods", "stiqf, icpp", "--json", js]) == 2
    assert "icpp" in capsys.readouterr().err
    assert not (tmp_path / "reg.json").exists()


def test_cli_register_estimate_scale_needs_stiqf(tmp_path, capsys):
    from vtlearn.cli import main
    from vtlearn.io import write_cloud

    cloud = _box_cloud(np.random.default_rng(2), 100)
    write_cloud(tmp_path / "m.xyz", cloud)
    assert main(["register", "--model", str(tmp_path / "m.xyz"), "--scene", str(tmp_path / "m.xyz"),
                 "--method", "icp", "--estimate-scale"]) == 2
    assert "--estimate-scale: only --method stiqf estimates a scale, not icp" in capsys.readouterr().err
