"""configs/{quick,cpu,gpu}/actor*.yaml through train.py (LightningCLI): fit, resume with
--ckpt_path last, test, and the recognition config on the resulting checkpoint. Tiny dataset and tiny
layer sizes."""

import os
import sys
from pathlib import Path

os.environ.setdefault("WANDB_MODE", "disabled")

import pytest
import torch
from _tiny_models import TINY_ACTOR, cli_args

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

torch.set_num_threads(1)

TINY_ARGS = cli_args(TINY_ACTOR)  # ["--model.init_args.num_points=64", ...]


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    from vtlearn.sim_data.fixtures import make_tiny_dataset

    return str(make_tiny_dataset("reconstruction", tmp_path_factory.mktemp("data")))


def _common(data: str) -> list[str]:
    # the configs' runs/... paths are relative, so with the working directory in tmp_path every
    # checkpoint and log lands there
    return [
        f"--data.init_args.data_dir={data}",
        "--data.init_args.batch_size=3",
        "--trainer.enable_progress_bar=false",
        "--trainer.check_val_every_n_epoch=1",  # configs/cpu validate every 3rd epoch
    ]


RUN_DIRS = {
    "configs/quick/actor.yaml": "runs/actor_quick",
    "configs/quick/actor_noattn.yaml": "runs/actor_quick_noattn",
    "configs/cpu/actor.yaml": "runs/actor_cpu",
    "configs/cpu/actor_noattn.yaml": "runs/actor_cpu_noattn",
    "configs/gpu/actor.yaml": "runs/actor_gpu",
}


def _device(config: str) -> list[str]:
    """configs/gpu name the GPU; the tests run them on the CPU."""
    return ["--trainer.accelerator=cpu"] if "/gpu/" in config else []


@pytest.mark.parametrize(
    "config",
    [
        "configs/quick/actor.yaml",
        pytest.param("configs/quick/actor_noattn.yaml", marks=pytest.mark.slow),
        "configs/cpu/actor.yaml",  # cosine schedule + tactile_fraction through the CLI
        pytest.param("configs/cpu/actor_noattn.yaml", marks=pytest.mark.slow),
        "configs/gpu/actor.yaml",  # thesis hyper-parameters, checkpoints every 5th epoch, max_time
    ],
)
def test_quick_actor_config_fit_resume_test(config, tiny_data, tmp_path, monkeypatch):
    from train import cli_main

    monkeypatch.chdir(tmp_path)
    ckpt_dir = tmp_path / RUN_DIRS[config] / "checkpoints"
    base = _common(tiny_data) + TINY_ARGS + _device(config)
    cli_main(["fit", f"--config={ROOT / config}", "--trainer.max_epochs=1", *base])
    last = ckpt_dir / "last.ckpt"
    assert last.is_file() and list(ckpt_dir.glob("best-*.ckpt"))
    # the state after the last step: saved at that epoch's end, or at the end of training by the
    # configs that checkpoint only every few epochs (configs/gpu)
    assert torch.load(last, map_location="cpu", weights_only=True)["global_step"] == 1
    cli = cli_main(["fit", f"--config={ROOT / config}", "--trainer.max_epochs=2", "--ckpt_path=last", *base])
    assert cli.trainer.current_epoch == 2 and cli.trainer.global_step == 2  # resumed: one more step only
    assert torch.load(last, map_location="cpu", weights_only=True)["global_step"] == 2
    cli = cli_main(["test", f"--config={ROOT / config}", f"--ckpt_path={last}", *base])
    assert "test/cd_mm" in cli.trainer.callback_metrics
    assert cli.model.hparams.attention == ("noattn" not in config)
    cli = cli_main(["validate", f"--config={ROOT / config}", f"--ckpt_path={last}", *base])
    assert "val/cd_mm" in cli.trainer.callback_metrics
    cli = cli_main(["predict", f"--config={ROOT / config}", f"--ckpt_path={last}", *base])
    preds = cli.trainer.predict_loop.predictions
    assert len(preds) > 0 and preds[0].shape[1:] == (64, 3)  # dense reconstructions of the test clouds


@pytest.mark.slow  # the recognition module itself is covered by tests/test_actor_recognition.py
@pytest.mark.parametrize("kind", ["quick", "cpu", "gpu"])
def test_recognition_config(kind, tiny_data, tmp_path, monkeypatch):
    from train import cli_main

    monkeypatch.chdir(tmp_path)
    actor_dir = RUN_DIRS[f"configs/{kind}/actor.yaml"]
    cli_main(
        [
            "fit",
            f"--config={ROOT / f'configs/{kind}/actor.yaml'}",
            "--trainer.max_epochs=1",
            *_common(tiny_data),
            *TINY_ARGS,
            *_device(f"configs/{kind}/"),
        ]
    )
    assert (tmp_path / actor_dir / "checkpoints/last.ckpt").is_file()  # the recognition config's actor_ckpt
    rec_dir = tmp_path / {"quick": "runs/actor_recognition_quick", "cpu": "runs/actor_cpu_recognition",
                          "gpu": "runs/actor_gpu_recognition"}[kind]
    cli = cli_main(
        [
            "fit",
            f"--config={ROOT / f'configs/{kind}/actor_recognition.yaml'}",
            "--trainer.max_epochs=1",
            "--model.init_args.num_classes=3",
            *_common(tiny_data),
            *_device(f"configs/{kind}/"),
        ]
    )
    assert "val/acc" in cli.trainer.callback_metrics
    from vtlearn.models.actor_recognition import load_recognition

    assert load_recognition(rec_dir / "checkpoints/last.ckpt").hparams.num_classes == 3


def test_thesis_config_logs_csv_and_honours_wandb_disabled(tiny_data, tmp_path, monkeypatch):
    """configs/actor.yaml logs to wandb and CSV together; with WANDB_MODE=disabled no wandb run is written
    (Lightning's offline flag used to overwrite the mode with "dryrun") and the CSV metrics still are."""
    from train import cli_main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("WANDB_MODE", "disabled")
    cli_main(["fit", f"--config={ROOT / 'configs/actor.yaml'}", "--trainer.max_epochs=1",
              "--data.init_args.num_workers=0", "--trainer.accelerator=cpu", *_common(tiny_data), *TINY_ARGS])
    assert os.environ["WANDB_MODE"] == "disabled"
    assert list((tmp_path / "runs/actor/csv").rglob("metrics.csv"))
    assert not (tmp_path / "runs/actor/wandb").exists()
    assert (tmp_path / "runs/actor/checkpoints/last.ckpt").is_file()
