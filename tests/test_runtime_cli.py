"""`vtlearn runtime`'s console output: the warning for a target outside the model's classes, and the
explore progress bar's total; `vtlearn bench declutter`'s figure."""

import io
import json
import logging

import tqdm

import vtlearn.runtime.robot as robot
import vtlearn.runtime.runtime_cli as runtime_cli
from vtlearn.cli import main


class _Stop(Exception):
    pass


def test_a_target_outside_the_xavtnet_classes_is_warned_about_before_the_run(monkeypatch, caplog, capsys):
    """`--target jar` with an xAVTNet of other classes reported "predicted wineglass, true jar" with no
    word that jar could never be predicted; now one warning says so before the scene is built."""
    paths = (None, ("xav.ckpt", "--xavtnet"), ("manifest.json", "--class-names"))
    monkeypatch.setattr(runtime_cli, "_model_paths", lambda args: paths)
    monkeypatch.setattr(runtime_cli, "_load_models", lambda p: (object(), object(), ["wineglass", "mug"]))
    built = []

    def stop(*a, **k):  # the scene: the warning must come before it
        built.append(True)
        raise _Stop

    monkeypatch.setattr(robot, "clutter_scene", stop)
    base = ["runtime", "--out", "unused", "--target-kind", "any"]
    with caplog.at_level(logging.WARNING, logger="vtlearn.runtime.runtime_cli"):
        for target, warned in (("jar", True), ("wineglass", False)):
            caplog.clear()
            try:
                main([*base, "--target", target])
            except _Stop:
                pass
            assert built, target
            msgs = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
            if warned:
                assert len(msgs) == 1 and "\n" not in msgs[0]
                assert msgs[0].startswith("--target jar is not one of the xAVTNet's 2 classes (--class-names")
                assert "wineglass, mug; its recognition cannot be right" in msgs[0]
            else:
                assert msgs == []


def test_explore_bar_ends_full_for_a_transparent_target(tmp_path, monkeypatch, capsys):
    """A transparent target gets no camera views: the bar's total was --n-touches + 3 and it stopped at
    2/5; its total is now the episode's own."""
    bars = []

    class RecordingBar(tqdm.tqdm):
        def close(self):
            if not self.disable:  # the first close (tqdm closes again on deletion, disabled by then)
                bars.append((self.desc, self.n, self.total))
            super().close()

    monkeypatch.setattr(tqdm, "tqdm", RecordingBar)
    out = tmp_path / "rt"
    argv = ["runtime", "--out", str(out), "--n-touches", "2", "--n-candidates", "4", "--max-declutter", "1",
            "--strategy", "random"]
    assert main(argv) == 0
    kinds = json.loads((out / "runtime.json").read_text())["episode"]["kinds"]
    assert kinds == ["touch", "touch"]  # the default target is a transparent wineglass
    assert [b for b in bars if b[0] == "explore"] == [("explore", 2, 2)]
    declutter = [b for b in bars if b[0] == "declutter"]  # closed when the exploration starts
    n_declutter = len(json.loads((out / "runtime.json").read_text())["declutter_actions"])
    assert declutter == [("declutter", n_declutter, 1)]


def test_explore_progress_follows_the_episode_total():
    bar = tqdm.tqdm(total=20, file=io.StringIO())
    update = runtime_cli._explore_progress(bar)
    for i in range(1, 24):  # an opaque target: 20 touches + 3 views
        update(i, 23)
    assert (bar.n, bar.total) == (23, 23)
    bar.close()


def test_bench_declutter_writes_its_figure_beside_the_json_or_at_figure(tmp_path, capsys):
    argv = ["bench", "declutter", "--scenes", "1", "--clutter", "1", "--policies", "graph",
            "--max-actions", "2"]
    js = tmp_path / "d.json"
    assert main([*argv, "--json", str(js)]) == 0
    r = json.loads(js.read_text())
    assert r["figure"] == str(tmp_path / "d.png") and (tmp_path / "d.png").stat().st_size > 10_000
    assert r["settings"]["max_actions"] == 2
    assert f"wrote {js} and {tmp_path / 'd.png'}" in capsys.readouterr().out
    js2, fig = tmp_path / "e.json", tmp_path / "figs" / "declutter.png"
    assert main([*argv, "--json", str(js2), "--figure", str(fig)]) == 0
    assert json.loads(js2.read_text())["figure"] == str(fig) and fig.stat().st_size > 10_000
    assert not (tmp_path / "e.png").exists()
    capsys.readouterr()
    # a figure path that cannot be written is refused before any scene is built
    assert main([*argv, "--json", str(tmp_path / "f.json"), "--figure", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith(f"vtlearn: error: --figure: {tmp_path} is a folder")
    assert not (tmp_path / "f.json").exists()
