"""The benches' journal of finished jobs (vtlearn.bench_journal): a bench stopped part-way goes on from the
jobs it finished when the same command runs again."""

from __future__ import annotations

import functools
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from _interrupt import CountedCalls

from tests._tiny_models import tiny_xavtnet_config
from vtlearn.bench_journal import JobJournal, JournalledJobs, job_key, journal_folder, source_digest


def test_journal_folder_sits_beside_the_json():
    assert journal_folder("runs/bench/cm.json").as_posix() == "runs/bench/cm.jobs"
    assert journal_folder("out/result").as_posix() == "out/result.jobs"


def test_job_key_is_canonical_and_tells_settings_apart():
    a = job_key("bench", ("noda", 0), {"lr": 1e-3, "layers": ("fc1", "fc2")})
    # dict order, tuples against lists and numpy scalars do not change the key
    assert a == job_key("bench", ["noda", np.int64(0)], {"layers": ["fc1", "fc2"], "lr": 1e-3})
    assert a != job_key("bench", ("noda", 1), {"lr": 1e-3, "layers": ("fc1", "fc2")})
    assert a != job_key("bench", ("noda", 0), {"lr": 2e-3, "layers": ("fc1", "fc2")})
    assert len(a) == 64 and int(a, 16) >= 0


def test_source_digest_follows_every_python_file_of_the_package(tmp_path, monkeypatch):
    """The job keys carry it, so that an edit to vtlearn under the same version trains again."""
    import vtlearn

    pkg = tmp_path / "vtlearn"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("x = 1\n")
    (pkg / "sub" / "a.py").write_text("y = 2\n")
    (pkg / "notes.txt").write_text("not code")
    monkeypatch.setattr(vtlearn, "__file__", str(pkg / "__init__.py"))
    first = source_digest()
    assert source_digest() == first and len(first) == 64
    (pkg / "notes.txt").write_text("other")  # not Python: no change
    assert source_digest() == first
    (pkg / "sub" / "a.py").write_text("y = 3\n")
    edited = source_digest()
    assert edited != first
    (pkg / "sub" / "a.py").rename(pkg / "sub" / "b.py")  # the same bytes under another name
    assert source_digest() not in (first, edited)
    (pkg / "sub" / "b.py").rename(pkg / "sub" / "a.py")
    assert source_digest() == edited


def test_source_digest_ignores_docstrings_comments_and_layout_but_not_code(tmp_path, monkeypatch):
    """An edit to a docstring, a comment or the layout keeps the kept jobs; one to what the code does,
    a string that is not a docstring included, does not."""
    import vtlearn

    pkg = tmp_path / "vtlearn"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    code = pkg / "m.py"
    monkeypatch.setattr(vtlearn, "__file__", str(pkg / "__init__.py"))

    def digest(text: str) -> str:
        code.write_text(text)
        return source_digest()

    base = digest('"""Module."""\n\nclass A:\n    """A."""\n\n    def f(self, x):\n        """f."""\n'
                  '        return x + 1  # one\n')
    same = ['"""Other words."""\nclass A:\n    """B."""\n    def f(self, x):\n        """g."""\n'
            '        # a comment\n        return (x\n                + 1)\n',
            'class A:\n    def f(self, x):\n        return x + 1\n']
    assert all(digest(t) == base for t in same)
    other = ['class A:\n    def f(self, x):\n        return x + 2\n',
             'class A:\n    def f(self, x):\n        "not first"\n        return x + 1\n        "x"\n',
             'class A:\n    def f(self, y):\n        return y + 1\n']
    digests = [digest(t) for t in other]
    assert base not in digests and len(set(digests)) == len(other)
    broken = digest("def f(:\n")  # not Python: counted by its bytes
    assert broken != base and digest("def f(:\n  ") != broken


def test_journal_round_trip_keeps_nan_numpy_values_and_arrays(tmp_path):
    journal = JobJournal(tmp_path / "j")
    feats = np.arange(12, dtype=np.float32).reshape(3, 4)
    k1, k2 = job_key(1), job_key(2)
    journal.add(k1, {"acc": np.float64(71.25), "ratio": float("nan"), "conf": np.eye(2, dtype=int)},
                {"features": feats, "labels": np.array([0, 1, 1])})
    journal.add(k2, [("full", 3), 0.5])
    journal.release()  # the folder is kept: it holds jobs
    done = JobJournal(tmp_path / "j").finished()
    assert set(done) == {k1, k2}
    result, arrays = done[k1]
    assert result["acc"] == 71.25 and math.isnan(result["ratio"]) and result["conf"] == [[1, 0], [0, 1]]
    assert arrays["features"].dtype == np.float32 and np.array_equal(arrays["features"], feats)
    assert arrays["labels"].tolist() == [0, 1, 1]
    assert done[k2] == ([["full", 3], 0.5], None)
    with pytest.raises(ValueError, match="object arrays"):  # files load with allow_pickle=False
        journal.add(job_key(3), {}, {"bad": np.array([{"a": 1}], dtype=object)})
    # a line whose key is not a job key (a path, say) is not read
    with open(tmp_path / "j" / "jobs.jsonl", "a") as fh:
        fh.write(json.dumps({"key": "../elsewhere", "result": 1, "arrays": None}) + "\n")
    journal.release()
    assert set(JobJournal(tmp_path / "j").finished()) == {k1, k2}


def test_journal_leaves_out_cut_lines_and_changed_arrays(tmp_path):
    folder = tmp_path / "j"
    journal = JobJournal(folder)
    whole, with_arrays, after = job_key("whole"), job_key("arrays"), job_key("after")
    journal.add(whole, {"acc": 1.0})
    journal.add(with_arrays, {"acc": 2.0}, {"x": np.ones(3)})
    assert set(journal.finished()) == {whole, with_arrays}
    with open(folder / "jobs.jsonl", "a") as fh:  # a kill in the middle of a line
        fh.write('{"key": "cut", "result": {"acc"')
    assert set(journal.finished()) == {whole, with_arrays}
    npz = folder / f"{with_arrays}.npz"
    data = bytearray(npz.read_bytes())  # the arrays changed after their line was written
    data[-30] ^= 0xFF
    npz.write_bytes(bytes(data))
    assert set(journal.finished()) == {whole}
    npz.unlink()
    assert set(journal.finished()) == {whole}
    # a line appended after a cut one is read: the next run's jobs are not lost behind it
    journal.add(after, {"acc": 3.0})
    journal.release()
    reread = JobJournal(folder)
    assert set(reread.finished()) == {whole, after}
    reread.release()
    emptied = JobJournal(folder, fresh=True)
    assert emptied.finished() == {} and [p.name for p in folder.iterdir()] == ["lock"]
    emptied.release()  # a folder that holds no job goes with the lock
    assert not folder.exists()


def test_journal_folder_that_is_a_file_is_refused(tmp_path):
    (tmp_path / "cm.jobs").write_text("x")
    with pytest.raises(ValueError, match=r"--json: .*cm.jobs, which is a file"):
        JobJournal(journal_folder(tmp_path / "cm.json"))


def _job(x, progress=None, calls=None):
    calls.append(x)
    if x == "stop":
        raise KeyboardInterrupt
    return {"x": x, "square": len(x) ** 2}


def test_journalled_jobs_keep_what_finished_and_run_only_the_rest(tmp_path, capsys):
    folder = tmp_path / "j"
    keys = [job_key(x) for x in ("a", "bb", "ccc")]
    encode, decode = (lambda r: (r, None)), (lambda stored, arrays: stored)

    calls: list[str] = []
    fn = functools.partial(_job, calls=calls)
    with pytest.raises(KeyboardInterrupt):  # the Ctrl-C reaches the third job
        with JournalledJobs("bench toy", JobJournal(folder), keys, fn, [("a",), ("bb",), ("stop",)], 1,
                            encode, decode) as jobs:
            seen = [r["x"] for r in jobs]
    assert calls == ["a", "bb", "stop"]
    assert capsys.readouterr().err == ("bench toy: 2 of 3 jobs are kept in "
                                       f"{folder}; the same command goes on from there\n")

    calls.clear()
    reused: list[dict] = []
    journal = JobJournal(folder)
    with JournalledJobs("bench toy", journal, keys, fn, [("a",), ("bb",), ("ccc",)], 1, encode, decode,
                        on_reused=reused.append) as jobs:
        seen = [r["x"] for r in jobs]
    assert calls == ["ccc"] and seen == ["a", "bb", "ccc"] and [r["x"] for r in reused] == ["a", "bb"]
    assert capsys.readouterr().out == f"bench toy: 2 of 3 jobs finished earlier are reused from {folder} " \
                                      "(--fresh runs them again)\n"
    # a second bench on the same folder while the first holds it is refused, naming --json
    with pytest.raises(ValueError, match=r"^--json: another bench writing the same --json is running"):
        JobJournal(folder)
    journal.release()
    # other settings: nothing is reused, and the line says the folder holds jobs of other settings
    calls.clear()
    with JournalledJobs("bench toy", JobJournal(folder), [job_key("other")], fn, [("d",)], 1, encode,
                        decode) as jobs:
        assert [r["x"] for r in jobs] == ["d"]
    assert calls == ["d"] and "holds 3 finished jobs of other settings; none is reused" in \
        capsys.readouterr().out
    jobs.journal.release()
    refused = JobJournal(folder)
    with pytest.raises(ValueError, match="keys: need one unique key per job"):
        JournalledJobs("bench toy", refused, [keys[0], keys[0]], fn, [("a",), ("b",)], 1, encode, decode)
    JobJournal(folder).release()  # the refusal let the lock go
    with pytest.raises(ValueError, match="--workers: need >= 1"):
        JournalledJobs("bench toy", JobJournal(tmp_path / "new"), keys, fn, [("a",), ("bb",), ("c",)], 0,
                       encode, decode)
    assert not (tmp_path / "new").exists()  # nor is an empty folder left behind


def _stateful_job(x, progress=None, state_dir=None, calls=None):
    """A job in two steps that keeps the first in ``state_dir``; ``x == "stop"`` is stopped after it."""
    calls.append((x, state_dir.name))
    step = state_dir / "step1"
    if not step.is_file():
        state_dir.mkdir(parents=True, exist_ok=True)
        step.write_text(x.upper())
        if x == "stop":
            raise KeyboardInterrupt
    return {"x": x, "first": step.read_text()}


def test_journalled_jobs_hand_an_unfinished_job_its_kept_state(tmp_path, capsys):
    folder = tmp_path / "j"
    keys = [job_key("a"), job_key("stop")]
    encode, decode = (lambda r: (r, None)), (lambda stored, arrays: stored)
    calls: list[tuple] = []
    fn = functools.partial(_stateful_job, calls=calls)
    with pytest.raises(KeyboardInterrupt):
        with JournalledJobs("bench toy", JobJournal(folder), keys, fn, [("a",), ("stop",)], 1, encode, decode,
                            partial=True) as jobs:
            list(jobs)
    assert calls == [("a", f"{keys[0]}.partial"), ("stop", f"{keys[1]}.partial")]
    assert f"1 of 2 jobs are kept in {folder} with the state of 1 unfinished; the same command goes on" in \
        capsys.readouterr().err
    assert not (folder / f"{keys[0]}.partial").exists()  # a finished job's state goes with its line
    assert (folder / f"{keys[1]}.partial" / "step1").read_text() == "STOP"

    calls.clear()
    with JournalledJobs("bench toy", JobJournal(folder), keys, fn, [("a",), ("stop",)], 1, encode, decode,
                        partial=True) as jobs:
        assert [r["first"] for r in jobs] == ["A", "STOP"]
    assert calls == [("stop", f"{keys[1]}.partial")]  # went on from its first step: no second stop
    assert "1 unfinished jobs go on from the state they kept" in capsys.readouterr().out
    assert sorted(p.name for p in folder.iterdir()) == ["jobs.jsonl", "lock"]
    jobs.journal.discard()
    assert not folder.exists()


@pytest.fixture(scope="module")
def tiny_crossmodal(tmp_path_factory):
    from vtlearn.sim_data.fixtures import make_tiny_dataset

    return make_tiny_dataset("crossmodal", tmp_path_factory.mktemp("cross"))


def test_bench_crossmodal_stopped_by_ctrl_c_goes_on_from_its_finished_trainings(tmp_path, tiny_crossmodal,
                                                                                  monkeypatch, capsys):
    import vtlearn.models.xavtnet_cli as xcli
    from vtlearn.cli import main

    real = xcli._crossmodal_job
    cfg = tiny_xavtnet_config(tmp_path, tiny_crossmodal)
    argv = ["bench", "crossmodal", "--config", str(cfg), "--variants", "noda", "--seeds", "2"]
    monkeypatch.setattr(xcli, "_crossmodal_job", CountedCalls(real, stop_at=("noda", 1)))
    out = tmp_path / "a.json"
    assert main([*argv, "--json", str(out)]) == 130
    err = capsys.readouterr().err
    assert f"1 of 2 jobs are kept in {tmp_path / 'a.jobs'}" in err and not out.exists()
    shutil.copytree(tmp_path / "a.jobs", tmp_path / "b.jobs")  # the same stopped run, for --fresh below

    jobs = CountedCalls(real)
    monkeypatch.setattr(xcli, "_crossmodal_job", jobs)
    assert main([*argv, "--json", str(out)]) == 0
    assert jobs.seen == [("noda", 1)]  # seed 0 came from the journal
    assert "1 of 2 jobs finished earlier are reused" in capsys.readouterr().out
    resumed = json.loads(out.read_text())
    assert not (tmp_path / "a.jobs").exists()  # removed once the results and the figures are written
    # seed 0 was the t-SNE figure's job: its features came back from the journal's arrays
    assert (tmp_path / "a" / "tsne_before_after.png").is_file()

    jobs.seen.clear()
    assert main([*argv, "--json", str(tmp_path / "b.json"), "--fresh"]) == 0
    assert jobs.seen == [("noda", 0), ("noda", 1)]
    fresh = json.loads((tmp_path / "b.json").read_text())
    same = ("variant", "seed", "tactile_acc", "visual_acc", "confusion")
    assert [[r[k] for k in same] for r in resumed["runs"]] == [[r[k] for k in same] for r in fresh["runs"]]
    assert resumed["rows"] == fresh["rows"]


def test_bench_active_learning_stopped_by_ctrl_c_goes_on_from_its_finished_runs(tmp_path, tiny_crossmodal,
                                                                                 monkeypatch, capsys):
    import vtlearn.models.xavtnet_cli as xcli
    from vtlearn.cli import main

    real = xcli._active_learning_job
    cfg = tiny_xavtnet_config(tmp_path, tiny_crossmodal, active=True)
    out = tmp_path / "al.json"
    argv = ["bench", "active-learning", "--config", str(cfg), "--seeds", "1", "--json", str(out)]
    monkeypatch.setattr(xcli, "_active_learning_job", CountedCalls(real, stop_at=("random", 0)))
    assert main(argv) == 130
    assert "2 of 3 jobs are kept" in capsys.readouterr().err
    kept = {tuple(r[:2]): r[2] for r, _ in JobJournal(tmp_path / "al.jobs").finished().values()}
    assert set(kept) == {("full", 0), ("entropy", 0)}

    jobs = CountedCalls(real)
    monkeypatch.setattr(xcli, "_active_learning_job", jobs)
    assert main(argv) == 0
    assert jobs.seen == [("random", 0)] and not (tmp_path / "al.jobs").exists()
    res = json.loads(out.read_text())
    assert res["full_acc"] == [kept["full", 0]] and res["curves"]["entropy"]["runs"] == [kept["entropy", 0]]
    assert [h["n_labels"] for h in res["curves"]["random"]["runs"][0]] == [3, 5]


@pytest.mark.parametrize("damaged", [False, True])
def test_bench_active_learning_stopped_inside_a_loop_goes_on_from_its_last_round(tmp_path, tiny_crossmodal,
                                                                                  monkeypatch, capsys, caplog,
                                                                                  damaged):
    """A Ctrl-C in the second round of the entropy loop: the rerun trains that round and random's, not the
    entropy loop's first round again, and writes what an unstopped run writes. A kept loop state that
    cannot be read (``damaged``) is dropped with a warning and that loop trains again from its first round."""
    import vtlearn.active.learning_loop as loop_module
    from vtlearn.cli import main

    real = loop_module.train_and_test
    cfg = tiny_xavtnet_config(tmp_path, tiny_crossmodal, active=True)
    argv = ["bench", "active-learning", "--config", str(cfg), "--seeds", "1", "--rounds", "2", "--kappa", "1"]
    out = tmp_path / "al.json"
    # trainings: full 1, entropy 2-4, random 5-7; the third is the entropy loop's second round
    monkeypatch.setattr(loop_module, "train_and_test", CountedCalls(real, stop_at=3))
    assert main([*argv, "--json", str(out)]) == 130
    assert "1 of 3 jobs are kept" in capsys.readouterr().err
    (state,) = (tmp_path / "al.jobs").glob("*.partial/loop_state.npz")
    with np.load(state, allow_pickle=False) as z:
        assert z["round"].tolist() == [0] and len(z["queried"]) == z["queried_count"][0] > 0

    if damaged:
        state.write_bytes(b"not a zip")
    trainings = CountedCalls(real)
    monkeypatch.setattr(loop_module, "train_and_test", trainings)
    assert main([*argv, "--json", str(out)]) == 0
    if damaged:  # entropy's three rounds, random's three
        assert trainings.calls == 3 + 3 and not (tmp_path / "al.jobs").exists()
        assert re.search(r"the entropy loop of seed 0 trains again from its first round, as its kept state "
                         r"cannot be used: state_dir: cannot read .*loop_state\.npz", caplog.text)
    else:  # entropy's rounds 1 and 2, random's three
        assert trainings.calls == 2 + 3
        assert "1 unfinished jobs go on from the state they kept" in capsys.readouterr().out
    trainings.calls = 0
    assert main([*argv, "--json", str(tmp_path / "fresh.json")]) == 0
    assert trainings.calls == 1 + 3 + 3
    resumed, fresh = json.loads(out.read_text()), json.loads((tmp_path / "fresh.json").read_text())
    assert resumed["curves"] == fresh["curves"] and resumed["full_acc"] == fresh["full_acc"]
    assert [h["n_labels"] for h in resumed["curves"]["entropy"]["runs"][0]] == [3, 4, 5]


def test_bench_active_learning_keep_loops_goes_on_to_more_rounds_and_reads_fewer(tmp_path, tiny_crossmodal,
                                                                                monkeypatch, capsys):
    """``--keep-loops``: a 2-round bench keeps each loop's last state beside its JSON. The same command with
    1 round then trains nothing (the kept loops' first rounds and the kept reference), and with 3 rounds
    only each loop's third round; each writes what a fresh run of its rounds writes. ``--fresh`` lets the
    kept states go."""
    import vtlearn.active.learning_loop as loop_module
    from vtlearn.cli import main

    cfg = tiny_xavtnet_config(tmp_path, tiny_crossmodal, active=True)
    argv = ["bench", "active-learning", "--config", str(cfg), "--seeds", "1", "--kappa", "1", "--strategies",
            "entropy"]
    out, folder = tmp_path / "al.json", tmp_path / "al.jobs"
    trainings = CountedCalls(loop_module.train_and_test)
    monkeypatch.setattr(loop_module, "train_and_test", trainings)

    def run(rounds: int, *flags: str, json_path=out) -> dict:
        trainings.calls = 0
        assert main([*argv, "--rounds", str(rounds), *flags, "--json", str(json_path)]) == 0
        return json.loads(Path(json_path).read_text())

    run(2, "--keep-loops")
    assert trainings.calls == 1 + 3 and len(list(folder.glob("*.kept"))) == 1
    assert "kept the last state of 1 loop in" in capsys.readouterr().out

    for rounds, trained in ((1, 0), (3, 1)):  # the flag is not needed once the folder holds kept states
        kept = run(rounds)
        assert trainings.calls == trained, rounds
        assert "holds the last state of 1 loop of an earlier --keep-loops run" in capsys.readouterr().out
        fresh = run(rounds, json_path=tmp_path / f"fresh{rounds}.json")
        assert trainings.calls == 1 + rounds + 1
        assert kept["curves"] == fresh["curves"] and kept["full_acc"] == fresh["full_acc"]
        assert [h["n_labels"] for h in kept["curves"]["entropy"]["runs"][0]] == list(range(3, 4 + rounds))
        assert kept["curves"]["entropy"]["runs"][0][-1]["queried"] == []  # a last round queries nothing
    assert folder.is_dir() and not (tmp_path / "fresh1.jobs").exists()

    run(1, "--fresh")
    assert trainings.calls == 1 + 2 and not folder.exists()


def test_a_kept_state_takes_its_names_place_and_keeps_the_folder(tmp_path):
    journal = JobJournal(tmp_path / "b.jobs")
    for key, text in (("a" * 64, "first"), ("b" * 64, "second")):
        journal.partial_dir(key).mkdir()
        (journal.partial_dir(key) / "state").write_text(text)
        journal.add(key, text, keep_as="loop")
        assert (journal.kept_dir("loop") / "state").read_text() == text
        assert not journal.partial_dir(key).exists()
    assert journal.kept_states() == [journal.kept_dir("loop")] and not list(journal.folder.glob("*.old"))
    assert journal.finish() == [journal.kept_dir("loop")] and journal.folder.is_dir()
    plain = JobJournal(tmp_path / "c.jobs")
    plain.add("a" * 64, 1)
    assert plain.finish() == [] and not plain.folder.exists()
    for bad in ("", "..", "../elsewhere", "a/b"):  # a name reaching outside the folder
        with pytest.raises(ValueError, match="name: need a file name within the journal folder"):
            journal.kept_dir(bad)
        with pytest.raises(ValueError, match="key: need a file name within the journal folder"):
            journal.partial_dir(bad)
    with pytest.raises(ValueError, match="keep_as: need one name or None per job of a partial=True journal"):
        JournalledJobs("bench", JobJournal(tmp_path / "d.jobs"), ["a" * 64], print, [(1,)], 1,
                       lambda r: (r, None), lambda r, _: r, keep_as=["loop"])
