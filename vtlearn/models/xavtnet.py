"""xAVTNet: visuo-tactile cross-modal object recognition with VTLoss, thesis ch.7.

A PointNet classifier (section 7.2.2, 7.3.1) trained on labelled dense visual clouds (source domain)
and adapted, without tactile labels, to sparse tactile clouds (target domain) by VTLoss (eq. 7.8):

    L = α·CE(source) + β·Σ_{l∈{fc1,fc2}} MK-MMD²_l + λ·Σ_l CORAL_l  (+ w_ft·‖I − A Aᵀ‖²_F)

The last term is PointNet's feature-transform regulariser on the source stream. Training is
two-stream (Fig. 7.2b): each step takes a labelled source batch and an unlabelled target batch
(``{"source": {...}, "target": {...}}`` from :class:`vtlearn.datamodules.CrossModalDataModule`); both go
through the *same* weights, one forward each. A plain labelled batch (``{"points", "lengths",
"label"}``, e.g. from the active-learning pool) trains with cross-entropy only.

``da_method`` selects the domain adaptation:

* ``"none"``: no-DA (xAVTNet-noDA of Table 7.4); the target stream is not used at all.
* ``"vtloss"``: eq. 7.8; ``use_mmd``, ``use_coral`` and ``da_layers`` give the rows of Table 7.2.
* ``"dann"``: DANN (Ganin et al. 2016), beyond the thesis: a domain discriminator on fc2 behind a
  gradient reversal layer whose λ follows Ganin's ramp over training; loss ``α·CE + dann_weight·L_dom``.
* ``"cdan"``: CDAN+E (Long et al. 2018), beyond the thesis: as DANN, but the discriminator reads the
  multilinear map of fc2 and the softmax (:mod:`vtlearn.losses.cdan`), so it aligns features jointly with
  the predicted classes, and each cloud's term is weighted by ``1 + e^{−H}`` of its prediction
  (``cdan_entropy``); same weight and ramp (``dann_weight``, ``dann_gamma``).

``im_weight > 0`` (beyond the thesis) adds ``im_weight·L_IM`` of the target batch's logits to any of
them, the information maximisation of :mod:`vtlearn.losses.info_max` (confident target predictions that
use every class); with ``da_method="none"`` it is the only use of the target stream. ``mcc_weight > 0``
adds ``mcc_weight·L_MCC`` in the same way, Jin et al.'s minimum class confusion of the target logits
(:mod:`vtlearn.losses.mcc`, at temperature ``mcc_temperature``). ``mcd_weight > 0`` adds Saito et al.'s
maximum classifier discrepancy (:mod:`vtlearn.losses.mcd`): a second classifier F₂ beside fc3 on the fc2
feature, trained on the source clouds with the same ``α·CE``, and ``−mcd_weight·d(F₁, F₂)`` of the target
batch through a gradient reversal, so the two classifiers pull apart on the target clouds and the network
below them pulls those clouds back to where the two agree. fc3 (F₁) alone makes the model's predictions.
``sa_nodes > 0`` puts PointDAN's self-adaptive nodes in the encoder after the feature T-net
(:mod:`~vtlearn.models.components.sa_nodes`; Qin et al. 2019, beyond the thesis), and ``node_mmd_weight > 0``
adds PointDAN's local alignment, ``node_mmd_weight·MK-MMD²`` of the source and target node features, each
domain's through its own node attention (:mod:`vtlearn.losses.pointdan`). With ``mcd_weight > 0`` as well,
the model is PointDAN: MCD's global alignment and the nodes' local one.
``afn_weight > 0`` adds Xu et al.'s stepwise adaptive feature norm (:mod:`vtlearn.losses.afn`),
``afn_weight·(L_SAFN(fc2 source) + L_SAFN(fc2 target))``: every step asks the fc2 feature of every source
and target cloud for a norm ``afn_step`` larger than it has, rather than aligning the two domains.

``pseudo_label_weight > 0`` (beyond the thesis) adds self-training on the target stream: from epoch
``⌈pseudo_label_start·max_epochs⌉`` on, each epoch starts with one pass over the target clouds, which
get SHOT's centroid pseudo-labels with CBST's class-balanced selection
(:func:`~vtlearn.losses.pseudo_labels.centroid_pseudo_labels`), and each step adds
``pseudo_label_weight·CE`` of the target batch's logits against the kept labels. The target items must
carry their ``"index"`` in the target dataset, as :class:`~vtlearn.datamodules.CrossModalDataModule`'s do.
With ``pseudo_label_groups`` the labels are voted over each object's touches instead
(:func:`~vtlearn.losses.pseudo_labels.group_vote_pseudo_labels`; the items' ``"group"`` names the object
instance, not its class).

``consistency_weight > 0`` (beyond the thesis) adds a mean teacher on the target stream (Tarvainen and
Valpola 2017; French et al. 2018 for domain adaptation): a copy of the network, ``teacher``, follows the
trained weights as an exponential moving average (``ema_decay``) and is never optimised. Each step the
target batch goes through the network as a perturbed copy (point dropout to a share in
``[consistency_keep, 1]`` of its points and Gaussian jitter of ``consistency_jitter``, the same copy
that the other target terms see), and through the teacher, without dropout or gradient, as another
perturbed copy, normalised by the batch statistics of the source batch and that copy together as the
network's own training forward is (``teacher_norm``); the step adds ``consistency_weight·r(p)·L_cons``
of the two softmaxes (:func:`~vtlearn.losses.consistency.softmax_consistency`), with Tarvainen's sigmoid
ramp-up ``r`` over the first ``consistency_rampup`` of the training progress ``p``. Evaluation uses the
trained network, unless :meth:`XAVTNet.adopt_teacher` has put the teacher's weights in its place.
``consistency_align=True`` first aligns the teacher's probabilities with the source class frequencies
(ReMixMatch's distribution alignment, :mod:`~vtlearn.models.components.class_balance`), so that the classes
the teacher over-predicts on the target stream weigh less in its targets and the neglected ones more.
``consistency_loss="cross_entropy"`` takes FixMatch's cross-entropy against the teacher's argmax in place
of the squared difference, and ``student_keep``, ``student_jitter`` and ``student_scale`` give the
network's copy a stronger perturbation than the teacher's (FixMatch's weak and strong views; AdaMatch,
Berthelot et al. 2022, for domain adaptation).

``neighbour_weight > 0`` (beyond the thesis) adds AaD's neighbourhood clustering of the target stream
(:mod:`vtlearn.losses.neighbourhood`): from epoch ``⌈neighbour_start·max_epochs⌉`` on (by default a
third, as for the pseudo-labels), a bank holds the ``neighbour_layer`` feature and the softmax of every
target cloud, filled by one eval-mode pass and then overwritten by each training batch's own rows; each
step adds ``neighbour_weight·L_AaD`` of the target batch's softmax against its ``neighbour_k`` nearest
bank neighbours (itself left out), with the batch dispersion weighted ``neighbour_dispersion``. The bank
is not saved in checkpoints: a resumed run refills it at its next epoch. The target items must carry
their ``"index"``.

``rotation_weight > 0`` (beyond the thesis) adds a self-supervised task shared by both domains: every step
the source and target clouds, each turned by a random number of quarter turns about the canonical x axis,
go through the encoder in one more forward (batch statistics, running ones untouched), and a rotation
head on the pooled feature must name the turn (:mod:`~vtlearn.models.components.rotation_task`; Sun et
al. 2019, GAST). The step adds ``rotation_weight·CE`` of that head.

``defrec_weight > 0`` (beyond the thesis) adds DefRec's deformation reconstruction, shared by both domains
(:mod:`~vtlearn.models.components.deformation_task`; Achituve et al., WACV 2021): every step each source
and target cloud has one voxel of its bounding box's ``defrec_regions³`` replaced by Gaussian draws at the
voxel's centre, the deformed clouds go through the encoder in one more forward (batch statistics, running
ones untouched), and a per-point decoder on each point's features and the pooled feature must put the
voxel's points back. The step adds ``defrec_weight`` times the region's symmetric Chamfer distance.

``contrast_weight > 0`` (beyond the thesis) adds SimCLR's contrastive task on the target stream
(:mod:`vtlearn.losses.contrastive`): every step the unperturbed target batch is perturbed twice as the
teacher's copy is (``consistency_keep``, ``consistency_jitter``), both copies go through the encoder in one
more forward (batch statistics, running ones untouched), and a projection head on the pooled feature
(:mod:`~vtlearn.models.components.projection_head`) must pair each copy with its partner among the
batch's others at temperature ``contrast_temperature``. The step adds ``contrast_weight·L_NT-Xent``.

``mix_weight > 0`` (beyond the thesis) adds cross-domain mixup
(:mod:`~vtlearn.models.components.cloud_mixup`): every target cloud of the step is mixed with a source
cloud of the batch into a cloud of the target's size, labelled by the source label and the teacher's (or
the network's) probability in the share of points each gave, and the step adds
``mix_weight·r(p)·CE_soft`` of the network on the mixed clouds (batch statistics, running ones untouched).

``domain_bn=True`` (beyond the thesis) gives every batch norm one set of running statistics per domain
(:mod:`vtlearn.models.components.domain_bn`, AdaBN / DSBN): source and target batches are then normalised
separately in training, and evaluation uses the target (tactile) statistics unless a block runs under
``model.bn_domain("source")``. With ``da_method="none"`` the target batches only update the target
statistics (no loss, no gradient): AdaBN as a baseline. A mean teacher then keeps both domains'
statistics as well, and normalises its copy of the target batch with the target ones (that copy's batch
statistics with ``teacher_norm="batch"``). Without ``domain_bn`` the two streams share one forward and
pooled statistics, as in DAN and Deep CORAL.

Shapes:
    forward: points (B, N, 3) zero-padded, lengths (B,) int64 -> :class:`XAVTNetOutput`
    (logits (B, k), features {"global": (B, global_dim), "fc1": (B, 512), "fc2": (B, 256)}).
"""

from __future__ import annotations

import contextlib
import copy
import math

import lightning as L
import torch
import torch.nn.functional as F
from torchmetrics import MeanMetric
from torchmetrics.classification import MulticlassAccuracy, MulticlassConfusionMatrix

from vtlearn.losses.afn import AFN_STEP, adaptive_feature_norm
from vtlearn.losses.cdan import entropy_weights, multilinear_map
from vtlearn.losses.consistency import confident_cross_entropy, probability_consistency
from vtlearn.losses.contrastive import nt_xent
from vtlearn.losses.dann import dann_lambda, domain_adversarial_loss, grad_reverse
from vtlearn.losses.info_max import information_maximization
from vtlearn.losses.mcc import MCC_TEMPERATURE, minimum_class_confusion
from vtlearn.losses.mcd import mcd_adversarial_loss
from vtlearn.losses.neighbourhood import attract_disperse, neighbour_probs
from vtlearn.losses.pointdan import node_alignment_loss
from vtlearn.losses.pseudo_labels import centroid_pseudo_labels, group_vote_pseudo_labels
from vtlearn.losses.vtloss import VTLoss, check_kernel_weights, check_mmd_kernel
from vtlearn.models.components.class_balance import align_distribution
from vtlearn.models.components.cloud_mixup import mix_clouds, soft_cross_entropy
from vtlearn.models.components.deformation_task import RegionDecoder, deform_region, region_chamfer
from vtlearn.models.components.domain_bn import DOMAINS, DomainBatchNorm, convert_batchnorm, set_bn_domain
from vtlearn.models.components.feature_queue import FeatureQueue, scale_grad
from vtlearn.models.components.mean_teacher import ema_update, perturb_padded, sigmoid_rampup
from vtlearn.models.components.pointnet_tnet import feature_transform_regularizer, lengths_to_mask
from vtlearn.models.components.projection_head import ProjectionHead
from vtlearn.models.components.rotation_task import RotationHead, random_quarter_turns
from vtlearn.models.components.sa_nodes import NodeAttention
from vtlearn.models.components.xavtnet_backbone import (
    DomainDiscriminator,
    PointNetEncoder,
    XAVTNetHead,
    XAVTNetOutput,
    check_cloud_batch,
)
from vtlearn.validation import ConfigMismatchError, as_bool, as_int, as_real

__all__ = ["XAVTNet", "load_xavtnet", "subsample_padded", "normalize_padded"]

DA_METHODS = ("none", "vtloss", "dann", "cdan")
LR_SCHEDULES = ("constant", "cosine")
INPUT_NORMALIZE = ("center", "none", "unit_sphere")  # CrossModalDataModule(normalize=...)
DA_LAYERS = ("global", "fc1", "fc2", "fc3")
FEATURE_LAYERS = ("global", "fc1", "fc2")
TEACHER_NORMS = ("batch", "running")
CONSISTENCY_LOSSES = ("squared", "cross_entropy")
NEIGHBOUR_BANKS = ("network", "teacher")
# The running class frequencies of consistency_align: ReMixMatch averages the last 128 batches' predictions
ALIGN_MOMENTUM = 0.99


def _stream_lengths(batch: dict) -> torch.Tensor:
    """The batch's ``"lengths"``, or every cloud's full width when it has none.

    Shapes:
        batch["points"] (B, N, 3) -> (B,)
    """
    points, lengths = batch["points"], batch.get("lengths")
    if lengths is not None:
        return lengths
    return torch.full((points.shape[0],), points.shape[1], device=points.device)


def _concat_streams(src: dict, tgt: dict) -> tuple[torch.Tensor, torch.Tensor, int]:
    """The source and target batches as one zero-padded batch, source first, and the source batch size.

    Shapes:
        src["points"] (Bs, Ns, 3), tgt["points"] (Bt, Nt, 3), optional "lengths" -> (Bs + Bt, max(Ns, Nt), 3),
        (Bs + Bt,), Bs
    """
    ps, pt = src["points"], tgt["points"]
    ls, lt = _stream_lengths(src), _stream_lengths(tgt)
    n = max(ps.shape[1], pt.shape[1])
    points = torch.cat([F.pad(ps, (0, 0, 0, n - ps.shape[1])), F.pad(pt, (0, 0, 0, n - pt.shape[1]))])
    return points, torch.cat([ls, lt]), ps.shape[0]


def _batch_norms(*modules: torch.nn.Module) -> list:
    """Every batch norm inside ``modules`` (plain or :class:`DomainBatchNorm`), in module order."""
    return [m for mod in modules for m in mod.modules()
            if isinstance(m, torch.nn.modules.batchnorm._BatchNorm | DomainBatchNorm)]


@contextlib.contextmanager
def _batch_statistics_only(bns: list):
    """Inside the block the batch norms ``bns`` normalise by the batch's statistics (training mode) and
    leave their running statistics as they are (momentum 0); their modes and momenta are restored after."""
    states = [(m.training, m.momentum) for m in bns]
    try:
        for m in bns:
            m.train()
            m.momentum = 0.0
        yield
    finally:
        for m, (training, momentum) in zip(bns, states, strict=True):
            m.momentum = momentum
            m.train(training)


@torch.no_grad()
def _average_bn_statistics(bns: list, batches, model) -> int:
    """Run ``model`` on each ``(points, lengths)`` of ``batches`` (batches of fewer than 2 clouds are
    skipped) with the k-th batch's momentum at ``1/(k+1)``, so that the running statistics of the batch
    norms ``bns`` (in training mode, reset by the caller) end as the exact mean of the batch statistics.
    Returns the number of clouds; a ValueError if no batch was used."""
    n_batches, n_clouds = 0, 0
    for points, lengths in batches:
        if points.shape[0] < 2:
            continue
        for m in bns:
            m.momentum = 1.0 / (n_batches + 1)
        model(points, lengths)
        n_batches += 1
        n_clouds += int(points.shape[0])
    if n_batches == 0:
        raise ValueError("loader: no batch of >= 2 clouds to estimate batch-norm statistics from")
    return n_clouds


def subsample_padded(points: torch.Tensor, lengths: torch.Tensor, max_points: int, random: bool):
    """Keep at most ``max_points`` valid points per cloud (random subset, or evenly strided if not random).

    Shapes:
        points (B, N, 3), lengths (B,) -> (B, min(N, max_points), 3), (B,)
    """
    b, n, _ = points.shape
    if n <= max_points:
        return points, lengths
    mask = lengths_to_mask(lengths, n)
    if random:
        keys = torch.rand(b, n, device=points.device)
    else:
        # Evenly strided ranks over each cloud's valid points: deterministic for evaluation.
        idx = torch.arange(n, device=points.device, dtype=points.dtype)[None].expand(b, n)
        stride = (lengths.to(points.dtype) / max_points).clamp_min(1.0)[:, None]
        keys = torch.remainder(idx, stride) + idx / n  # multiples of the stride come first
    keys = keys.masked_fill(~mask, float("inf"))
    order = keys.argsort(dim=1)[:, :max_points]
    new_lengths = lengths.clamp(max=max_points)
    out = torch.gather(points, 1, order[..., None].expand(-1, -1, 3))
    return out.masked_fill(~lengths_to_mask(new_lengths, max_points)[..., None], 0.0), new_lengths


def normalize_padded(points: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """Centre each cloud on its centroid and scale it into the unit ball (padding stays 0).

    Shapes:
        points (B, N, 3), lengths (B,) -> (B, N, 3)
    """
    mask = lengths_to_mask(lengths, points.shape[1])[..., None]
    centroid = (points * mask).sum(1, keepdim=True) / lengths[:, None, None].to(points.dtype)
    centred = (points - centroid) * mask
    radius = centred.norm(dim=-1).amax(dim=1).clamp_min(1e-9)[:, None, None]
    return centred / radius


class XAVTNet(L.LightningModule):
    """xAVTNet LightningModule (thesis ch.7).

    Args:
        num_classes: k (thesis: 12).
        global_dim: PointNet global feature size (thesis: 1024).
        fc_dims: sizes of fc1 and fc2 (thesis: 512, 256).
        dropout: dropout on fc2 (thesis: 0.4); MC-dropout uses it at test time.
        input_transform, feature_transform: the 3×3 and 64×64 T-nets.
        feature_transform_weight: weight of the orthogonality regulariser (PointNet: 0.001).
        da_method: "none", "vtloss", "dann" or "cdan" (see module docstring).
        use_mmd, use_coral, da_layers: VTLoss switches (Table 7.2 rows); with ``da_method="vtloss"`` at
            least one of the terms is on and ``da_layers`` names each layer once. ``da_layers`` may also name
            ``"fc3"``, the k logits (beyond the thesis, whose eq. 7.8 adapts fc1 and fc2): DAN adapts
            fc6-fc8 of AlexNet, its logits included, and Deep CORAL applies CORAL to fc8 only. It may
            name ``"global"``, the max-pooled PointNet feature that fc1 reads: the pool is where a cloud's
            point count acts (a max over 30-120 touched points against one over 256 seen ones).
        alpha, beta, lam: VTLoss weights α, β, λ (thesis: 10, 10, 10).
        lam_balance: ``None`` (default): λ is ``lam``. A momentum in [0, 1): λ is set each step by Deep
            CORAL's balance rule from running means of the source cross-entropy and the CORAL sum
            (:class:`~vtlearn.losses.vtloss.VTLoss`; beyond the thesis); logged as ``train/lam``. Needs
            ``da_method="vtloss"`` with ``use_coral``. It runs away on these clouds and the training
            collapses (stop 51); a fixed ``lam`` is the working setting.
        mmd_num_kernels, mmd_kernel_mul, mmd_unbiased: MK-MMD family and estimator.
        mmd_kernel_weights, mmd_kernel_momentum: eq. 7.6's kernel weights β_u, ``"uniform"`` (1/b, default)
            or ``"optimal"`` (Gretton et al. 2012's weights of the most powerful test, re-estimated while
            training from running means with that momentum, as DAN does;
            :class:`~vtlearn.losses.vtloss.VTLoss`, :mod:`vtlearn.losses.kernel_choice`). Rows without
            MK-MMD (no-DA, CORAL only, DANN) ignore them, so one config can set them for every row; not with
            ``mmd_conditional``.
        mmd_linear_time: MK-MMD's linear-time estimator, the one DAN trains with (Gretton et al. 2012 eq. 5,
            :func:`~vtlearn.losses.mmd.linear_time_terms`), instead of the biased V-statistic: each of a
            batch's clouds meets one other cloud of its domain and one of the other, so the term is unbiased
            and noisier. Rows without MK-MMD ignore it; not with ``mmd_unbiased`` or ``mmd_conditional``.
        mmd_kernel: ``"gaussian"`` (default, eq. 7.6's family) or ``"linear"``: the MMD terms with DDC's
            linear kernel, the squared distance between the two domains' mean features
            (:func:`~vtlearn.losses.mmd.linear_kernel_mmd`; beyond the thesis, another reading of Table 7.2's
            "MMD only" row). Rows without MMD ignore it; not with ``mmd_kernel_weights="optimal"``,
            ``mmd_linear_time`` or ``mmd_conditional``.
        mmd_conditional: VTLoss's MMD terms class-conditional (DSAN's LMMD,
            :func:`~vtlearn.losses.lmmd.local_mmd`; beyond the thesis): the source labels and the target
            batch's softmax, without gradient, as pseudo-labels weight each cloud per class. Not with
            ``da_memory`` (the queue keeps features, not labels).
        dann_weight, dann_gamma: the adversarial loss weight and the γ of its λ ramp, each > 0 with
            ``da_method="dann"`` or ``"cdan"`` (either at 0 leaves the encoder without the adversarial
            gradient, the no-DA row).
        cdan_entropy: CDAN+E's entropy conditioning (default) with ``da_method="cdan"``; ``False`` gives
            plain CDAN, every cloud weighted alike.
        da_ramp_gamma: if set, VTLoss's MMD and CORAL terms are scaled by Ganin's ramp
            ``2/(1+exp(−γp)) − 1`` of the training progress ``p`` (the warm-up DAN and DANN use; beyond
            the thesis, whose eq. 7.8 weights are constant). ``None`` (default): constant weights.
        da_memory: if > 0, VTLoss's MMD and CORAL terms see the current batch of each domain followed by
            the detached fc features of that domain's last ``da_memory`` clouds
            (:class:`~vtlearn.models.components.feature_queue.FeatureQueue`; beyond the thesis). The
            current rows' alignment gradient is scaled by ``(batch + queued) / batch``, so a step
            estimates the update of a batch that large at the cost of one batch. 0 (default): the batch
            alone, as in eq. 7.8. Unused by the rows without MMD or CORAL (no-DA, DANN).
        da_memory_rescale: scale the current rows' alignment gradient as above (default). ``False`` leaves
            it as the loss gives it, ``batch / (batch + queued)`` of a real batch that large.
        im_weight: weight of the information-maximisation loss on the target batch's logits
            (:func:`~vtlearn.losses.info_max.information_maximization`, beyond the thesis), added to the
            loss of ``da_method``; it needs two-stream batches. 0 (default): off, as in eq. 7.8.
        mcc_weight: weight of the minimum class confusion of the target batch's logits
            (:func:`~vtlearn.losses.mcc.minimum_class_confusion`; Jin et al. 2020, beyond the thesis), added
            to the loss of ``da_method``; it needs two-stream batches. 0 (default): off, as in eq. 7.8.
        mcc_temperature: the temperature T of its softmax (2.5, Jin et al.'s on every benchmark), > 0.
        mcd_weight: weight of MCD's adversarial classifier discrepancy on the target batch (module
            docstring; Saito et al. 2018, beyond the thesis), added to the loss of ``da_method`` with the
            second classifier's source cross-entropy. 0 (default): off, no second classifier.
        sa_nodes: PointDAN's self-adaptive nodes per cloud in the encoder (Qin et al. 2019, beyond the
            thesis; theirs: 64). 0 (default): none, the thesis's PointNet.
        sa_group: the points in each node's group (theirs: 64).
        sa_radius: each group's radius as a fraction of its cloud's radius (theirs: 0.3 in the unit ball);
            > 0.
        sa_feature_ball: a node's feature reads only its group's points within that radius, instead of
            all ``sa_group`` nearest (theirs), so a sparse tactile cloud's nodes are local as a dense
            visual cloud's are (:mod:`~vtlearn.models.components.sa_nodes`, "Sparse clouds"). False
            (default): theirs.
        node_mmd_weight: weight of PointDAN's local alignment, the MK-MMD of the node features through
            per-domain node attention (:func:`~vtlearn.losses.pointdan.node_alignment_loss`); it needs
            ``sa_nodes > 0`` and two-stream batches. 0 (default): off.
        afn_weight: weight of the stepwise adaptive feature norm of the fc2 features, source and target
            (:func:`~vtlearn.losses.afn.adaptive_feature_norm`; Xu et al. 2019, beyond the thesis), added to
            the loss of ``da_method``; it needs two-stream batches. 0 (default): off, as in eq. 7.8.
        afn_step: its residual step Δr, the norm each step asks for beyond the current one (1, Xu et
            al.'s), > 0.
        l2_preserved_dropout: Xu et al.'s L2-preserved dropout on fc2 (:class:`XAVTNetHead`): while the
            dropout is on, its output is rescaled by ``1/√(1 − p)`` instead of ``1/(1 − p)``, fc3 reads it,
            and the adaptive feature norm is taken on it, as their classifier has it, in place of the fc2
            feature before the dropout. False (default): the thesis's dropout.
        pseudo_label_weight: weight of the cross-entropy of the target batch against its centroid
            pseudo-labels (module docstring; SHOT and CBST, beyond the thesis), added to the loss of
            ``da_method``. 0 (default): off, as in eq. 7.8.
        pseudo_label_start: the share of ``max_epochs`` trained before the first labelling, in [0, 1)
            (of the optimiser steps when the run is bounded by ``max_steps`` alone).
        pseudo_label_fraction: the share of each pseudo-class kept, the most confident first, in (0, 1].
        pseudo_label_layer: the feature layer whose class centroids label the target clouds
            (``"global"``, ``"fc1"`` or ``"fc2"``).
        pseudo_label_groups: label the target clouds by a vote over their groups instead of by centroids
            (:func:`~vtlearn.losses.pseudo_labels.group_vote_pseudo_labels`, beyond the thesis): the
            clouds touched on one object take the argmax of their mean softmax, and the share
            ``pseudo_label_fraction`` of each pseudo-class's objects is kept. The target items must carry
            their ``"group"`` (the object instance, not its class), as CrossModalDataModule's target stream
            does. False (default): SHOT's centroids.
        consistency_weight: weight of the mean-teacher consistency on the target stream (module
            docstring; beyond the thesis), added to the loss of ``da_method``. 0 (default): off, no teacher.
        consistency_rampup: the share of the training progress over which the consistency weight ramps up
            (Tarvainen's ``exp(−5(1 − t)²)``), in [0, 1]; 0: full weight from the first step.
        ema_decay: the teacher's moving-average decay per optimiser step, in [0, 1).
        consistency_keep: the least share of a target cloud's points kept by each perturbation, in (0, 1].
        consistency_jitter: the standard deviation of the perturbations' point jitter, in the clouds' units
            (CrossModalDataModule's default canonical units: the object fits the unit cube, and the
            simulated contacts lie a median 0.037 from their nearest neighbour).
        consistency_threshold: French et al.'s confidence threshold: only the target clouds whose teacher
            softmax peaks at this value or above count, in [0, 1); 0 (default): every cloud.
        teacher_norm: how the teacher's batch norms normalise its target copy. ``"batch"`` (default): by the
            statistics of the source batch and that copy together, as the network normalises its own
            training forward (``_joint_forward``), leaving the teacher's running statistics as they are;
            with ``domain_bn``, by the statistics of that copy alone, as the network normalises its target
            batch (``_split_forward``). ``"running"``: eval mode, on the running statistics averaged from
            the network's (the target ones with ``domain_bn``). With
            ``"running"`` the bench row's teacher scored 8-25 % on the tactile stream while the network
            scored 37-49 % (docs/xavtnet_results.md): averaged weights do not match averaged statistics.
        consistency_align: ReMixMatch's distribution alignment of the teacher's target probabilities before
            the threshold and the consistency
            (:func:`~vtlearn.models.components.class_balance.align_distribution`, beyond the thesis):
            ``p̃ = normalise(p ⊙ ρ_s / ρ_t)``, with ``ρ_s`` a running mean of the source batches' class
            frequencies and ``ρ_t`` one of the teacher's target probabilities (momentum ``ALIGN_MOMENTUM``
            per step, both starting uniform and kept in checkpoints). It assumes the target classes occur
            as often as the source's. Needs ``consistency_weight > 0``.
        consistency_loss: ``"squared"`` (default): the squared softmax difference of Mean Teacher and
            French et al. (:func:`~vtlearn.losses.consistency.probability_consistency`); ``"cross_entropy"``:
            FixMatch's and AdaMatch's cross-entropy against the teacher's argmax on the confident clouds
            (:func:`~vtlearn.losses.consistency.confident_cross_entropy`).
        student_keep, student_jitter, student_scale: the network's own perturbed copy of the target batch
            when it should differ from the teacher's (FixMatch's strong view against the teacher's weak
            one): the least share of the points kept, the jitter, and the per-axis stretch bound of
            :func:`~vtlearn.models.components.mean_teacher.perturb_padded`. ``None`` (default) takes
            ``consistency_keep`` and ``consistency_jitter``; ``student_scale`` 1 (default) stretches
            nothing. Every target term of the step sees this copy.
        neighbour_weight: weight of AaD's attract-and-disperse loss on the target stream (module docstring;
            Yang et al. 2022, beyond the thesis), added to the loss of ``da_method``. 0 (default): off.
        neighbour_k: the nearest bank neighbours each target cloud is attracted to (AaD's K; 3 on
            Office-Home).
        neighbour_dispersion: AaD's λ, the weight of the batch's mutual dispersion (1 on Office-Home).
        neighbour_start: the share of ``max_epochs`` trained before the bank is filled and the loss
            starts, in [0, 1) (of the optimiser steps when the run is bounded by ``max_steps`` alone).
        neighbour_layer: the feature layer the bank compares (``"global"``, ``"fc1"`` or ``"fc2"``; AaD
            uses the bottleneck before the classifier, fc2 here).
        neighbour_bank: whose outputs fill the bank rows of each training batch and find its neighbours:
            ``"network"`` (default; AaD), or ``"teacher"``, the mean teacher's on its own copy of the batch
            (AdaContrast's momentum bank, Chen et al. 2022; needs ``consistency_weight > 0``). The
            network's softmax is the one pulled and dispersed either way, and the first fill is the
            network's.
        rotation_weight: weight of the rotation-prediction cross-entropy on the source and target clouds
            (module docstring; beyond the thesis), added to the loss of ``da_method``. 0 (default): off, no
            rotation head.
        defrec_weight: weight of DefRec's region Chamfer distance on the deformed source and target clouds
            (module docstring; beyond the thesis), added to the loss of ``da_method``. 0 (default): off, no
            decoder.
        defrec_regions: voxels per axis of the deformation grid (DefRec's 3).
        contrast_weight: weight of SimCLR's NT-Xent on two perturbed copies of the target batch (module
            docstring; Chen et al. 2020, beyond the thesis), added to the loss of ``da_method``. 0
            (default): off, no projection head.
        contrast_temperature: NT-Xent's τ (0.5: SimCLR's CIFAR-10 setting, the small-data one).
        mix_weight: weight of the cross-domain mixup loss (beyond the thesis;
            :mod:`~vtlearn.models.components.cloud_mixup`): each target cloud of the step, as the target
            terms see it, is mixed with a source cloud of the batch into a cloud of its own size, and the
            network learns the mixed label, the source's one-hot label and the target cloud's probability
            (the mean teacher's when there is one, else the network's, without gradient) in the share of
            points each gave. Ramped up as the consistency (``consistency_rampup``). 0 (default): off.
        mix_alpha: the source share λ of each mix is drawn from Beta(``mix_alpha``, ``mix_alpha``)
            (default 1: uniform in [0, 1]).
        lr, weight_decay: Adam (thesis: lr 1e-3).
        lr_schedule: "constant" (thesis) or "cosine": the learning rate decays from ``lr`` to 0 over the
            run's optimiser steps (SGDR without restarts, Loshchilov & Hutter 2017). With a constant Adam
            rate the final weights are one point of a noisy trajectory, so the test accuracy of two
            short trainings of the same data differs by several points; the cosine decay settles them,
            which the active-learning curves need (docs/xavtnet_results.md).
        max_points: if set, clouds with more points are subsampled to this many (random in training,
            strided in evaluation). A speed knob for quick CPU runs; the thesis uses all 1024.
        normalize_clouds: centre each cloud and scale it into the unit ball before the network.
        domain_bn: batch-norm statistics per domain (module docstring); needs two-stream batches. With a
            teacher (``consistency_weight > 0``) the teacher keeps both domains' statistics too.
        class_names: the name of each class index, kept in the checkpoint's hyper-parameters so that
            inference (``vtlearn recognize``) needs no dataset. ``None`` is filled from the datamodule's
            ``class_names`` when training starts (:meth:`setup`).
        input_normalize: the per-cloud normalisation of the training clouds
            (:class:`~vtlearn.datamodules.CrossModalDataModule`'s ``normalize``), kept in the checkpoint so
            that inference applies the same one (:func:`~vtlearn.models.xavtnet_inference.recognize_clouds`):
            ``"center"`` (each cloud on its centroid), ``"none"`` (the object's bounding-box frame, which
            inference rebuilds from the object's box) or ``"unit_sphere"``. ``None`` is filled from the
            datamodule when training starts (:meth:`setup`); checkpoints without it were trained with
            ``"center"``.
    """

    def __init__(
        self,
        num_classes: int = 12,
        global_dim: int = 1024,
        fc_dims: list[int] = [512, 256],  # noqa: B006 - plain list so save_hyperparameters stays simple
        dropout: float = 0.4,
        input_transform: bool = True,
        feature_transform: bool = True,
        feature_transform_weight: float = 0.001,
        da_method: str = "vtloss",
        use_mmd: bool = True,
        use_coral: bool = True,
        da_layers: list[str] = ["fc1", "fc2"],  # noqa: B006
        alpha: float = 10.0,
        beta: float = 10.0,
        lam: float = 10.0,
        mmd_num_kernels: int = 5,
        mmd_kernel_mul: float = 2.0,
        mmd_unbiased: bool = False,
        mmd_conditional: bool = False,
        lam_balance: float | None = None,
        mmd_kernel_weights: str = "uniform",
        mmd_kernel_momentum: float = 0.9,
        mmd_linear_time: bool = False,
        mmd_kernel: str = "gaussian",
        dann_weight: float = 1.0,
        dann_gamma: float = 10.0,
        cdan_entropy: bool = True,
        da_ramp_gamma: float | None = None,
        da_memory: int = 0,
        da_memory_rescale: bool = True,
        im_weight: float = 0.0,
        mcc_weight: float = 0.0,
        mcc_temperature: float = MCC_TEMPERATURE,
        mcd_weight: float = 0.0,
        sa_nodes: int = 0,
        sa_group: int = 64,
        sa_radius: float = 0.3,
        sa_feature_ball: bool = False,
        node_mmd_weight: float = 0.0,
        afn_weight: float = 0.0,
        afn_step: float = AFN_STEP,
        l2_preserved_dropout: bool = False,
        pseudo_label_weight: float = 0.0,
        pseudo_label_start: float = 1 / 3,
        pseudo_label_fraction: float = 0.5,
        pseudo_label_layer: str = "fc1",
        pseudo_label_groups: bool = False,
        consistency_weight: float = 0.0,
        consistency_rampup: float = 1 / 3,
        ema_decay: float = 0.99,
        consistency_keep: float = 0.5,
        consistency_jitter: float = 0.01,
        consistency_threshold: float = 0.0,
        teacher_norm: str = "batch",
        consistency_align: bool = False,
        consistency_loss: str = "squared",
        student_keep: float | None = None,
        student_jitter: float | None = None,
        student_scale: float = 1.0,
        neighbour_weight: float = 0.0,
        neighbour_k: int = 3,
        neighbour_dispersion: float = 1.0,
        neighbour_start: float = 1 / 3,
        neighbour_layer: str = "fc2",
        neighbour_bank: str = "network",
        rotation_weight: float = 0.0,
        defrec_weight: float = 0.0,
        defrec_regions: int = 3,
        contrast_weight: float = 0.0,
        contrast_temperature: float = 0.5,
        mix_weight: float = 0.0,
        mix_alpha: float = 1.0,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        lr_schedule: str = "constant",
        max_points: int | None = None,
        normalize_clouds: bool = False,
        domain_bn: bool = False,
        class_names: list[str] | None = None,
        input_normalize: str | None = None,
    ) -> None:
        super().__init__()
        as_int(num_classes, "num_classes", minimum=2)
        if da_method not in DA_METHODS:
            raise ValueError(f"da_method must be one of {DA_METHODS}, got {da_method!r}")
        as_real(lr, "lr", low=0.0, open_low=True)
        if lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"lr_schedule must be one of {LR_SCHEDULES}, got {lr_schedule!r}")
        if da_ramp_gamma is not None:
            as_real(da_ramp_gamma, "da_ramp_gamma", low=0.0, open_low=True)
        as_int(da_memory, "da_memory", minimum=0)
        as_real(im_weight, "im_weight", low=0.0)
        as_real(mcc_weight, "mcc_weight", low=0.0)
        as_real(mcc_temperature, "mcc_temperature", low=0.0, open_low=True)
        as_real(mcd_weight, "mcd_weight", low=0.0)
        as_int(sa_nodes, "sa_nodes", minimum=0)
        as_int(sa_group, "sa_group")
        as_real(sa_radius, "sa_radius", low=0.0, open_low=True)
        as_bool(sa_feature_ball, "sa_feature_ball")
        as_real(node_mmd_weight, "node_mmd_weight", low=0.0)
        if node_mmd_weight > 0 and sa_nodes == 0:
            raise ValueError("node_mmd_weight: PointDAN's local alignment needs the self-adaptive nodes "
                             "(sa_nodes > 0, theirs 64)")
        as_real(afn_weight, "afn_weight", low=0.0)
        as_real(afn_step, "afn_step", low=0.0, open_low=True)
        as_real(pseudo_label_weight, "pseudo_label_weight", low=0.0)
        as_real(pseudo_label_start, "pseudo_label_start", low=0.0, high=1.0, open_high=True)
        as_real(pseudo_label_fraction, "pseudo_label_fraction", low=0.0, high=1.0, open_low=True)
        if pseudo_label_layer not in FEATURE_LAYERS:
            raise ValueError(f"pseudo_label_layer: need one of {list(FEATURE_LAYERS)}, got "
                             f"{pseudo_label_layer!r}")
        if pseudo_label_groups and pseudo_label_weight <= 0:
            raise ValueError("pseudo_label_groups: needs pseudo_label_weight > 0 (it says how the "
                             "self-training labels are drawn)")
        as_real(consistency_weight, "consistency_weight", low=0.0)
        as_real(consistency_rampup, "consistency_rampup", low=0.0, high=1.0)
        as_real(ema_decay, "ema_decay", low=0.0, high=1.0, open_high=True)
        as_real(consistency_keep, "consistency_keep", low=0.0, high=1.0, open_low=True)
        as_real(consistency_jitter, "consistency_jitter", low=0.0)
        as_real(consistency_threshold, "consistency_threshold", low=0.0, high=1.0, open_high=True)
        if teacher_norm not in TEACHER_NORMS:
            raise ValueError(f"teacher_norm: expected one of {TEACHER_NORMS}, got {teacher_norm!r}")
        if consistency_loss not in CONSISTENCY_LOSSES:
            raise ValueError(f"consistency_loss: expected one of {CONSISTENCY_LOSSES}, got "
                             f"{consistency_loss!r}")
        if student_keep is not None:
            as_real(student_keep, "student_keep", low=0.0, high=1.0, open_low=True)
        if student_jitter is not None:
            as_real(student_jitter, "student_jitter", low=0.0)
        as_real(student_scale, "student_scale", low=1.0)
        if consistency_weight <= 0:  # without a teacher no target copy is made and no consistency taken
            unused = [name for name, on in (("consistency_loss", consistency_loss != "squared"),
                                            ("student_keep", student_keep is not None),
                                            ("student_jitter", student_jitter is not None),
                                            ("student_scale", student_scale != 1.0)) if on]
            if unused:
                raise ValueError(f"{unused[0]}: needs consistency_weight > 0 (a mean teacher)")
        if consistency_align and consistency_weight <= 0:
            raise ValueError("consistency_align: needs consistency_weight > 0 (it aligns the teacher's "
                             "targets)")
        as_real(neighbour_weight, "neighbour_weight", low=0.0)
        as_int(neighbour_k, "neighbour_k")
        as_real(neighbour_dispersion, "neighbour_dispersion", low=0.0)
        as_real(neighbour_start, "neighbour_start", low=0.0, high=1.0, open_high=True)
        if neighbour_layer not in FEATURE_LAYERS:
            raise ValueError(f"neighbour_layer: need one of {list(FEATURE_LAYERS)}, got {neighbour_layer!r}")
        if neighbour_bank not in NEIGHBOUR_BANKS:
            raise ValueError(f"neighbour_bank: expected one of {NEIGHBOUR_BANKS}, got {neighbour_bank!r}")
        if neighbour_bank == "teacher" and consistency_weight <= 0:
            raise ValueError("neighbour_bank: 'teacher' needs consistency_weight > 0 (a mean teacher)")
        as_real(rotation_weight, "rotation_weight", low=0.0)
        as_real(contrast_weight, "contrast_weight", low=0.0)
        as_real(contrast_temperature, "contrast_temperature", low=0.0, open_low=True)
        if contrast_weight > 0 and domain_bn:
            raise ValueError("contrast_weight: not with domain_bn=True (the copies are normalised by their "
                             "own batch, not by a domain's statistics)")
        as_real(mix_weight, "mix_weight", low=0.0)
        as_real(mix_alpha, "mix_alpha", low=0.0, open_low=True)
        if mix_weight > 0 and domain_bn:
            raise ValueError("mix_weight: not with domain_bn=True (a mixed cloud belongs to neither domain)")
        if rotation_weight > 0 and domain_bn:
            raise ValueError("rotation_weight: not with domain_bn=True (the turned clouds of both domains "
                             "share one forward)")
        as_real(defrec_weight, "defrec_weight", low=0.0)
        as_int(defrec_regions, "defrec_regions")
        if defrec_weight > 0 and domain_bn:
            raise ValueError("defrec_weight: not with domain_bn=True (the deformed clouds of both domains "
                             "share one forward)")
        check_kernel_weights(mmd_kernel_weights)  # before the rows without MK-MMD pass VTLoss "uniform"
        check_mmd_kernel(mmd_kernel)
        if mmd_conditional and da_memory:
            raise ValueError("mmd_conditional: not with da_memory > 0, whose queue holds no labels or "
                             "target probabilities")
        if max_points is not None:
            as_int(max_points, "max_points")
        if isinstance(da_layers, str):  # one layer's name, as VTLoss takes it
            da_layers = [da_layers]
        unknown = set(da_layers) - set(DA_LAYERS)
        if unknown:
            raise ValueError(f"da_layers may only contain {list(DA_LAYERS)}, got {sorted(unknown)}")
        if da_method == "vtloss":
            if not (use_mmd or use_coral):
                raise ValueError("use_mmd, use_coral: both off leaves VTLoss no alignment term, which is the "
                                 "no-DA row; say da_method='none' for it")
            if not da_layers:
                raise ValueError("da_layers: VTLoss needs at least one layer to align (thesis: fc1, fc2)")
            repeated = sorted({name for name in da_layers if list(da_layers).count(name) > 1})
            if repeated:
                raise ValueError(f"da_layers: {repeated} named more than once, which would count its "
                                 "alignment terms twice")
        if lam_balance is not None and not (da_method == "vtloss" and use_coral):
            raise ValueError(f"lam_balance: sets VTLoss's CORAL weight, but da_method={da_method!r} with "
                             f"use_coral={use_coral} has no CORAL term")
        as_real(feature_transform_weight, "feature_transform_weight", low=0.0)
        as_real(weight_decay, "weight_decay", low=0.0)
        # a zero weight or ramp leaves the discriminator without effect on the encoder: the DANN row is no-DA
        dann = da_method in ("dann", "cdan")
        as_real(dann_weight, "dann_weight", low=0.0, open_low=dann)
        as_real(dann_gamma, "dann_gamma", low=0.0, open_low=dann)
        if class_names is not None:
            class_names = [str(n) for n in class_names]
            if len(class_names) != num_classes:
                raise ValueError(
                    f"class_names: {len(class_names)} names for num_classes={num_classes}"
                )
        if input_normalize is not None and input_normalize not in INPUT_NORMALIZE:
            raise ValueError(
                f"input_normalize: expected one of {INPUT_NORMALIZE} or None, got {input_normalize!r}"
            )
        fc_dims, da_layers = list(fc_dims), list(da_layers)
        self.save_hyperparameters()
        self.encoder = PointNetEncoder(global_dim, input_transform, feature_transform, sa_nodes, sa_group,
                                       sa_radius, sa_feature_ball)
        self.head = XAVTNetHead(global_dim, num_classes, fc_dims, dropout, l2_preserved_dropout)
        self._bn_domain = "target"  # evaluation clouds are tactile unless bn_domain("source") says otherwise
        if domain_bn:
            self._convert_to_domain_bn()
        vt = da_method == "vtloss"
        self.vtloss = VTLoss(
            alpha, beta, lam, da_layers, use_mmd=vt and use_mmd, use_coral=vt and use_coral,
            mmd_num_kernels=mmd_num_kernels, mmd_kernel_mul=mmd_kernel_mul, mmd_unbiased=mmd_unbiased,
            mmd_conditional=mmd_conditional, lam_balance=lam_balance if vt else None,
            mmd_kernel_weights=mmd_kernel_weights if vt and use_mmd else "uniform",
            mmd_kernel_momentum=mmd_kernel_momentum, mmd_linear_time=bool(mmd_linear_time) and vt and use_mmd,
            mmd_kernel=mmd_kernel if vt and use_mmd else "gaussian",
        )
        # CDAN's discriminator reads fc2 ⊗ softmax (256·k entries) through Long et al.'s 1024-wide layers
        self.discriminator = None
        if da_method == "dann":
            self.discriminator = DomainDiscriminator(fc_dims[1])
        elif da_method == "cdan":
            self.discriminator = DomainDiscriminator(fc_dims[1] * num_classes, hidden=1024)
        self._memory = (
            {d: FeatureQueue(int(da_memory)) for d in DOMAINS} if da_memory and self.vtloss.adapts else None
        )
        self._pseudo_labels: torch.Tensor | None = None  # per target-dataset index, -1 where not kept
        # AaD's bank (neighbour_weight): features, softmax and filled rows per target-dataset index
        self._neighbour_bank: dict[str, torch.Tensor] | None = None
        # The mean teacher: saved in checkpoints (a resumed run keeps its average), never optimised.
        self.teacher = (
            torch.nn.ModuleDict({"encoder": copy.deepcopy(self.encoder), "head": copy.deepcopy(self.head)})
            if consistency_weight > 0 else None
        )
        if self.teacher is not None:
            self.teacher.requires_grad_(False)
        if consistency_align:  # ρ_s and ρ_t of the distribution alignment, saved with the weights
            self.register_buffer("align_source_prior", torch.full((num_classes,), 1.0 / num_classes))
            self.register_buffer("align_target_mean", torch.full((num_classes,), 1.0 / num_classes))
        self.rotation_head = RotationHead(global_dim) if rotation_weight > 0 else None
        self.defrec_head = (RegionDecoder(self.encoder.point_dim, global_dim) if defrec_weight > 0
                            else None)
        self.projection_head = ProjectionHead(global_dim) if contrast_weight > 0 else None
        # MCD's second classifier F₂ on the fc2 feature, beside fc3 (F₁)
        self.mcd_head = torch.nn.Linear(fc_dims[1], num_classes) if mcd_weight > 0 else None
        # PointDAN's node attention, one per domain, ahead of the local alignment's MMD
        self.node_attention = (torch.nn.ModuleDict({d: NodeAttention(sa_nodes) for d in DOMAINS})
                               if node_mmd_weight > 0 else None)
        self.train_loss = MeanMetric()
        self.train_acc = MulticlassAccuracy(num_classes, average="micro")
        self.val_loss, self.test_loss = MeanMetric(), MeanMetric()
        self.val_acc = MulticlassAccuracy(num_classes, average="micro")
        self.test_acc = MulticlassAccuracy(num_classes, average="micro")
        self.test_confusion = MulticlassConfusionMatrix(num_classes)
        self.last_test_confusion: torch.Tensor | None = None

    def setup(self, stage: str) -> None:
        """Record the datamodule's class names and cloud normalisation in the hyper-parameters (and so in
        every checkpoint); a ValueError if they contradict what the model already has."""
        dm = getattr(self._trainer, "datamodule", None)
        mode = getattr(dm, "normalize", None)
        if mode is not None:
            if self.hparams.input_normalize is None:
                self.hparams.input_normalize = str(mode)
            elif self.hparams.input_normalize != mode:
                raise ConfigMismatchError(
                    f"input_normalize: the model's {self.hparams.input_normalize!r} differs from the "
                    f"datamodule's normalize={mode!r}; set them alike (or leave input_normalize unset)"
                )
        names = getattr(dm, "class_names", None)
        if names is None:
            return
        names = [str(n) for n in names]
        if len(names) != self.hparams.num_classes:
            raise ConfigMismatchError(
                f"datamodule: {len(names)} classes {names}, "
                f"the model has num_classes={self.hparams.num_classes} (set model.init_args.num_classes: "
                f"{len(names)} in the config, or --model.init_args.num_classes {len(names)})"
            )
        if self.hparams.class_names is None:
            self.hparams.class_names = names
        elif list(self.hparams.class_names) != names:
            raise ConfigMismatchError(
                f"class_names: the model's {list(self.hparams.class_names)} "
                f"differ from the datamodule's {names}"
            )

    # ---- network ---------------------------------------------------------------------------------
    def _prepare(self, points: torch.Tensor, lengths: torch.Tensor | None):
        points, lengths = check_cloud_batch(points, lengths)
        if self.hparams.max_points is not None:
            points, lengths = subsample_padded(points, lengths, self.hparams.max_points, self.training)
        if self.hparams.normalize_clouds:
            points = normalize_padded(points, lengths)
        return points, lengths

    def forward(self, points: torch.Tensor, lengths: torch.Tensor | None = None) -> XAVTNetOutput:
        """The PointNet classifier of section 7.2.2 on a padded batch: T-nets, per-point MLP, masked max
        pool, fc1 → fc2 → dropout → fc3. ``softmax(logits)`` is one term ``p(y|x, W_t)`` of eq. 7.3 when
        dropout is on (:func:`~vtlearn.active.mc_dropout.mc_dropout_probs`); fc1 and fc2 are the features
        VTLoss aligns (eq. 7.8). Clouds are subsampled to ``max_points`` and, with ``normalize_clouds``,
        put in the unit ball first. Bad clouds (wrong shape, empty, NaN/inf, lengths out of range) are a
        ValueError naming ``points`` or ``lengths``.

        Shapes:
            points (B, N, 3) zero-padded, lengths (B,) int64 (None: every cloud has N points) ->
            logits (B, k), features {"global": (B, global_dim), "fc1": (B, fc_dims[0]),
            "fc2": (B, fc_dims[1])}, trans_input (B, 3, 3) or None, trans_feat (B, 64, 64) or None
        """
        points, lengths = self._prepare(points, lengths)
        g, trans_input, trans_feat, nodes = self.encoder.forward_nodes(points, lengths)
        logits, feats = self.head(g)
        return XAVTNetOutput(logits, {"global": g, **feats}, trans_input, trans_feat, nodes)

    @contextlib.contextmanager
    def bn_domain(self, domain: str):
        """Normalise with ``domain``'s batch-norm statistics (``"source"``: visual, ``"target"``: tactile)
        inside the block, then restore the previous domain. A no-op without ``domain_bn``."""
        if domain not in DOMAINS:
            raise ValueError(f"domain: expected one of {DOMAINS}, got {domain!r}")
        previous = self._bn_domain
        self._set_bn_domain(domain)
        try:
            yield self
        finally:
            self._set_bn_domain(previous)

    @torch.no_grad()
    def adapt_bn_statistics(self, loader, domain: str = "target", passes: int = 1) -> int:
        """AdaBN (Li et al., Pattern Recognition 2018): re-estimate ``domain``'s batch-norm statistics on
        unlabelled clouds after training; no weight changes.

        A model trained without ``domain_bn`` is converted first, with its trained statistics kept as the
        source statistics and ``hparams.domain_bn`` set, so a checkpoint saved afterwards reloads as is.
        Every batch norm of ``domain`` is reset and set to the exact average of the batch statistics over
        ``passes`` passes of ``loader`` (training-mode forwards; batches of fewer than 2 clouds are
        skipped). Evaluation then uses them for that domain (``bn_domain``).

        Args:
            loader: batches ``{"points", "lengths"}`` (labels are not read), e.g.
                :meth:`~vtlearn.datamodules.CrossModalDataModule.target_dataloader`.
            domain: ``"target"`` (tactile) or ``"source"``.
            passes: passes over ``loader``.

        Returns:
            the number of clouds the statistics were averaged over (counted once per pass).

        Shapes:
            loader batches: points (B, N, 3), lengths (B,)
        """
        if domain not in DOMAINS:
            raise ValueError(f"domain: expected one of {DOMAINS}, got {domain!r}")
        passes = as_int(passes, "passes")
        if not self.hparams.get("domain_bn", False):
            self._convert_to_domain_bn()
            self.hparams["domain_bn"] = True
        bns = [m for m in self.modules() if isinstance(m, DomainBatchNorm)]
        momentum = bns[0].momentum
        for m in bns:
            getattr(m, f"running_mean_{domain}").zero_()
            getattr(m, f"running_var_{domain}").fill_(1.0)
        was_training = self.training
        self.train()
        try:
            with self.bn_domain(domain):
                batches = ((b["points"], b.get("lengths")) for _ in range(int(passes)) for b in loader)
                return _average_bn_statistics(bns, batches, self)
        finally:
            for m in bns:
                m.momentum = momentum
            self.train(was_training)

    @torch.no_grad()
    def reestimate_bn_statistics(self, loader, passes: int = 1) -> int:
        """Set every batch norm's running statistics to the exact average of its batch statistics over the
        joint source + target batches of ``loader``, the batches the network normalised with in training
        (:meth:`_joint_forward`); no weight changes. This is SWA's batch-norm update (Izmailov et al., UAI
        2018) on the two-stream batches: the running statistics of a training are an exponential average
        of statistics that belonged to earlier weights, these belong to the current ones. Dropout stays
        off, and the clouds are subsampled as in evaluation. With ``domain_bn`` each domain's statistics
        are averaged over its own stream's batches instead, the batches :meth:`_split_forward` normalised
        with.

        Args:
            loader: two-stream batches ``{"source": {...}, "target": {...} or None}`` (labels are not
                read), e.g. :meth:`~vtlearn.datamodules.CrossModalDataModule.train_dataloader` (a
                CombinedLoader, whose items ``(batch, batch_idx, dataloader_idx)`` are unpacked); a batch
                without a target part, or with a single target cloud, counts its source clouds alone.
            passes: passes over ``loader``.

        Returns:
            the number of clouds the statistics were averaged over (counted once per pass).

        Shapes:
            loader batches: source/target points (B, N, 3), lengths (B,)
        """
        passes = as_int(passes, "passes")
        bns = _batch_norms(self.encoder, self.head)
        momenta = [m.momentum for m in bns]

        def streams(batch):
            if isinstance(batch, tuple):  # a CombinedLoader's (batch, batch_idx, dataloader_idx)
                batch = batch[0]
            if not isinstance(batch, dict) or "source" not in batch:
                raise ValueError("loader: need two-stream batches {'source': ..., 'target': ...}, got one "
                                 "labelled stream")
            src, tgt = batch["source"], batch.get("target")
            if tgt is not None and tgt["points"].shape[0] < 2:  # training skips such a target batch too
                tgt = None
            return src, tgt

        def joint(batch):
            src, tgt = streams(batch)
            if tgt is None:
                return src["points"], src.get("lengths")
            points, lengths, _ = _concat_streams(src, tgt)
            return points, lengths

        def one(domain):  # that domain's (points, lengths) of each batch that has the domain
            parts = (streams(b)[DOMAINS.index(domain)] for _ in range(int(passes)) for b in loader)
            return ((part["points"], part.get("lengths")) for part in parts if part is not None)

        was_training = self.training
        self.eval()
        for m in bns:
            m.train()
        try:
            if not self.hparams.get("domain_bn", False):
                for m in bns:
                    m.reset_running_stats()
                return _average_bn_statistics(bns, (joint(b) for _ in range(int(passes)) for b in loader),
                                              self)
            n = 0
            for domain in DOMAINS:
                for m in bns:
                    getattr(m, f"running_mean_{domain}").zero_()
                    getattr(m, f"running_var_{domain}").fill_(1.0)
                with self.bn_domain(domain):
                    n += _average_bn_statistics(bns, one(domain), self)
            return n
        finally:
            for m, momentum in zip(bns, momenta, strict=True):
                m.momentum = momentum
            self.train(was_training)

    def adopt_teacher(self, loader, passes: int = 1) -> int:
        """Replace the network's weights by the mean teacher's average and re-estimate their batch-norm
        statistics on ``loader`` (:meth:`reestimate_bn_statistics`), so that evaluation, prediction and
        checkpoints from here on use the teacher. Mean Teacher evaluates the averaged model (Tarvainen and
        Valpola 2017), and an average of the weights along a constant-rate Adam trajectory is a flatter,
        less noisy point than its last step (SWA). The teacher's own running statistics are an average of
        statistics that belonged to other weights, hence the re-estimation (docs/xavtnet.md). The teacher
        keeps its weights, so training can go on.

        Returns:
            the number of clouds the statistics were averaged over.
        """
        if self.teacher is None:
            raise ValueError("adopt_teacher: the model has no teacher (consistency_weight is 0)")
        ema_update(self.encoder, self.teacher["encoder"], 0.0)
        ema_update(self.head, self.teacher["head"], 0.0)
        return self.reestimate_bn_statistics(loader, passes)

    def _convert_to_domain_bn(self) -> None:
        """Every batch norm of the encoder and head becomes a :class:`DomainBatchNorm` (both domains start
        from its statistics), set to the current domain."""
        convert_batchnorm(self.encoder)
        convert_batchnorm(self.head)
        set_bn_domain(self, self._bn_domain)

    def _set_bn_domain(self, domain: str) -> None:
        self._bn_domain = domain
        if self.hparams.get("domain_bn", False):
            set_bn_domain(self, domain)

    def _regulariser(self, out: XAVTNetOutput) -> torch.Tensor:
        if out.trans_feat is None or self.hparams.feature_transform_weight == 0:
            return out.logits.new_zeros(())
        return self.hparams.feature_transform_weight * feature_transform_regularizer(out.trans_feat)

    # ---- shared step (lightning-hydra-template habit) -------------------------------------------
    def model_step(self, batch: dict):
        """Cross-entropy on a labelled batch ``{"points", "lengths", "label"}``; returns (loss, preds, y)."""
        out = self(batch["points"], batch.get("lengths"))
        y = batch["label"]
        loss = F.cross_entropy(out.logits, y)
        return loss, out.logits.argmax(-1), y

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor | None:
        labelled = batch["source"] if "source" in batch else batch
        if labelled["points"].shape[0] < 2:
            return None  # batch norm needs >= 2 clouds; Lightning skips a step that returns None
        domain_bn = self.hparams.get("domain_bn", False)
        if "source" not in batch:
            if domain_bn:
                raise ValueError("batch: domain_bn needs two-stream batches {'source': ..., 'target': ...}, "
                                 "got one labelled stream (no domain to normalise it as)")
            out = self(batch["points"], batch.get("lengths"))
            y = batch["label"]
            ce = F.cross_entropy(out.logits, y)  # no target stream without a "target" batch: α·CE only
            loss = self.hparams.alpha * ce + self._regulariser(out)
            self._log_train(loss, out.logits, y, {"ce": ce.detach()})
            return loss
        src, tgt = batch["source"], batch["target"]
        y = src["label"]
        # CORAL needs >= 2 target clouds; a lone leftover target cloud is skipped.
        im_weight = self.hparams.get("im_weight", 0.0)
        mcc_weight = self.hparams.get("mcc_weight", 0.0)
        afn_weight = self.hparams.get("afn_weight", 0.0)
        pl_weight = self.hparams.get("pseudo_label_weight", 0.0)
        nb_weight = self.hparams.get("neighbour_weight", 0.0)
        mix_weight = self.hparams.get("mix_weight", 0.0)
        adapts = (self.vtloss.adapts or self.discriminator is not None or im_weight > 0 or mcc_weight > 0
                  or afn_weight > 0 or pl_weight > 0 or nb_weight > 0 or self.teacher is not None
                  or self.rotation_head is not None or mix_weight > 0 or self.projection_head is not None
                  or self.defrec_head is not None or self.mcd_head is not None
                  or self.node_attention is not None)
        use_target = adapts and tgt is not None and tgt["points"].shape[0] >= 2
        teacher_logits = teacher_feats = None
        unperturbed = tgt
        if use_target and self.teacher is not None:
            teacher_logits, teacher_feats = self._teacher_forward(src, tgt)
            tgt = self._perturb(tgt, student=True)
        if use_target:
            out_s, out_t = self._split_forward(src, tgt) if domain_bn else self._joint_forward(src, tgt)
        else:
            with self.bn_domain("source"):
                out_s = self(src["points"], src.get("lengths"))
            if domain_bn and tgt is not None and tgt["points"].shape[0] >= 2:
                # AdaBN: the target batch only updates the target statistics (no loss, no gradient)
                with torch.no_grad(), self.bn_domain("target"):
                    self(tgt["points"], tgt.get("lengths"))
        parts: dict[str, torch.Tensor] = {}
        if use_target and self.hparams.da_method == "vtloss":
            gamma = self.hparams.get("da_ramp_gamma")
            scale = 1.0 if gamma is None else dann_lambda(self._progress(), gamma)
            feats_s, feats_t = out_s.features, out_t.features
            if "fc3" in self.vtloss.layers:  # the k logits, the layer DAN and Deep CORAL adapt
                feats_s, feats_t = {**feats_s, "fc3": out_s.logits}, {**feats_t, "fc3": out_t.logits}
            if self._memory is not None:
                feats_s, feats_t = self._with_memory(feats_s, feats_t)
            probs_t = out_t.logits.detach().softmax(-1) if self.vtloss.mmd_conditional else None
            loss, parts = self.vtloss(out_s.logits, y, feats_s, feats_t, da_scale=scale, target_probs=probs_t)
            if gamma is not None:
                parts["da_scale"] = torch.tensor(scale)
        elif use_target and self.hparams.da_method in ("dann", "cdan"):
            ce = F.cross_entropy(out_s.logits, y)
            lambd = dann_lambda(self._progress(), self.hparams.dann_gamma)
            dom = self._adversarial_loss(out_s, out_t, lambd)
            loss = self.hparams.alpha * ce + self.hparams.dann_weight * dom
            parts = {"ce": ce.detach(), "domain": dom.detach(), "grl_lambda": torch.tensor(lambd)}
        else:
            ce = F.cross_entropy(out_s.logits, y)
            loss, parts = self.hparams.alpha * ce, {"ce": ce.detach()}
        if use_target and im_weight > 0:
            im, im_parts = information_maximization(out_t.logits)
            loss = loss + im_weight * im
            parts = {**parts, "im": im.detach(), **im_parts}
        if use_target and mcc_weight > 0:
            mcc, mcc_parts = minimum_class_confusion(out_t.logits, self.hparams.get("mcc_temperature",
                                                                                     MCC_TEMPERATURE))
            loss = loss + mcc_weight * mcc
            parts = {**parts, "mcc": mcc.detach(), **mcc_parts}
        if use_target and afn_weight > 0:
            step = self.hparams.get("afn_step", AFN_STEP)
            layer = "fc2_dropout" if self.head.l2_preserved_dropout else "fc2"
            afn_s, norm_s = adaptive_feature_norm(out_s.features[layer], step)
            afn_t, norm_t = adaptive_feature_norm(out_t.features[layer], step)
            loss = loss + afn_weight * (afn_s + afn_t)
            parts = {**parts, "afn_norm_source": norm_s, "afn_norm_target": norm_t}
        if use_target and self.mcd_head is not None:
            mcd, mcd_parts = self._mcd_loss(out_s, out_t, y)
            loss = loss + mcd
            parts = {**parts, **mcd_parts}
        if use_target and self.node_attention is not None:
            att = self.node_attention
            node = node_alignment_loss(out_s.nodes, out_t.nodes, att["source"], att["target"])
            loss = loss + self.hparams.node_mmd_weight * node
            parts = {**parts, "node_mmd": node.detach()}
        if use_target and self._pseudo_labels is not None:
            if "index" not in tgt:
                raise ValueError("batch: pseudo_label_weight needs the target items' 'index' in the target "
                                 "dataset (CrossModalDataModule's target stream has it)")
            pseudo = self._pseudo_labels.to(tgt["index"].device)[tgt["index"]]
            keep = pseudo >= 0
            pce = F.cross_entropy(out_t.logits[keep], pseudo[keep]) if keep.any() else out_t.logits.sum() * 0
            loss = loss + pl_weight * pce
            parts = {**parts, "pseudo_ce": pce.detach(), "pseudo_kept": keep.float().mean()}
        if use_target and self._neighbour_bank is not None:
            by_teacher = self.hparams.get("neighbour_bank") == "teacher"
            aad = self._neighbour_loss(out_t, tgt, (teacher_logits, teacher_feats) if by_teacher else None)
            loss = loss + nb_weight * aad
            parts = {**parts, "aad": aad.detach()}
        if teacher_logits is not None:
            hp = self.hparams
            teacher_probs = teacher_logits.softmax(-1)
            if hp.get("consistency_align", False):
                teacher_probs = self._align_teacher(teacher_probs, y)
            hard = hp.get("consistency_loss", "squared") == "cross_entropy"
            cons = (confident_cross_entropy if hard else probability_consistency)(
                out_t.logits, teacher_probs, hp.get("consistency_threshold", 0.0))
            w = hp.consistency_weight * sigmoid_rampup(self._progress(), hp.consistency_rampup)
            loss = loss + w * cons
            parts = {**parts, "consistency": cons.detach(), "consistency_w": torch.tensor(w)}
        if use_target and mix_weight > 0:
            probs_t = (teacher_logits if teacher_logits is not None else out_t.logits).detach().softmax(-1)
            mix = self._mixup_loss(src, tgt, probs_t)
            w = mix_weight * sigmoid_rampup(self._progress(), self.hparams.consistency_rampup)
            loss = loss + w * mix
            parts = {**parts, "mixup": mix.detach(), "mixup_w": torch.tensor(w)}
        if use_target and self.rotation_head is not None:
            rot, rot_acc = self._rotation_loss(src, tgt)
            loss = loss + self.hparams.rotation_weight * rot
            parts = {**parts, "rotation": rot.detach(), "rotation_acc": rot_acc}
        if use_target and self.defrec_head is not None:
            rec = self._defrec_loss(src, tgt)
            loss = loss + self.hparams.defrec_weight * rec
            parts = {**parts, "defrec": rec.detach()}
        if use_target and self.projection_head is not None:
            con = self._contrast_loss(unperturbed)
            loss = loss + self.hparams.contrast_weight * con
            parts = {**parts, "contrast": con.detach()}
        loss = loss + self._regulariser(out_s)
        self._log_train(loss, out_s.logits, y, parts)
        return loss

    def _neighbour_loss(self, out_t: XAVTNetOutput, tgt: dict, teacher: tuple | None = None) -> torch.Tensor:
        """AaD's loss of the target batch against its bank neighbours, after the batch's rows have
        replaced its own in the bank (``neighbour_weight``). ``teacher``: the teacher's (logits, features)
        of its copy of the batch, which then give the batch's bank rows and find its neighbours
        (``neighbour_bank="teacher"``)."""
        if "index" not in tgt:
            raise ValueError("batch: neighbour_weight needs the target items' 'index' in the target dataset "
                             "(CrossModalDataModule's target stream has it)")
        hp, bank = self.hparams, self._neighbour_bank
        index = tgt["index"].to(bank["features"].device)
        if int(index.max()) >= bank["features"].shape[0]:
            raise ValueError(f"batch: target index {int(index.max())} is beyond the bank's "
                             f"{bank['features'].shape[0]} target clouds")
        probs = out_t.logits.softmax(-1)
        logits, feats = (out_t.logits, out_t.features) if teacher is None else teacher
        feats = feats[hp.neighbour_layer].detach()
        bank["features"][index] = F.normalize(feats, dim=1).to(bank["features"])
        bank["probs"][index] = logits.detach().softmax(-1).to(bank["probs"])
        bank["valid"][index] = True
        near = neighbour_probs(feats, bank["features"], bank["probs"], int(hp.neighbour_k), index,
                               bank["valid"])
        return attract_disperse(probs, near.to(probs), hp.neighbour_dispersion)

    @torch.no_grad()
    def fill_neighbour_bank(self, loader) -> dict[str, torch.Tensor]:
        """AaD's bank of the target clouds in ``loader`` (items with ``"index"``), in eval mode: the
        unit-length ``neighbour_layer`` feature and the softmax of each, and which rows hold a cloud.

        Shapes:
            -> {"features": (N, d), "probs": (N, k), "valid": (N,) bool}, N = max index + 1
        """
        index, feats, probs, _ = self._indexed_outputs(loader, self.hparams.neighbour_layer,
                                                    "the neighbour bank needs", "for the neighbour bank")
        feats = F.normalize(feats, dim=1)
        n = int(index.max()) + 1
        bank = {"features": feats.new_zeros(n, feats.shape[1]), "probs": probs.new_zeros(n, probs.shape[1]),
                "valid": torch.zeros(n, dtype=torch.bool, device=self.device)}
        bank["features"][index], bank["probs"][index], bank["valid"][index] = feats, probs, True
        return bank

    @torch.no_grad()
    def _align_teacher(self, teacher_probs: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Update the running ρ_s (source labels ``y``) and ρ_t (``teacher_probs``) and return the aligned
        probabilities (``consistency_align``).

        Shapes:
            teacher_probs (n, k), y (B,) int64 -> (n, k)
        """
        m, k = ALIGN_MOMENTUM, teacher_probs.shape[1]
        freq = torch.bincount(y, minlength=k).to(self.align_source_prior) / y.numel()
        self.align_source_prior.mul_(m).add_(freq, alpha=1 - m)
        self.align_target_mean.mul_(m).add_(teacher_probs.mean(0).to(self.align_target_mean), alpha=1 - m)
        # renormalised against rounding drift; a class not yet seen keeps a share of its uniform start
        return align_distribution(teacher_probs, self.align_source_prior / self.align_source_prior.sum(),
                                  self.align_target_mean / self.align_target_mean.sum())

    def _perturb(self, batch: dict, student: bool = False) -> dict:
        """A perturbed copy of a target batch (``consistency_keep``, ``consistency_jitter``); the network's
        own copy (``student``) takes ``student_keep``, ``student_jitter`` and ``student_scale`` where set."""
        points, lengths = check_cloud_batch(batch["points"], batch.get("lengths"))
        hp = self.hparams
        keep, jitter, scale = hp.consistency_keep, hp.consistency_jitter, 1.0
        if student:
            keep = hp.get("student_keep") if hp.get("student_keep") is not None else keep
            jitter = hp.get("student_jitter") if hp.get("student_jitter") is not None else jitter
            scale = hp.get("student_scale", 1.0)
        points, lengths = perturb_padded(points, lengths, keep, jitter, scale=scale)
        return {**batch, "points": points, "lengths": lengths}

    def _mixup_loss(self, src: dict, tgt: dict, probs_t: torch.Tensor) -> torch.Tensor:
        """The soft cross-entropy of the network on the target clouds ``tgt`` mixed with source clouds
        (``mix_weight``; :func:`~vtlearn.models.components.cloud_mixup.mix_clouds`): target cloud i with
        source cloud i of a random permutation of the source batch (cycled when the target batch is the
        larger), its label the mix of that source label and ``probs_t[i]``. The mixed clouds are
        normalised by their own batch statistics; the running statistics are left to the clouds that
        evaluation sees.

        Shapes:
            probs_t (Bt, k) -> ()
        """
        ps, pt = src["points"], tgt["points"]
        ls, lt = _stream_lengths(src), _stream_lengths(tgt)
        pick = torch.randperm(ps.shape[0], device=ps.device).repeat(-(-pt.shape[0] // ps.shape[0]))
        pick = pick[: pt.shape[0]]
        a = self.hparams.get("mix_alpha", 1.0)
        lam = torch.distributions.Beta(a, a).sample((pt.shape[0],)).to(pt)
        mixed, lengths, share = mix_clouds(ps[pick], ls[pick], pt, lt, lam)
        onehot = F.one_hot(src["label"][pick], probs_t.shape[1]).to(probs_t)
        target = share[:, None] * onehot + (1 - share[:, None]) * probs_t
        with _batch_statistics_only(_batch_norms(self.encoder, self.head)):
            logits = self(mixed, lengths).logits
        return soft_cross_entropy(logits, target)

    def _rotation_loss(self, src: dict, tgt: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """The cross-entropy of the rotation head on the source and target clouds, each turned by a random
        number of quarter turns about x (:mod:`~vtlearn.models.components.rotation_task`), and its accuracy.
        The turned clouds share one forward, normalised by their own batch statistics; the running
        statistics are left to the clouds that evaluation sees."""
        points, lengths, _ = _concat_streams(src, tgt)
        turned, turns = random_quarter_turns(points)
        logits = self.rotation_head(self._pool_by_batch_statistics(turned, lengths))
        return F.cross_entropy(logits, turns), (logits.detach().argmax(-1) == turns).float().mean()

    def _defrec_loss(self, src: dict, tgt: dict) -> torch.Tensor:
        """DefRec's region Chamfer distance on the source and target clouds, each with one voxel deformed
        (:mod:`~vtlearn.models.components.deformation_task`). The deformed clouds share one forward,
        normalised by their own batch statistics; the running statistics are left to the clouds that
        evaluation sees.

        Shapes:
            src["points"] (Bs, Ns, 3), tgt["points"] (Bt, Nt, 3) -> ()
        """
        points, lengths, _ = _concat_streams(src, tgt)
        points, lengths = self._prepare(points, lengths)
        deformed, region, scale = deform_region(points, lengths, self.hparams.defrec_regions)
        with _batch_statistics_only(_batch_norms(self.encoder, self.defrec_head)):
            per_point, g = self.encoder.point_features(deformed, lengths)
            pred = self.defrec_head(per_point, g, region)
        return region_chamfer(pred, points, region, scale)

    def _mcd_loss(self, out_s: XAVTNetOutput, out_t: XAVTNetOutput, y: torch.Tensor
                  ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """MCD's terms (``mcd_weight``; :mod:`vtlearn.losses.mcd`): the second classifier's ``α·CE`` on the
        source batch (step A; fc3's is the model's own) plus ``−mcd_weight·d`` of the two classifiers on the
        target batch's fc2 feature behind a gradient reversal (steps B and C in one). Both classifiers read
        the feature after the head's dropout, the target's with one mask for both.

        Shapes:
            out_s.features["fc2"] (Bs, d), out_t.features["fc2"] (Bt, d), y (Bs,) -> (), {name: ()}
        """
        hp, head = self.hparams, self.head
        ce_2 = F.cross_entropy(self.mcd_head(head.dropout(out_s.features["fc2"])), y)
        adversarial, d = mcd_adversarial_loss(head.dropout(out_t.features["fc2"]), head.fc3, self.mcd_head,
                                              hp.mcd_weight)
        return hp.alpha * ce_2 + adversarial, {"ce_f2": ce_2.detach(), "mcd": d}

    def _contrast_loss(self, tgt: dict) -> torch.Tensor:
        """NT-Xent of the projection head on two perturbed copies of the target batch ``tgt``
        (``contrast_weight``; :func:`~vtlearn.losses.contrastive.nt_xent`). The copies share one forward,
        normalised by their own batch statistics; the running statistics are left to the clouds that
        evaluation sees.

        Shapes:
            tgt["points"] (n, N, 3), tgt["lengths"] (n,) -> ()
        """
        points, lengths, n = _concat_streams(self._perturb(tgt), self._perturb(tgt))
        z = self.projection_head(self._pool_by_batch_statistics(points, lengths))
        return nt_xent(z[:n], z[n:], self.hparams.contrast_temperature)

    def _pool_by_batch_statistics(self, points: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        """The encoder's pooled feature of an extra batch (the self-supervised tasks' transformed clouds),
        normalised by that batch's own statistics, the running ones left as they are.

        Shapes:
            points (B, N, 3), lengths (B,) -> (B, global_dim)
        """
        with _batch_statistics_only(_batch_norms(self.encoder)):
            g, _, _ = self.encoder(*self._prepare(points, lengths))
        return g

    def _teacher_logits(self, src: dict, tgt: dict) -> torch.Tensor:
        """The teacher's logits of :meth:`_teacher_forward`."""
        return self._teacher_forward(src, tgt)[0]

    @torch.no_grad()
    def _teacher_forward(self, src: dict, tgt: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The teacher's logits and features of a perturbed copy of the target batch ``tgt``, without
        dropout. Its batch norms use the statistics of ``src`` and that copy together
        (``teacher_norm="batch"``; the running statistics are left as they are) or the running statistics
        (``"running"``). With ``domain_bn`` they are the target statistics: of that copy alone
        (``"batch"``), as the network's own target forward is normalised, or the target running
        statistics (``"running"``).

        Shapes:
            -> logits (n, k), {"global": (n, global_dim), "fc1": (n, 512), "fc2": (n, 256)} of the n target
            clouds
        """
        tgt = self._perturb(tgt)
        self.teacher.eval()  # Lightning's model.train() reaches the teacher too
        norm = self.hparams.get("teacher_norm", "running")
        if norm == "batch" and not self.hparams.get("domain_bn", False):
            points, lengths, b = _concat_streams(src, tgt)
        else:
            points, lengths, b = tgt["points"], tgt["lengths"], 0
        bns = _batch_norms(self.teacher) if norm == "batch" else []  # normalised by batch statistics
        points, lengths = self._prepare(points, lengths)
        with self.bn_domain("target"), _batch_statistics_only(bns):
            g, _, _ = self.teacher["encoder"](points, lengths)
            logits, feats = self.teacher["head"](g)
        return logits[b:], {k: v[b:] for k, v in {"global": g, **feats}.items()}

    def on_fit_start(self) -> None:
        """A run from step 0 starts the teacher at the network's weights (which may have been loaded since
        ``__init__``); a resumed run keeps the teacher of its checkpoint."""
        if self.teacher is not None and self.global_step == 0:
            self._update_teacher(0.0)

    def on_train_batch_end(self, outputs, batch, batch_idx: int) -> None:
        if self.teacher is not None:
            self._update_teacher(self.hparams.ema_decay)

    def _update_teacher(self, decay: float) -> None:
        ema_update(self.teacher["encoder"], self.encoder, decay)
        ema_update(self.teacher["head"], self.head, decay)

    def on_train_epoch_start(self) -> None:
        """Relabel the target stream (``pseudo_label_weight > 0``, from ``pseudo_label_start`` on), and fill
        the neighbour bank once (``neighbour_weight > 0``, from ``neighbour_start`` on)."""
        self._pseudo_labels = None
        hp = self.hparams
        if hp.get("pseudo_label_weight", 0.0) > 0 and self._started(hp.pseudo_label_start):
            self._pseudo_labels = self.label_target(self._target_loader())
        if hp.get("neighbour_weight", 0.0) > 0 and self._neighbour_bank is None \
                and self._started(hp.neighbour_start):
            self._neighbour_bank = self.fill_neighbour_bank(self._target_loader())

    def on_fit_end(self) -> None:
        self._neighbour_bank = None  # the next fit fills its own

    def _started(self, share: float) -> bool:
        """Whether this epoch is past ``share`` of ``max_epochs`` (of the optimiser steps when the run is
        bounded by ``max_steps`` alone)."""
        max_epochs = self.trainer.max_epochs
        if max_epochs is None or max_epochs < 0:
            return self._progress() >= share
        return self.current_epoch >= math.ceil(share * max_epochs)

    def _target_loader(self):
        """The training target stream's dataset, in order, with the training loader's collate function."""
        from torch.utils.data import DataLoader

        loaders = self.trainer.train_dataloader  # the CombinedLoader's dict of loaders
        loaders = getattr(loaders, "iterables", loaders)
        target = loaders.get("target") if isinstance(loaders, dict) else None
        if target is None:
            raise ValueError("pseudo_label_weight, neighbour_weight: need two-stream training "
                             "({'source': ..., 'target': ...} loaders, e.g. "
                             "CrossModalDataModule.train_dataloader())")
        return DataLoader(target.dataset, batch_size=target.batch_size or 64, shuffle=False,
                          collate_fn=target.collate_fn)

    @torch.no_grad()
    def label_target(self, loader) -> torch.Tensor:
        """Centroid pseudo-labels of the target clouds in ``loader`` (items with ``"index"``), in eval mode;
        with ``pseudo_label_groups`` the labels voted over each group of clouds (items with ``"group"``).

        Shapes:
            -> (max index + 1,) int64, -1 for indices not labelled or not kept
        """
        hp = self.hparams
        by_group = hp.get("pseudo_label_groups", False)
        index, feats, probs, groups = self._indexed_outputs(loader, hp.pseudo_label_layer,
                                                            "pseudo-labels need", "to label", by_group)
        labels = torch.full((int(index.max()) + 1,), -1, dtype=torch.long, device=self.device)
        if by_group:
            labels[index] = group_vote_pseudo_labels(probs, groups, hp.pseudo_label_fraction)
        else:
            labels[index] = centroid_pseudo_labels(feats, probs, hp.pseudo_label_fraction)
        return labels

    @torch.no_grad()
    def _indexed_outputs(self, loader, layer: str, needs: str, purpose: str, with_group: bool = False):
        """One eval-mode pass over the target clouds of ``loader`` (items with ``"index"``): their indices,
        ``layer`` features and softmax, in loader order, and with ``with_group`` their ``"group"`` ids.
        ``needs`` and ``purpose`` word the errors ("loader: {needs} each target item's 'index'",
        "loader: no target clouds {purpose}").

        Shapes:
            -> index (n,) int64, features (n, d), probs (n, k), groups (n,) int64 or None
        """
        feats, probs, index, groups = [], [], [], []
        for batch in loader:
            if "index" not in batch:
                raise ValueError(f"loader: {needs} each target item's 'index'")
            if with_group:
                if "group" not in batch:
                    raise ValueError("loader: pseudo_label_groups needs each target item's 'group' (the "
                                     "object instance it was touched on; CrossModalDataModule's target "
                                     "stream has it)")
                groups.append(batch["group"].to(self.device))
            out = self.extract_features(batch["points"].to(self.device), batch["lengths"].to(self.device))
            feats.append(out[layer])
            probs.append(out["logits"].softmax(-1))
            index.append(batch["index"].to(self.device))
        if not index:
            raise ValueError(f"loader: no target clouds {purpose}")
        return torch.cat(index), torch.cat(feats), torch.cat(probs), torch.cat(groups) if with_group else None

    def _with_memory(self, feats_s: dict, feats_t: dict) -> tuple[dict, dict]:
        """The adapted layers' features of each domain followed by its queued ones (``da_memory``), the
        current rows' gradient scaled by (rows in all) / (rows now); then the current rows are queued."""
        out = []
        for domain, feats in (("source", feats_s), ("target", feats_t)):
            queue = self._memory[domain]
            feats = {k: feats[k] for k in self.vtloss.layers}
            b = next(iter(feats.values())).shape[0]
            factor = (b + len(queue)) / b if self.hparams.get("da_memory_rescale", True) else 1.0
            out.append(queue.extend({k: scale_grad(v, factor) for k, v in feats.items()}))
            queue.push(feats)
        return out[0], out[1]

    def _split_forward(self, src: dict, tgt: dict) -> tuple[XAVTNetOutput, XAVTNetOutput]:
        """One forward per domain, each normalised with its own batch statistics (``domain_bn``)."""
        with self.bn_domain("source"):
            out_s = self(src["points"], src.get("lengths"))
        with self.bn_domain("target"):
            out_t = self(tgt["points"], tgt.get("lengths"))
        return out_s, out_t

    def _joint_forward(self, src: dict, tgt: dict) -> tuple[XAVTNetOutput, XAVTNetOutput]:
        """One forward of source and target clouds together, split afterwards.

        Sharing the batch keeps batch-norm statistics pooled over both domains, so training-mode
        normalisation matches the running statistics used at test time (as in DAN / Deep CORAL, which
        concatenate the two batches). Padding is harmless: the per-point MLPs see valid points only.
        """
        points, lengths, b = _concat_streams(src, tgt)
        out = self(points, lengths)

        def part(sl):
            return XAVTNetOutput(
                out.logits[sl], {k: v[sl] for k, v in out.features.items()},
                None if out.trans_input is None else out.trans_input[sl],
                None if out.trans_feat is None else out.trans_feat[sl],
                None if out.nodes is None else out.nodes[sl],
            )

        return part(slice(0, b)), part(slice(b, None))

    def _progress(self) -> float:
        total = self.trainer.estimated_stepping_batches if self._trainer is not None else 0
        if not total or total == float("inf"):
            return 1.0
        return float(min(1.0, self.global_step / total))

    def _log_train(self, loss, logits, y, parts) -> None:
        self.train_loss(loss.detach())
        self.train_acc(logits.detach().argmax(-1), y)
        bs = y.shape[0]
        self.log("train/loss", self.train_loss, on_step=False, on_epoch=True, prog_bar=True, batch_size=bs)
        self.log("train/acc", self.train_acc, on_step=False, on_epoch=True, prog_bar=True, batch_size=bs)
        for name, value in parts.items():
            self.log(f"train/{name}", value, on_step=False, on_epoch=True, batch_size=bs)

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        loss, preds, y = self.model_step(batch)
        self.val_loss(loss)
        self.val_acc(preds, y)
        bs = y.shape[0]
        self.log("val/loss", self.val_loss, on_step=False, on_epoch=True, prog_bar=True, batch_size=bs)
        self.log("val/acc", self.val_acc, on_step=False, on_epoch=True, prog_bar=True, batch_size=bs)

    def test_step(self, batch: dict, batch_idx: int) -> None:
        loss, preds, y = self.model_step(batch)
        self.test_loss(loss)
        self.test_acc(preds, y)
        self.test_confusion.update(preds, y)
        self.log("test/loss", self.test_loss, on_step=False, on_epoch=True, batch_size=y.shape[0])
        self.log("test/acc", self.test_acc, on_step=False, on_epoch=True, batch_size=y.shape[0])

    def on_test_epoch_start(self) -> None:
        self.test_confusion.reset()

    def on_test_epoch_end(self) -> None:
        # Rows: true class, columns: predicted class (counts), as in thesis Table 7.3 before row-normalising.
        self.last_test_confusion = self.test_confusion.compute().cpu()

    def predict_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        return self(batch["points"], batch.get("lengths")).logits.softmax(-1)

    @torch.no_grad()
    def extract_features(self, points: torch.Tensor, lengths: torch.Tensor | None = None) -> dict:
        """Global, fc1 and fc2 features and logits in eval mode (for t-SNE, Fig. 7.4); restores the
        training flag.

        Shapes:
            points (B, N, 3), lengths (B,) -> {"global": (B, global_dim), "fc1": (B, fc_dims[0]),
            "fc2": (B, fc_dims[1]), "logits": (B, k)}
        """
        was_training = self.training
        self.eval()
        try:
            out = self(points, lengths)
        finally:
            self.train(was_training)
        return {**out.features, "logits": out.logits}

    def _adversarial_loss(self, out_s: XAVTNetOutput, out_t: XAVTNetOutput, lambd: float) -> torch.Tensor:
        """The discriminator's loss behind a gradient reversal of ``lambd``: DANN's on fc2, or CDAN's on
        fc2 ⊗ softmax (detached) with CDAN+E's entropy weights."""
        f_s, f_t = (grad_reverse(o.features["fc2"], lambd) for o in (out_s, out_t))
        if self.hparams.da_method == "dann":
            return domain_adversarial_loss(self.discriminator(f_s), self.discriminator(f_t))
        g_s, g_t = (o.logits.detach().softmax(-1) for o in (out_s, out_t))
        w_s = w_t = None
        if self.hparams.get("cdan_entropy", True):
            w_s, w_t = entropy_weights(g_s), entropy_weights(g_t)
        return domain_adversarial_loss(self.discriminator(multilinear_map(f_s, g_s)),
                                       self.discriminator(multilinear_map(f_t, g_t)), w_s, w_t)

    def configure_optimizers(self):
        params = [p for n, p in self.named_parameters() if not n.startswith("teacher.")]
        opt = torch.optim.Adam(params, lr=self.hparams.lr, weight_decay=self.hparams.weight_decay)
        if self.hparams.get("lr_schedule", "constant") == "constant":
            return opt
        total = max(1, int(self.trainer.estimated_stepping_batches))
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=total)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}


def load_xavtnet(ckpt, data: dict | None = None):
    """:class:`XAVTNet` from a Lightning checkpoint (``train.py``'s or ``vtlearn quickstart``'s, read with
    ``weights_only=True``), in eval mode; ValueError for a checkpoint of another model. ``data``: the
    checkpoint ``ckpt`` already read by :func:`~vtlearn.models.actor.read_lightning_checkpoint` (then the
    file is not read again)."""
    import inspect

    from vtlearn.models.actor import read_lightning_checkpoint

    data = read_lightning_checkpoint(ckpt) if data is None else data
    if not any(k.startswith("encoder.") for k in data["state_dict"]) or not any(
        k.startswith("head.") for k in data["state_dict"]
    ):
        raise ValueError(f"ckpt: {ckpt} is not an xAVTNet checkpoint (no encoder.* / head.* weights)")
    if any(k.startswith("encoder.features.convs.") for k in data["state_dict"]):
        raise ValueError(f"ckpt: {ckpt} is an ACTOR recognition checkpoint, not an XAVTNet one (load it with "
                         "vtlearn.models.actor_recognition.load_recognition)")
    names = set(inspect.signature(XAVTNet.__init__).parameters) - {"self"}
    hp = {k: v for k, v in dict(data["hyper_parameters"]).items() if k in names}
    try:
        model = XAVTNet(**hp)
        model.load_state_dict(data["state_dict"], strict=True)
    except (RuntimeError, TypeError, ValueError) as exc:
        raise ValueError(
            f"ckpt: {ckpt} does not match the xAVTNet architecture: {str(exc).splitlines()[0]}"
        ) from exc
    return model.eval()
