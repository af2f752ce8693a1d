"""VTLoss: the visuo-tactile domain-adaptation loss, thesis ch.7, eq. (7.8).

    L_VTLoss = α·L_CE + β·(MMD²_fc1 + MMD²_fc2) + λ·(CORAL_fc1 + CORAL_fc2)

``L_CE`` is the cross-entropy on labelled source (visual) clouds; the MK-MMD (eq. 7.5-7.6,
:mod:`vtlearn.losses.mmd`) and Deep CORAL (eq. 7.7, :mod:`vtlearn.losses.coral`) terms compare source
and unlabelled target (tactile) activations of the fully connected layers. Thesis defaults:
α = β = λ = 10 (section 7.3.1, "Network Implementation").

The switches reproduce the rows of thesis Tables 7.2 and 7.4:

=================  =====================================================
row                arguments
=================  =====================================================
no-DA              ``use_mmd=False, use_coral=False``
MMD                ``use_coral=False`` (both layers)
CORAL              ``use_mmd=False`` (both layers)
VTLoss fc1         ``layers=("fc1",)``
VTLoss fc2         ``layers=("fc2",)``
VTLoss             defaults
=================  =====================================================

Beyond the thesis, ``lam_balance`` sets λ during training by Deep CORAL's balance rule (Sun & Saenko
2016: λ such that the CORAL and classification losses are about equal at the end of training), from
running means of the two: ``λ_t = α·mean(CE)_t / mean(CORAL)_t``. The thesis fixes λ = 10; the rule,
read off the end of a λ = 10 training in the centred frame, gives λ ≈ 500-650 (docs/xavtnet_results.md).
Applied online, the ratio feeds back (λ ∝ 1/CORAL, and a larger λ shrinks CORAL) and, on xAVTNet's
clouds, runs away to the cap and stalls the classifier (stop 51).

``mmd_kernel_weights="optimal"`` gives eq. 7.6's β_u the values of Gretton et al. (2012), whom the thesis
cites for MK-MMD: the weights of the most powerful two-sample test, from running means of each kernel's
linear-time MMD² and their covariance (:mod:`vtlearn.losses.kernel_choice`; DAN re-estimates them while it
trains in the same way). The default, ``"uniform"``, keeps β_u = 1/b.

``mmd_linear_time=True`` estimates each MK-MMD² term with the linear-time estimator that DAN trains with
(Gretton et al. 2012 eq. 5; Long et al. 2015 eq. 6; :func:`~vtlearn.losses.mmd.linear_time_terms`) instead
of the biased V-statistic: the mean over disjoint quadruples of two source and two target rows, unbiased,
and noisier than the quadratic estimators.

``mmd_kernel="linear"`` replaces eq. 7.6's Gaussian family by the linear kernel of DDC (Tzeng et al. 2014;
:func:`~vtlearn.losses.mmd.linear_kernel_mmd`), whose MMD² is the squared distance between the two domains'
mean features: the "MMD loss" that Deep CORAL set its covariance term beside, so another reading of Table
7.2's "MMD only" row, in which CORAL has the second moments left to align.

Also beyond the thesis, ``mmd_conditional=True`` replaces each layer's MK-MMD by the class-conditional
LMMD of DSAN (:mod:`vtlearn.losses.lmmd`), which needs the source labels and the target class
probabilities.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from vtlearn.losses.coral import coral
from vtlearn.losses.kernel_choice import MAX_KERNELS, linear_time_statistics, optimal_kernel_weights
from vtlearn.losses.lmmd import local_mmd
from vtlearn.losses.mmd import kernel_bandwidths, linear_kernel_mmd, mk_mmd
from vtlearn.validation import as_int, as_real

__all__ = ["VTLoss", "KERNEL_WEIGHTS", "MMD_KERNELS", "check_kernel_weights", "check_mmd_kernel"]

#: the choices of ``VTLoss(mmd_kernel_weights=...)``
KERNEL_WEIGHTS = ("uniform", "optimal")
#: the choices of ``VTLoss(mmd_kernel=...)``: eq. 7.6's Gaussian family, or DDC's linear kernel
MMD_KERNELS = ("gaussian", "linear")


def check_kernel_weights(choice: str) -> str:
    """``choice`` if it is one of :data:`KERNEL_WEIGHTS`, else a ValueError naming ``mmd_kernel_weights``."""
    if choice not in KERNEL_WEIGHTS:
        raise ValueError(f"mmd_kernel_weights: expected one of {KERNEL_WEIGHTS}, got {choice!r}")
    return choice


def check_mmd_kernel(choice: str) -> str:
    """``choice`` if it is one of :data:`MMD_KERNELS`, else a ValueError naming ``mmd_kernel``."""
    if choice not in MMD_KERNELS:
        raise ValueError(f"mmd_kernel: expected one of {MMD_KERNELS}, got {choice!r}")
    return choice


class VTLoss(nn.Module):
    """Weighted sum of eq. (7.8).

    Args:
        alpha, beta, lam: α (cross-entropy), β (MK-MMD), λ (CORAL) weights; each ≥ 0.
        layers: names of the feature layers adapted, a subset of what the model exposes
            (xAVTNet exposes ``"fc1"`` and ``"fc2"``).
        use_mmd, use_coral: switch the MK-MMD and CORAL terms on or off.
        mmd_num_kernels, mmd_kernel_mul, mmd_unbiased: MK-MMD options (see :func:`mk_mmd`).
        mmd_linear_time: MK-MMD's linear-time estimator (DAN's; :func:`mk_mmd` ``linear_time``) instead of
            the biased or unbiased quadratic one; needs batches of 2 or more clouds per domain (one
            quadruple), and not with ``mmd_unbiased`` or ``mmd_conditional``.
        mmd_conditional: the class-conditional LMMD (:func:`~vtlearn.losses.lmmd.local_mmd`, biased
            estimator) in place of MK-MMD; ``forward`` then needs ``target_probs``.
        mmd_kernel_weights: ``"uniform"`` (default): eq. 7.6's β_u = 1/b. ``"optimal"``: for each layer,
            the weights of :func:`~vtlearn.losses.kernel_choice.optimal_kernel_weights` from exponential
            means (momentum ``mmd_kernel_momentum``, bias-corrected) of the batch's per-kernel linear-time
            MMD² ``η`` and its covariance ``Q`` (:func:`~vtlearn.losses.kernel_choice.linear_time_statistics`,
            on detached features, from batches of 4 or more clouds per domain). The means update in
            training mode only and are saved with the module; before the first update the weights are
            equal. The weights are logged as the parts ``"kernel_beta_<layer>_<u>"``. Needs ``use_mmd``
            without ``mmd_conditional``, and at most :data:`~vtlearn.losses.kernel_choice.MAX_KERNELS`
            kernels.
        mmd_kernel_momentum: the momentum of those means, in [0, 1) (0: this batch's statistics alone).
        mmd_kernel: ``"gaussian"`` (default): eq. 7.6's Gaussian family. ``"linear"``: DDC's linear kernel
            (:func:`~vtlearn.losses.mmd.linear_kernel_mmd`, biased or, with ``mmd_unbiased``, unbiased; module
            docstring), which has no bandwidths to weigh, so not with ``mmd_kernel_weights="optimal"``,
            ``mmd_linear_time`` or ``mmd_conditional``.
        lam_balance: ``None`` (default): λ is ``lam``, as in eq. 7.8. A momentum ``m`` in [0, 1): λ is
            set each training step by Deep CORAL's balance rule (module docstring),
            ``λ_t = α·mean(CE)_t / mean(CORAL)_t``, over exponential means of the detached source
            cross-entropy and CORAL sum with momentum ``m``, started at 0 (their common start-up factor
            cancels in the ratio, so the first step uses that step's ratio); ``lam`` is then unused.
            λ_t is capped at :attr:`LAM_BALANCE_MAX`. The means update in training mode only and are
            saved with the module (a resumed run keeps them). Needs ``use_coral``.
            Kept as a documented negative result: on xAVTNet's clouds the rule runs away (λ ∝ 1/CORAL,
            and a larger λ shrinks CORAL further), λ reaches the cap and the classifier hardly learns
            (docs/xavtnet_results.md, "Deep CORAL's balance rule, online", stop 51). Deep CORAL sets λ
            once, as the fixed ``lam`` does.

    Shapes:
        logits_source (n_s, k), labels_source (n_s,) int64,
        features_source[name] (n_s, d_name), features_target[name] (n_t, d_name),
        target_probs (n_t, k) (``mmd_conditional`` only)
        -> (scalar total, dict of detached scalar parts: "ce", "mmd", "coral", "mmd_<layer>", ...;
        "lam" with ``lam_balance``)
    """

    #: the largest λ that ``lam_balance`` sets, a guard against a CORAL sum of 0 (an unbounded weight), not
    #: a limit on the rule: eq. 7.8's object-frame trainings end with CE ≈ 0.3 and a CORAL sum near 5·10⁻⁵,
    #: where the rule asks for λ ≈ 5·10⁴ (a first cap of 10⁴ bound from the second epoch on; stop 51).
    LAM_BALANCE_MAX = 1e6

    def __init__(
        self,
        alpha: float = 10.0,
        beta: float = 10.0,
        lam: float = 10.0,
        layers: Sequence[str] = ("fc1", "fc2"),
        use_mmd: bool = True,
        use_coral: bool = True,
        mmd_num_kernels: int = 5,
        mmd_kernel_mul: float = 2.0,
        mmd_unbiased: bool = False,
        mmd_conditional: bool = False,
        lam_balance: float | None = None,
        mmd_kernel_weights: str = "uniform",
        mmd_kernel_momentum: float = 0.9,
        mmd_linear_time: bool = False,
        mmd_kernel: str = "gaussian",
    ) -> None:
        super().__init__()
        for name, v in (("alpha", alpha), ("beta", beta), ("lam", lam)):
            as_real(v, name, low=0.0)
        if isinstance(layers, str):
            layers = (layers,)
        if (use_mmd or use_coral) and len(layers) == 0:
            raise ValueError("layers must name at least one layer when MMD or CORAL is on")
        repeated = sorted({name for name in layers if list(layers).count(name) > 1})
        if repeated:
            raise ValueError(f"layers: {repeated} named more than once (its terms would count twice)")
        mmd_num_kernels = as_int(mmd_num_kernels, "mmd_num_kernels")
        mmd_kernel_mul = as_real(mmd_kernel_mul, "mmd_kernel_mul", low=0.0, open_low=True)
        if mmd_conditional and mmd_unbiased:
            raise ValueError("mmd_unbiased: the conditional LMMD has the biased estimator only")
        if mmd_linear_time and (mmd_unbiased or mmd_conditional):
            raise ValueError("mmd_linear_time: not with mmd_unbiased (choose one estimator) or "
                             "mmd_conditional (the LMMD has the biased estimator only)")
        check_mmd_kernel(mmd_kernel)
        self.linear_kernel = mmd_kernel == "linear"
        if self.linear_kernel and use_mmd and (mmd_kernel_weights == "optimal" or mmd_linear_time
                                               or mmd_conditional):
            raise ValueError("mmd_kernel: 'linear' (DDC's kernel) has no Gaussian bandwidths to weigh or "
                             "estimate in linear time and no class-conditional form, so not with "
                             "mmd_kernel_weights='optimal', mmd_linear_time or mmd_conditional")
        self.alpha, self.beta, self.lam = float(alpha), float(beta), float(lam)
        self.layers = tuple(layers)
        self.use_mmd, self.use_coral = bool(use_mmd), bool(use_coral)
        self.kernel_kwargs = dict(num_kernels=int(mmd_num_kernels), kernel_mul=float(mmd_kernel_mul))
        self.mmd_kwargs = {**self.kernel_kwargs, "unbiased": bool(mmd_unbiased),
                           "linear_time": bool(mmd_linear_time)}
        self.mmd_conditional = bool(mmd_conditional)
        if lam_balance is not None:
            lam_balance = as_real(lam_balance, "lam_balance", low=0.0, high=1.0, open_high=True)
            if not self.use_coral:
                raise ValueError("lam_balance: sets the CORAL weight λ, but use_coral is off")
            # the balance rule's running means [CE, CORAL sum, steps], saved in checkpoints; registered only
            # with the rule on, so that the state dicts of eq. 7.8's rows stay as they were
            self.register_buffer("balance_state", torch.zeros(3, dtype=torch.float64))
        self.lam_balance = lam_balance
        check_kernel_weights(mmd_kernel_weights)
        self.mmd_kernel_momentum = as_real(mmd_kernel_momentum, "mmd_kernel_momentum", low=0.0, high=1.0,
                                           open_high=True)
        self.optimal_kernels = mmd_kernel_weights == "optimal"
        if self.optimal_kernels:
            if not self.use_mmd or self.mmd_conditional:
                raise ValueError("mmd_kernel_weights: 'optimal' weighs MK-MMD's kernels, so it needs use_mmd "
                                 "without mmd_conditional")
            if mmd_num_kernels > MAX_KERNELS:
                raise ValueError(f"mmd_num_kernels: 'optimal' kernel weights take at most {MAX_KERNELS} "
                                 f"kernels, got {mmd_num_kernels}")
            b, n_layers = int(mmd_num_kernels), len(self.layers)
            # per layer: running η (b), Q (b x b) and the number of updates; registered only with the option
            # on, so that the state dicts of the other rows stay as they were
            self.register_buffer("kernel_eta", torch.zeros(n_layers, b, dtype=torch.float64))
            self.register_buffer("kernel_q", torch.zeros(n_layers, b, b, dtype=torch.float64))
            self.register_buffer("kernel_updates", torch.zeros(n_layers, dtype=torch.float64))

    @property
    def adapts(self) -> bool:
        """Whether any domain term is on (False for the no-DA row)."""
        return self.use_mmd or self.use_coral

    def forward(
        self,
        logits_source: torch.Tensor,
        labels_source: torch.Tensor,
        features_source: Mapping[str, torch.Tensor] | None = None,
        features_target: Mapping[str, torch.Tensor] | None = None,
        da_scale: float = 1.0,
        target_probs: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Eq. 7.8, ``α·CE + s·β·Σ_l MK-MMD²_l + s·λ·Σ_l CORAL_l`` over the layers ``l`` of ``layers``, with
        ``s = da_scale`` (1 in eq. 7.8; a warm-up ramp may pass less early in training). MK-MMD is eq.
        7.5-7.6 (:func:`~vtlearn.losses.mmd.mk_mmd`), CORAL eq. 7.7 (:func:`~vtlearn.losses.coral.coral`).
        Returns the total and its detached parts.

        Shapes:
            logits_source (n_s, k), labels_source (n_s,) int64, features_source[l] (n_s, d_l),
            features_target[l] (n_t, d_l) with n_t >= 2 when CORAL is on, target_probs (n_t, k)
            -> (scalar, {"ce", "mmd", "coral", "mmd_<l>", "coral_<l>": scalar})
        """
        da_scale = as_real(da_scale, "da_scale", low=0.0)
        if logits_source.dim() != 2:
            raise ValueError(f"logits_source must be (n, k), got {tuple(logits_source.shape)}")
        if labels_source.shape != logits_source.shape[:1]:
            raise ValueError(
                f"labels_source must be ({logits_source.shape[0]},), got {tuple(labels_source.shape)}"
            )
        ce = F.cross_entropy(logits_source, labels_source)
        total = self.alpha * ce
        parts: dict[str, torch.Tensor] = {"ce": ce.detach()}
        if not self.adapts:
            return total, parts
        if features_source is None or features_target is None:
            raise ValueError("features_source and features_target are required when MMD or CORAL is on")
        if self.use_mmd and self.mmd_conditional and target_probs is None:
            raise ValueError("target_probs: the conditional MMD (mmd_conditional) needs the target "
                             "class probabilities")
        zero = logits_source.new_zeros(())
        mmd_sum, coral_sum = zero, zero
        for i, layer in enumerate(self.layers):
            if layer not in features_source or layer not in features_target:
                raise ValueError(f"layer {layer!r} missing from features_source/features_target")
            fs, ft = features_source[layer], features_target[layer]
            if self.use_mmd:
                if self.linear_kernel:
                    m = linear_kernel_mmd(fs, ft, unbiased=self.mmd_kwargs["unbiased"])
                elif self.mmd_conditional:
                    m = local_mmd(fs, ft, labels_source, target_probs, **self.kernel_kwargs)
                elif self.optimal_kernels:
                    h = kernel_bandwidths(fs, ft, **self.kernel_kwargs)
                    w = self._kernel_weights(i, fs, ft, h)
                    m = mk_mmd(fs, ft, bandwidths=h, kernel_weights=w, unbiased=self.mmd_kwargs["unbiased"],
                               linear_time=self.mmd_kwargs["linear_time"])
                    parts.update({f"kernel_beta_{layer}_{u}": w[u].detach() for u in range(w.numel())})
                else:
                    m = mk_mmd(fs, ft, **self.mmd_kwargs)
                mmd_sum = mmd_sum + m
                parts[f"mmd_{layer}"] = m.detach()
            if self.use_coral:
                c = coral(fs, ft)
                coral_sum = coral_sum + c
                parts[f"coral_{layer}"] = c.detach()
        if self.use_mmd:
            total = total + da_scale * self.beta * mmd_sum
            parts["mmd"] = mmd_sum.detach()
        if self.use_coral:
            balanced = self.lam_balance is not None
            lam = self._balanced_lam(ce.detach(), coral_sum.detach()) if balanced else self.lam
            total = total + da_scale * lam * coral_sum
            parts["coral"] = coral_sum.detach()
            if balanced:
                parts["lam"] = ce.new_tensor(lam)
        return total, parts

    def _kernel_weights(self, i: int, fs: torch.Tensor, ft: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """β of ``mmd_kernel_weights="optimal"`` for layer ``i``: the running η and Q take this batch's
        linear-time statistics in training mode (batches of 4 or more clouds per domain); the weights solve
        Gretton et al.'s programme on the bias-corrected means, or are equal before the first update.

        Shapes:
            fs (n_s, d), ft (n_t, d), h (b,) -> (b,) in fs's dtype
        """
        if self.training and min(fs.shape[0], ft.shape[0]) >= 4:
            stats = linear_time_statistics(fs.detach(), ft.detach(), h).to(torch.float64)
            m = self.mmd_kernel_momentum
            self.kernel_eta[i] = m * self.kernel_eta[i] + (1 - m) * stats.mean(0)
            self.kernel_q[i] = m * self.kernel_q[i] + (1 - m) * torch.cov(stats.T).reshape(h.numel(), -1)
            self.kernel_updates[i] += 1
        t = float(self.kernel_updates[i])
        if t == 0:
            return torch.full_like(h, 1.0 / h.numel())
        correction = 1.0 - self.mmd_kernel_momentum ** t
        w = optimal_kernel_weights(self.kernel_eta[i] / correction, self.kernel_q[i] / correction)
        return w.to(h)

    def _balanced_lam(self, ce: torch.Tensor, coral_sum: torch.Tensor) -> float:
        """λ_t of ``lam_balance`` (Deep CORAL's balance rule, online): the running means take this step's
        values in training mode; in eval mode the λ of the last training step is returned."""
        state = self.balance_state
        if self.training:
            m = self.lam_balance
            state[0] = m * state[0] + (1 - m) * ce.to(state)
            state[1] = m * state[1] + (1 - m) * coral_sum.to(state)
            state[2] += 1
        if state[2] == 0:
            return self.lam
        # the means start at 0; Adam's bias correction would divide both by 1 − m^t, which cancels here
        if state[1] <= 0:
            return self.LAM_BALANCE_MAX
        return float(min(self.alpha * state[0] / state[1], self.LAM_BALANCE_MAX))

    def extra_repr(self) -> str:
        return (
            f"alpha={self.alpha}, beta={self.beta}, lam={self.lam}, layers={self.layers}, "
            f"use_mmd={self.use_mmd}, use_coral={self.use_coral}, mmd_conditional={self.mmd_conditional}, "
            f"lam_balance={self.lam_balance}, optimal_kernels={self.optimal_kernels}, "
            f"linear_time={self.mmd_kwargs['linear_time']}, linear_kernel={self.linear_kernel}"
        )
