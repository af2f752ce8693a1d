"""Tiny ACTOR architectures shared by the ACTOR tests (not a test module: pytest collects only test_*.py).

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
