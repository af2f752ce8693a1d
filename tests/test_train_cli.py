"""train.py (LightningCLI) on bad input: a config it cannot parse, a --ckpt_path it cannot use, and
validate/test with --ckpt_path last before any training end in one line naming the argument, exit code 2;
and the quick xAVTNet config resumes from last.ckpt."""

import json
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
        text = capsys.readouterr().err
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
