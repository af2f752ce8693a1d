"""train.py (LightningCLI) on bad input: a config it cannot parse, a --ckpt_path it cannot use, and
validate/test with --ckpt_path last before any training end in one line naming the argument, exit code 2;
and the quick xAVTNet config resumes from last.ckpt."""

import json
import os
import re
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
QUICK = f"--config={ROOT / 'configs/quick/xavtnet.yaml'}"
TINY = ["--model.init_args.global_dim=32", "--model.init_args.fc_dims=[16, 8]",
        "--data.init_args.batch_size=4", "--trainer.limit_train_batches=2", "--trainer.limit_val_batches=1",
        "--trainer.enable_progress_bar=false", "--trainer.enable_model_summary=false",
        "--trainer.logger=false"]


@pytest.fixture
def run(cross_dir, tmp_path, monkeypatch, capsys):
    """``run(subcommand, *args) -> (exit code, last stderr line)`` of ``train.main`` with the quick xAVTNet
    config on the tiny dataset, in ``tmp_path``."""
    monkeypatch.syspath_prepend(str(ROOT))
    monkeypatch.chdir(tmp_path)
    from train import main

    n = len(json.loads((Path(cross_dir) / "manifest.json").read_text())["class_names"])
    data = [f"--data.init_args.data_dir={cross_dir}", f"--model.init_args.num_classes={n}"]

    def call(sub, *args):
        capsys.readouterr()
        code = main([sub, QUICK, *data, *TINY, *args])
        captured = capsys.readouterr()
        call.out, text = captured.out, captured.err
        # a logging handler of an earlier call may still write to a stream capsys has closed since; its
        # "--- Logging error ---" report is pytest's artefact, not train.py's output
        text = re.sub(r"--- Logging error ---.*?\nArguments:[^\n]*\n", "", text, flags=re.S)
        err = [ln for ln in text.splitlines() if ln.strip()]
        assert not any("Traceback" in ln or ln.startswith("usage:") for ln in err), "\n".join(err)
        call.lines = err
        return code, (err[-1] if err else "")

    return call


def test_parse_errors_are_one_line(run):
    code, err = run("fit", "--model.init_args.dropout=abc")
    assert code == 2 and err.startswith("train.py: error: ") and 'Parser key "dropout"' in err
    code, err = run("fit", "--model.init_args.num_clases=3")
    assert code == 2 and "Option 'num_clases' is not accepted" in err
    code, err = run("fit", "--trainer.max_epochs=abc")  # the key sits in the header, not in an alternative
    assert (code, err) == (2, "train.py: error: trainer.max_epochs: Expected a <class 'int'> (got abc)")


def test_unusable_ckpt_path_is_named(run, tmp_path):
    code, err = run("validate", f"--ckpt_path={tmp_path / 'none.ckpt'}")
    assert (code, err) == (2, f"train.py: error: ckpt_path: no checkpoint file at {tmp_path / 'none.ckpt'}")
    (tmp_path / "bad.ckpt").write_bytes(b"\x80not a checkpoint")
    code, err = run("test", f"--ckpt_path={tmp_path / 'bad.ckpt'}")
    assert code == 2 and "ckpt_path: " in err and "is not a readable PyTorch checkpoint" in err
    assert "weights_only=False" not in err  # torch's advice to load untrusted pickles is not passed on
    other = {"state_dict": {"w": torch.ones(2)}, "hyper_parameters": {"num_points": 64}}  # not an XAVTNet's
    torch.save(other, tmp_path / "o.ckpt")
    code, err = run("validate", f"--ckpt_path={tmp_path / 'o.ckpt'}")
    assert code == 2 and "ckpt_path: the hyper-parameters of" in err
    assert "do not fit the config's model" in err


def test_last_before_training_is_refused_and_fit_resumes(run, tmp_path):
    ckpts = tmp_path / "runs" / "xavtnet_quick" / "checkpoints"
    for sub in ("validate", "test", "predict"):
        code, err = run(sub, "--ckpt_path=last")
        assert code == 2
        assert f"ckpt_path: 'last' found no last.ckpt in {ckpts}; {sub} would score untrained" in err
    assert run("fit", "--trainer.max_epochs=1") == (0, "")
    last = ckpts / "last.ckpt"
    assert f"train.py: checkpoints: last {last}" in run.out  # where the run's checkpoints are, said
    assert torch.load(last, weights_only=True)["epoch"] == 0
    assert run("fit", "--trainer.max_epochs=2", "--ckpt_path=last")[0] == 0
    assert torch.load(last, weights_only=True)["epoch"] == 1  # resumed: the second epoch, not a new first one
    assert run("validate", "--ckpt_path=last")[0] == 0
    # predict keeps what it computes: the class probabilities of the test tactile clouds, with their labels
    import numpy as np

    assert run("predict", "--ckpt_path=last")[0] == 0
    with np.load(ckpts.parent / "predictions.npz", allow_pickle=False) as out:  # no logger: the root folder
        probs, label, names = out["predictions"], out["label"], out["class_names"]
    assert probs.ndim == 2 and probs.shape == (len(label), len(names))
    np.testing.assert_allclose(probs.sum(1), 1.0, atol=1e-5)


def test_ctrl_c_during_fit_says_where_to_go_on_from_and_resumes(run, tmp_path, monkeypatch):
    """A Ctrl-C in the second epoch: Lightning shuts down and exits 1; train.py says which checkpoint holds
    the first epoch, ends with its interrupted line and 130, and ``--ckpt_path last`` goes on from there."""
    from vtlearn.models.xavtnet import XAVTNet

    step = XAVTNet.training_step

    def interrupted_in_epoch_1(self, batch, batch_idx):
        if self.current_epoch == 1:
            raise KeyboardInterrupt
        return step(self, batch, batch_idx)

    monkeypatch.setattr(XAVTNet, "training_step", interrupted_in_epoch_1)
    last = tmp_path / "runs" / "xavtnet_quick" / "checkpoints" / "last.ckpt"
    assert run("fit", "--trainer.max_epochs=3") == (130, "train.py: interrupted")
    assert f"train.py: stopped in epoch 1; the last checkpoint is {last}; fit --ckpt_path last goes on " \
        "from it" in run.lines
    assert torch.load(last, weights_only=True)["epoch"] == 0
    monkeypatch.setattr(XAVTNet, "training_step", step)
    assert run("fit", "--trainer.max_epochs=2", "--ckpt_path=last")[0] == 0
    assert torch.load(last, weights_only=True)["epoch"] == 1


def test_a_checkpoint_of_another_model_class_is_refused(run, tmp_path):
    """Lightning would build the checkpoint's class in place of the config's and fail deep in training."""
    other = {"state_dict": {"w": torch.ones(2)},
             "hyper_parameters": {"_class_path": "vtlearn.models.actor.ACTOR", "num_points": 64}}
    torch.save(other, tmp_path / "actor.ckpt")
    for sub in ("fit", "test"):
        code, err = run(sub, f"--ckpt_path={tmp_path / 'actor.ckpt'}")
        assert code == 2 and err.startswith(f"train.py: error: ckpt_path: {tmp_path / 'actor.ckpt'} is a "
                                            "checkpoint of vtlearn.models.actor.ACTOR; the config's model is "
                                            "vtlearn.models.xavtnet.XAVTNet")


def test_resuming_with_another_architecture_is_said_not_silent(run, tmp_path):
    """--ckpt_path last with a changed architecture is one line naming the setting (was a state-dict
    traceback); a checkpoint file's hyper-parameters replace the config's, and each replaced one is said
    (was silent); validate/test without a checkpoint say they run untrained weights."""
    assert run("fit", "--trainer.max_epochs=1")[0] == 0
    code, err = run("fit", "--trainer.max_epochs=2", "--ckpt_path=last", "--model.init_args.global_dim=64")
    assert code == 2 and "ckpt_path: last (" in err
    assert "does not fit the config's model: global_dim=32 there, 64 here; resume with the settings it was " \
        "trained with" in err
    last = tmp_path / "runs" / "xavtnet_quick" / "checkpoints" / "last.ckpt"
    # the learning rate lives in the optimizer state that fit restores: the checkpoint's applies, and is said
    trained_lr = torch.load(last, weights_only=True)["optimizer_states"][0]["param_groups"][0]["lr"]
    assert run("fit", "--trainer.max_epochs=2", "--ckpt_path=last", "--model.init_args.lr=0.05")[0] == 0
    assert (f"train.py: note: model.lr: {trained_lr!r} from the optimizer state resumed from {last} applies, "
            "not the config's 0.05 (the checkpoint records the config's)") in run.lines
    assert torch.load(last, weights_only=True)["optimizer_states"][0]["param_groups"][0]["lr"] == trained_lr
    code, _ = run("validate", f"--ckpt_path={last}", "--model.init_args.global_dim=64")
    assert code == 0
    assert (f"train.py: note: model.global_dim: 32 from {last} replaces the config's 64 (a checkpoint keeps "
            "the hyper-parameters it was trained with)") in run.lines
    assert run("test")[0] == 0
    assert any(ln.startswith("train.py: note: test without --ckpt_path runs the config's freshly initialised")
               for ln in run.lines)


def test_an_abbreviated_option_is_not_taken_for_the_full_one(run):
    code, err = run("fit", "--trainer.max_epoch=1")
    assert code == 2 and "--trainer.max_epoch" in err


CSV = ('--trainer.logger={"class_path": "lightning.pytorch.loggers.CSVLogger", '
       '"init_args": {"save_dir": "runs/log"}}')


def _rows(path: Path) -> list[dict]:
    import csv

    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_resumed_fit_logs_on_into_the_version_folder_it_resumes(run, tmp_path):
    """fit --ckpt_path last logs into the version folder of the run it resumes, the earlier rows kept (it
    started a new version_N, and Lightning's CSV writer deletes the metrics.csv of a folder it reuses); the
    newest version folder is not taken for it (here validate's)."""
    logs = tmp_path / "runs" / "log" / "lightning_logs"
    assert run("fit", "--trainer.max_epochs=1", CSV)[0] == 0
    assert run("validate", "--ckpt_path=last", CSV)[0] == 0  # its own version_1
    validated = (logs / "version_1" / "metrics.csv").read_text()
    assert run("fit", "--trainer.max_epochs=3", "--ckpt_path=last", CSV)[0] == 0
    assert sorted(p.name for p in logs.iterdir()) == ["version_0", "version_1"]
    rows = _rows(logs / "version_0" / "metrics.csv")
    assert sorted({int(r["epoch"]) for r in rows if r["val/acc"]}) == [0, 1, 2]
    assert sorted({int(r["epoch"]) for r in rows if r["train/loss"]}) == [0, 1, 2]
    assert (logs / "version_1" / "metrics.csv").read_text() == validated


def test_a_resumed_csv_log_keeps_its_rows_when_new_columns_come(tmp_path, monkeypatch):
    """The kept rows of a version folder and the resumed run's rows with a column they lack share one file;
    rows logged after the resumed checkpoint are not kept twice."""
    import lightning as L
    from lightning.pytorch.loggers import CSVLogger

    monkeypatch.syspath_prepend(str(ROOT))
    from train import LogVersions, _continue_versions

    folder = tmp_path / "log" / "version_3"
    folder.mkdir(parents=True)
    # epoch 1's row came after the checkpoint (global step 2) that the run resumes: epoch 1 is trained and
    # logged again, so its first row goes
    (folder / "metrics.csv").write_text("epoch,step,val/acc\n0,1,0.5\n1,3,0.625\n")
    logger = CSVLogger(tmp_path, name="log")
    trainer = L.Trainer(logger=logger, accelerator="cpu", enable_progress_bar=False)
    record = {"global_step": 2, LogVersions.key: {f"CSVLogger:{tmp_path / 'log'}": 3}}
    assert _continue_versions(trainer, record) == []
    logger.log_metrics({"epoch": 1, "val/acc": 0.75, "val/loss": 0.25}, step=3)
    logger.save()
    assert logger.log_dir == str(folder)
    assert _rows(folder / "metrics.csv") == [
        {"epoch": "0", "step": "1", "val/acc": "0.5", "val/loss": ""},
        {"epoch": "1", "step": "3", "val/acc": "0.75", "val/loss": "0.25"},
    ]
    # the dropped row is not lost: the file as it was stays beside it
    assert (folder / "metrics.before-step2.csv").read_text() == "epoch,step,val/acc\n0,1,0.5\n1,3,0.625\n"


def test_a_checkpoint_with_the_first_record_layout_still_continues_its_folder(tmp_path, monkeypatch):
    """The first checkpoints with log versions (2026-12-04) kept them as callback state, keyed by the root
    folder as given; they continue their folder, and train.py's callback still owns that state."""
    import lightning as L
    from lightning.pytorch.loggers import CSVLogger

    monkeypatch.syspath_prepend(str(ROOT))
    monkeypatch.chdir(tmp_path)
    from train import LogVersions, _continue_versions

    (tmp_path / "log" / "version_2").mkdir(parents=True)
    trainer = L.Trainer(logger=CSVLogger("log", name=""), accelerator="cpu", enable_progress_bar=False)
    old = {"global_step": 0, "callbacks": {"train.py:log_versions": {"versions": {"CSVLogger:log": 2}}}}
    assert _continue_versions(trainer, old) == []
    assert Path(trainer.logger.log_dir).resolve() == (tmp_path / "log" / "version_2").resolve()
    assert LogVersions().state_key == "train.py:log_versions"


def test_a_refused_run_leaves_nothing_on_disk(run, tmp_path, cross_dir):
    """A run the model's setup refuses (model and data disagree) wrote config.yaml into a new version
    folder, and over the run folder's config.yaml without a logger; a refused resume keeps the logs it would
    resume."""
    n = len(json.loads((Path(cross_dir) / "manifest.json").read_text())["class_names"])
    assert run("fit", "--trainer.max_epochs=1", CSV)[0] == 0
    assert run("fit", "--trainer.max_epochs=1")[0] == 0  # no logger: config.yaml in the run folder

    def snapshot():
        return {p: p.read_bytes() if p.is_file() else None for p in tmp_path.rglob("*")}

    before = snapshot()
    for logger in (CSV, "--trainer.logger=false"):
        code, err = run("fit", "--trainer.max_epochs=1", f"--model.init_args.num_classes={n + 2}", logger)
        assert code == 2 and err.startswith(f"train.py: error: datamodule: {n} classes")
    code, err = run("fit", "--trainer.max_epochs=2", "--ckpt_path=last", "--model.init_args.global_dim=64",
                    CSV)
    assert code == 2 and "does not fit the config's model" in err
    assert snapshot() == before


def test_a_refusal_comes_before_the_trainer_banner(cross_dir, tmp_path):
    """The --ckpt_path last checks run before the Trainer is built: its "GPU available: ..." lines no longer
    precede the refusal (they are Lightning's log records, so the command runs in its own process)."""
    import subprocess
    import sys

    n = len(json.loads((Path(cross_dir) / "manifest.json").read_text())["class_names"])
    cmd = [sys.executable, str(ROOT / "train.py"), "validate", QUICK,
           f"--data.init_args.data_dir={cross_dir}", f"--model.init_args.num_classes={n}", *TINY,
           "--ckpt_path=last"]
    out = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300,
                         env={**os.environ, "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"})
    assert out.returncode == 2
    err = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert err[-1].startswith("train.py: error: ckpt_path: 'last' found no last.ckpt in")
    assert not any("GPU available" in ln or "TPU available" in ln for ln in err), "\n".join(err)
    assert list(tmp_path.iterdir()) == []


EVERY_EPOCH = ["--trainer.callbacks.init_args.save_top_k=-1",
               "--trainer.callbacks.init_args.filename={epoch}"]  # epoch=0.ckpt, epoch=1.ckpt, ...


def test_fit_from_an_epoch_checkpoint_logs_on_into_its_version_folder(run, tmp_path):
    """fit --ckpt_path FILE, a checkpoint of an earlier epoch of the same run, continues that run's version
    folder like --ckpt_path last (it started a new version_N); metrics.csv drops the rows of the epochs it
    trains again, so each step is logged once. A checkpoint of another log folder starts a new version, and
    says so."""
    logs = tmp_path / "runs" / "log" / "lightning_logs"
    ckpts = tmp_path / "runs" / "xavtnet_quick" / "checkpoints"
    assert run("fit", "--trainer.max_epochs=3", CSV, *EVERY_EPOCH)[0] == 0
    first = _rows(logs / "version_0" / "metrics.csv")
    text_first = (logs / "version_0" / "metrics.csv").read_text()
    assert sorted({int(r["epoch"]) for r in first if r["val/acc"]}) == [0, 1, 2]
    epoch0 = ckpts / "epoch=0.ckpt"
    assert run("fit", "--trainer.max_epochs=3", f"--ckpt_path={epoch0}", CSV, *EVERY_EPOCH)[0] == 0
    assert not any("records no log version" in ln for ln in run.lines)
    assert sorted(p.name for p in logs.iterdir()) == ["version_0"]
    rows = _rows(logs / "version_0" / "metrics.csv")
    for key in ("val/acc", "train/loss"):
        logged = [(int(r["epoch"]), int(r["step"])) for r in rows if r[key]]
        assert sorted(e for e, _ in logged) == [0, 1, 2]  # each epoch once: the retrained ones replaced
        assert sorted(logged) == sorted((int(r["epoch"]), int(r["step"])) for r in first if r[key])
    assert rows[0] == first[0]  # epoch 0's rows, from before the checkpoint, kept as they were
    # the rows of the epochs trained again are not lost: the file as it was is kept beside the new one
    step = torch.load(epoch0, weights_only=True)["global_step"]
    copy = logs / "version_0" / f"metrics.before-step{step}.csv"
    assert copy.read_text() == text_first
    assert any(f"the file as it was is kept in {copy.name}" in ln for ln in run.lines)
    # a resume the model's setup refuses (model and data disagree) keeps every row, the later epochs' too,
    # and leaves no copy
    before = {p.name: p.read_text() for p in (logs / "version_0").glob("*.csv")}
    code, err = run("fit", "--trainer.max_epochs=3", f"--ckpt_path={epoch0}", CSV, *EVERY_EPOCH,
                    "--data.init_args.normalize=none")  # the checkpoint was trained on centred clouds
    assert code == 2 and err.startswith("train.py: error: input_normalize:"), err
    assert {p.name: p.read_text() for p in (logs / "version_0").glob("*.csv")} == before
    other = CSV.replace("runs/log", "runs/other")
    assert run("fit", "--trainer.max_epochs=2", f"--ckpt_path={epoch0}", other)[0] == 0
    root = Path("runs/other/lightning_logs")
    assert (f"train.py: note: {epoch0} records no log version for CSVLogger in {root} (it was written with "
            "another log folder); logging into a new version folder") in run.lines
    assert sorted(p.name for p in (tmp_path / root).iterdir()) == ["version_0"]
    assert sorted(p.name for p in logs.iterdir()) == ["version_0"]


def test_a_plain_trainer_resumes_a_train_py_checkpoint_without_a_callback_warning(run, tmp_path, cross_dir):
    """train.py's log-version record is a key of the checkpoint, not the state of a callback that a plain
    Lightning Trainer lacks: resuming with one no longer warns "callbacks used to create the checkpoint need
    to be provided ... ['train.py:log_versions']"; the record still loads with weights_only=True."""
    import warnings

    import lightning as L

    from train import LogVersions
    from vtlearn.datamodules import CrossModalDataModule
    from vtlearn.models.xavtnet import XAVTNet

    assert run("fit", "--trainer.max_epochs=1", CSV)[0] == 0
    last = tmp_path / "runs" / "xavtnet_quick" / "checkpoints" / "last.ckpt"
    n = len(json.loads((Path(cross_dir) / "manifest.json").read_text())["class_names"])
    model = XAVTNet(num_classes=n, global_dim=32, fc_dims=[16, 8], max_points=128)
    data = CrossModalDataModule(data_dir=cross_dir, batch_size=4, normalize="center")
    trainer = L.Trainer(max_epochs=2, limit_train_batches=2, limit_val_batches=1, logger=False,
                        accelerator="cpu", enable_progress_bar=False, enable_model_summary=False,
                        default_root_dir=tmp_path / "plain")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        trainer.fit(model, datamodule=data, ckpt_path=last)
    assert trainer.current_epoch == 2 and trainer.global_step == 4  # resumed: one more epoch of 2 batches
    said = [str(w.message) for w in caught if "callbacks used to create the checkpoint" in str(w.message)]
    assert said == []
    record = torch.load(last, weights_only=True)[LogVersions.key]
    assert record == {f"CSVLogger:{tmp_path / 'runs' / 'log' / 'lightning_logs'}": 0}


def _tensorboard_events(folder: Path) -> list:
    """The events of the TensorBoard event files in ``folder``, file after file in the order they were
    started (by name: the start second, then a resumed run's suffix), read from their TFRecord framing (a
    little-endian u64 length, its CRC, the Event proto, its CRC)."""
    import struct

    from tensorboardX.proto import event_pb2

    events = []
    for f in sorted(folder.glob("events.out.tfevents.*")):
        data, i = f.read_bytes(), 0
        while i < len(data):
            (n,) = struct.unpack("<Q", data[i:i + 8])
            events.append(event_pb2.Event.FromString(data[i + 12:i + 12 + n]))
            i += 12 + n + 4
    return events


def _scalar_steps(events: list, tag: str, purge: bool) -> list[int]:
    """The steps at which ``tag`` was logged; with ``purge``, as TensorBoard shows them: a SessionLog START
    at step s (a writer's ``purge_step``) hides the earlier events at steps >= s."""
    steps = []
    for e in events:
        if purge and e.HasField("session_log") and e.session_log.status == e.session_log.START:
            steps = [s for s in steps if s < e.step]
        if e.HasField("summary"):
            steps += [e.step for v in e.summary.value if v.tag == tag]
    return steps


def test_a_resumed_tensorboard_log_shows_each_step_once(run, tmp_path, monkeypatch):
    """fit --ckpt_path FILE with a TensorBoard logger continues the run's version folder, and its writer's
    purge_step is the checkpoint's global step: TensorBoard hides the events of the epochs trained again
    (they stay on disk), so each logged step shows once, as in metrics.csv. tensorboardX names an event file
    by the second and the host: both runs here start in the same second, and the resumed run's file does not
    overwrite the first's."""
    import types

    writer = pytest.importorskip("tensorboardX.event_file_writer")
    monkeypatch.setattr(writer, "time", types.SimpleNamespace(time=lambda: 1_800_000_000.25))
    tb = ('--trainer.logger={"class_path": "lightning.pytorch.loggers.TensorBoardLogger", '
          '"init_args": {"save_dir": "runs/tb"}}')
    logs = tmp_path / "runs" / "tb" / "lightning_logs"
    epoch0 = tmp_path / "runs" / "xavtnet_quick" / "checkpoints" / "epoch=0.ckpt"
    assert run("fit", "--trainer.max_epochs=3", tb, *EVERY_EPOCH)[0] == 0
    first = _scalar_steps(_tensorboard_events(logs / "version_0"), "val/acc", purge=True)
    assert len(first) == 3 and len(set(first)) == 3
    assert run("fit", "--trainer.max_epochs=3", f"--ckpt_path={epoch0}", tb, *EVERY_EPOCH)[0] == 0
    assert sorted(p.name for p in logs.iterdir()) == ["version_0"]
    events = _tensorboard_events(logs / "version_0")
    step = torch.load(epoch0, weights_only=True)["global_step"]
    starts = [e.step for e in events
              if e.HasField("session_log") and e.session_log.status == e.session_log.START]
    assert starts == [step]
    raw = _scalar_steps(events, "val/acc", purge=False)
    assert len(raw) == 5  # epochs 1 and 2 are on disk twice: the earlier run's events are kept
    assert len(list((logs / "version_0").glob(f"events.out.tfevents.*.resumed-step{step}"))) == 1
    assert sorted(_scalar_steps(events, "val/acc", purge=True)) == sorted(first)
