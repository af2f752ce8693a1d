"""Checkpoint inference with xAVTNet: recognise clouds from a robot or from files, with the MC-dropout
uncertainty of thesis ch.7, Sec. 7.2.2 (eq. 7.3-7.4) and the confidence stop of Sec. 7.2.4 (ζ = 0.8).

**Input frame.** xAVTNet is trained on clouds in the canonical frame of each object's bounding box
(:class:`~vtlearn.datamodules.CrossModalDataModule`, ``units="canonical"``): z up (gravity), centred on the
axis-aligned box and divided by its largest extent, then (by default) centred on the centroid
(``normalize="center"``). Yaw is free, since training rotates every cloud about z. :func:`canonical_cloud`
brings a cloud in metres (any gravity-aligned frame, z up) there. The scale is the object's largest
bounding-box extent ``extent_m``, e.g. from the camera's box of the object, or the gripper opening. Without
it the cloud's own extent is used: exact for a dense view, an underestimate for a few touches, so pass
``extent_m`` when it is known. A model trained with ``units="metres"`` takes the cloud as it is
(``units="metres"`` here).

A checkpoint records the normalisation it was trained with (``XAVTNet(input_normalize=...)``, older ones:
``"center"``), and :func:`recognize_clouds` applies the same one. With ``"none"`` (the object frame,
``configs/cpu/xavtnet_object_frame.yaml``) the network reads where on the object each point lies, so a cloud
in metres needs the object's box itself (``box_m``: its lower and upper corners, from the camera's
segmentation or from the box the touches were planned on), not the cloud's own box.

**Uncertainty.** With ``mc_samples = T > 0`` the class probability is the mean of ``T`` stochastic passes
with dropout on and batch norm in eval mode (eq. 7.3). The uncertainty is the entropy of that mean
(eq. 7.4). The mutual information between the prediction and the weights (BALD, Houlsby et al. 2011) is
reported beside it: the part of the entropy that more training data, not more touches of this object,
would remove. With ``T = 0`` there is one deterministic pass and no mutual information.

Shapes:
    clouds: list of ``(N_i, 3)`` -> :class:`Recognition` with ``probs (B, C)``, ``entropy (B,)``,
    ``mutual_information (B,)`` or ``None``, ``std (B, C)`` or ``None``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vtlearn.geometry.transforms import canonical_box
from vtlearn.validation import as_points

__all__ = [
    "UNITS",
    "ZETA",
    "Recognition",
    "canonical_cloud",
    "checkpoint_class_names",
    "checkpoint_normalize",
    "recognize_clouds",
    "recognition_figure",
]

UNITS = ("metres", "canonical")
ZETA = 0.8  # thesis 7.2.4: stop touching once the top class probability exceeds ζ


def canonical_cloud(
    points, extent_m: float | None = None, units: str = "metres", name: str = "points", box_m=None
):
    """A gravity-aligned cloud (z up) in the network's input frame (module docstring).

    Args:
        points: the cloud, in metres for ``units="metres"``, already canonical for ``"canonical"``.
        extent_m: the object's largest axis-aligned bounding-box extent in metres; ``None``: the cloud's own.
        units: the units the checkpoint was trained on (``CrossModalDataModule(units=...)``). ``"metres"``
            returns the points centred on their bounding box and unscaled.
        name: the argument name for error messages.
        box_m: the object's axis-aligned bounding box in metres, ``[[x, y, z]_lo, [x, y, z]_hi]``: the cloud
            is centred on it and divided by its largest extent (the frame of the simulated datasets,
            :meth:`vtlearn.active.closed_loop.SimObject.to_canonical`). Only with ``units="metres"`` and
            without ``extent_m`` (the box has the extent).

    Shapes:
        points ``(N, 3)``, box_m ``(2, 3)`` -> ``(N, 3)``, centred on the bounding box (the object's with
        ``box_m``, else the cloud's).
    """
    if units not in UNITS:
        raise ValueError(f"units: expected one of {UNITS}, got {units!r}")
    pts = as_points(points, name, min_points=3)
    if box_m is not None:
        if units != "metres":
            raise ValueError("box_m: only for units='metres'; canonical clouds are in the box frame already")
        if extent_m is not None:
            raise ValueError("extent_m: give extent_m or box_m, not both (the box has the extent)")
        lo, hi = _check_box(box_m, "box_m")
        return (pts - (lo + hi) / 2) / float((hi - lo).max())
    if units == "canonical":
        return pts - (pts.min(0) + pts.max(0)) / 2
    centre, scale = canonical_box(pts, extent_m, name)
    return (pts - centre) / scale


def _check_box(box, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` of an axis-aligned box given as ``(2, 3)``, or a ValueError naming ``name``."""
    try:
        b = np.asarray(box, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a (2, 3) box [lo, hi] in metres, got {box!r}") from None
    if b.shape != (2, 3):
        raise ValueError(f"{name}: expected a (2, 3) box [lo, hi] in metres, got shape {b.shape}")
    if not np.isfinite(b).all():
        raise ValueError(f"{name}: the box has NaN or infinite corners: {b.tolist()}")
    if (b[1] < b[0]).any() or float((b[1] - b[0]).max()) <= 1e-9:
        raise ValueError(f"{name}: need lo <= hi on every axis and a positive extent, got {b.tolist()}")
    return b[0], b[1]


def _one_per_cloud(value, n: int, name: str, what: str, shared: bool) -> list:
    """``value`` for each of ``n`` clouds: repeated when it is ``shared`` by all, else its own list, which
    must hold one entry per cloud (a ValueError naming ``name`` otherwise)."""
    if shared:
        return [value] * n
    values = list(value)
    if len(values) != n:
        raise ValueError(f"{name}: {len(values)} {what} for {n} clouds")
    return values


def checkpoint_normalize(hparams: dict) -> str:
    """The per-cloud normalisation a checkpoint was trained with (``XAVTNet(input_normalize=...)``);
    ``"center"`` for checkpoints that predate the record (every one of them was trained so)."""
    return str(hparams.get("input_normalize") or "center")


def checkpoint_class_names(hparams: dict, override: Sequence[str] | None = None) -> list[str]:
    """Class names for a checkpoint: ``override`` if given, else the names the checkpoint recorded (models
    trained since the names were kept), else ``class_0 ... class_{C-1}``. A ValueError if ``override``
    has the wrong length, or if ``hparams`` is not a checkpoint's hyper-parameters (``dict(model.hparams)``,
    or ``torch.load(...)["hyper_parameters"]``; a checkpoint path goes through ``load_xavtnet`` first)."""
    if not isinstance(hparams, Mapping) or "num_classes" not in hparams:
        got = type(hparams).__name__ if not isinstance(hparams, Mapping) else f"keys {sorted(hparams)[:8]}"
        raise ValueError(f"hparams: need a checkpoint's hyper-parameters with num_classes "
                         f"(dict(model.hparams)), got {got}")
    n = int(hparams["num_classes"])
    if override is not None:
        names = [str(s) for s in override]
        if len(names) != n:
            raise ValueError(f"class_names: {len(names)} names {names} for a classifier of {n} classes")
        return names
    recorded = hparams.get("class_names")
    if recorded:
        return [str(s) for s in recorded]
    return [f"class_{i}" for i in range(n)]


@dataclass
class Recognition:
    """xAVTNet's belief about each cloud (module docstring)."""

    class_names: list[str]
    probs: np.ndarray  # (B, C) mean class probability (eq. 7.3; one pass when mc_samples == 0)
    entropy: np.ndarray  # (B,) nats (eq. 7.4)
    mutual_information: np.ndarray | None  # (B,) nats, BALD; None without MC dropout
    std: np.ndarray | None  # (B, C) std of the probability over the passes; None without MC dropout
    mc_samples: int

    def predicted(self, i: int) -> str:
        """The name of cloud ``i``'s most probable class."""
        return self.class_names[int(np.argmax(self.probs[i]))]

    def confident(self, i: int, zeta: float = ZETA) -> bool:
        """The thesis's stop rule (7.2.4): the top class probability exceeds ζ."""
        return bool(self.probs[i].max() > zeta)

    def top(self, i: int, k: int = 3) -> list[tuple[str, float]]:
        """Cloud ``i``'s ``k`` most probable classes as ``(name, probability)``, most probable first."""
        order = np.argsort(-self.probs[i])[: max(int(k), 1)]
        return [(self.class_names[j], float(self.probs[i, j])) for j in order]

    def to_dict(self, i: int, zeta: float = ZETA) -> dict:
        """Cloud ``i``'s belief as plain JSON-ready values: the predicted class and its probability, the stop
        rule at ``zeta``, the entropy, every class's probability and, with MC dropout, the mutual
        information and the probabilities' std."""
        out = {
            "predicted": self.predicted(i),
            "probability": float(self.probs[i].max()),
            "confident": self.confident(i, zeta),
            "zeta": float(zeta),
            "entropy_nats": float(self.entropy[i]),
            "class_probabilities": dict(zip(self.class_names, map(float, self.probs[i]), strict=True)),
            "mc_samples": int(self.mc_samples),
        }
        if self.mutual_information is not None:
            out["mutual_information_nats"] = float(self.mutual_information[i])
            out["class_probability_std"] = dict(zip(self.class_names, map(float, self.std[i]), strict=True))
        return out


def recognize_clouds(
    model,
    clouds: Sequence,
    *,
    class_names: Sequence[str] | None = None,
    extent_m: float | Sequence[float | None] | None = None,
    units: str = "metres",
    mc_samples: int = 0,
    domain: str = "target",
    seed: int = 0,
    box_m=None,
) -> Recognition:
    """Class probabilities and uncertainty of ``clouds`` under an xAVTNet ``model`` (module docstring).

    Args:
        model: :class:`~vtlearn.models.xavtnet.XAVTNet`, e.g. from
            :func:`~vtlearn.models.xavtnet.load_xavtnet` (``weights_only=True``); another model (e.g. an
            ACTOR) is a ValueError.
        clouds: a list of gravity-aligned clouds (z up), at least 3 points each.
        class_names: names of the classes; default from the checkpoint (:func:`checkpoint_class_names`).
        extent_m: the objects' largest bounding-box extents in metres, one for all or one per cloud
            (``None`` entries: the cloud's own extent).
        units: the units the model was trained on, see :func:`canonical_cloud`.
        mc_samples: ``T`` stochastic passes with dropout on (eq. 7.3), an int; 0 for one deterministic pass.
        domain: batch-norm statistics of a ``domain_bn`` model: ``"target"`` (tactile clouds) or
            ``"source"`` (visual clouds). Ignored by other models.
        seed: the dropout masks of the MC passes.
        box_m: the objects' bounding boxes in metres, one ``(2, 3)`` ``[lo, hi]`` for all clouds or a list
            of one per cloud (:func:`canonical_cloud`). Needed by a checkpoint trained in the object frame
            (``input_normalize="none"``) on clouds in metres; with ``"center"`` it only fixes the scale.

    Shapes:
        clouds: list of ``(N_i, 3)``, box_m ``(2, 3)`` or ``[(2, 3)] * B`` -> probs ``(B, C)``, entropy
        ``(B,)``, mutual information ``(B,)``.
    """
    import torch

    from vtlearn.active.mc_dropout import bald_score, mc_dropout_probs, predictive_entropy
    from vtlearn.datamodules.shards import normalize_cloud
    from vtlearn.geometry.sampling import pad_clouds
    from vtlearn.models.xavtnet import XAVTNet
    from vtlearn.validation import as_int

    if not isinstance(model, XAVTNet):
        raise ValueError(
            f"model: expected an XAVTNet (e.g. from load_xavtnet), got {type(model).__name__}"
        )
    if hasattr(clouds, "shape") and len(clouds.shape) == 2:  # one numpy array or torch tensor
        raise ValueError("clouds: expected a list of (N, 3) clouds, got a single array; wrap it in a list")
    if clouds is None or isinstance(clouds, (str, bytes, dict)):
        raise ValueError(f"clouds: expected a list of (N, 3) clouds, got {type(clouds).__name__}")
    try:
        clouds = list(clouds)
    except TypeError:
        raise ValueError(f"clouds: expected a list of (N, 3) clouds, got {type(clouds).__name__}") from None
    if not clouds:
        raise ValueError("clouds: empty list; need at least one cloud")
    try:
        mc_samples = as_int(mc_samples, "mc_samples", 0)
    except ValueError:
        raise ValueError(
            f"mc_samples: need an integer >= 0 (0: one deterministic pass), got {mc_samples!r}"
        ) from None
    n = len(clouds)
    extents = _one_per_cloud(extent_m, n, "extent_m", "extents", extent_m is None or np.isscalar(extent_m))
    boxes = _one_per_cloud(
        box_m, n, "box_m", "boxes", box_m is None or np.asarray(box_m, dtype=object).shape == (2, 3)
    )
    names = checkpoint_class_names(dict(model.hparams), class_names)
    mode = checkpoint_normalize(dict(model.hparams))
    if mode == "none" and units == "metres" and any(b is None for b in boxes):
        raise ValueError(
            "box_m: this checkpoint was trained in the object frame (input_normalize='none'), so a cloud "
            "in metres needs its object's bounding box [lo, hi], not the cloud's own"
        )
    canon = [
        canonical_cloud(c, e, units, name=f"clouds[{i}]", box_m=b)
        if mode != "none" or units == "metres"
        else as_points(c, f"clouds[{i}]", min_points=3)  # canonical clouds are in the object frame already
        for i, (c, e, b) in enumerate(zip(clouds, extents, boxes, strict=True))
    ]
    canon = [normalize_cloud(c, mode) for c in canon]  # as in training
    x, lengths = pad_clouds(canon)
    was_training = model.training
    bn = model.bn_domain(domain) if hasattr(model, "bn_domain") else contextlib.nullcontext()
    try:
        with bn, torch.no_grad(), torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(seed))
            passes = mc_dropout_probs(
                model, x, lengths, num_passes=max(int(mc_samples), 1), dropout=int(mc_samples) > 0
            )
    finally:
        model.train(was_training)
    mean = passes.mean(0)
    mi = std = None
    if int(mc_samples) > 0:
        mi = bald_score(passes).numpy().astype(np.float64)
        std = passes.std(0, unbiased=False).numpy().astype(np.float64)
    return Recognition(
        class_names=names,
        probs=mean.numpy().astype(np.float64),
        entropy=predictive_entropy(mean).numpy().astype(np.float64),
        mutual_information=mi,
        std=std,
        mc_samples=int(mc_samples),
    )


def recognition_figure(clouds: Sequence, labels: Sequence[str], result: Recognition, path, top: int = 5):
    """One row per cloud: the cloud from the side and from above, and its ``top`` class probabilities (error
    bars: std over the MC passes), the ζ line of the confidence stop. Saved to ``path``.

    Shapes:
        clouds: list of ``(N_i, 3)``; labels: one title per cloud.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vtlearn.bench_utils import save_figure

    n = len(clouds)
    fig, axes = plt.subplots(n, 3, figsize=(11, 3.0 * n), squeeze=False)
    for i, (c, label) in enumerate(zip(clouds, labels, strict=True)):
        c = np.asarray(c)
        for ax, (a, b, title) in zip(axes[i, :2], [(0, 2, "side (x-z)"), (0, 1, "top (x-y)")], strict=True):
            ax.scatter(c[:, a], c[:, b], s=6, c=c[:, 2], cmap="viridis")
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_title(f"{label}: {title}, {len(c)} points", fontsize=9)
            ax.tick_params(labelsize=7)
        ax = axes[i, 2]
        order = np.argsort(-result.probs[i])[: max(int(top), 1)][::-1]
        err = None if result.std is None else result.std[i, order]
        colors = ["tab:green" if result.confident(i) and j == order[-1] else "tab:blue" for j in order]
        ax.barh([result.class_names[j] for j in order], result.probs[i, order], xerr=err, color=colors)
        ax.axvline(ZETA, color="tab:red", ls="--", lw=1, label=f"ζ = {ZETA}")
        ax.set_xlim(0, 1)
        extra = "" if result.mutual_information is None else f", MI {result.mutual_information[i]:.2f}"
        ax.set_title(f"H {result.entropy[i]:.2f} nats{extra}", fontsize=9)
        ax.tick_params(labelsize=8)
        ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return save_figure(fig, Path(path))
