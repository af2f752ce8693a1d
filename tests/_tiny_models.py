"""Tiny ACTOR architectures shared by the ACTOR tests, and the tiny xAVTNet bench config of the bench tests
(not a test module: pytest collects only test_*.py).

The thesis model (encoder 64-64-128-1024, FC 1024, 2048 output points) takes seconds per step on a CPU;
these keep the same layer structure at a size that trains in milliseconds.
"""

# 64 output points: the models of test_actor, test_actor_recognition and test_best_metric_resume.
TINY_ACTOR = dict(
    num_points=64,
    encoder_channels=(8, 8, 16, 32),
    fc_channels=32,
    deconv_channels=(16, 16, 8, 8),
    deconv_strides=(2, 2, 2, 2, 4),
    emd_points=32,
)

# 256 output points (strides 2, 2, 4, 4, 4), otherwise TINY_ACTOR: the checkpoints of test_actor_cli, whose
# `vtlearn reconstruct` test meshes the reconstruction by ball pivoting (and of test_cli_errors_data).
TINY_ACTOR_256 = {**TINY_ACTOR, "num_points": 256, "deconv_strides": (2, 2, 4, 4, 4)}


def cli_args(init_args: dict) -> list[str]:
    """``--model.init_args.KEY=VALUE`` flags of LightningCLI for ``init_args`` (tuples as ``[a,b]`` lists)."""

    def text(v) -> str:
        return "[" + ",".join(str(x) for x in v) + "]" if isinstance(v, (tuple, list)) else str(v)

    return [f"--model.init_args.{k}={text(v)}" for k, v in init_args.items()]


def tiny_xavtnet_config(tmp_path, data_dir, active=False):
    """A LightningCLI-style config of a tiny xAVTNet on ``data_dir`` for `vtlearn bench crossmodal` (and,
    with ``active``, `bench active-learning`), written to ``tmp_path/cfg.yaml``; returns its path."""
    import yaml

    cfg = {
        "model": {"class_path": "vtlearn.models.xavtnet.XAVTNet",
                  "init_args": {"global_dim": 32, "fc_dims": [16, 8], "max_points": 64}},
        "data": {"init_args": {"data_dir": str(data_dir), "batch_size": 4}},
        "trainer": {"max_epochs": 1},
    }
    if active:
        cfg["data"]["init_args"]["modality"] = "visual"
        cfg["active"] = {"strategies": "entropy,random", "n0": 3, "kappa": 2, "rounds": 1, "mc_passes": 2}
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path
