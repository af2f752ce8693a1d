"""``vtlearn bench crossmodal`` and ``vtlearn bench active-learning``: thesis ch.7 experiments in simulation.

* ``bench crossmodal``: the Table 7.2 / 7.4 analogue. Every domain-adaptation variant (no-DA, MMD,
  CORAL, VTLoss fc1, VTLoss fc2, VTLoss, and DANN beyond the thesis) is trained on labelled visual
  clouds + unlabelled tactile clouds and scored on labelled tactile test clouds, mean ± std over
  seeds. No target labels are used for model selection (a fixed epoch budget). It also writes the
  VTLoss confusion matrix (Table 7.3 analogue) and a t-SNE of source/target fc2 features before
  (no-DA) and after (VTLoss) adaptation (Fig. 7.4).
* ``bench active-learning``: the Fig. 7.5a / Table 7.1 analogue. Accuracy against labels for
  MC-dropout entropy (thesis), BALD and random queries, and the labels each needs to come within
  10/5/3/2 % relative error of a model trained on the whole pool.

Both read a LightningCLI-style YAML (``--config``) for the model's ``init_args``, the datamodule's
``init_args`` and ``trainer.max_epochs``; command-line flags override it.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import time
from pathlib import Path

import numpy as np

from vtlearn.bench_journal import JobJournal, JournalledJobs, job_key, journal_folder, source_digest
from vtlearn.bench_utils import csv_list, sample_std, save_figure
from vtlearn.classical import crossmodal_baseline
from vtlearn.classical.crossmodal_baseline import CLASSICAL_ROWS, THESIS_TABLE_7_4
from vtlearn.cli_args import count, real, with_flag
from vtlearn.validation import as_int, as_real

log = logging.getLogger(__name__)

# Table 7.2/7.4 rows -> XAVTNet overrides; configs/xavtnet_ablation/<name>.yaml hold the same values.
_VTLOSS = {"da_method": "vtloss", "use_mmd": True, "use_coral": True, "da_layers": ["fc1", "fc2"]}
VARIANTS: dict[str, dict] = {
    "noda": {"da_method": "none"},
    "mmd": {**_VTLOSS, "use_coral": False},
    "coral": {**_VTLOSS, "use_mmd": False},
    "vtloss_fc1": {**_VTLOSS, "da_layers": ["fc1"]},
    "vtloss_fc2": {**_VTLOSS, "da_layers": ["fc2"]},
    "vtloss": _VTLOSS,
    "dann": {"da_method": "dann"},
    # Beyond the thesis: CDAN+E (Long et al. 2018; losses/cdan.py), DANN's discriminator conditioned on the
    # classifier's prediction through fc2 ⊗ softmax, with entropy weights; DANN's weight and ramp.
    "cdan": {"da_method": "cdan"},
    # Beyond the thesis: batch-norm statistics per domain during training (models/components/domain_bn.py).
    # "noda_dbn" is no-DA whose target statistics follow the unlabelled tactile stream (AdaBN online);
    # "vtloss_dbn" is VTLoss with each domain normalised by its own statistics (DSBN, shared affine
    # parameters). --adabn re-estimates the target statistics of any row after training instead.
    "noda_dbn": {"da_method": "none", "domain_bn": True},
    "vtloss_dbn": {**_VTLOSS, "domain_bn": True},
    # Beyond the thesis: information maximisation on the target logits (losses/info_max.py), weighted
    # equally with the cross-entropy (im_weight = α = 10), alone ("noda_im") and added to VTLoss.
    "noda_im": {"da_method": "none", "im_weight": 10.0},
    "vtloss_im": {**_VTLOSS, "im_weight": 10.0},
    # Beyond the thesis: Jin et al.'s minimum class confusion on the target logits (losses/mcc.py, T = 2.5),
    # weighted as the source cross-entropy (their trade-off of 1: α = 10), alone and added to VTLoss.
    "noda_mcc": {"da_method": "none", "mcc_weight": 10.0},
    "vtloss_mcc": {**_VTLOSS, "mcc_weight": 10.0},
    # Beyond the thesis: DefRec's deformation reconstruction on both domains' clouds (Achituve et al. 2021;
    # models/components/deformation_task.py), weighted 20 times the cross-entropy as theirs (0.5 x 20 against
    # 0.5), alone and added to VTLoss.
    "noda_defrec": {"da_method": "none", "defrec_weight": 200.0, "defrec_regions": 3},
    "vtloss_defrec": {**_VTLOSS, "defrec_weight": 200.0, "defrec_regions": 3},
    # Beyond the thesis: Saito et al.'s maximum classifier discrepancy (losses/mcd.py; PointDAN's global
    # alignment), its adversarial discrepancy weighted as the cross-entropy (their steps weigh the two alike:
    # α = 10), alone and added to VTLoss.
    "mcd": {"da_method": "none", "mcd_weight": 10.0},
    "vtloss_mcd": {**_VTLOSS, "mcd_weight": 10.0},
    # Beyond the thesis: PointDAN (Qin et al. 2019), MCD's global alignment plus the local alignment of 64
    # self-adaptive nodes (models/components/sa_nodes.py, losses/pointdan.py); the node MMD's weight is
    # PointDAN's 1 on a sum of five kernels (5 on eq. 7.6's mean) times α = 10, as the MCD terms are theirs
    # times α. Alone, and added to VTLoss.
    "pointdan": {"da_method": "none", "mcd_weight": 10.0, "sa_nodes": 64, "node_mmd_weight": 50.0},
    "vtloss_pointdan": {**_VTLOSS, "mcd_weight": 10.0, "sa_nodes": 64, "node_mmd_weight": 50.0},
    # PointDAN with each node's feature read within its ball (sa_feature_ball): on 30-120 tactile contacts
    # the 64 nearest points of PointDAN's nodes are most of the cloud, so every tactile node reads about the
    # same global maximum while a visual node reads a local region (sa_nodes.py, "Sparse clouds").
    "pointdan_ball": {"da_method": "none", "mcd_weight": 10.0, "sa_nodes": 64, "sa_feature_ball": True,
                      "node_mmd_weight": 50.0},
    # Beyond the thesis: Xu et al.'s stepwise adaptive feature norm of the fc2 features, source and target
    # (losses/afn.py, SAFN, Δr = 1), at their ratio to the cross-entropy (0.05 against 1: 0.5 against
    # α = 10), alone and added to VTLoss.
    "noda_afn": {"da_method": "none", "afn_weight": 0.5},
    "vtloss_afn": {**_VTLOSS, "afn_weight": 0.5},
    # ... with their L2-preserved dropout: fc3 and the feature norm read fc2 after a dropout rescaled by
    # √(1 − p) (models/components/xavtnet_backbone.py, XAVTNetHead)
    "vtloss_afn_l2": {**_VTLOSS, "afn_weight": 0.5, "l2_preserved_dropout": True},
    # Beyond the thesis: VTLoss on the logits (fc3) as well as fc1 and fc2, as DAN adapts its classifier
    # layer and Deep CORAL its fc8.
    "vtloss_fc123": {**_VTLOSS, "da_layers": ["fc1", "fc2", "fc3"]},
    # ... and on the max-pooled global feature that fc1 reads
    "vtloss_g12": {**_VTLOSS, "da_layers": ["global", "fc1", "fc2"]},
    # Beyond the thesis: DSAN's class-conditional LMMD in place of MK-MMD (losses/lmmd.py), with DSAN's
    # warm-up ramp of the alignment weight (early pseudo-labels are an untrained classifier's guesses).
    "vtloss_lmmd": {**_VTLOSS, "mmd_conditional": True, "da_ramp_gamma": 10.0},
    # Beyond the thesis: the pooled-feature row plus self-training on the target stream (SHOT's centroid
    # pseudo-labels, CBST's class-balanced half; losses/pseudo_labels.py) from a third of the epochs on,
    # weighted as the source cross-entropy (α = 10).
    "vtloss_g12_pl": {**_VTLOSS, "da_layers": ["global", "fc1", "fc2"], "pseudo_label_weight": 10.0},
    # Beyond the thesis: the pooled-feature row plus a mean teacher on the target stream (French et al.'s
    # self-ensembling for UDA): softmax consistency with an EMA of the weights under point dropout and
    # jitter, on the clouds the teacher gives 0.9 or more, weighted α·3/k as French weights his per-class
    # mean against the cross-entropy; the teacher normalises with the joint batch's statistics (the
    # default teacher_norm). Without the threshold the tactile predictions collapse onto one or two classes
    # at weights 10-100 (docs/xavtnet_results.md).
    "vtloss_g12_mt": {**_VTLOSS, "da_layers": ["global", "fc1", "fc2"], "consistency_weight": 2.5,
                      "consistency_threshold": 0.9},
}
# Beyond the thesis: the teacher row plus rotation prediction on both domains' clouds (Sun et al. 2019;
# GAST's quarter turns of object clouds), weighted as the source cross-entropy (α = 10).
VARIANTS["vtloss_g12_mt_rot"] = {**VARIANTS["vtloss_g12_mt"], "rotation_weight": 10.0}
# Beyond the thesis: the teacher row with ReMixMatch's distribution alignment of the teacher's targets to
# the source class frequencies (models/components/class_balance.py; AdaMatch's assumption that the target
# classes occur as often as the source's).
VARIANTS["vtloss_g12_mt_align"] = {**VARIANTS["vtloss_g12_mt"], "consistency_align": True}
# Beyond the thesis: the teacher row with batch-norm statistics per domain (DSBN; AdaBN gave no-DA 11
# points): the network and the teacher normalise each target batch by its own statistics, and evaluation
# on touch uses the target ones.
VARIANTS["vtloss_g12_mt_dbn"] = {**VARIANTS["vtloss_g12_mt"], "domain_bn": True}
# Beyond the thesis: AaD's neighbourhood clustering of the target stream (losses/neighbourhood.py; Yang et
# al. 2022 with their Office-Home K = 3 and λ = 1) from a third of the epochs on, weighted as the source
# cross-entropy (α = 10), on the pooled-feature row and on the teacher row.
VARIANTS["vtloss_g12_aad"] = {**VARIANTS["vtloss_g12"], "neighbour_weight": 10.0}
VARIANTS["vtloss_g12_mt_aad"] = {**VARIANTS["vtloss_g12_mt"], "neighbour_weight": 10.0}
# ... with the bank rows and the neighbours taken from the teacher's outputs (AdaContrast's momentum bank)
VARIANTS["vtloss_g12_mt_aadt"] = {**VARIANTS["vtloss_g12_mt_aad"], "neighbour_bank": "teacher"}
# Beyond the thesis: the teacher row with FixMatch's consistency (Sohn et al. 2020; AdaMatch, Berthelot et
# al. 2022, for UDA): the cross-entropy against the teacher's argmax where it gives 0.95 or more (FixMatch's
# threshold), weighted as the source cross-entropy (λ_u = 1 of FixMatch: α = 10); the teacher sees a weak
# copy (every contact, jitter 0.01) and the network a strong one (30 % or more of the contacts, jitter 0.02,
# DGCNN's anisotropic stretch in [2/3, 3/2]).
VARIANTS["vtloss_g12_mt_fm"] = {**VARIANTS["vtloss_g12_mt"], "consistency_weight": 10.0,
                                "consistency_threshold": 0.95, "consistency_loss": "cross_entropy",
                                "consistency_keep": 1.0, "consistency_jitter": 0.01, "student_keep": 0.3,
                                "student_jitter": 0.02, "student_scale": 1.5}
# Beyond the thesis: the teacher row with cross-domain mixup (models/components/cloud_mixup.py; Xu et al.
# 2020, and Point Cloud Mixup's union of point subsets): each target cloud mixed with a source cloud at a
# uniform share, its label the source label and the teacher's probability in the share of points each
# gave, weighted as the source cross-entropy (α = 10) and ramped up as the consistency.
VARIANTS["vtloss_g12_mt_mix"] = {**VARIANTS["vtloss_g12_mt"], "mix_weight": 10.0}
# Beyond the thesis: the teacher row plus SimCLR's contrastive task on the tactile stream (losses/
# contrastive.py; Chen et al. 2020's NT-Xent at their CIFAR-10 τ = 0.5 on a projection of the pooled
# feature), two copies of each target cloud perturbed as the teacher's is, weighted as the source
# cross-entropy (α = 10).
VARIANTS["vtloss_g12_mt_con"] = {**VARIANTS["vtloss_g12_mt"], "contrast_weight": 10.0}
# ... with self-training on SHOT's centroid pseudo-labels as well (vtloss_g12_pl's settings: fc1 centroids
# from a third of the epochs on, CBST's confident half per class, weighted as the source cross-entropy)
VARIANTS["vtloss_g12_mt_con_pl"] = {**VARIANTS["vtloss_g12_mt_con"], "pseudo_label_weight": 10.0}
# Beyond the thesis: the teacher row plus self-training on labels voted over each object's touches
# (losses/pseudo_labels.py group_vote_pseudo_labels: the robot knows which touches fell on one object, not
# what it is), from a third of the epochs on, the confident half of each pseudo-class's objects, weighted
# as the source cross-entropy (α = 10); "noda_vote" is the same self-training without VTLoss or a teacher.
VARIANTS["vtloss_g12_mt_vote"] = {**VARIANTS["vtloss_g12_mt"], "pseudo_label_weight": 10.0,
                                  "pseudo_label_groups": True}
VARIANTS["noda_vote"] = {"da_method": "none", "pseudo_label_weight": 10.0, "pseudo_label_groups": True}
# Table 7.2's "MMD only" ablation of the rows above that align the pooled feature too: CORAL off, all else
# equal, so that VTLoss's CORAL share can be read where alignment reaches further than fc1 and fc2.
VARIANTS["mmd_g12"] = {**VARIANTS["vtloss_g12"], "use_coral": False}
VARIANTS["mmd_g12_mt_vote"] = {**VARIANTS["vtloss_g12_mt_vote"], "use_coral": False}
# Beyond the thesis: VTLoss and CORAL only with λ set during training by Deep CORAL's balance rule (λ·CORAL
# kept equal to α·CE from running means with momentum 0.9; losses/vtloss.py), the rule the fixed λ = 500
# rows apply once, at the end of a λ = 10 training. A negative result: online, λ ∝ 1/CORAL runs away and the
# training collapses (docs/xavtnet_results.md, stop 51).
VARIANTS["vtloss_bal"] = {**_VTLOSS, "lam_balance": 0.9}
VARIANTS["coral_bal"] = {**VARIANTS["coral"], "lam_balance": 0.9}
# Beyond the thesis: the teacher row's mean teacher with no alignment (no MK-MMD, no CORAL): no-DA plus the
# consistency, so that the teacher row's margin over no-DA splits into the teacher's share and VTLoss's.
VARIANTS["noda_mt"] = {"da_method": "none", **{k: VARIANTS["vtloss_g12_mt"][k] for k in ("consistency_weight",
                                                                          "consistency_threshold")}}
# Eq. 7.6's kernel weights β_u as Gretton et al. (2012) choose them, the weights of the most powerful
# two-sample test, re-estimated during training from running means (momentum 0.9) of each kernel's
# linear-time MMD² and their covariance, as DAN does (losses/kernel_choice.py), instead of 1/b: eq. 7.8 and
# Table 7.2's "MMD only" row.
VARIANTS["vtloss_kopt"] = {**_VTLOSS, "mmd_kernel_weights": "optimal"}
VARIANTS["mmd_kopt"] = {**VARIANTS["mmd"], "mmd_kernel_weights": "optimal"}
# MK-MMD estimated as DAN trains it, with the linear-time estimator (Gretton et al. 2012 eq. 5; losses/mmd.py
# linear_time_terms: disjoint quadruples of two source and two target clouds) instead of the biased
# V-statistic over all pairs: eq. 7.8 and Table 7.2's "MMD only" row.
VARIANTS["vtloss_lin"] = {**_VTLOSS, "mmd_linear_time": True}
VARIANTS["mmd_lin"] = {**VARIANTS["mmd"], "mmd_linear_time": True}
# Beyond the thesis: the MMD terms with DDC's linear kernel (Tzeng et al. 2014; losses/mmd.py
# linear_kernel_mmd), the squared distance between the domains' mean features, the "MMD loss" that Deep CORAL
# compared its covariance term against: Table 7.2's "MMD only" row read that way, and eq. 7.8 with it.
VARIANTS["vtloss_ddc"] = {**_VTLOSS, "mmd_kernel": "linear"}
VARIANTS["mmd_ddc"] = {**VARIANTS["mmd"], "mmd_kernel": "linear"}
# Rows beyond the thesis that the bench runs only when --variants names them.
OPT_IN_SUFFIXES = ("_dbn", "_im", "_fc123", "_g12", "_lmmd", "_pl", "_mt", "_rot", "_align", "_aad", "_aadt",
                   "_fm", "_mix", "_con", "_vote", "_bal", "_kopt", "_lin", "_ddc")
# Not a thesis row: the same network trained with cross-entropy on the *labelled* tactile training clouds,
# the "train on target" upper bound that UDA papers report beside their methods.
ORACLE = "tactile_oracle"
# Per-run tactile accuracies beyond the row's own, each summarised as "<key> mean ± std" where runs have it:
# after AdaBN (--adabn), a teacher row's network with re-estimated statistics and its teacher (after AdaBN
# too, with --adabn), the class-balanced assignments of the network and the teacher (--balanced), their
# centroid labels (--centroid) and the linear probe of their features (--probe, a diagnostic with labels).
EXTRA_SCORES = ("tactile_acc_adabn", "tactile_acc_bn", "tactile_acc_teacher", "tactile_acc_teacher_adabn",
                "tactile_acc_balanced", "tactile_acc_teacher_balanced", "tactile_acc_centroid",
                "tactile_acc_teacher_centroid", "tactile_acc_probe", "tactile_acc_teacher_probe")
# The layer that --centroid and --probe read: the max-pooled global feature, the backbone's representation.
FEATURE_SCORE_LAYER = "global"
AL_DEFAULTS = {"strategies": "entropy,random", "n0": 24, "kappa": 24, "rounds": 6, "mc_passes": 20,
               "warm_start": False, "min_steps": 0, "power_beta": 1.0, "equal_steps": False}
THESIS_TABLE_7_2 = {"noda": 51.25, "mmd": 57.28, "coral": 58.34, "vtloss_fc1": 70.42, "vtloss_fc2": 62.19,
                    "vtloss": 81.25}


# What a --config of each bench must build: its datamodule class and an example config.
_BENCH_CONFIGS = {"crossmodal": ("CrossModalDataModule", "configs/quick/xavtnet.yaml"),
                  "active-learning": ("ActivePoolDataModule", "configs/quick/active_learning.yaml")}


def load_config(path: str | None, bench: str | None = None) -> dict:
    """``{"model", "data", "trainer", "active"}`` sections of a LightningCLI-style YAML.

    Read with ``yaml.safe_load``; ``active`` is the bench-only section of configs/active_learning.yaml.
    ``bench`` (``"crossmodal"`` or ``"active-learning"``): also check, before any work, that the config is
    one that bench can run (:func:`_check_bench_config`), a ValueError naming ``--config`` otherwise.
    """
    if path is None:
        return {"model": {}, "data": {}, "trainer": {}, "active": {}}
    import yaml

    if not os.path.isfile(path):
        raise ValueError(f"--config: no such file: {path}")
    with open(path) as f:
        try:
            raw = yaml.safe_load(f) or {}
        except yaml.YAMLError as exc:
            raise ValueError(f"--config: {path} is not valid YAML ({exc})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"--config: {path} is not a YAML mapping")

    def init_args(section):
        sec = raw.get(section) or {}
        return dict(sec.get("init_args", {}) or {}) if isinstance(sec, dict) else {}

    cfg = {"model": init_args("model"), "data": init_args("data"), "trainer": dict(raw.get("trainer") or {}),
           "active": dict(raw.get("active") or {})}
    if bench is not None:
        _check_bench_config(raw, cfg, path, bench)
    return cfg


def _check_bench_config(raw: dict, cfg: dict, path: str, bench: str) -> None:
    """A ValueError naming ``--config`` unless ``raw`` is a config ``bench`` can run: its model an
    ``XAVTNet`` and its datamodule the bench's (where the config names their ``class_path``), and every
    ``init_args`` key an argument of those classes. Without it an ACTOR config fails inside the first
    training as a ``TypeError`` about an unexpected keyword."""
    import inspect

    from vtlearn import datamodules
    from vtlearn.models.xavtnet import XAVTNet

    data_name, example = _BENCH_CONFIGS[bench]
    needs = f"bench {bench} needs an xAVTNet config such as {example}"

    def class_path(section: str) -> str | None:
        sec = raw.get(section)
        return str(sec["class_path"]) if isinstance(sec, dict) and sec.get("class_path") else None

    model_path, data_path = class_path("model"), class_path("data")
    if model_path is not None and model_path.rsplit(".", 1)[-1] != "XAVTNet":
        kind = "an ACTOR config" if "actor" in model_path.lower() else "not an xAVTNet config"
        raise ValueError(f"--config: {path} is {kind} (model {model_path}); {needs}")
    if data_path is not None and data_path.rsplit(".", 1)[-1] != data_name:
        kind = {"CrossModalDataModule": "a crossmodal config", "ActivePoolDataModule": "an active-learning "
                "config"}.get(data_path.rsplit(".", 1)[-1], "not an xAVTNet bench config")
        raise ValueError(f"--config: {path} is {kind} (data {data_path}); bench {bench} needs one whose "
                         f"data is {data_name}, such as {example}")
    for section, cls in (("model", XAVTNet), ("data", getattr(datamodules, data_name))):
        accepted = set(inspect.signature(cls.__init__).parameters) - {"self"}
        unknown = sorted(set(cfg[section]) - accepted)
        if unknown:
            raise ValueError(f"--config: {path}: {section}.init_args {unknown} are not arguments of "
                             f"{cls.__name__}; {needs}")


def _config_max_epochs(args: argparse.Namespace, cfg: dict, default: int) -> int:
    """``--max-epochs``, else the config's ``trainer.max_epochs`` (checked: an integer >= 1), else
    ``default``."""
    if args.max_epochs:
        return int(args.max_epochs)
    return as_int(cfg["trainer"].get("max_epochs", default), "--config: trainer.max_epochs")


def _data_kwargs(cfg: dict, data_dir: str | None) -> dict:
    """The config's data init_args with ``--data`` taking precedence; one of them must name the dataset."""
    kwargs = {**cfg["data"], **({"data_dir": data_dir} if data_dir else {})}
    if "data_dir" not in kwargs:
        raise ValueError("--data: no dataset directory given (and none in --config)")
    return kwargs


# The datamodule arguments that a bench flag sets, and the flag (errors name the flag the user typed).
_DATA_FLAGS = {"data_dir": "--data", "batch_size": "--batch-size", "target_split": "--target-split",
               "target_data_dir": "--target-data", "source_points": "--source-points",
               "source_views": "--source-views", "source_touch": "--source-touch",
               "source_splits": "--source-splits", "target_holdout": "--target-holdout",
               "modality": "--modality"}


def _given_flags(args: argparse.Namespace) -> dict[str, str]:
    """The datamodule arguments of :data:`_DATA_FLAGS` that this command line sets -> their flags."""
    return {k: flag for k, flag in _DATA_FLAGS.items()
            if getattr(args, flag[2:].replace("-", "_"), None) not in (None, False)}


def _check_up_front(build, given: dict[str, str], what: str | None):
    """``build()``, a datamodule or model built before any training only to check the command's arguments;
    its ValueError (or FileNotFoundError) ``"key: ..."`` is re-raised naming the flag that set ``key``
    (``given``: argument -> flag, :func:`~vtlearn.cli_args.with_flag`), else the config's ``what`` section
    (``--config: data.key: ...``); a command without a config (``what`` None) re-raises it as it is."""
    try:
        return build()
    except (ValueError, FileNotFoundError) as exc:
        named = with_flag(exc, given)
        if named is not None:
            raise named from exc
        key = str(exc).split(":", 1)[0].strip()
        if what is None or not key.isidentifier():  # already a flag, or about no argument in particular
            raise
        raise type(exc)(f"--config: {what}.{exc}") from exc


def _quiet_lightning() -> None:
    """Lightning's info logs, and two warnings that say nothing about the run: the torch 2.13 ``LeafSpec``
    deprecation inside Lightning's pytree helper, and the missing validation loader the bench's trainers
    turn off on purpose. Called in every (spawned) worker, whose warning filters start afresh."""
    import warnings

    for name in ("lightning", "lightning.pytorch", "lightning.fabric"):
        logging.getLogger(name).setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)` is deprecated",
                            category=FutureWarning)
    warnings.filterwarnings("ignore", message=r"You defined a `validation_step` but have no `val_dataloader`")


def _trainer(max_epochs: int, accelerator: str = "cpu", progress=None):
    """The bench's trainer: no logger, checkpoints, validation or bar of its own; with a ``progress`` sink
    it ticks once per epoch (:class:`~vtlearn.job_progress.TickCallback`)."""
    import lightning as L

    from vtlearn.job_progress import TickCallback

    return L.Trainer(max_epochs=max_epochs, accelerator=accelerator, devices=1, logger=False,
                     enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
                     num_sanity_val_steps=0, limit_val_batches=0,
                     callbacks=[TickCallback(progress)] if progress is not None else None)


def _collect_features(model, loader, layers: tuple[str, ...] = ("fc2",)):
    """The eval-mode ``layers`` (keys of ``XAVTNet.extract_features``: ``"fc2"``, ``"logits"``, ...) of
    every cloud of ``loader``, read in one pass, and their labels.

    Shapes:
        -> ({layer: (n_clouds, d)} numpy arrays, labels (n_clouds,))
    """
    feats, labels = {k: [] for k in layers}, []
    for batch in loader:
        out = model.extract_features(batch["points"], batch["lengths"])
        for k in layers:
            feats[k].append(out[k].numpy())
        labels.append(batch["label"].numpy())
    return {k: np.concatenate(v) for k, v in feats.items()}, np.concatenate(labels)


def _tsne_figure(panels: dict, class_names, path: Path, seed: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from sklearn.manifold import TSNE

    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 5.5))
    axes = np.atleast_1d(axes)
    cmap = plt.get_cmap("tab20")
    for ax, (title, (fs, ys, ft, yt)) in zip(axes, panels.items(), strict=True):
        both = np.concatenate([fs, ft])
        emb = TSNE(n_components=2, perplexity=min(30.0, (len(both) - 1) / 3), init="pca",
                   random_state=seed).fit_transform(both)
        es, et = emb[: len(fs)], emb[len(fs):]
        ax.scatter(es[:, 0], es[:, 1], c=[cmap(int(y) % 20) for y in ys], marker="o", s=14, alpha=0.6,
                   label="visual (source)")
        ax.scatter(et[:, 0], et[:, 1], c=[cmap(int(y) % 20) for y in yt], marker="^", s=22,
                   edgecolors="k", linewidths=0.4, label="tactile (target)")
        ax.set_title(title)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.legend(loc="best", fontsize=8)
    fig.suptitle("fc2 features, colour = class (Fig. 7.4 analogue)")
    fig.tight_layout()
    save_figure(fig, path, dpi=120)


def _confusion_figure(conf: np.ndarray, class_names, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    norm = conf / np.clip(conf.sum(1, keepdims=True), 1, None)
    fig, ax = plt.subplots(figsize=(7, 6))
    im = ax.imshow(norm, cmap="Blues", vmin=0, vmax=1)
    ax.set_xticks(range(len(class_names)), class_names, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(class_names)), class_names, fontsize=7)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    for i in range(len(class_names)):
        for j in range(len(class_names)):
            if norm[i, j] > 0:
                ax.text(j, i, f"{norm[i, j]:.2f}", ha="center", va="center", fontsize=6,
                        color="white" if norm[i, j] > 0.5 else "black")
    ax.set_title(title)
    fig.colorbar(im, ax=ax)
    fig.tight_layout()
    save_figure(fig, path, dpi=120)


def _crossmodal_job(variant: str, seed: int, data_kwargs: dict, base: dict, max_epochs: int, threads: int,
                    features: bool, accelerator: str = "cpu", adabn: bool = False, balanced: bool = False,
                    centroid: bool = False, probe: bool = False, discrepancy: bool = False, progress=None):
    """Train one (variant, seed) of the Table 7.2/7.4 analogue and score it on tactile and visual test clouds.
    ``progress``: a sink that the training ticks once per epoch (:mod:`vtlearn.job_progress`).

    ``adabn``: afterwards, re-estimate the target batch-norm statistics on the unlabelled target stream
    (:meth:`~vtlearn.models.xavtnet.XAVTNet.adapt_bn_statistics`) and score the tactile clouds again
    (``tactile_acc_adabn``, :func:`_adabn_acc`). Every optional score, and the figures' features, restore
    torch's random state, so a row's scores do not depend on which other options were asked for (before
    stop 43, ``--adabn`` and the figures moved the draws of the teacher's scores).

    A row with a mean teacher (``consistency_weight > 0``) is scored twice more, on a copy of the trained
    model, after the features: with the network's batch-norm statistics re-estimated on the joint training
    batches (:meth:`~vtlearn.models.xavtnet.XAVTNet.reestimate_bn_statistics`, ``tactile_acc_bn``), and with
    the teacher's weights and statistics so re-estimated
    (:meth:`~vtlearn.models.xavtnet.XAVTNet.adopt_teacher`, ``tactile_acc_teacher`` and
    ``visual_acc_teacher``); with ``adabn`` that teacher is scored once more after AdaBN
    (``tactile_acc_teacher_adabn``).

    ``balanced``, ``centroid`` and ``probe``: also score the network and, on a teacher row, its teacher,
    before AdaBN, by :func:`_readout_scores` (``tactile_acc_balanced``, ``tactile_acc_centroid``,
    ``tactile_acc_probe`` and their ``tactile_acc_teacher_*`` twins), from one further pass over the test
    clouds per model. They leave torch's random state as they found it, so the scores after them are
    those of a run without them.

    ``accelerator`` is Lightning's (``cpu``, ``gpu``, ``auto``); Lightning hands the model back on the CPU
    after each fit and test, so the feature extraction below runs there.

    Returns (row, (fc2 features and labels of visual and tactile test clouds) or None, class names).
    A module-level function so that ``--workers`` can run it in a spawned process.
    """
    import copy

    import lightning as L
    import torch

    from vtlearn.datamodules import CrossModalDataModule
    from vtlearn.models.xavtnet import XAVTNet

    _quiet_lightning()
    torch.set_num_threads(threads)
    L.seed_everything(seed, verbose=False)
    dm = CrossModalDataModule(**{**data_kwargs, "seed": seed})
    oracle = variant == ORACLE
    kwargs = {**base, **VARIANTS["noda" if oracle else variant]}
    if kwargs.get("input_normalize") not in (None, dm.normalize):
        raise ValueError(f"model.input_normalize: {kwargs['input_normalize']!r} in the config, but the "
                         f"data's normalize is {dm.normalize!r}; leave it unset (the bench records that)")
    model = XAVTNet(num_classes=dm.num_classes, **{**kwargs, "input_normalize": dm.normalize})
    t0 = time.perf_counter()
    trainer = _trainer(max_epochs, accelerator, progress)
    loader = dm.labelled_target_train_dataloader() if oracle else dm.train_dataloader()
    trainer.fit(model, train_dataloaders=loader)
    fit_s = time.perf_counter() - t0
    tactile = _test_acc(trainer, model, dm.test_dataloader())
    conf = model.last_test_confusion.numpy()
    with model.bn_domain("source"):  # visual clouds: the source statistics (only differ with domain_bn)
        visual = _test_acc(trainer, model, dm.source_test_dataloader())
    row = {"variant": variant, "seed": seed, "tactile_acc": 100 * float(tactile),
           "visual_acc": 100 * float(visual), "fit_s": fit_s, "confusion": conf.astype(int).tolist()}
    prior = dm.source_class_prior() if balanced else None
    # the network as scored for tactile_acc, before AdaBN
    row.update(_readout_scores(model, dm, prior, probe, centroid))
    if discrepancy:
        row["discrepancy"] = _domain_discrepancy(model, dm)
    # the teacher is scored on a copy, as trained: AdaBN below converts the model to domain_bn
    twin = copy.deepcopy(model) if model.teacher is not None else None
    if adabn:
        row["tactile_acc_adabn"] = _adabn_acc(trainer, model, dm)
    feats = None
    if features:  # the random state is restored, as by the scores above, so the teacher's draws below
        with torch.no_grad(), torch.random.fork_rng():  # are those of a run without figures
            with model.bn_domain("source"):
                source, source_labels = _collect_features(model, dm.source_test_dataloader())
            target, target_labels = _collect_features(model, dm.test_dataloader())
            feats = (source["fc2"], source_labels, target["fc2"], target_labels)
    if twin is not None:
        twin.reestimate_bn_statistics(dm.train_dataloader())
        row["tactile_acc_bn"] = 100 * _test_acc(trainer, twin, dm.test_dataloader())
        twin.adopt_teacher(dm.train_dataloader())
        row["tactile_acc_teacher"] = 100 * _test_acc(trainer, twin, dm.test_dataloader())
        with twin.bn_domain("source"):
            row["visual_acc_teacher"] = 100 * _test_acc(trainer, twin, dm.source_test_dataloader())
        # the teacher as scored for tactile_acc_teacher, before AdaBN
        row.update({k.replace("tactile_acc", "tactile_acc_teacher"): v
                    for k, v in _readout_scores(twin, dm, prior, probe, centroid).items()})
        if adabn:  # the teacher's weights with AdaBN's target statistics, as the network above
            row["tactile_acc_teacher_adabn"] = _adabn_acc(trainer, twin, dm)
    return row, feats, dm.class_names


def _call(fn, *args, progress=None):
    """``fn(*args, progress=progress)``: lets one pool of ``--workers`` processes run trainings and classical
    rows alike."""
    return fn(*args, progress=progress)


def _classical_job(variants: list[str], seed: int, data_kwargs: dict, threads: int, units: int = 0,
                   progress=None):
    """The classical rows ``variants`` of one seed (:func:`~vtlearn.classical.crossmodal_baseline.
    classical_runs`), as (their rows, no features, class names). ``progress``: a sink that the descriptors
    tick ``units`` times in all, spread over the clouds as they are done (the bench counts a seed's classical
    rows as one training's epochs)."""
    sent = 0

    def on_cloud(done: int, total: int) -> None:
        nonlocal sent
        due = units * done // total
        if due > sent:
            progress.put(due - sent)
            sent = due

    rows, names = crossmodal_baseline.classical_runs(variants, seed, data_kwargs, threads,
                                                     on_cloud=on_cloud if progress is not None else None)
    return rows, None, names


def _test_acc(trainer, model, loader) -> float:
    return float(trainer.test(model, dataloaders=loader, verbose=False)[0]["test/acc"])


def _adabn_acc(trainer, model, dm) -> float:
    """Tactile test accuracy (%) after AdaBN: ``model``'s target batch-norm statistics re-estimated on the
    unlabelled target stream (:meth:`~vtlearn.models.xavtnet.XAVTNet.adapt_bn_statistics`, which converts
    it to statistics per domain in place). Torch's random state is restored afterwards (the target
    stream is shuffled), so that the teacher's scores that follow in :func:`_crossmodal_job`, which draw
    shuffled training batches, are those of a run without ``--adabn``."""
    import torch

    with torch.random.fork_rng():
        model.adapt_bn_statistics(dm.target_dataloader())
        return 100 * _test_acc(trainer, model, dm.test_dataloader())


def _score_checks(rows: list[dict], what: str, checks: dict) -> None:
    """``checks`` for the ``what`` scores (``"adabn"``, ``"balanced"``, ``"centroid"`` or ``"probe"``: the
    ``tactile_{what}_mean`` and ``tactile_teacher_{what}_mean`` of the rows that have them), for every row
    and, where it has one, its teacher (``who`` = ``""`` or ``"_teacher"``):

    * ``{variant}{who}_{what}_minus_acc``: the score less the same model's own tactile accuracy (what the
      reading adds to the classifier);
    * ``{variant}{who}_{what}_minus_noda``: the score less plain no-DA's tactile accuracy (for no-DA itself
      this equals its ``_minus_acc``: no-DA's own gain, e.g. ``noda_adabn_minus_noda``);
    * ``{variant}{who}_{what}_minus_noda_{what}``: like for like, the score less no-DA's score of the same
      kind (not written for no-DA's own network).

    The ``_minus_noda`` checks need a ``noda`` row; ``_minus_noda_{what}`` needs it to have the score."""
    noda_row = next((r for r in rows if r["variant"] == "noda"), None)
    key = f"tactile_{what}_mean"
    noda_score = noda_row.get(key) if noda_row is not None else None
    for r in rows:
        for who, k, own in (("", key, "tactile_mean"),
                            ("_teacher", f"tactile_teacher_{what}_mean", "tactile_teacher_mean")):
            if k not in r:
                continue
            name = f"{r['variant']}{who}_{what}"
            checks[f"{name}_minus_acc"] = r[k] - r[own]
            if noda_row is not None:
                checks[f"{name}_minus_noda"] = r[k] - noda_row["tactile_mean"]
            if noda_score is not None and (r["variant"] != "noda" or who):
                checks[f"{name}_minus_noda_{what}"] = r[k] - noda_score


#: The layers whose domain discrepancy --discrepancy measures: the pooled feature and the two that VTLoss
#: aligns (eq. 7.8).
DISCREPANCY_LAYERS = ("global", "fc1", "fc2")


def _domain_discrepancy(model, dm, layers: tuple[str, ...] = DISCREPANCY_LAYERS) -> dict:
    """How far apart a trained model leaves the two domains: the squared MK-MMD (eq. 7.5-7.6, the training
    loss's biased estimate and kernel family, :func:`~vtlearn.losses.mmd.mk_mmd`) and the Deep CORAL
    distance (eq. 7.7, :func:`~vtlearn.losses.coral.coral`) of each of ``layers``, between the eval-mode
    features of the visual test clouds (the source statistics) and of the tactile test clouds, each set
    whole. It tells whether a row's alignment terms, or another row's, left the covariances apart: for
    instance whether MMD alone already closes CORAL's distance. ``norm_<layer>`` is the tactile clouds' mean
    feature norm over the visual clouds' (Xu et al.'s premise for the adaptive feature norm,
    :mod:`vtlearn.losses.afn`, is that it is below 1 after source training); it is NaN where every visual
    feature of the layer is zero. Torch's random state is restored, as by :func:`_readout_scores`.

    Shapes:
        ``layer`` features (n_visual, d) and (n_tactile, d) -> {"mmd_<layer>": float, "coral_<layer>": float,
        "norm_<layer>": float}
    """
    import torch

    from vtlearn.losses.coral import coral
    from vtlearn.losses.mmd import mk_mmd

    with torch.no_grad(), torch.random.fork_rng():
        with model.bn_domain("source"):
            source, _ = _collect_features(model, dm.source_test_dataloader(), layers)
        target, _ = _collect_features(model, dm.test_dataloader(), layers)
    out = {}
    for layer in layers:
        s_feat = torch.from_numpy(source[layer]).double()
        t_feat = torch.from_numpy(target[layer]).double()
        out[f"mmd_{layer}"] = float(mk_mmd(s_feat, t_feat))
        out[f"coral_{layer}"] = float(coral(s_feat, t_feat))
        s_norm = float(s_feat.norm(dim=1).mean())
        # all-zero visual features (a layer of dead ReLUs) have no ratio: NaN, "-" in the table, null in JSON
        out[f"norm_{layer}"] = float(t_feat.norm(dim=1).mean()) / s_norm if s_norm > 0 else float("nan")
    return out


def _discrepancy_rows(variants: list[str], per_run: list[dict]) -> list[dict]:
    """Each row's mean ± std over seeds of every ``discrepancy`` key of its runs (the rows that have them),
    as text for the table and ``<key>_mean`` floats for the JSON."""
    out = []
    for variant in variants:
        runs = [r["discrepancy"] for r in per_run if r["variant"] == variant and "discrepancy" in r]
        if not runs:
            continue
        row = {"variant": variant, "seeds": len(runs)}
        for key in runs[0]:
            a = np.array([d[key] for d in runs])
            row[key] = f"{a.mean():.3g} ± {sample_std(a):.2g}"
            row[f"{key}_mean"] = float(a.mean())
        out.append(row)
    return out


def _readout_scores(model, dm, prior=None, probe: bool = False, centroid: bool = False,
                    layer: str = FEATURE_SCORE_LAYER) -> dict:
    """Three further readings of a trained model's tactile test clouds, in eval mode, from one pass over
    ``dm.test_dataloader()`` (its logits and ``layer`` features together):

    * ``prior`` (class frequencies, or None to skip) -> ``tactile_acc_balanced``: the accuracy (%) of the
      class-balanced assignment of the whole test set at once, the eval-mode probabilities rescaled by
      Sinkhorn-Knopp to ``prior``
      (:func:`~vtlearn.models.components.class_balance.sinkhorn_balance`). Transductive, label-free: the
      labels only score the assignment.
    * ``centroid`` -> ``tactile_acc_centroid``: the accuracy (%) of SHOT's centroid labels of the whole
      tactile test set at once (:func:`~vtlearn.losses.pseudo_labels.centroid_pseudo_labels`, every label
      kept: each class centroid is the softmax-weighted, then the hard-label mean of the unit-length
      features, and each cloud takes the nearest by cosine). Transductive and label-free, like the
      balanced assignment. It lets the clusters of tactile features, not the classifier's boundaries,
      decide.
    * ``probe`` -> ``tactile_acc_probe``: the accuracy (%) on the tactile test clouds of a linear probe, a
      multinomial logistic regression (scikit-learn, L2 with C = 1, standardised features) fitted on the
      same layer's features of the labelled tactile training clouds
      (:meth:`~vtlearn.datamodules.CrossModalDataModule.labelled_target_train_dataloader`, those the
      ``tactile_oracle`` row trains on, yaw-augmented as it sees them). A diagnostic that uses tactile
      labels, which no UDA row trains with: it measures how separable the row's representation leaves the
      tactile classes, whatever its classifier does, so ``tactile_acc_probe - tactile_acc`` is what the
      row's own classifier leaves.

    The model is on the CPU (Lightning hands it back there). Torch's random state is restored afterwards
    (iterating a loader draws from it), so the scores computed after these do not depend on whether they
    ran, and the probe's augmentation draws do not depend on which other readings ran.

    Shapes:
        ``layer`` features (n_clouds, d), logits (n_clouds, k), prior (k,) -> {score name: float in [0, 100]}
    """
    import torch

    from vtlearn.losses.pseudo_labels import centroid_pseudo_labels
    from vtlearn.models.components.class_balance import sinkhorn_balance

    out = {}
    if prior is None and not (probe or centroid):
        return out
    with torch.random.fork_rng():
        test, labels = _collect_features(model, dm.test_dataloader(), ("logits", layer))
    probs = torch.from_numpy(test["logits"]).double().softmax(-1)
    if prior is not None:
        q = sinkhorn_balance(probs, torch.as_tensor(prior, dtype=probs.dtype))
        out["tactile_acc_balanced"] = 100 * float((q.argmax(-1).numpy() == labels).mean())
    if centroid:
        pseudo = centroid_pseudo_labels(torch.from_numpy(test[layer]), probs)
        out["tactile_acc_centroid"] = 100 * float((pseudo.numpy() == labels).mean())
    if probe:
        from sklearn.linear_model import LogisticRegression
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler

        with torch.random.fork_rng():
            train, train_labels = _collect_features(model, dm.labelled_target_train_dataloader(), (layer,))
        clf = make_pipeline(StandardScaler(), LogisticRegression(C=1.0, max_iter=5000))
        clf.fit(train[layer], train_labels)
        out["tactile_acc_probe"] = 100 * float(clf.score(test[layer], labels))
    return out


def _run_line(row: dict, adabn: bool, balanced: bool) -> str:
    """The line ``bench crossmodal`` prints as a training comes back: its tactile and visual accuracy, and the
    further scores the row has (after AdaBN, the teacher's, the balanced, centroid and probe readings)."""
    extra = f"  tactile after AdaBN {row['tactile_acc_adabn']:.1f}%" if adabn else ""
    if "tactile_acc_teacher" in row:
        extra += (f"  re-estimated BN {row['tactile_acc_bn']:.1f}%  teacher "
                  f"{row['tactile_acc_teacher']:.1f}% (visual {row['visual_acc_teacher']:.1f}%)")
        if "tactile_acc_teacher_adabn" in row:
            extra += f"  teacher after AdaBN {row['tactile_acc_teacher_adabn']:.1f}%"
    if balanced:
        extra += f"  balanced {row['tactile_acc_balanced']:.1f}%"
        if "tactile_acc_teacher_balanced" in row:
            extra += f"  teacher balanced {row['tactile_acc_teacher_balanced']:.1f}%"
    for who, prefix in (("", "tactile_acc"), ("teacher ", "tactile_acc_teacher")):
        for what in ("centroid", "probe"):
            if f"{prefix}_{what}" in row:
                extra += f"  {who}{what} {row[f'{prefix}_{what}']:.1f}%"
    return (f"{row['variant']} seed {row['seed']}: tactile {row['tactile_acc']:.1f}%  "
            f"visual {row['visual_acc']:.1f}%{extra}  ({row['fit_s']:.0f} s)")


def _job_environment() -> dict[str, str]:
    """The versions of vtlearn and torch, the digest of vtlearn's source and the vector capability torch's CPU
    kernels use (AVX2, AVX512, ...), part of every bench job's journal key (:mod:`vtlearn.bench_journal`): a
    job kept by another version or other code, or on a CPU whose sums may round differently, is trained
    again instead of mixed in."""
    import torch

    import vtlearn

    return {"vtlearn": vtlearn.__version__, "source": source_digest(), "torch": torch.__version__,
            "cpu_capability": torch.backends.cpu.get_cpu_capability()}


def _journal(args: argparse.Namespace) -> JobJournal:
    """The job journal of a training bench, beside its ``--json``, emptied first with ``--fresh``."""
    return JobJournal(journal_folder(args.json), fresh=bool(getattr(args, "fresh", False)))


def _encode_crossmodal(result: tuple) -> tuple[dict, dict | None]:
    """A crossmodal job's ``(row or classical rows, features or None, class names)`` as the journal keeps it
    (:class:`~vtlearn.bench_journal.JobJournal`): the JSON part, and the figure's features as arrays."""
    out, feats, names = result
    arrays = None if feats is None else dict(zip(_FEATURE_KEYS, feats, strict=True))
    return {"out": out, "names": names}, arrays


def _decode_crossmodal(stored: dict, arrays: dict | None) -> tuple:
    """:func:`_encode_crossmodal` undone: the job's result as :func:`_crossmodal_job` returned it."""
    feats = None if arrays is None else tuple(arrays[k] for k in _FEATURE_KEYS)
    return stored["out"], feats, stored["names"]


#: the t-SNE figure's features of a crossmodal job, as :func:`_crossmodal_job` returns them
_FEATURE_KEYS = ("source", "source_labels", "target", "target_labels")


def run_crossmodal_bench(args: argparse.Namespace) -> int:
    from tqdm.auto import tqdm

    from vtlearn.bench_utils import check_output_path, machine_info, write_json
    from vtlearn.models.crossmodal_compare import paired_figure, parse_pairs, score_field, summed_confusion

    margin = getattr(args, "margin", None)
    if margin is not None and not np.isfinite(margin):
        raise ValueError(f"--margin: need a finite number of accuracy points, got {margin}")
    asked = parse_pairs(getattr(args, "pairs", None))  # a malformed --pairs is refused before any work
    if getattr(args, "merge", None) and getattr(args, "merge_sets", None):
        raise ValueError("--merge-sets: give either --merge (the seeds of one dataset) or --merge-sets (one "
                         "protocol on several datasets), not both")
    if getattr(args, "versus_sets", None) and not getattr(args, "merge_sets", None):
        raise ValueError("--versus-sets: only with --merge-sets, whose object sets it is paired with")
    if getattr(args, "merge", None):
        return _merge_crossmodal(args, asked)
    if getattr(args, "merge_sets", None):
        return _merge_sets_crossmodal(args, asked)
    if getattr(args, "rows", None):
        raise ValueError("--rows: only with --merge or --merge-sets; a training run's rows are --variants")

    cfg = load_config(args.config, "crossmodal")
    data_kwargs = _data_kwargs(cfg, args.data)
    if args.batch_size:
        data_kwargs["batch_size"] = args.batch_size
    if args.target_split:
        data_kwargs["target_split"] = args.target_split
    if args.target_data:
        data_kwargs["target_data_dir"] = args.target_data
    if args.source_points:
        data_kwargs["source_points"] = list(args.source_points)
    if args.source_views is not None:
        data_kwargs["source_views"] = args.source_views
    if args.source_touch:
        data_kwargs["source_touch"] = True
    if args.source_splits:
        data_kwargs["source_splits"] = csv_list(args.source_splits)
    if args.target_holdout is not None:
        data_kwargs["target_holdout"] = args.target_holdout
    max_epochs = _config_max_epochs(args, cfg, 15)
    variants = csv_list(args.variants)
    unknown = [v for v in variants if v not in VARIANTS and v != ORACLE and v not in CLASSICAL_ROWS]
    if unknown or not variants:
        raise ValueError(f"--variants: {f'unknown {unknown}' if unknown else 'no variant given'}; choose "
                         f"from {[*VARIANTS, ORACLE, *CLASSICAL_ROWS]}")
    for spec in (side for pair in asked for side in pair):
        if score_field(spec)[0] not in variants:
            raise ValueError(f"--pairs: {spec} names a row that --variants does not train ({variants})")
    _check_baseline(args, variants)
    seeds = list(range(args.seed, args.seed + args.seeds))
    out_dir = Path(args.out_dir) if args.out_dir else Path(args.json).with_suffix("")
    if not args.no_figures:  # the default folder beside --json, checked before the trainings too
        check_output_path(out_dir, "--out-dir", "figures", folder=True)
    base = {k: v for k, v in cfg["model"].items() if k not in VARIANTS["vtloss"] and k != "num_classes"}
    # Build the datamodule and every row's model once before any training, so that a bad argument (a
    # missing split, a holdout without the test target, a model setting out of range) is refused naming its
    # flag or its place in the config instead of failing inside the first (or a spawned) training.
    from vtlearn.datamodules import CrossModalDataModule
    from vtlearn.models.xavtnet import XAVTNet

    given = _given_flags(args)
    dm = _check_up_front(lambda: CrossModalDataModule(**{**data_kwargs, "seed": seeds[0]}), given, "data")
    if base.get("input_normalize") not in (None, dm.normalize):
        raise ValueError(f"--config: model.input_normalize is {base['input_normalize']!r}, but the data's "
                         f"normalize is {dm.normalize!r}; leave it unset (the bench records that)")
    for variant in (v for v in variants if v not in CLASSICAL_ROWS):
        _check_up_front(lambda v=variant: XAVTNet(num_classes=dm.num_classes, **{
            **base, **VARIANTS["noda" if v == ORACLE else v], "input_normalize": dm.normalize}), {}, "model")

    jobs = [(v, s) for v in variants for s in seeds]
    classical = [v for v in variants if v in CLASSICAL_ROWS]
    figure_jobs = {(v, seeds[0]) for v in ("noda", "vtloss")} if not args.no_figures else set()
    adabn = bool(getattr(args, "adabn", False))
    balanced = bool(getattr(args, "balanced", False))
    centroid, probe = bool(getattr(args, "centroid", False)), bool(getattr(args, "probe", False))
    discrepancy = bool(getattr(args, "discrepancy", False))
    # the classical rows of a seed share its descriptors: one job per seed computes them all
    job_args = [(_classical_job, classical, seed, data_kwargs, args.threads, max_epochs)
                for seed in seeds if classical]
    job_args += [(_crossmodal_job, variant, seed, data_kwargs, base, max_epochs, args.threads,
                  (variant, seed) in figure_jobs, args.accelerator, adabn, balanced, centroid, probe,
                  discrepancy) for variant, seed in jobs if variant not in CLASSICAL_ROWS]
    # the bar counts epochs, ticked by the trainings while they run; a seed's classical rows count as one
    # training's epochs, spread over their descriptors
    bar = tqdm(total=(len(job_args) * max_epochs), desc="bench crossmodal", unit="epoch")
    fingerprint = _data_fingerprints(data_kwargs)
    # finished trainings are kept as they end, so that the same command, stopped, goes on where it stopped
    journal, env = _journal(args), _job_environment()
    keys = [job_key("bench crossmodal", a[0].__name__, a[1:], fingerprint, env,
                    _variant_settings([a[1]]) if a[0] is _crossmodal_job else None) for a in job_args]
    jobs_run = JournalledJobs("bench crossmodal", journal, keys, _call, job_args, args.workers,
                              _encode_crossmodal, _decode_crossmodal, tick=bar.update,
                              on_reused=lambda _: bar.update(max_epochs))
    per_run: list[dict] = []
    keep: dict = {}
    class_names: list[str] = []
    with jobs_run:
        for out, feats, names in jobs_run:
            class_names = names
            if isinstance(out, list):  # a seed's classical rows
                per_run.extend(out)
                for row in out:
                    tqdm.write(f"{row['variant']} seed {row['seed']}: tactile {row['tactile_acc']:.1f}%  "
                               f"visual {row['visual_acc']:.1f}%  ({row['descriptor_s']:.0f} s descriptors, "
                               "shared)")
                continue
            per_run.append(out)
            if feats is not None:
                keep[out["variant"]] = feats
            tqdm.write(_run_line(out, adabn, balanced))
    bar.close()
    order = {job: i for i, job in enumerate(jobs)}
    per_run.sort(key=lambda r: order[(r["variant"], r["seed"])])

    rows, checks, discrepancy_rows = _report_rows(variants, per_run, data_kwargs, max_epochs, len(seeds))
    per_class = _report_per_class(variants, per_run, class_names)
    paired = _report_paired(args, variants, per_run, asked, strict=False)  # trained results are kept whatever

    result = {
        "bench": "crossmodal", "config": args.config, "data": data_kwargs,
        "data_fingerprint": fingerprint, "data_generation": _data_generation(data_kwargs),
        "max_epochs": max_epochs, "seeds": seeds, "model_base": base,
        "variant_settings": _variant_settings(variants),
        "rows": rows, "runs": per_run, "checks": checks,
        **({"discrepancy": discrepancy_rows} if discrepancy_rows else {}),
        **({"per_class": per_class} if per_class else {}),
        **({"paired": paired} if paired else {}),
        "class_names": class_names, "figures": {}, "machine": machine_info(),
        "accelerator": args.accelerator, "workers": args.workers,
        "note": "trainings run side by side (--workers); fit_s timings are noisy",
    }
    write_json(args.json, result)  # before the figures: a figure that fails loses no trained results
    figures = result["figures"]
    if not args.no_figures:
        # VTLoss's, else the first row's: the matrices of different rows are not summed into one
        shown = "vtloss" if "vtloss" in variants else variants[0]
        figures["confusion"] = str(out_dir / f"confusion_{shown}.png")
        _confusion_figure(summed_confusion(per_run, shown), class_names, Path(figures["confusion"]),
                          f"Tactile confusion ({shown}, summed over seeds)")
        panels = {}
        if "noda" in keep:
            panels["before adaptation (no-DA)"] = keep["noda"]
        if "vtloss" in keep:
            panels["after adaptation (VTLoss)"] = keep["vtloss"]
        if panels:
            figures["tsne"] = str(out_dir / "tsne_before_after.png")
            _tsne_figure(panels, class_names, Path(figures["tsne"]), seeds[0])
        if paired:
            figures["paired"] = str(out_dir / "paired.png")
            paired_figure(paired, figures["paired"], getattr(args, "margin", None))
        for name, path in figures.items():
            print(f"{name}: {path}")
    if figures:
        write_json(args.json, result)
    journal.discard()  # kept until now: a rerun after a failed figure trains nothing again
    print(f"wrote {args.json}")
    return 0


def _merged_output(args: argparse.Namespace, inputs: list[str], flag: str) -> Path:
    """The figure folder of a ``--merge`` / ``--merge-sets`` result, after checking its outputs before any
    work: ``--json`` writable and not one of the ``inputs`` (named by ``flag``), ``--out-dir`` a folder."""
    from vtlearn.bench_utils import check_output_path

    out = check_output_path(args.json, "--json", "JSON")
    if any(Path(m).resolve() == out.resolve() for m in inputs):
        raise ValueError(f"--json: {args.json} is one of the {flag} inputs; write the merged result "
                         "elsewhere")
    out_dir = Path(args.out_dir) if args.out_dir else Path(args.json).with_suffix("")
    if not args.no_figures:
        check_output_path(out_dir, "--out-dir", "figures", folder=True)
    return out_dir


def _merge_crossmodal(args: argparse.Namespace, asked: list[tuple[str, str]]) -> int:
    """``bench crossmodal --merge``: pool the runs of earlier results of one protocol
    (:func:`~vtlearn.models.crossmodal_compare.load_crossmodal_results`), print their table and the
    seed-paired comparisons (``asked``: the parsed ``--pairs``, beside those against ``--baseline``), and
    write both as a JSON (and the paired differences as a figure). Trains nothing."""
    from vtlearn.bench_utils import write_json
    from vtlearn.models.crossmodal_compare import load_crossmodal_results, paired_figure

    out_dir = _merged_output(args, args.merge, "--merge")
    meta, runs = load_crossmodal_results(args.merge)
    runs = _keep_rows(args, meta, runs)
    variants = list(dict.fromkeys(r["variant"] for r in runs))
    _check_baseline(args, variants)
    seeds = sorted({r["seed"] for r in runs})
    print(f"merged {len(args.merge)} results: rows {variants}, seeds {seeds}")
    rows, checks, discrepancy_rows = _report_rows(variants, runs, meta["data"], meta["max_epochs"],
                                                  len(seeds))
    per_class = _report_per_class(variants, runs, meta.get("class_names"))
    paired = _report_paired(args, variants, runs, asked)
    machines = list({json.dumps(r["machine"], sort_keys=True): r["machine"] for r in runs if r.get("machine")}
                    .values())
    result = {"bench": "crossmodal", **meta, "seeds": seeds, "rows": rows, "runs": runs, "checks": checks,
              **({"discrepancy": discrepancy_rows} if discrepancy_rows else {}),
              **({"per_class": per_class} if per_class else {}),
              **({"paired": paired} if paired else {}), "machines": machines, "figures": {}}
    write_json(args.json, result)
    if paired and not args.no_figures:
        result["figures"]["paired"] = str(out_dir / "paired.png")
        paired_figure(paired, result["figures"]["paired"], getattr(args, "margin", None),
                      f"Seed-paired differences, {len(args.merge)} merged results")
        print(f"paired: {result['figures']['paired']}")
        write_json(args.json, result)
    print(f"wrote {args.json}")
    return 0


def _merge_sets_crossmodal(args: argparse.Namespace, asked: list[tuple[str, str]]) -> int:
    """``bench crossmodal --merge-sets``: the results of one protocol on several datasets (the thesis's
    twelve-object protocol on several object draws; ``crossmodal_compare.load_object_sets``), each set's
    files pooled as ``--merge`` pools them. Prints each set's row means and
    the comparisons paired by object set (every row against ``--baseline``, and ``asked``; one pair per set,
    its mean over the seeds both rows have there), writes both as a JSON and the set differences as a
    figure. Trains nothing."""
    from vtlearn.bench_utils import print_table, write_json
    from vtlearn.models.crossmodal_compare import (
        check_versus_protocol,
        default_pairs,
        paired_figure,
        paired_table_columns,
        set_paired_rows,
        set_summaries,
        set_table_rows,
    )

    versus_paths = getattr(args, "versus_sets", None)
    out_dir = _merged_output(args, args.merge_sets + (versus_paths or []), "--merge-sets")
    meta, sets = _object_sets(args, args.merge_sets, "--merge-sets")
    versus = _object_sets(args, versus_paths, "--versus-sets") if versus_paths else None
    if versus is not None:  # before any table: B of A's protocol, as many sets, a row in common
        check_versus_protocol(meta, versus[0], [args.merge_sets[0], versus_paths[0]], sets, versus[1])
    runs = [r for s in sets for r in s["runs"]]
    baseline = getattr(args, "baseline", "noda")
    variants = list(dict.fromkeys(r["variant"] for r in runs))
    _check_baseline(args, variants)
    variants.sort(key=lambda v: v != baseline)  # the baseline's column first, the rest as first found
    margin = getattr(args, "margin", None)
    print(f"merged {len(args.merge_sets)} results on {len(sets)} object sets: rows {variants}")
    summaries = set_summaries(sets)
    print_table(set_table_rows(summaries, variants), ["set", *variants, "seeds"],
                "V→T accuracy (%) on tactile test clouds per object set: each row's mean over the set's "
                "seeds")
    pairs = list(dict.fromkeys(default_pairs(variants, runs, baseline) + asked))
    paired = set_paired_rows(sets, pairs, margin) if pairs else []
    if paired:
        cols = paired_table_columns(paired, margin)
        cols[cols.index("seeds ahead")] = "sets ahead"
        cols.insert(cols.index("sets ahead") + 1, "runs ahead")
        print_table(paired, cols,
                    "Set-paired differences of tactile accuracy (points): mean ± std over the object sets "
                    "that have both rows (each set: its mean over the seeds both rows have there), 95 % "
                    "interval, two-sided p of the paired t and Wilcoxon tests over the sets, the t-test's "
                    "p adjusted by Holm's method over the comparisons of the table, sets and runs ahead"
                    + (f"; p(≤ {margin:g}): one-sided p that the margin is no more than {margin:g}"
                       if margin is not None else ""))
    if versus is not None:
        versus_result = _versus_sets(args, sets, versus[1], variants, pairs)
        runs += [r for s in versus[1] for r in s["runs"]]
    machines = list({json.dumps(r["machine"], sort_keys=True): r["machine"] for r in runs if r.get("machine")}
                    .values())
    result = {"bench": "crossmodal", "by": "object set", **meta, "sets": summaries, "paired": paired,
              **({"versus": versus_result} if versus is not None else {}), "machines": machines,
              "figures": {}}
    write_json(args.json, result)
    if not args.no_figures:
        if paired:
            result["figures"]["paired"] = str(out_dir / "paired_sets.png")
            paired_figure(paired, result["figures"]["paired"], margin,
                          f"Object-set-paired differences, {len(sets)} sets", unit="object sets")
        if versus is not None:
            result["figures"]["versus"] = str(out_dir / "versus_sets.png")
            paired_figure(versus_result["paired"], result["figures"]["versus"], None,
                          "--merge-sets minus --versus-sets, paired by object set", unit="object sets")
        for name, path in result["figures"].items():
            print(f"{name}: {path}")
        if result["figures"]:
            write_json(args.json, result)
    print(f"wrote {args.json}")
    return 0


def _object_sets(args: argparse.Namespace, paths: list[str], flag: str) -> tuple[dict, list[dict]]:
    """:func:`~vtlearn.models.crossmodal_compare.load_object_sets` of ``paths`` (named by ``flag``) with only
    the rows of ``--rows``; a set left without any is dropped with a line saying so, and fewer than two sets
    left are refused."""
    from vtlearn.models.crossmodal_compare import load_object_sets

    meta, sets = load_object_sets(paths, flag)
    kept = {r["variant"] for r in _keep_rows(args, meta, [r for s in sets for r in s["runs"]])}
    for s in sets:
        s["runs"] = [r for r in s["runs"] if r["variant"] in kept]
    dropped = [s["label"] for s in sets if not s["runs"]]
    if dropped:
        print(f"--rows: {', '.join(dropped)} hold none of the rows kept, so they are left out")
        sets = [s for s in sets if s["runs"]]
    if len(sets) < 2:
        raise ValueError(f"--rows: only {len(sets)} object set of {flag} holds the rows kept; pairing by "
                         "object set needs two or more")
    return meta, sets


def _versus_sets(args: argparse.Namespace, sets: list[dict], versus: list[dict], variants: list[str],
                 pairs: list[tuple[str, str]]) -> dict:
    """``--merge-sets A ... --versus-sets B ...``: the same object sets read twice (rendered otherwise, other
    touches), the i-th set of A paired with the i-th of B (checked beforehand by
    :func:`~vtlearn.models.crossmodal_compare.check_versus_protocol`). Prints B's per-set table, the pairs
    of sets and how every row both hold (its accuracy) and every comparison of A's table (its margin) moved
    from B to A
    (:func:`~vtlearn.models.crossmodal_compare.versus_set_rows`), and returns that for the JSON."""
    from vtlearn.bench_utils import print_table
    from vtlearn.models.crossmodal_compare import (
        generation_differences,
        paired_table_columns,
        score_field,
        set_summaries,
        set_table_rows,
        versus_set_rows,
    )

    held = {r["variant"] for s in versus for r in s["runs"]}
    summaries = set_summaries(versus)
    shown = [v for v in variants if v in held] + sorted(held - set(variants))
    print(f"--versus-sets: {len(args.versus_sets)} results on {len(versus)} object sets: rows {shown}")
    print_table(set_table_rows(summaries, shown), ["set", *shown, "seeds"],
                "--versus-sets: V→T accuracy (%) on tactile test clouds per object set")
    comparisons = [(v, None) for v in variants if v in held]
    comparisons += [p for p in pairs if all(score_field(side)[0] in held for side in p)]
    differ = generation_differences(sets, versus)
    if differ:
        print("--versus-sets: the paired datasets were generated with other " + "; ".join(
            f"{key} ({' / '.join(map(str, values))} here, against {' / '.join(map(str, others))})"
            for key, (values, others) in differ.items()))
    rows = versus_set_rows(sets, versus, comparisons)
    cols = paired_table_columns(rows, None)
    cols[cols.index("seeds ahead")] = "sets ahead"
    print_table(rows, cols,
                "How each row's accuracy and each margin moved from --versus-sets to --merge-sets (points), "
                "paired by object set in the order first named (" + ", ".join(
                    f"{s['label']} : {v['label']}" for s, v in zip(sets, versus, strict=True)) + "): mean ± "
                "std over the pairs of sets, 95 % interval, two-sided p of the paired t and Wilcoxon tests, "
                "the t-test's p adjusted by Holm's method over the table's rows, sets ahead")
    return {"merged_from": [str(p) for p in args.versus_sets], "sets": summaries,
            "pairing": [[s["label"], v["label"]] for s, v in zip(sets, versus, strict=True)],
            "generation_differences": {k: {"sets": a, "versus": b} for k, (a, b) in differ.items()},
            "paired": rows}


def _keep_rows(args: argparse.Namespace, meta: dict, runs: list[dict]) -> list[dict]:
    """The runs of the rows ``--rows`` names (all when it is not given), for ``--merge`` and
    ``--merge-sets``; ``meta["variant_settings"]`` keeps those rows' settings only, so the merged JSON holds
    nothing of the rows left out. A named row that no file holds is refused by name."""
    if not getattr(args, "rows", None):
        return runs
    keep = list(dict.fromkeys(csv_list(args.rows)))
    if not keep:
        raise ValueError(f"--rows: need a comma list of rows, got {args.rows!r}")
    held = list(dict.fromkeys(r["variant"] for r in runs))
    missing = [v for v in keep if v not in held]
    if missing:
        raise ValueError(f"--rows: {missing} are in none of the merged files (their rows: {held})")
    if isinstance(meta.get("variant_settings"), dict):
        meta["variant_settings"] = {v: st for v, st in meta["variant_settings"].items() if v in keep}
    return [r for r in runs if r["variant"] in keep]


def _check_baseline(args: argparse.Namespace, variants: list[str]) -> None:
    """A ``--baseline`` given on the command line must be one of the rows (no-DA, the default, may be
    absent: then no row is paired with it)."""
    baseline = getattr(args, "baseline", "noda")
    if baseline != "noda" and baseline not in variants:
        raise ValueError(f"--baseline: {baseline!r} is not one of the rows ({variants})")


def _report_rows(variants: list[str], per_run: list[dict], data_kwargs: dict, max_epochs: int,
                 n_seeds: int) -> tuple[list[dict], dict, list[dict]]:
    """The Table 7.2/7.4 rows of ``per_run`` (mean ± std over seeds of every score they hold), the checks
    on their means (margins over no-DA, the thesis's orderings, the readings'), and the domain-discrepancy
    rows of the runs that measured it, each table printed. Returns (rows, checks, discrepancy rows)."""
    from vtlearn.bench_utils import print_table

    rows = []
    for variant in variants:
        t = np.array([r["tactile_acc"] for r in per_run if r["variant"] == variant])
        v = np.array([r["visual_acc"] for r in per_run if r["variant"] == variant])
        rows.append({
            "variant": variant,
            "tactile_acc": f"{t.mean():.2f} ± {sample_std(t):.2f}",
            "visual_acc": f"{v.mean():.2f} ± {sample_std(v):.2f}",
            "thesis_V→T": {**THESIS_TABLE_7_2, **THESIS_TABLE_7_4}.get(variant, "-"),
            "tactile_mean": float(t.mean()), "tactile_std": sample_std(t),
            "visual_mean": float(v.mean()), "seeds": len(t),
        })
        for key in EXTRA_SCORES:  # "tactile_acc_adabn" -> its text and "tactile_adabn_mean", ...
            a = np.array([r[key] for r in per_run if r["variant"] == variant and key in r])
            if len(a):
                rows[-1].update({key: f"{a.mean():.2f} ± {sample_std(a):.2f}",
                                 key.replace("_acc", "") + "_mean": float(a.mean())})
    extra_cols = [c for c in EXTRA_SCORES if any(c in r for r in rows)]
    epochs = (f"{max_epochs} epoch{'s' if max_epochs != 1 else ''}"
              if any(v not in CLASSICAL_ROWS for v in variants) else "no training (classical rows)")
    source = "+".join(data_kwargs.get("source_splits", ["train"]))
    held = float(data_kwargs.get("target_holdout", 0.0))
    holdout = f" less the {held:g} of their tactile clouds held out for the test" if held > 0 else ""
    print_table(rows, ["variant", "tactile_acc", *extra_cols, "visual_acc", "thesis_V→T", "seeds"],
                f"Table 7.2/7.4 analogue: V→T accuracy (%) on tactile test clouds, {n_seeds} seeds, "
                f"{epochs}, unlabelled target: "
                f"{data_kwargs.get('target_split', 'train')} instances{holdout}, "
                f"labelled visual source: {source}")
    means = {r["variant"]: r["tactile_mean"] for r in rows}
    checks = {}
    if {"vtloss", "noda"} <= means.keys():
        checks["vtloss_minus_noda"] = means["vtloss"] - means["noda"]
    if "noda" in means:
        for name in (v for v in means if v.endswith(OPT_IN_SUFFIXES)):
            checks[f"{name}_minus_noda"] = means[name] - means["noda"]
        for r in rows:
            if "tactile_teacher_mean" in r:
                checks[f"{r['variant']}_teacher_minus_noda"] = r["tactile_teacher_mean"] - means["noda"]
    if {"vtloss", "mmd", "coral"} <= means.keys():
        checks["vtloss_beats_mmd_and_coral"] = means["vtloss"] > max(means["mmd"], means["coral"])
    if {"vtloss", "vtloss_fc1", "vtloss_fc2"} <= means.keys():
        checks["both_layers_beat_each"] = means["vtloss"] > max(means["vtloss_fc1"], means["vtloss_fc2"])
    for what in ("adabn", "balanced", "centroid", "probe"):  # each where the rows have it
        _score_checks(rows, what, checks)
    for k, v in checks.items():
        print(f"{k}: {v:.2f}" if isinstance(v, float) else f"{k}: {v}")
    discrepancy_rows = _discrepancy_rows(variants, per_run)
    if discrepancy_rows:
        keys = [k for k in discrepancy_rows[0] if k not in ("variant", "seeds") and not k.endswith("_mean")]
        print_table(discrepancy_rows, ["variant", *keys, "seeds"],
                    "Domain discrepancy left by each row: squared MK-MMD and Deep CORAL distance of "
                    "eval-mode features, visual test clouds vs tactile test clouds, and the tactile over "
                    "the visual mean feature norm (mean ± std over seeds)")
    return rows, checks, discrepancy_rows


def _report_per_class(variants: list[str], per_run: list[dict], class_names: list[str] | None) -> dict:
    """Prints and returns each row's tactile recall and share of the predictions per class, seeds
    pooled (:func:`~vtlearn.models.crossmodal_compare.per_class_scores`): where a row's mean is won or lost,
    and a class that absorbs the clouds of others (no-DA sends a third of the tactile clouds to a class whose
    visual clouds are as sparse as touches; docs/xavtnet_results.md, stop 78)."""
    from vtlearn.bench_utils import print_table
    from vtlearn.models.crossmodal_compare import per_class_scores, per_class_table_rows

    scores = per_class_scores(per_run, variants)
    if scores:
        print_table(per_class_table_rows(scores, class_names), ["class", *scores],
                    "Per class: tactile recall % (share of the tactile predictions %), seeds pooled "
                    "(the diagonal of Table 7.3's confusion matrix, and its column sums)")
    return scores


def _report_paired(args: argparse.Namespace, variants: list[str], per_run: list[dict],
                   asked: list[tuple[str, str]], strict: bool = True) -> list[dict]:
    """The seed-paired comparisons (:mod:`vtlearn.models.crossmodal_compare`) of every row against
    ``--baseline`` where the runs have it with two seeds or more, and of ``asked`` (the parsed ``--pairs``),
    printed as a table.
    Returns the rows (empty when there is nothing to pair). A pair that cannot be read (a ``--pairs`` score
    that the runs do not hold, such as ``.teacher`` of a row without a teacher) raises ``ValueError``, or,
    without ``strict`` (after trainings, whose results must not be lost), is left out with a note."""
    from vtlearn.bench_utils import print_table
    from vtlearn.models.crossmodal_compare import default_pairs, paired_rows, paired_table_columns, with_holm

    margin = getattr(args, "margin", None)
    pairs = asked
    if len({r["seed"] for r in per_run}) >= 2:  # one seed: only the pairs asked for
        baseline = getattr(args, "baseline", "noda")
        pairs = list(dict.fromkeys(default_pairs(variants, per_run, baseline) + asked))
    if not pairs:
        return []
    if strict:
        rows = paired_rows(per_run, pairs, margin)
    else:
        rows = []
        for pair in pairs:
            try:
                rows += paired_rows(per_run, [pair], margin)
            except ValueError as exc:
                print(f"left out of the paired table: {exc}")
        if not rows:
            return []
        with_holm(rows)  # the family is the pairs that could be read
    print_table(rows, paired_table_columns(rows, margin),
                "Seed-paired differences of tactile accuracy (points): mean ± std over the seeds both rows "
                "have, 95 % interval, two-sided p of the paired t and Wilcoxon tests, the t-test's p "
                "adjusted by Holm's method over the comparisons of the table, seeds ahead"
                + (f"; p(≤ {margin:g}): one-sided p that the margin is no more than {margin:g}"
                   if margin is not None else ""))
    if any(r["cross_machine"] for r in rows):
        print("cross_machine: pairs whose runs ran on different machines; a training repeats bit for bit on "
              "one machine only, so those pairs keep the seed but not its shared noise")
    return rows


def _data_fingerprints(data_kwargs: dict) -> dict[str, str]:
    """The :func:`~vtlearn.datamodules.shards.dataset_fingerprint` of every dataset folder a bench reads
    (``data_dir``, and ``target_data_dir`` where given), so that its JSON says which data made its numbers
    and a rerun on a regenerated folder can be told apart from one on other data."""
    from vtlearn.datamodules.shards import dataset_fingerprint

    return {key: dataset_fingerprint(data_kwargs[key], key) for key in ("data_dir", "target_data_dir")
            if data_kwargs.get(key)}


def _data_generation(data_kwargs: dict) -> dict[str, dict | None]:
    """The ``gen-data`` settings (its manifest's ``config``: seed, categories, rendering, touches) of every
    dataset folder a bench reads, keyed as :func:`_data_fingerprints`, or None for a folder whose manifest
    records none: so that a JSON says how its data were drawn, and ``--versus-sets`` can check that it pairs
    the same object draws."""
    from vtlearn.datamodules.shards import load_manifest

    out = {}
    for key in ("data_dir", "target_data_dir"):
        if data_kwargs.get(key):
            config = load_manifest(data_kwargs[key], key).get("config")
            out[key] = config if isinstance(config, dict) else None
    return out


def _variant_settings(variants: list[str]) -> dict[str, dict]:
    """What each run row sets over ``model_base`` (its :data:`VARIANTS` entry; the oracle: no-DA's, trained
    on labelled touches), and, for a row with Deep CORAL's online balance rule, the cap on its λ_t
    (:attr:`~vtlearn.losses.vtloss.VTLoss.LAM_BALANCE_MAX`, a class constant), so that a JSON says which
    setting made its numbers."""
    from vtlearn.losses.vtloss import VTLoss

    out = {}
    for v in variants:
        if v in CLASSICAL_ROWS:
            out[v] = {**CLASSICAL_ROWS[v], "esf_samples": crossmodal_baseline.ESF_SAMPLES}
            continue
        kw = dict(VARIANTS["noda" if v == ORACLE else v])
        if kw.get("lam_balance") is not None:
            kw["lam_balance_max"] = VTLoss.LAM_BALANCE_MAX
        out[v] = kw
    return out


def _active_learning_job(strategy: str, seed: int, data_kwargs: dict, base: dict, al: dict, max_epochs: int,
                         threads: int, pool: int, train_steps: int = 0, accelerator: str = "cpu",
                         progress=None, state_dir=None):
    """One seed of one strategy of the Fig. 7.5a analogue, or (``strategy="full"``) the reference model
    trained on the whole labelled pool of ``pool`` clouds. Returns (strategy, seed, history dicts or the
    full-pool accuracy). ``train_steps > 0``: every training runs exactly that many optimiser steps.
    ``progress``: a sink that every training ticks once, when it ends (:mod:`vtlearn.job_progress`), and
    that the rounds restored from ``state_dir`` tick at once. ``state_dir``: where the loop keeps its state
    after every round and goes on from (``ActiveLearningLoop(state_dir=...)``); a state there that cannot be
    used is dropped, with a warning, and the loop trains from its first round. A state there of a longer
    loop (a copy of one kept by ``--keep-loops``) gives this loop's rounds without training
    (:func:`~vtlearn.active.learning_loop.history_of_fewer_rounds`).

    A module-level function so that ``--workers`` can run it in a spawned process.
    """
    from dataclasses import asdict

    import lightning as L
    import torch

    from vtlearn.active.learning_loop import (
        LOOP_STATE_FILE,
        ActiveLearningLoop,
        history_of_fewer_rounds,
        train_and_test,
    )
    from vtlearn.datamodules import ActivePoolDataModule
    from vtlearn.job_progress import TickCallback
    from vtlearn.models.xavtnet import XAVTNet

    _quiet_lightning()
    torch.set_num_threads(threads)
    min_steps = int(al["min_steps"])
    trainer_kwargs = {"accelerator": accelerator}
    if progress is not None:
        trainer_kwargs["callbacks"] = [TickCallback(progress, every="fit")]
    if strategy == "full":
        L.seed_everything(seed, verbose=False)
        dm = ActivePoolDataModule(initial_labels=pool, seed=seed, **data_kwargs)
        model = XAVTNet(num_classes=dm.num_classes, **base)
        return strategy, seed, train_and_test(model, dm.train_dataloader(), dm.test_dataloader(), max_epochs,
                                              min_steps, train_steps, **trainer_kwargs)

    def new_loop() -> ActiveLearningLoop:
        dm = ActivePoolDataModule(initial_labels=al["n0"], seed=seed, **data_kwargs)
        return ActiveLearningLoop(dm, lambda round_seed: XAVTNet(num_classes=dm.num_classes, **base),
                                  strategy=strategy, kappa=al["kappa"], rounds=al["rounds"],
                                  mc_passes=al["mc_passes"], max_epochs=max_epochs, min_steps=min_steps,
                                  train_steps=train_steps, warm_start=bool(al["warm_start"]),
                                  power_beta=float(al["power_beta"]), seed=seed, show_progress=False,
                                  trainer_kwargs=trainer_kwargs, state_dir=state_dir)

    if state_dir is not None:
        # a longer loop's last state, kept by --keep-loops: its first rounds are this loop's
        shorter = history_of_fewer_rounds(state_dir, al["rounds"])
        if shorter is not None:
            if progress is not None:
                progress.put(len(shorter))
            return strategy, seed, [asdict(h) for h in shorter]
    loop = new_loop()
    try:
        restored = loop.restore()
    except ValueError as exc:
        if state_dir is None:
            raise
        # the journal's own state of this job (its key fixes the settings) that cannot be used: like a
        # journal line cut short, it is not kept work, and the loop trains again from its first round
        log.warning("the %s loop of seed %d trains again from its first round, as its kept state cannot be "
                    "used: %s", strategy, seed, exc)
        (Path(state_dir) / LOOP_STATE_FILE).unlink(missing_ok=True)
        loop = new_loop()
        restored = loop.restore()
    if restored and progress is not None:
        progress.put(restored)
    return strategy, seed, (loop.history_dicts() if loop.run() else [])


def _active_source(args: argparse.Namespace, key: str) -> str:
    """Where the active-learning setting ``key`` came from: its flag, or the config's ``active`` section."""
    flag = "--" + key.replace("_", "-")
    return flag if getattr(args, key, None) is not None else f"--config: active.{key}"


def _check_active_settings(args: argparse.Namespace, al: dict) -> None:
    """The numbers of the active-learning protocol (flags over the config's ``active`` section over
    :data:`AL_DEFAULTS`), checked before any work, each error naming where the bad value came from."""
    for key, minimum in (("n0", 1), ("kappa", 1), ("rounds", 1), ("mc_passes", 1), ("min_steps", 0)):
        al[key] = as_int(al[key], _active_source(args, key), minimum)
    al["power_beta"] = as_real(al["power_beta"], _active_source(args, "power_beta"), low=0.0)
    for key in ("warm_start", "equal_steps"):
        if not isinstance(al[key], bool):
            raise ValueError(f"{_active_source(args, key)}: need true or false, got {al[key]!r}")


def _check_budget(args: argparse.Namespace, al: dict, pool: int, modality: str = "training") -> None:
    """n0, kappa and rounds against the pool's ``pool`` (``modality``) clouds, before the full-pool
    references train: n0 must leave clouds to query, and the rounds' queries must fit in what is left
    (otherwise the loop stops early and the curves end before the asked-for budget)."""
    n0, kappa, rounds = al["n0"], al["kappa"], al["rounds"]
    where = f"the pool of {modality} training clouds"
    if n0 >= pool:
        raise ValueError(f"{_active_source(args, 'n0')}: {n0} initial labels, but {where} has only {pool} "
                         f"clouds; need n0 < {pool} so that some are left to query")
    left = pool - n0
    if kappa > left:
        raise ValueError(f"{_active_source(args, 'kappa')}: {kappa} queries per round, but only {left} of "
                         f"the {pool} pool clouds are unlabelled after n0 = {n0}; need kappa <= {left}")
    if n0 + rounds * kappa > pool:
        raise ValueError(f"{_active_source(args, 'rounds')}: n0 + rounds x kappa = {n0} + {rounds} x "
                         f"{kappa} = {n0 + rounds * kappa} labels, more than the pool's {pool} clouds; need "
                         f"rounds <= {left // kappa} (or a smaller --kappa / --n0)")


def _plot_path(args: argparse.Namespace) -> Path:
    """``--plot``, by default beside ``--json`` with the suffix ``.png``."""
    return Path(args.plot) if args.plot else Path(args.json).with_suffix(".png")


def run_active_learning_bench(args: argparse.Namespace) -> int:
    from tqdm.auto import tqdm

    from vtlearn.bench_utils import check_output_path
    from vtlearn.datamodules import ActivePoolDataModule
    from vtlearn.models.xavtnet import XAVTNet

    # the plot's default place, beside --json, is checked before any work as --json itself is
    check_output_path(_plot_path(args), "--plot", "plot")
    if getattr(args, "merge", None):
        meta, runs = merge_active_learning_runs(args.merge)
        print(f"merged {len(args.merge)} results: seeds {meta['seeds']}, strategies {list(runs)}")
        return _summarize_active_learning(args, meta, runs)

    cfg = load_config(args.config, "active-learning")
    data_kwargs = _data_kwargs(cfg, args.data)
    for key in ("initial_labels", "seed"):
        data_kwargs.pop(key, None)
    if args.modality:
        data_kwargs["modality"] = args.modality
    if args.batch_size:
        data_kwargs["batch_size"] = args.batch_size
    al = {**AL_DEFAULTS, **cfg["active"]}
    for key in AL_DEFAULTS:
        if getattr(args, key, None) is not None:
            al[key] = getattr(args, key)
    _check_active_settings(args, al)
    max_epochs = _config_max_epochs(args, cfg, 10)
    strategies = al["strategies"]
    if isinstance(strategies, str):
        strategies = csv_list(strategies)
    from vtlearn.active.mc_dropout import QUERY_STRATEGIES

    unknown = [s for s in strategies if s not in QUERY_STRATEGIES]
    if unknown or not isinstance(strategies, list) or not strategies:
        raise ValueError(f"{_active_source(args, 'strategies')}: expected a comma list of "
                         f"{QUERY_STRATEGIES}, got {al['strategies']!r}")
    seeds = list(range(args.seed, args.seed + args.seeds))
    base = {k: v for k, v in cfg["model"].items() if k != "num_classes"}
    base.setdefault("da_method", "none")
    # the pool and the model are built once before any training, so that a bad argument is refused naming
    # its flag (or its place in the config), and n0, kappa and rounds are checked against the pool's size
    pool_dm = _check_up_front(lambda: ActivePoolDataModule(initial_labels=0, seed=seeds[0], **data_kwargs),
                              _given_flags(args), "data")
    pool = pool_dm.pool_size
    _check_up_front(lambda: XAVTNet(num_classes=pool_dm.num_classes, **base), {}, "model")
    _check_budget(args, al, pool, pool_dm.modality)
    # Equal-budget protocol: every round trains as many optimiser steps as the full-pool reference
    # (max_epochs over the whole pool), so the relative error measures labels, not training length.
    train_steps = 0
    if al["equal_steps"]:
        full_batches = len(ActivePoolDataModule(initial_labels=pool, seed=seeds[0], **data_kwargs)
                           .train_dataloader())
        train_steps = max_epochs * full_batches
        print(f"equal steps: every training runs {train_steps} optimiser steps "
              f"({max_epochs} epochs of the {pool}-cloud pool)")

    # The reference is the model trained on the fully labelled pool (Table 7.1 "fully trained network").
    jobs = [(s, seed) for s in ["full", *strategies] for seed in seeds]
    # the bar counts trainings, ticked as each ends: one per reference, rounds + 1 per strategy and seed (a
    # pool used up early ends its run sooner, and the bar jumps its missing rounds when the run comes back)
    trainings = {s: 1 if s == "full" else al["rounds"] + 1 for s in ["full", *strategies]}
    bar = tqdm(total=sum(trainings[s] for s, _ in jobs), desc="bench active-learning", unit="training")
    # each job gets (and is keyed by) the settings it reads: a reference none of the loops', a loop not the
    # list of strategies, so that another --rounds or --strategies reuses the jobs it shares
    job_args = [(s, seed, data_kwargs, base, _job_settings(al, s), max_epochs, args.threads, pool,
                 train_steps, args.accelerator) for s, seed in jobs]
    fingerprint = _data_fingerprints(data_kwargs)
    # finished runs are kept as they end, and unfinished loops round by round, so that the same command,
    # stopped, goes on where it stopped; with --keep-loops each loop's last state is kept too, under a name
    # without its rounds, from which the command with more (or fewer) --rounds goes on
    journal, env = _journal(args), _job_environment()
    keys = [job_key("bench active-learning", a, fingerprint, env) for a in job_args]
    keep_as = None
    if _keep_loops(args, journal):
        keep_as = [None if a[0] == "full" else
                   job_key("bench active-learning", _without_rounds(a), fingerprint, env) for a in job_args]
    jobs_run = JournalledJobs("bench active-learning", journal, keys, _active_learning_job, job_args,
                              args.workers, lambda r: (list(r), None), lambda stored, _: tuple(stored),
                              tick=bar.update, on_reused=lambda r: bar.update(_trainings_done(r)),
                              partial=True, keep_as=keep_as)
    results: dict = {}
    with jobs_run:
        for strategy, seed, res in jobs_run:
            results[strategy, seed] = res
            done = _trainings_done((strategy, seed, res))
            if done < trainings[strategy]:
                bar.update(trainings[strategy] - done)
            if strategy == "full":
                tqdm.write(f"full pool ({pool} labels) seed {seed}: acc {100 * res:.1f}%")
            elif res:
                tqdm.write(f"{strategy} seed {seed}: " + ", ".join(
                    f"{h['n_labels']}: {100 * h['accuracy']:.1f}%" for h in res))
    bar.close()
    full = [results["full", seed] for seed in seeds]
    runs = {strategy: [results[strategy, seed] for seed in seeds] for strategy in strategies}
    meta = {"config": args.config, "model": base, "data": data_kwargs,
            "data_fingerprint": fingerprint, "pool_size": pool, "active": al,
            "max_epochs": max_epochs, "train_steps": train_steps or None, "seeds": seeds, "full_acc": full,
            "accelerator": args.accelerator}
    return _summarize_active_learning(args, meta, runs, journal)


def _job_settings(al: dict, strategy: str) -> dict:
    """The active-learning settings a job of ``strategy`` reads (:func:`_active_learning_job`): a full-pool
    reference only ``min_steps``; a loop all but the list of strategies and ``equal_steps`` (which reaches it
    as ``train_steps``)."""
    if strategy == "full":
        return {"min_steps": al["min_steps"]}
    return {k: v for k, v in al.items() if k not in ("strategies", "equal_steps")}


def _without_rounds(job_args: tuple) -> tuple:
    """A loop job's arguments without its number of rounds: the name its last state is kept under."""
    strategy, seed, data_kwargs, base, al, *rest = job_args
    return (strategy, seed, data_kwargs, base, {k: v for k, v in al.items() if k != "rounds"}, *rest)


def _keep_loops(args: argparse.Namespace, journal: JobJournal) -> bool:
    """Whether this run keeps each loop's last state: ``--keep-loops``, or a journal that holds states kept by
    an earlier run (which this run then goes on from, and keeps with its own)."""
    from tqdm.auto import tqdm

    asked = bool(getattr(args, "keep_loops", False))
    kept = journal.kept_states()
    if kept and not asked:  # above the bar, which is drawn by now
        tqdm.write(f"bench active-learning: {journal.folder} holds the last state of {_loops(len(kept))} of "
                   f"an earlier --keep-loops run; this run goes on from them and keeps its own (--fresh lets "
                   f"them go)")
    return asked or bool(kept)


def _loops(n: int) -> str:
    return f"{n} loop" if n == 1 else f"{n} loops"


def _trainings_done(result: tuple) -> int:
    """The trainings an active-learning job ran: 1 for a full-pool reference, one per round otherwise (a
    pool used up early ends the run sooner)."""
    strategy, _, res = result
    return 1 if strategy == "full" else len(res)


# The keys two bench JSONs must share for their seeds to be pooled (`--merge`).
_MERGE_KEYS = ("data", "pool_size", "max_epochs", "train_steps")
_MERGE_ACTIVE_KEYS = ("n0", "kappa", "rounds", "mc_passes", "warm_start", "min_steps", "power_beta",
                      "equal_steps")


def merge_active_learning_runs(paths: list[str]) -> tuple[dict, dict[str, list]]:
    """Pool the seeds of several `bench active-learning` JSONs made with the same protocol.

    Files with the same seeds and the same full-pool references (runs of other strategies on those seeds,
    e.g. ``--strategies bald`` after ``--strategies entropy,random``) are joined strategy by strategy
    first; the groups of different seeds are then pooled. Returns the merged metadata and ``{strategy:
    [per-seed round histories]}`` for the strategies every group has. Raises ValueError if a file is
    missing, is not an active-learning result, differs in the protocol (model, data, pool, training
    length, n₀, κ, rounds, ...), repeats a (seed, strategy) pair, shares some seeds but not all with
    another file, has the seeds of another with different references, or was run on other data under the
    same folder name (``data_fingerprint``). Results written before the model or the fingerprint was
    recorded are compared on everything else.
    """
    from vtlearn.bench_utils import check_same_protocol, read_results

    docs = read_results(paths, "active-learning", "curves")
    first = docs[0]
    fingerprint = check_same_protocol(paths, docs, _MERGE_KEYS)
    for path, doc in zip(paths[1:], docs[1:], strict=True):
        if "model" in doc and "model" in first and doc["model"] != first["model"]:
            raise ValueError(f"--merge: {path} and {paths[0]} trained different models")
        for key in _MERGE_ACTIVE_KEYS:
            if key == "min_steps" and first.get("train_steps"):
                continue  # equal steps: every training runs train_steps, min_steps is not used
            if doc["active"].get(key) != first["active"].get(key):
                raise ValueError(f"--merge: {path} has active.{key}={doc['active'].get(key)!r}, {paths[0]} "
                                 f"has {first['active'].get(key)!r}")
    groups: dict[tuple, dict] = {}  # seeds -> {"path", "full_acc", "curves"} joined over strategies
    for path, doc in zip(paths, docs, strict=True):
        key = tuple(doc["seeds"])
        group = groups.get(key)
        if group is None:
            shared = [s for k in groups for s in k if s in key]
            if shared:
                raise ValueError(f"--merge: {path} and another file repeat seeds {sorted(set(shared))} "
                                 "without having the same seeds; each seed may appear in one group of files")
            groups[key] = {"path": path, "full_acc": doc["full_acc"], "curves": dict(doc["curves"])}
            continue
        both = sorted(set(group["curves"]) & set(doc["curves"]))
        if both:
            raise ValueError(f"--merge: {path} and {group['path']} repeat seeds {list(key)} with the "
                             f"strategies {both}; each (seed, strategy) may appear once")
        if doc["full_acc"] != group["full_acc"]:
            raise ValueError(f"--merge: {path} has the seeds of {group['path']} but other full-pool "
                             f"references ({doc['full_acc']} against {group['full_acc']}), so it is not the "
                             "same protocol")
        group["curves"].update(doc["curves"])
    strategies = [s for s in dict.fromkeys(s for g in groups.values() for s in g["curves"])
                  if all(s in g["curves"] for g in groups.values())]
    if not strategies:
        raise ValueError("--merge: the files have no strategy in common")
    runs = {s: [r for g in groups.values() for r in g["curves"][s]["runs"]] for s in strategies}
    seeds = [s for key in groups for s in key]
    meta = {key: first.get(key) for key in _MERGE_KEYS}
    meta["model"] = next((doc["model"] for doc in docs if "model" in doc), None)
    meta["data_fingerprint"] = fingerprint
    meta.update({"config": [doc.get("config") for doc in docs], "active": {**first["active"],
                 "strategies": ",".join(strategies)}, "seeds": seeds,
                 "full_acc": [a for g in groups.values() for a in g["full_acc"]],
                 "accelerator": [doc.get("accelerator") for doc in docs], "merged_from": list(paths)})
    return meta, runs


def _ratio_text(labels: int | None, random_labels: int | None, max_labels: int,
                random_max_labels: int | None = None) -> str:
    """A strategy's labels over random's at one relative-error line, as text, where a count is None when
    its mean curve does not reach the line by its last round (``max_labels`` for the strategy,
    ``random_max_labels`` for random, the same by default): the ratio itself when both reach it, a lower
    bound ``> max_labels / random_labels`` when only random does, an upper bound
    ``< labels / random_max_labels`` when only the strategy does, and ``n/a`` when neither does."""
    random_max = max_labels if random_max_labels is None else random_max_labels
    if labels is not None and random_labels is not None:
        return f"{labels / random_labels:.2f}"
    if random_labels is not None:
        return f"> {max_labels / random_labels:.2f} (not reached by {max_labels} labels)"
    if labels is not None:
        return f"< {labels / random_max:.2f} (random does not reach it by {random_max} labels)"
    return f"n/a (neither reaches it by {max_labels} labels)"


def _summarize_active_learning(args: argparse.Namespace, meta: dict, runs: dict[str, list],
                               journal=None) -> int:
    """Table 7.1 analogue (first reached and sustained), ratios to random, paired comparison, plot, JSON.
    ``journal``: the trained runs' :class:`~vtlearn.bench_journal.JobJournal`, removed once both are
    written."""
    from vtlearn.active.learning_loop import bootstrap_label_ratio, labels_to_reach, paired_advantage
    from vtlearn.bench_utils import machine_info, print_table, write_json_and_figure

    seeds, pool, full = meta["seeds"], meta["pool_size"], meta["full_acc"]
    acc_full = float(np.mean(full))
    curves: dict[str, dict] = {}
    accs: dict[str, np.ndarray] = {}  # (seeds, rounds) accuracy per strategy
    for strategy, runs_s in runs.items():
        n = [h["n_labels"] for h in runs_s[0]]
        if any([h["n_labels"] for h in r] != n for r in runs_s):
            raise ValueError(f"{strategy}: the seeds' runs have different label counts; cannot average them")
        acc = accs[strategy] = np.array([[h["accuracy"] for h in r] for r in runs_s])
        curves[strategy] = {"n_labels": n, "acc_mean": acc.mean(0).tolist(), "acc_std": acc.std(0).tolist(),
                            "runs": runs_s}
    thresholds = (0.10, 0.05, 0.03, 0.02)
    rows = []
    stay_rows = []
    for strategy, c in curves.items():
        reach = labels_to_reach(c["n_labels"], c["acc_mean"], acc_full, thresholds)
        stay = labels_to_reach(c["n_labels"], c["acc_mean"], acc_full, thresholds, sustained=True)
        c["labels_to_reach"] = {f"{int(t * 100)}%": v for t, v in reach.items()}
        c["labels_to_stay"] = {f"{int(t * 100)}%": v for t, v in stay.items()}
        for out_rows, got in ((rows, reach), (stay_rows, stay)):
            cells = {f"{int(t * 100)}%": (v if v is not None else f"> {c['n_labels'][-1]}")
                     for t, v in got.items()}
            out_rows.append({"strategy": strategy, **cells, "final_acc": 100 * c["acc_mean"][-1]})
    print_table(rows, ["strategy", "10%", "5%", "3%", "2%", "final_acc"],
                f"Table 7.1 analogue: labels to reach relative error vs full-pool model "
                f"(acc {100 * acc_full:.1f}%, {pool} labels), mean over {len(seeds)} seeds")
    print_table(stay_rows, ["strategy", "10%", "5%", "3%", "2%", "final_acc"],
                "The same, labels from which the mean curve stays within the relative error to its end")
    # Labels at 2 % relative error, each query strategy over random (the issue's target is <= 0.65).
    ratios: dict[str, float | None] = {}
    ratios_stay: dict[str, float | None] = {}
    ratio_texts: dict[str, dict[str, str]] = {}  # with the bound where a curve misses the line
    if "random" in curves:
        for key, out in (("labels_to_reach", ratios), ("labels_to_stay", ratios_stay)):
            r = curves["random"][key]["2%"]
            for strategy, c in curves.items():
                if strategy == "random":
                    continue
                a = c[key]["2%"]
                out[strategy] = a / r if a is not None and r is not None else None
                text = ratio_texts.setdefault(strategy, {})[key] = _ratio_text(
                    a, r, c["n_labels"][-1], curves["random"]["n_labels"][-1])
                print(f"{strategy}/random labels at 2% relative error ({key.replace('_', ' ')}): "
                      f"{text} (target <= 0.65)")
    # How much of that ratio is the draw of seeds: resample them (the same draw for every curve).
    boot: dict[str, dict] = {}
    if "random" in curves:
        n_boot = int(getattr(args, "n_boot", 2000))
        for strategy, acc in accs.items():
            if strategy == "random":
                continue
            boot[strategy] = {key: bootstrap_label_ratio(curves[strategy]["n_labels"], acc, accs["random"],
                                                         full, n_boot=n_boot, sustained=key == "sustained")
                              for key in ("reached", "sustained")}

        def cell(v):
            return "-" if v is None else f"{v:.2f}"

        print_table([{"strategy": s, "reading": key, "ratio": cell(b["ratio"]), "median": cell(b["median"]),
                      "90% interval": f"{cell(b['ci90'][0])}-{cell(b['ci90'][1])}",
                      "P(<=0.65)": b["p_target"], "never": b["never"]}
                     for s, both in boot.items() for key, b in both.items()],
                    ["strategy", "reading", "ratio", "median", "90% interval", "P(<=0.65)", "never"],
                    f"Seed bootstrap of the 2% label ratio to random ({n_boot} draws of the "
                    f"{len(seeds)} seeds; '-' = never reached, or random never reaches the line)")
    # Every (seed, round) pair against random: the table reads one point of a noisy mean curve.
    paired: dict[str, dict] = {}
    if "random" in curves:
        for strategy, acc in accs.items():
            if strategy != "random":
                paired[strategy] = paired_advantage(acc, accs["random"])
        print_table([{"strategy": s, "mean_diff": p["mean_diff"], "ahead": f"{p['ahead']}/{p['pairs']}",
                      "wilcoxon_p": "n/a" if p["wilcoxon_p"] is None else p["wilcoxon_p"]}
                     for s, p in paired.items()],
                    ["strategy", "mean_diff", "ahead", "wilcoxon_p"],
                    "Paired against random over seeds and query rounds (accuracy points)")
    plot = _plot_path(args)
    write_json_and_figure(args.json, {
        "bench": "active-learning", **meta,
        "curves": curves, "table_7_1": rows, "table_7_1_sustained": stay_rows,
        "ratio_entropy_random_2pct": ratios.get("entropy"), "ratios_2pct": ratios,
        "ratios_2pct_sustained": ratios_stay, "ratios_2pct_text": ratio_texts,
        "paired_vs_random": paired, "bootstrap_2pct": boot,
        "machine": machine_info(),
    }, plot, active_learning_figure)
    print(f"wrote {args.json}\nplot: {plot}")
    if journal is not None:  # kept until now: a rerun after a failed plot trains nothing again
        kept = journal.finish()
        if kept:
            size = sum(f.stat().st_size for d in kept for f in d.rglob("*") if f.is_file())
            print(f"kept the last state of {_loops(len(kept))} in {journal.folder} ({size / 2**20:.1f} MiB): "
                  f"the same command with more or fewer --rounds goes on from them; --fresh or removing the "
                  f"folder lets them go")
    return 0


def active_learning_figure(result: dict, path) -> Path:
    """Test accuracy against labelled clouds per strategy (mean ± std over seeds), with the full-pool model
    and its 2 % relative-error line (Fig. 7.5a analogue), from ``bench active-learning``'s result or JSON."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    acc_full = float(np.mean(result["full_acc"]))
    fig, ax = plt.subplots(figsize=(6, 4))
    for strategy, c in result["curves"].items():
        m, s = 100 * np.array(c["acc_mean"]), 100 * np.array(c["acc_std"])
        ax.plot(c["n_labels"], m, marker="o", label=strategy)
        ax.fill_between(c["n_labels"], m - s, m + s, alpha=0.2)
    ax.axhline(100 * acc_full, color="k", ls="--", lw=1, label="full pool")
    ax.axhline(100 * acc_full * (1 - 0.02), color="k", ls=":", lw=1, label="2 % relative error")
    ax.set_xlabel("labelled clouds")
    ax.set_ylabel("test accuracy (%)")
    ax.set_title("MC-dropout active learning (Fig. 7.5a analogue)")
    ax.legend()
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def _read_xavtnet(ckpt_path: Path):
    """``(checkpoint dict, XAVTNet in eval mode)`` of ``--ckpt`` (``weights_only=True``); an unreadable file
    or a checkpoint of another model is a ValueError naming ``--ckpt``, before any data is read."""
    from vtlearn.models.actor import read_lightning_checkpoint
    from vtlearn.models.xavtnet import load_xavtnet
    from vtlearn.validation import load_named

    ckpt = load_named(read_lightning_checkpoint, ckpt_path, "--ckpt")
    return ckpt, load_named(lambda p: load_xavtnet(p, ckpt), ckpt_path, "--ckpt")


def run_adapt_bn(args: argparse.Namespace) -> int:
    """``vtlearn adapt-bn``: AdaBN for a trained xAVTNet checkpoint (no labels, no weight changes).

    Loads ``--ckpt`` (``weights_only=True``), re-estimates the target batch-norm statistics on the unlabelled
    tactile clouds of ``--data`` (split ``--split``, or those of ``--target-data``) with
    :meth:`~vtlearn.models.xavtnet.XAVTNet.adapt_bn_statistics`, prints the tactile test accuracy before and
    after when the dataset has a labelled test split, and writes ``--out`` atomically: the input checkpoint
    with the new state dict and ``domain_bn: true``, so ``XAVTNet.load_from_checkpoint`` and the runtime
    load it as before and score tactile clouds with the new statistics.
    """
    import lightning as L

    from vtlearn.bench_utils import check_output_path
    from vtlearn.datamodules import CrossModalDataModule

    _quiet_lightning()
    ckpt_path, out = Path(args.ckpt), Path(args.out)
    if not ckpt_path.is_file():
        raise FileNotFoundError(f"--ckpt: no checkpoint at {ckpt_path}")
    check_output_path(out, "--out", "adapted checkpoint")  # a folder, or below a file: before any work
    if out.resolve() == ckpt_path.resolve():
        raise ValueError("--out: must differ from --ckpt (the input checkpoint is kept)")
    if args.passes < 1:
        raise ValueError(f"--passes: need >= 1, got {args.passes}")
    ckpt, model = _read_xavtnet(ckpt_path)
    L.seed_everything(args.seed, verbose=False)
    from vtlearn.models.xavtnet_inference import checkpoint_normalize

    dm = _check_up_front(lambda: CrossModalDataModule(
        args.data, batch_size=args.batch_size, target_split=args.split, target_data_dir=args.target_data,
        seed=args.seed, normalize=checkpoint_normalize(dict(model.hparams))),  # the clouds as trained
        {"data_dir": "--data", "target_data_dir": "--target-data", "target_split": "--split",
         "batch_size": "--batch-size", "seed": "--seed"}, None)  # adapt-bn has no --config
    if dm.num_classes != model.hparams.num_classes:
        raise ValueError(f"--data: {dm.num_classes} classes, the checkpoint has {model.hparams.num_classes}")
    from vtlearn.datamodules.shards import load_manifest

    has_test = "test" in load_manifest(args.data)["splits"]

    def tactile_accuracy() -> float:
        trainer = L.Trainer(accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
                            enable_model_summary=False)
        result = trainer.test(model, dataloaders=dm.test_dataloader(), verbose=False)[0]
        return 100 * float(result["test/acc"])

    before = tactile_accuracy() if has_test else None
    n = model.adapt_bn_statistics(dm.target_dataloader(), passes=args.passes)
    after = tactile_accuracy() if has_test else None
    ckpt["state_dict"] = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    ckpt["hyper_parameters"] = {**ckpt["hyper_parameters"], "domain_bn": True}
    ckpt.pop("optimizer_states", None)  # the new statistics are not a training state to resume
    ckpt.pop("lr_schedulers", None)
    import torch

    from vtlearn.io import atomic_path

    with atomic_path(out) as tmp:  # a failed write leaves neither half a checkpoint nor its temporary file
        torch.save(ckpt, tmp)
    print(f"target statistics from {n} unlabelled tactile clouds x {args.passes} pass(es)")
    if has_test:
        print(f"tactile test accuracy: {before:.1f} % before, {after:.1f} % after")
    print(f"wrote {out}")
    return 0


def run_recognize(args: argparse.Namespace) -> int:
    """``vtlearn recognize``: xAVTNet class probabilities and MC-dropout uncertainty of clouds from files, or
    of stored tactile clouds of a crossmodal dataset (with their true labels), from a checkpoint loaded with
    ``weights_only=True`` (:mod:`vtlearn.models.xavtnet_inference`)."""
    import torch

    from vtlearn.bench_utils import write_json
    from vtlearn.io import read_cloud
    from vtlearn.models.xavtnet_inference import (
        _check_box,
        checkpoint_class_names,
        recognition_figure,
        recognize_clouds,
    )

    if args.threads:
        torch.set_num_threads(args.threads)
    if bool(args.inputs) == (args.data is not None):
        raise ValueError("inputs: give cloud files, or --data DIR with --index, not both and not neither")
    if args.data is not None:
        for flag, value in (("--extent-m", args.extent_m), ("--units", args.units), ("--box-m", args.box_m)):
            if value is not None:
                raise ValueError(f"{flag}: only for cloud files in metres; stored clouds are in their "
                                 "object's frame")
        if args.index is None:
            raise ValueError("--index: required with --data: the indices of the stored tactile clouds to "
                             "recognise (e.g. --index 0 1 2)")
    else:
        for flag, value in (("--index", args.index), ("--split", args.split)):
            if value is not None:
                raise ValueError(f"{flag}: only with --data DIR (stored tactile clouds); cloud files are "
                                 "recognised as given")
    box = None if args.box_m is None else [args.box_m[:3], args.box_m[3:]]
    if box is not None:
        _check_box(box, "--box-m")
    ckpt_path = Path(args.ckpt)
    if not ckpt_path.is_file():
        raise FileNotFoundError(f"--ckpt: no checkpoint at {ckpt_path}")
    _, model = _read_xavtnet(ckpt_path)
    n_classes = int(model.hparams.num_classes)
    override = None
    if args.class_names:
        if args.class_names.endswith(".json"):
            from vtlearn.datamodules.shards import read_class_names

            override = read_class_names(args.class_names, "--class-names")
        else:
            override = [s.strip() for s in args.class_names.split(",")]
        try:  # one name per class, checked before any cloud is read
            checkpoint_class_names(dict(model.hparams), override)
        except ValueError as exc:
            raise ValueError(f"--class-names: {str(exc).removeprefix('class_names: ')}") from None
    truth = None
    if args.data is not None:
        from vtlearn.datamodules.crossmodal import modality_clouds
        from vtlearn.datamodules.shards import load_manifest, load_split

        split = args.split or "test"
        manifest = load_manifest(args.data, name="--data")
        if len(manifest["class_names"]) != n_classes:
            raise ValueError(f"--data: {args.data} has {len(manifest['class_names'])} classes, the "
                             f"checkpoint {n_classes}")
        if split not in manifest["splits"]:
            raise ValueError(f"--split: {args.data} has no {split!r} split (it has "
                             f"{sorted(manifest['splits'])})")
        stored, labels, _ = modality_clouds(load_split(args.data, split, verify=True, name="--data"),
                                            "tactile", False)
        bad = [i for i in args.index if not 0 <= i < len(stored)]
        if bad:
            raise ValueError(
                f"--index: {bad} out of range; split {split!r} has {len(stored)} tactile clouds"
            )
        clouds = [stored[i].astype(np.float64) for i in args.index]
        titles = [f"{split}[{i}]" for i in args.index]
        override = override or list(manifest["class_names"])
        truth = [override[int(labels[i])] for i in args.index]
        units, extent = "canonical", None  # stored clouds are in the canonical frame already
    else:
        clouds = [read_cloud(p) for p in args.inputs]
        titles = [Path(p).name for p in args.inputs]
        units, extent = args.units or "metres", args.extent_m
    names = checkpoint_class_names(dict(model.hparams), override)
    try:
        result = recognize_clouds(model, clouds, class_names=names, extent_m=extent, units=units,
                                  mc_samples=args.mc_samples, domain=args.domain, seed=args.seed, box_m=box)
    except ValueError as exc:  # "clouds[i]: ..." names the i-th file (or stored cloud) as the user gave it
        sources = titles if args.data is not None else list(args.inputs)
        raise ValueError(re.sub(r"^clouds\[(\d+)\]", lambda m: sources[int(m.group(1))], str(exc))) from None
    rows = []
    for i, title in enumerate(titles):
        row = {"input": title, "points": len(clouds[i]), **result.to_dict(i, args.zeta)}
        if truth is not None:
            row["true"] = truth[i]
        rows.append(row)
        top = ", ".join(f"{n} {p:.2f}" for n, p in result.top(i, args.top))
        extra = "" if result.mutual_information is None else f", MI {result.mutual_information[i]:.3f}"
        verdict = "confident" if row["confident"] else f"below zeta={args.zeta}: touch more"
        known = "" if truth is None else f" (true: {truth[i]})"
        h = row["entropy_nats"]
        print(f"{title}: {row['predicted']}{known} [{top}]; H {h:.3f} nats{extra}; {verdict}")
    if truth is not None:
        right = sum(r["predicted"] == r["true"] for r in rows)
        print(f"{right}/{len(rows)} right")
    if args.json:
        write_json(args.json, {"ckpt": str(ckpt_path), "class_names": names, "units": units,
                               "extent_m": extent, "box_m": box, "mc_samples": args.mc_samples,
                               "domain": args.domain, "results": rows})
        print(f"wrote {args.json}")
    if args.figure:
        print(f"wrote {recognition_figure(clouds, titles, result, args.figure, top=args.top)}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("recognize", help="xAVTNet: class and MC-dropout uncertainty of tactile clouds (ch.7)")
    p.add_argument("--ckpt", required=True, help="XAVTNet checkpoint (loaded with weights_only=True)")
    p.add_argument("inputs", nargs="*", help="gravity-aligned clouds, z up (.ply .pcd .xyz .txt .npy .npz)")
    p.add_argument("--data", default=None,
                   help="instead of files: a crossmodal dataset dir; recognises its stored tactile clouds "
                        "--index of --split and prints their true classes")
    p.add_argument("--split", default=None, help="--data: the split of the stored clouds (default test)")
    p.add_argument("--index", type=count(0), nargs="+", default=None,
                   help="--data (required with it): the indices of its tactile clouds to recognise")
    p.add_argument("--class-names", default=None,
                   help="a crossmodal manifest.json or a comma list; default: the names in the checkpoint "
                        "(--data: its manifest), else class_0..")
    p.add_argument("--units", choices=["metres", "canonical"], default=None,
                   help="files: metres (default; scaled by --extent-m into the canonical frame) or already "
                        "canonical")
    p.add_argument("--extent-m", type=real(0.0, open_low=True), default=None,
                   help="the object's largest bounding-box extent in metres (default: each cloud's own, an "
                        "underestimate for a few touches)")
    p.add_argument("--box-m", type=float, nargs=6, default=None,
                   metavar=("LO_X", "LO_Y", "LO_Z", "HI_X", "HI_Y", "HI_Z"),
                   help="the object's axis-aligned bounding box in metres, instead of --extent-m; needed by "
                        "a checkpoint trained in the object frame (input_normalize none)")
    p.add_argument("--mc-samples", type=count(0), default=20,
                   help="MC-dropout passes T (eq. 7.3); 0 for one deterministic pass")
    p.add_argument("--domain", choices=["target", "source"], default="target",
                   help="batch-norm statistics of a domain-BN model: target (tactile) or source (visual)")
    p.add_argument("--zeta", type=real(0.0, 1.0, open_high=True), default=0.8,
                   help="confidence stop of thesis 7.2.4 (default 0.8)")
    p.add_argument("--top", type=count(1), default=3, help="classes to print")
    p.add_argument("--seed", type=count(0), default=0, help="dropout masks of the MC passes")
    p.add_argument("--threads", type=count(0), default=0, help="torch CPU threads (0: default)")
    p.add_argument("--json", default=None, help="write the results as JSON")
    p.add_argument("--figure", default=None, help="PNG: each cloud and its class probabilities")
    p.set_defaults(func=run_recognize)

    p = sub.add_parser("adapt-bn", help="AdaBN: re-estimate an xAVTNet checkpoint's target batch-norm "
                                        "statistics on unlabelled tactile clouds")
    p.add_argument("--ckpt", required=True, help="trained XAVTNet checkpoint")
    p.add_argument("--data", required=True, help="crossmodal dataset dir (vtlearn gen-data crossmodal)")
    p.add_argument("--split", choices=["train", "test"], default="train",
                   help="whose unlabelled tactile clouds: train instances (default) or the test instances "
                        "themselves (transductive)")
    p.add_argument("--target-data", default=None,
                   help="read the tactile clouds of --split from this dataset instead (e.g. vtlearn "
                        "gen-episodes); --data still gives the test clouds")
    p.add_argument("--passes", type=count(1), default=1, help="passes over the clouds (default 1)")
    p.add_argument("--batch-size", type=count(1), default=32)
    p.add_argument("--seed", type=count(0), default=0, help="order and yaw augmentation of the clouds")
    p.add_argument("--out", required=True, help="adapted checkpoint (the input is kept)")
    p.set_defaults(func=run_adapt_bn)


_FRESH_HELP = ("train every job again: discard the finished jobs that a stopped run with this --json kept "
               "beside it (in JSON_STEM.jobs/; by default the same command goes on from them)")


def register_bench(sub) -> None:
    p = sub.add_parser("crossmodal", help="Table 7.2/7.4 analogue: V->T accuracy of each DA variant")
    p.add_argument("--config", default=None, help="LightningCLI YAML (e.g. configs/quick/xavtnet.yaml)")
    p.add_argument("--data", default=None, help="crossmodal dataset dir (overrides the config's data_dir)")
    p.add_argument("--variants", default=",".join(v for v in VARIANTS if not v.endswith(OPT_IN_SUFFIXES)),
                   help=f"comma list of {list(VARIANTS)}, or {ORACLE} (trained on labelled tactile clouds, "
                        f"the upper bound), or the classical rows {list(CLASSICAL_ROWS)} (Table 7.4's ESF "
                        "descriptors, with or without the Geodesic Flow Kernel, 1-NN or linear SVM, and "
                        "their _oracle rows fitted on labelled touches); default: the thesis rows and dann")
    p.add_argument("--seeds", type=count(1), default=3, help="number of seeds (default 3)")
    p.add_argument("--seed", type=count(0), default=0, help="first seed")
    p.add_argument("--max-epochs", type=count(1), default=None)
    p.add_argument("--batch-size", type=count(1), default=None)
    p.add_argument("--threads", type=count(1), default=1, help="torch threads (default 1: the CPU is shared)")
    p.add_argument("--workers", type=count(1), default=1,
                   help="(variant, seed) trainings run in parallel, each with --threads threads")
    p.add_argument("--target-split", choices=["train", "test", "train+test"], default=None,
                   help="unlabelled tactile clouds for adaptation: train instances (inductive), the "
                        "test instances themselves (transductive UDA protocol) or both in one stream "
                        "(train+test); default from the config (its data.init_args.target_split, else "
                        "train)")
    p.add_argument("--source-points", nargs=2, type=count(1), default=None, metavar=("N_MIN", "N_MAX"),
                   help="thin every visual training cloud to N_MIN..N_MAX points (the tactile density; "
                        "CrossModalDataModule source_points); default from the config: dense")
    p.add_argument("--source-views", type=count(1), default=None, metavar="K",
                   help="fuse K views of the instance into every visual training cloud (CrossModalDataModule "
                        "source_views); default from the config: 1, the single view")
    p.add_argument("--source-touch", action="store_true",
                   help="replace each visual training cloud by simulated pad touches on it "
                        "(CrossModalDataModule source_touch; use with --source-views 6)")
    p.add_argument("--source-splits", default=None, metavar="SPLITS",
                   help="comma list of splits whose labelled visual clouds form the source (default: the "
                        "config's, train). 'train,test' with --target-split test is the thesis's "
                        "known-objects protocol (7.3.1): the test objects are seen, labelled, by vision and "
                        "recognised by touch; 'test' on a dataset with one test instance per class is its "
                        "twelve objects (configs/cpu/xavtnet_objects.yaml)")
    p.add_argument("--target-holdout", type=real(0.0, 1.0), default=None, metavar="F",
                   help="with --target-split test: hold this fraction of each test instance's tactile clouds "
                        "out of the target stream and score only those (the thesis's 900 + 300 split is "
                        "0.25; CrossModalDataModule target_holdout); default from the config: 0. The "
                        "tactile_oracle variant then trains on the stream's touches with their labels")
    p.add_argument("--target-data", default=None,
                   help="dataset whose tactile clouds of the target split form the unlabelled target stream "
                        "(e.g. closed-loop episodes from `vtlearn gen-episodes`); default: --data's own")
    p.add_argument("--adabn", action="store_true",
                   help="also score every row after re-estimating its target batch-norm statistics on the "
                        "unlabelled target stream (AdaBN, XAVTNet.adapt_bn_statistics): tactile_acc_adabn, "
                        "and tactile_acc_teacher_adabn on teacher rows")
    p.add_argument("--balanced", action="store_true",
                   help="also score every row's class-balanced assignment of the whole tactile test set "
                        "(Sinkhorn-Knopp to the source class frequencies; transductive, label-free): "
                        "tactile_acc_balanced, and tactile_acc_teacher_balanced on teacher rows")
    p.add_argument("--centroid", action="store_true",
                   help="also score SHOT's centroid labels of the whole tactile test set from every row's "
                        "global features (transductive, label-free): tactile_acc_centroid, and "
                        "tactile_acc_teacher_centroid on teacher rows")
    p.add_argument("--probe", action="store_true",
                   help="diagnostic: also score a linear probe of every row's global features, fitted on the "
                        "labelled tactile training clouds (labels no row trains with): tactile_acc_probe, "
                        "and tactile_acc_teacher_probe on teacher rows")
    p.add_argument("--discrepancy", action="store_true",
                   help="also measure the squared MK-MMD and the Deep CORAL distance (eq. 7.5-7.7) that "
                        "every row leaves between the visual and the tactile test clouds' eval-mode global, "
                        "fc1 and fc2 features, and the tactile over the visual mean feature norm (per run: "
                        "discrepancy; a table of means ± std)")
    p.add_argument("--accelerator", choices=["cpu", "gpu", "auto"], default="cpu",
                   help="Lightning accelerator of every training (default cpu; with gpu, --workers trainings "
                        "share the one device)")
    p.add_argument("--baseline", default="noda",
                   help="the row every other row is paired against, seed by seed, after the table (default "
                        "noda; with two seeds or more)")
    p.add_argument("--pairs", default=None, metavar="A-B,...",
                   help="further seed-paired comparisons, each the row expected ahead, a minus sign and the "
                        "other row; ROW.SCORE reads another score of the row, e.g. "
                        "'vtloss-mmd,vtloss_g12_mt_vote.teacher-noda_vote' (.teacher: tactile_acc_teacher)")
    p.add_argument("--margin", type=float, default=None, metavar="POINTS",
                   help="also give, for every comparison, the one-sided p-value that the row is no more "
                        "than POINTS ahead (the issue's target: 20)")
    p.add_argument("--merge", nargs="+", default=None, metavar="JSON",
                   help="train nothing: pool the runs of earlier results of one protocol (more seeds, or "
                        "rows run apart; the same data, epochs and model) into one table, the paired "
                        "comparisons, a figure and --json; pairs whose runs ran on different machines are "
                        "counted (cross_machine). --variants and the training flags are not used")
    p.add_argument("--merge-sets", dest="merge_sets", nargs="+", default=None, metavar="JSON",
                   help="train nothing: read the results of one protocol on several datasets (object sets, "
                        "e.g. the thesis's twelve-object protocol on several draws; told apart by their data "
                        "fingerprints), pool each set's files as --merge does, and pair the rows by object "
                        "set (each set's mean over its seeds is one pair): a per-set table, the set-paired "
                        "comparisons (--baseline, --pairs, --margin), a figure and --json")
    p.add_argument("--versus-sets", dest="versus_sets", nargs="+", default=None, metavar="JSON",
                   help="with --merge-sets: the same object sets read otherwise (rendered opaque, other "
                        "touches; the same protocol bar the data), paired with --merge-sets' sets in the "
                        "order first named: how each row's accuracy and each margin moved, set by set, a "
                        "figure and a 'versus' part of --json")
    p.add_argument("--rows", default=None, metavar="ROW,...",
                   help="with --merge or --merge-sets: keep only these rows of the files read (default: "
                        "all), in the tables, the comparisons and --json")
    p.add_argument("--no-figures", action="store_true",
                   help="skip the confusion matrix, t-SNE and paired-difference figures")
    p.add_argument("--out-dir", default=None,
                   help="figure folder (default: beside --json, named after it without .json)")
    p.add_argument("--fresh", action="store_true", help=_FRESH_HELP)
    p.add_argument("--json", default="runs/bench/crossmodal.json")
    p.set_defaults(func=run_crossmodal_bench)

    q = sub.add_parser("active-learning", help="Table 7.1 analogue: MC-dropout entropy/BALD vs random")
    q.add_argument("--config", default=None, help="YAML, e.g. configs/quick/active_learning.yaml")
    q.add_argument("--data", default=None, help="dataset dir (overrides the config's data_dir)")
    q.add_argument("--modality", default=None, help="visual (thesis) or tactile; default from the config")
    # None = take the config's `active:` section, else AL_DEFAULTS
    q.add_argument("--strategies", default=None,
                   help="comma list of entropy, bald, random, power_entropy, power_bald (power_*: draw the "
                        "batch ∝ score^beta instead of the top kappa)")
    q.add_argument("--power-beta", dest="power_beta", type=real(0.0), default=None,
                   help="beta of the power_* strategies (default 1)")
    q.add_argument("--n0", type=count(1), default=None, help="initial random labels")
    q.add_argument("--kappa", type=count(1), default=None, help="queries per round")
    q.add_argument("--rounds", type=count(1), default=None)
    q.add_argument("--mc-passes", dest="mc_passes", type=count(1), default=None, help="T of eq. 7.3")
    q.add_argument("--warm-start", dest="warm_start", action="store_const", const=True, default=None,
                   help="fine-tune between rounds (default: retrain from scratch)")
    q.add_argument("--min-steps", dest="min_steps", type=count(0), default=None,
                   help="at least this many optimiser steps per training (more epochs on small sets)")
    q.add_argument("--equal-steps", dest="equal_steps", action="store_const", const=True, default=None,
                   help="every training (each round and the full-pool reference) runs the same number of "
                        "optimiser steps: max_epochs over the whole pool (default: max_epochs over the "
                        "labelled set, at least --min-steps)")
    q.add_argument("--accelerator", choices=["cpu", "gpu", "auto"], default="cpu",
                   help="Lightning accelerator of every training (default cpu)")
    q.add_argument("--seeds", type=count(1), default=2)
    q.add_argument("--seed", type=count(0), default=0)
    q.add_argument("--max-epochs", type=count(1), default=None)
    q.add_argument("--batch-size", type=count(1), default=None)
    q.add_argument("--threads", type=count(1), default=1)
    q.add_argument("--workers", type=count(1), default=1,
                   help="(strategy, seed) loops and full-pool references run in parallel processes")
    q.add_argument("--merge", nargs="+", default=None, metavar="JSON",
                   help="train nothing: pool the seeds of earlier results made with the same protocol "
                        "(e.g. --seed 0 --seeds 3 and --seed 3 --seeds 3) into one table, plot and JSON; "
                        "files of the same seeds with other strategies (e.g. --strategies bald) are "
                        "joined first")
    q.add_argument("--n-boot", dest="n_boot", type=count(1), default=2000,
                   help="seed-bootstrap draws for the interval of the 2%% label ratio (default 2000)")
    q.add_argument("--plot", default=None, help="PNG of accuracy against labels (default: beside --json)")
    q.add_argument("--fresh", action="store_true", help=_FRESH_HELP)
    q.add_argument("--keep-loops", dest="keep_loops", action="store_true",
                   help="keep each loop's last state (its weights and labels) beside --json, in "
                        "JSON_STEM.jobs/, so that the same command with more --rounds trains only the new "
                        "rounds, and with fewer trains nothing (a folder holding kept states is kept)")
    q.add_argument("--json", default="runs/bench/active_learning.json")
    q.set_defaults(func=run_active_learning_bench)
