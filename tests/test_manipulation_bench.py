"""The pushing and articulation benchmark commands at the smallest sizes, the heuristic baseline, flags."""

import json

import numpy as np
import pytest

from vtlearn.cli import main
from vtlearn.runtime.articulation import KinematicArticulationSim, detect_articulation
from vtlearn.runtime.manipulation_bench import (
    ARTICULATION_CATEGORIES,
    PUSH_METHODS,
    articulation_figure,
    heuristic_articulation,
    run_articulation_benchmark,
    run_pushing_benchmark,
)
from vtlearn.sim_data.articulated import ArticulatedObject, make_articulated
from vtlearn.sim_data.scene import Scene


def test_bench_pushing_one_trial(tmp_path, capsys):
    out, fig = tmp_path / "push.json", tmp_path / "fig" / "push.png"
    assert main(["bench", "pushing", "--trials", "1", "--json", str(out), "--figure", str(fig)]) == 0
    text = capsys.readouterr().out
    assert "thesis, single object" in text and "19.1 +- 8.6" in text
    r = json.loads(out.read_text())
    assert set(r["summary"]) == set(PUSH_METHODS)
    assert len(r["runs"]) == len(PUSH_METHODS)
    # identical trial for every method: same object, same goal
    assert len({(x["object"], tuple(x["goal"])) for x in r["runs"]}) == 1
    for x in r["runs"]:
        assert 200 <= x["start_mm"] <= 360  # goals 0.2-0.35 m away, start settled near the origin
        assert 1 <= x["pushes"] <= 30 and x["final_mm"] >= 0
        assert x["success"] == (x["final_mm"] < 20.0)
        assert len(x["path"]) == x["pushes"] + 1
    for s in r["summary"].values():
        assert 0.0 <= s["success_rate"] <= 1.0 and s["seconds_per_push"] > 0
    base = r["summary"]["no_correction"]
    assert base["pid_gains"] == [0.0, 0.0, 0.0] and base["face"] == "y"
    assert base["final_mm_median_ratio"] == 1.0
    assert r["thesis"]["single_object_cm"] == [1.908, 0.86]
    assert fig.is_file() and fig.stat().st_size > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig", "push.json"]  # no temporary file left


def test_bench_articulation_one_trial_noiseless(tmp_path):
    out = tmp_path / "art.json"
    args = ["bench", "articulation", "--trials", "1", "--noise-mm", "0", "--noise-deg", "0"]
    assert main([*args, "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert list(r["summary"]) == list(ARTICULATION_CATEGORIES)
    assert len(r["runs"]) == 2 * len(ARTICULATION_CATEGORIES)
    for block in [*r["summary"].values(), r["overall"]]:
        assert set(block) == {"relative_motion", "heuristic"}
        for s in block.values():
            assert 0.0 <= s["accuracy"] <= 1.0 and s["actions_mean"] >= 1
    assert r["thesis"]["quantitative"] is False
    for x in r["runs"]:
        if x["method"] == "heuristic":
            assert x["axis_deg"] is None  # the heuristic gives no axis
        elif x["correct"] and x["truth"] != "rigid":
            # noiseless poses: the axis and the pivot are exact
            assert x["axis_deg"] < 1e-4
            assert x["truth"] == "prismatic" or x["pivot_mm"] < 1e-3
    assert r["summary"]["rigid"]["relative_motion"]["accuracy"] == 1.0
    # the figure goes beside the JSON by default, and the JSON names it
    assert r["figure"] == str(tmp_path / "art.png") and (tmp_path / "art.png").stat().st_size > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["art.json", "art.png"]
    # the JSON read back (nulls where the heuristic has no axis) draws too
    assert articulation_figure(r, tmp_path / "again.png").stat().st_size > 1000


def test_a_tracker_other_than_noisy_truth_or_artreg_is_refused():
    with pytest.raises(ValueError, match="tracker"):
        run_articulation_benchmark(trials=1, tracker="oracle")


@pytest.mark.slow  # 21 s; tests/test_articulation.py tracks the same articulations with ArtReg by default
def test_bench_articulation_tracked_by_artreg(tmp_path):
    out = tmp_path / "art.json"
    args = ["bench", "articulation", "--trials", "1", "--categories", "drawer", "--tracker", "artreg"]
    assert main([*args, "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["settings"]["tracker"] == "artreg" and list(r["summary"]) == ["drawer"]
    for x in r["runs"]:  # tracked poses: a tracking error is measured, and it is that of a working tracker
        assert 0.0 < x["tracking_mm_median"] < 30.0


def _pair_of_runs(spec, q):
    with Scene() as scene:
        obj = ArticulatedObject(scene, spec, n_model_points=0.01)
        sim = KinematicArticulationSim(obj, np.eye(4), q)
        res = detect_articulation(sim.observe, sim.execute)
        sim = KinematicArticulationSim(obj, np.eye(4), q)
        return res, heuristic_articulation(sim.observe, sim.execute)


def test_heuristic_baseline_misreads_a_drawer_pushed_along_its_axis():
    res, heur = _pair_of_runs(make_articulated("drawer", 2), [0.4])
    assert res.joint_type == "prismatic"
    # the drawer moves alone when pushed: "only the pushed part moved" reads as revolute
    assert heur["joint_type"] == "revolute" and heur["explored"]
    assert heur["heuristics"][:2] == ["rigid_or_prismatic", "revolute"]
    assert heur["actions"] == ["push"] * heur["n_actions"]


def test_heuristic_baseline_recognises_a_revolute_door():
    res, heur = _pair_of_runs(make_articulated("dishwasher", 0), [0.4])
    assert res.joint_type == heur["joint_type"] == "revolute"
    assert heur["heuristics"][:2] == ["rigid_or_prismatic", "revolute"]


def test_bad_flags_and_arguments(tmp_path, capsys):
    js = str(tmp_path / "x.json")
    for argv, flag in (
        (["bench", "pushing", "--trials", "0", "--json", js], "--trials"),
        (["bench", "pushing", "--max-pushes", "-2", "--json", js], "--max-pushes"),
        (["bench", "pushing", "--tolerance", "0", "--json", js], "--tolerance"),
        (["bench", "articulation", "--trials", "x", "--json", js], "--trials"),
        (["bench", "articulation", "--noise-mm", "-1", "--json", js], "--noise-mm"),
        (["bench", "articulation", "--noise-deg", "nan", "--json", js], "--noise-deg"),
    ):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        assert flag in capsys.readouterr().err
    # a list flag's error names the flag typed, not the function argument it feeds
    assert main(["bench", "pushing", "--methods", "magic", "--json", js]) == 2
    assert capsys.readouterr().err.startswith("vtlearn: error: --methods: need some of")
    assert main(["bench", "pushing", "--objects", "teapot", "--json", js]) == 2
    assert capsys.readouterr().err.startswith("vtlearn: error: --objects: need some of")
    assert main(["bench", "articulation", "--categories", "door", "--json", js]) == 2
    assert capsys.readouterr().err.startswith("vtlearn: error: --categories: need some of")
    # a figure path that cannot be written is refused before the run, not after it
    assert main(["bench", "articulation", "--figure", str(tmp_path), "--json", js]) == 2
    assert capsys.readouterr().err.startswith(f"vtlearn: error: --figure: {tmp_path} is a folder")
    assert not (tmp_path / "x.json").exists()
    with pytest.raises(ValueError, match="trials"):
        run_pushing_benchmark(trials=0)
    with pytest.raises(ValueError, match="objects"):
        run_pushing_benchmark(objects=["teapot"])
    with pytest.raises(ValueError, match="noise_deg"):
        run_articulation_benchmark(noise_deg=-1.0)
    with pytest.raises(ValueError, match="trials"):
        run_articulation_benchmark(trials=0)
    with pytest.raises(ValueError, match="observe, execute"):
        heuristic_articulation(None, None)
    with pytest.raises(ValueError, match="result: no runs"):
        articulation_figure({"runs": [], "summary": {}, "overall": {}}, tmp_path / "x.png")


def test_articulation_table_prints_a_dash_where_a_value_does_not_apply(tmp_path, capsys):
    js, fig = tmp_path / "a.json", tmp_path / "figs" / "rigid.png"
    argv = ["bench", "articulation", "--trials", "1", "--categories", "rigid", "--json", str(js)]
    assert main([*argv, "--figure", str(fig)]) == 0
    out = capsys.readouterr().out
    # --figure replaces the default path; a rigid object has no axis to draw, and the figure still draws
    assert f"wrote {js} and {fig}" in out and json.loads(js.read_text())["figure"] == str(fig)
    assert fig.stat().st_size > 1000 and not (tmp_path / "a.png").exists()
    table = [line for line in out.splitlines() if line.startswith("| rigid")]
    assert len(table) == 2 and "nan" not in out
    # a rigid object has no axis, and noisy truth no tracking error: "-" in the table, null in the JSON
    cells = [c.strip() for c in table[0].strip("|").split("|")]
    assert cells[7:12] == ["-"] * 5
    s = json.loads(js.read_text())["summary"]["rigid"]["relative_motion"]
    assert s["axis_deg_median"] is None and s["tracking_mm_median"] is None
