"""Tests for vtlearn.losses: MK-MMD, CORAL, VTLoss, DANN (thesis eq. 7.5-7.8), CDAN+E's conditioning,
information maximisation, minimum class confusion, maximum classifier discrepancy and the adaptive feature
norm."""

import copy
import math

import pytest
import torch

from vtlearn.losses import (
    GradientReversal,
    VTLoss,
    adaptive_feature_norm,
    classifier_discrepancy,
    coral,
    covariance,
    dann_lambda,
    domain_adversarial_loss,
    entropy_weights,
    gaussian_bandwidths,
    grad_reverse,
    information_maximization,
    linear_kernel_mmd,
    local_mmd,
    mcd_adversarial_loss,
    minimum_class_confusion,
    mk_mmd,
    multilinear_map,
)


def naive_mk_mmd(xs, xt, h, unbiased=False):
    """Deliberately naive double loops over sample pairs and kernels."""

    def k(a, b):
        d2 = sum((float(a[i]) - float(b[i])) ** 2 for i in range(len(a)))
        return sum(math.exp(-d2 / float(hu)) for hu in h) / len(h)

    ns, nt = len(xs), len(xt)
    ss = tt = st = 0.0
    for i in range(ns):
        for j in range(ns):
            if unbiased and i == j:
                continue
            ss += k(xs[i], xs[j])
    for i in range(nt):
        for j in range(nt):
            if unbiased and i == j:
                continue
            tt += k(xt[i], xt[j])
    for i in range(ns):
        for j in range(nt):
            st += k(xs[i], xt[j])
    if unbiased:
        return ss / (ns * (ns - 1)) + tt / (nt * (nt - 1)) - 2 * st / (ns * nt)
    return ss / ns**2 + tt / nt**2 - 2 * st / (ns * nt)


def naive_coral(xs, xt):
    d = len(xs[0])

    def cov(x):
        n = len(x)
        mu = [sum(r[a] for r in x) / n for a in range(d)]
        return [[sum((r[a] - mu[a]) * (r[b] - mu[b]) for r in x) / (n - 1) for b in range(d)]
                for a in range(d)]

    cs, ct = cov(xs.tolist()), cov(xt.tolist())
    return sum((cs[a][b] - ct[a][b]) ** 2 for a in range(d) for b in range(d)) / (4 * d * d)


@pytest.mark.parametrize("unbiased", [False, True])
def test_mk_mmd_matches_naive_loop(unbiased):
    g = torch.Generator().manual_seed(0)
    xs = torch.randn(7, 4, generator=g, dtype=torch.float64)
    xt = torch.randn(5, 4, generator=g, dtype=torch.float64) + 0.5
    h = gaussian_bandwidths(torch.cat([xs, xt]))
    got = mk_mmd(xs, xt, unbiased=unbiased)
    assert got.item() == pytest.approx(naive_mk_mmd(xs, xt, h.tolist(), unbiased), rel=1e-10, abs=1e-12)


def test_mk_mmd_hand_computed():
    xs = torch.tensor([[0.0]], dtype=torch.float64)
    xt = torch.tensor([[1.0]], dtype=torch.float64)
    # one kernel h=1: k_ss = k_tt = 1, k_st = e^-1
    assert mk_mmd(xs, xt, bandwidths=[1.0]).item() == pytest.approx(2 - 2 * math.exp(-1))
    # two kernels h = 1, 2 with weights 1/2 each
    expected = 2 - (math.exp(-1) + math.exp(-0.5))
    assert mk_mmd(xs, xt, bandwidths=[1.0, 2.0]).item() == pytest.approx(expected)
    # unbiased: source {0, 1}, target {0, 2}, h = 1
    xs = torch.tensor([[0.0], [1.0]], dtype=torch.float64)
    xt = torch.tensor([[0.0], [2.0]], dtype=torch.float64)
    e = math.exp
    expected = e(-1) + e(-4) - 2 * (1 + e(-4) + e(-1) + e(-1)) / 4
    assert mk_mmd(xs, xt, bandwidths=[1.0], unbiased=True).item() == pytest.approx(expected)


def test_mk_mmd_zero_for_identical_and_grows_with_shift():
    g = torch.Generator().manual_seed(1)
    x = torch.randn(32, 8, generator=g)
    assert mk_mmd(x, x.clone()).item() == pytest.approx(0.0, abs=1e-6)
    shifts = [0.0, 0.25, 0.5, 1.0, 2.0]
    h = gaussian_bandwidths(x)  # fixed family so only the shift changes
    vals = [mk_mmd(x, x + s, bandwidths=h).item() for s in shifts]
    assert all(b > a for a, b in zip(vals, vals[1:], strict=False)), vals


def test_mk_mmd_gradcheck():
    g = torch.Generator().manual_seed(2)
    xs = torch.randn(5, 3, generator=g, dtype=torch.float64, requires_grad=True)
    xt = torch.randn(4, 3, generator=g, dtype=torch.float64, requires_grad=True)
    for unbiased in (False, True):
        assert torch.autograd.gradcheck(
            lambda a, b, u=unbiased: mk_mmd(a, b, bandwidths=[0.5, 1.0, 4.0], unbiased=u), (xs, xt)
        )


def test_mk_mmd_bandwidth_family_documented():
    x = torch.tensor([[0.0], [1.0]], dtype=torch.float64)
    # mean pairwise squared distance over off-diagonal pairs = (1 + 1) / 2 = 1
    h = gaussian_bandwidths(x, num_kernels=5, kernel_mul=2.0)
    assert h.tolist() == pytest.approx([0.25, 0.5, 1.0, 2.0, 4.0])


def test_mk_mmd_rejects_bad_input():
    x = torch.randn(4, 3)
    with pytest.raises(ValueError, match="target"):
        mk_mmd(x, torch.randn(4, 2))
    with pytest.raises(ValueError, match="source"):
        mk_mmd(torch.randn(4), x)
    with pytest.raises(ValueError, match="source"):
        mk_mmd(torch.full((4, 3), float("nan")), x)
    with pytest.raises(ValueError, match="target"):
        mk_mmd(x, torch.randn(1, 3), unbiased=True)
    with pytest.raises(ValueError, match="bandwidths"):
        mk_mmd(x, x, bandwidths=[0.0])


def naive_linear_time_mmd(xs, xt, h):
    """Gretton et al. (2012) eq. 5 written out: the mean over disjoint quadruples of consecutive rows."""

    def k(a, b):
        d2 = sum((float(a[i]) - float(b[i])) ** 2 for i in range(len(a)))
        return sum(math.exp(-d2 / float(hu)) for hu in h) / len(h)

    n = min(len(xs), len(xt)) // 2
    return sum(k(xs[2 * i], xs[2 * i + 1]) + k(xt[2 * i], xt[2 * i + 1]) - k(xs[2 * i], xt[2 * i + 1])
               - k(xs[2 * i + 1], xt[2 * i]) for i in range(n)) / n


def test_mk_mmd_linear_time_matches_the_quadruple_formula_and_vanishes_for_identical_samples():
    g = torch.Generator().manual_seed(5)
    xs = torch.randn(9, 4, generator=g, dtype=torch.float64)  # 3 quadruples: rows 6-8 of xs, 6 of xt left out
    xt = torch.randn(7, 4, generator=g, dtype=torch.float64) + 0.5
    h = gaussian_bandwidths(torch.cat([xs, xt]))  # the bandwidths still come from the whole pooled sample
    got = mk_mmd(xs, xt, linear_time=True)
    assert got.item() == pytest.approx(naive_linear_time_mmd(xs, xt, h.tolist()), rel=1e-10, abs=1e-12)
    # rows past the last quadruple do not enter the terms, only the bandwidths
    first = mk_mmd(xs[:6], xt[:6], bandwidths=h, linear_time=True)
    assert first.item() == pytest.approx(got.item(), rel=1e-12)
    # with kernel weights: the weighted sum of the one-kernel estimates
    single = [mk_mmd(xs, xt, bandwidths=[hu], linear_time=True).item() for hu in h.tolist()]
    w = [0.1, 0.2, 0.3, 0.4, 0.0]
    assert mk_mmd(xs, xt, bandwidths=h, kernel_weights=w, linear_time=True).item() == pytest.approx(
        sum(a * b for a, b in zip(w, single, strict=True)), rel=1e-12)
    assert mk_mmd(xs, xs.clone(), linear_time=True).item() == 0.0


def test_mk_mmd_linear_time_averaged_over_every_row_order_is_the_unbiased_estimate():
    """Its expectation over the rows' order is the U-statistic: each quadruple's terms are uniform over the
    distinct pairs within a domain and over all pairs across the two, which is what makes it unbiased."""
    import itertools

    g = torch.Generator().manual_seed(6)
    xs = torch.randn(4, 2, generator=g, dtype=torch.float64)
    xt = torch.randn(4, 2, generator=g, dtype=torch.float64) + 0.7
    h = [0.5, 2.0]
    orders = [list(p) for p in itertools.permutations(range(4))]
    mean = sum(mk_mmd(xs[a], xt[b], bandwidths=h, linear_time=True).item() for a in orders for b in orders)
    mean /= len(orders) ** 2
    assert mean == pytest.approx(mk_mmd(xs, xt, bandwidths=h, unbiased=True).item(), rel=1e-10)
    # and one order is not it: the estimate is noisier than the quadratic ones
    assert mk_mmd(xs, xt, bandwidths=h, linear_time=True).item() != pytest.approx(mean, rel=1e-3)


def test_mk_mmd_linear_time_gradcheck_and_errors():
    g = torch.Generator().manual_seed(7)
    xs = torch.randn(5, 3, generator=g, dtype=torch.float64, requires_grad=True)
    xt = torch.randn(4, 3, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda a, b: mk_mmd(a, b, bandwidths=[0.5, 1.0, 4.0], linear_time=True), (xs, xt))
    x = torch.randn(4, 3)
    with pytest.raises(ValueError, match="unbiased, linear_time"):
        mk_mmd(x, x, linear_time=True, unbiased=True)
    with pytest.raises(ValueError, match="target needs at least 2 rows"):
        mk_mmd(x, torch.randn(1, 3), linear_time=True)


@pytest.mark.parametrize("unbiased", [False, True])
def test_linear_kernel_mmd_matches_a_naive_loop_over_dot_products(unbiased):
    g = torch.Generator().manual_seed(3)
    xs = torch.randn(7, 4, generator=g, dtype=torch.float64)
    xt = torch.randn(5, 4, generator=g, dtype=torch.float64) + 0.3
    rows_s, rows_t = xs.tolist(), xt.tolist()

    def dots(a, b, skip_diagonal):
        return sum(sum(u * v for u, v in zip(a[i], b[j], strict=True))
                   for i in range(len(a)) for j in range(len(b)) if not (skip_diagonal and i == j))

    ns, nt = len(rows_s), len(rows_t)
    norm_ss, norm_tt = (ns * (ns - 1), nt * (nt - 1)) if unbiased else (ns * ns, nt * nt)
    want = dots(rows_s, rows_s, unbiased) / norm_ss + dots(rows_t, rows_t, unbiased) / norm_tt \
        - 2 * dots(rows_s, rows_t, False) / (ns * nt)
    assert linear_kernel_mmd(xs, xt, unbiased=unbiased).item() == pytest.approx(want, rel=1e-10, abs=1e-12)


def test_linear_kernel_mmd_compares_the_means_alone():
    g = torch.Generator().manual_seed(4)
    xs = torch.randn(40, 3, generator=g, dtype=torch.float64)
    # the biased estimate is the squared distance between the means: 0.5^2 + 0.2^2 for this shift
    shift = torch.tensor([0.5, -0.2, 0.0], dtype=torch.float64)
    assert linear_kernel_mmd(xs, xs + shift).item() == pytest.approx(0.29, rel=1e-12)
    assert linear_kernel_mmd(xs, xs).item() == pytest.approx(0.0, abs=1e-15)
    # a sample spread 3x wider about the same mean: MK-MMD sees it, the linear kernel does not
    centred = xs - xs.mean(0)
    assert linear_kernel_mmd(centred, 3 * centred).item() == pytest.approx(0.0, abs=1e-12)
    assert mk_mmd(centred, 3 * centred).item() > 0.05
    assert torch.autograd.gradcheck(lambda a, b: linear_kernel_mmd(a, b, unbiased=True),
                                    (xs[:6].clone().requires_grad_(), xs[6:11].clone().requires_grad_()))
    with pytest.raises(ValueError, match="target"):
        linear_kernel_mmd(xs, xs[:1], unbiased=True)
    with pytest.raises(ValueError, match="source"):
        linear_kernel_mmd(torch.full((3, 3), float("nan")), xs)
    with pytest.raises(ValueError, match="feature size"):
        linear_kernel_mmd(xs, xs[:, :2])


def test_coral_hand_computed():
    xs = torch.tensor([[0.0, 0.0], [2.0, 0.0]])
    xt = torch.tensor([[0.0, 0.0], [0.0, 2.0]])
    # C_s = diag(2, 0), C_t = diag(0, 2): ||C_s - C_t||_F^2 = 8, d = 2 -> 8 / 16
    assert torch.allclose(covariance(xs), torch.tensor([[2.0, 0.0], [0.0, 0.0]]))
    assert coral(xs, xt).item() == pytest.approx(0.5)


def test_coral_matches_naive_and_torch_cov():
    g = torch.Generator().manual_seed(3)
    xs = torch.randn(9, 5, generator=g, dtype=torch.float64)
    xt = 2 * torch.randn(6, 5, generator=g, dtype=torch.float64)
    assert torch.allclose(covariance(xs), torch.cov(xs.T))
    assert coral(xs, xt).item() == pytest.approx(naive_coral(xs, xt), rel=1e-10)
    assert coral(xs, xs + 3.0).item() == pytest.approx(0.0, abs=1e-12)  # a shift leaves covariances alone


def test_coral_gradcheck_and_errors():
    g = torch.Generator().manual_seed(4)
    xs = torch.randn(5, 3, generator=g, dtype=torch.float64, requires_grad=True)
    xt = torch.randn(4, 3, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(coral, (xs, xt))
    with pytest.raises(ValueError, match="source"):
        coral(torch.randn(1, 3), torch.randn(4, 3))
    with pytest.raises(ValueError, match="feature size"):
        coral(torch.randn(4, 3), torch.randn(4, 2))


def _feats(seed, n_s=6, n_t=5):
    g = torch.Generator().manual_seed(seed)
    fs = {"fc1": torch.randn(n_s, 8, generator=g, dtype=torch.float64),
          "fc2": torch.randn(n_s, 4, generator=g, dtype=torch.float64)}
    ft = {"fc1": torch.randn(n_t, 8, generator=g, dtype=torch.float64) + 1,
          "fc2": torch.randn(n_t, 4, generator=g, dtype=torch.float64) - 1}
    logits = torch.randn(n_s, 3, generator=g, dtype=torch.float64)
    labels = torch.randint(0, 3, (n_s,), generator=g)
    return logits, labels, fs, ft


def test_vtloss_is_weighted_sum_of_eq_7_8():
    logits, labels, fs, ft = _feats(5)
    total, parts = VTLoss()(logits, labels, fs, ft)
    ce = torch.nn.functional.cross_entropy(logits, labels)
    mmd = mk_mmd(fs["fc1"], ft["fc1"]) + mk_mmd(fs["fc2"], ft["fc2"])
    cor = coral(fs["fc1"], ft["fc1"]) + coral(fs["fc2"], ft["fc2"])
    assert total.item() == pytest.approx((10 * ce + 10 * mmd + 10 * cor).item())
    assert set(parts) >= {"ce", "mmd", "coral", "mmd_fc1", "mmd_fc2", "coral_fc1", "coral_fc2"}


def test_vtloss_with_the_linear_time_estimator_sums_the_linear_time_terms():
    logits, labels, fs, ft = _feats(5)
    loss = VTLoss(mmd_linear_time=True)
    total, parts = loss(logits, labels, fs, ft)
    ce = torch.nn.functional.cross_entropy(logits, labels)
    lin = {name: mk_mmd(fs[name], ft[name], linear_time=True) for name in ("fc1", "fc2")}
    cor = coral(fs["fc1"], ft["fc1"]) + coral(fs["fc2"], ft["fc2"])
    assert total.item() == pytest.approx((10 * ce + 10 * (lin["fc1"] + lin["fc2"]) + 10 * cor).item())
    assert parts["mmd_fc1"].item() == pytest.approx(lin["fc1"].item())
    assert parts["mmd_fc1"].item() != pytest.approx(mk_mmd(fs["fc1"], ft["fc1"]).item(), rel=1e-3)
    assert "linear_time=True" in repr(loss)
    # with Gretton et al.'s optimal kernel weights, the weighted linear-time estimate
    opt = VTLoss(mmd_linear_time=True, mmd_kernel_weights="optimal", use_coral=False, layers=("fc1",))
    _, parts = opt(logits, labels, fs, ft)
    w = torch.stack([parts[f"kernel_beta_fc1_{u}"] for u in range(5)])
    assert parts["mmd_fc1"].item() == pytest.approx(
        mk_mmd(fs["fc1"], ft["fc1"], kernel_weights=w, linear_time=True).item(), rel=1e-9)
    for kwargs in (dict(mmd_unbiased=True), dict(mmd_conditional=True)):
        with pytest.raises(ValueError, match="mmd_linear_time"):
            VTLoss(mmd_linear_time=True, **kwargs)


def test_vtloss_with_ddcs_linear_kernel_sums_the_linear_kernel_terms():
    logits, labels, fs, ft = _feats(5)
    loss = VTLoss(mmd_kernel="linear")
    total, parts = loss(logits, labels, fs, ft)
    ce = torch.nn.functional.cross_entropy(logits, labels)
    lin = {name: linear_kernel_mmd(fs[name], ft[name]) for name in ("fc1", "fc2")}
    cor = coral(fs["fc1"], ft["fc1"]) + coral(fs["fc2"], ft["fc2"])
    assert total.item() == pytest.approx((10 * ce + 10 * (lin["fc1"] + lin["fc2"]) + 10 * cor).item())
    assert parts["mmd_fc2"].item() == pytest.approx(lin["fc2"].item())
    assert parts["mmd_fc2"].item() != pytest.approx(mk_mmd(fs["fc2"], ft["fc2"]).item(), rel=1e-3)
    assert "linear_kernel=True" in repr(loss)
    unbiased = VTLoss(mmd_kernel="linear", mmd_unbiased=True, use_coral=False)(logits, labels, fs, ft)[1]
    assert unbiased["mmd_fc1"].item() == pytest.approx(
        linear_kernel_mmd(fs["fc1"], ft["fc1"], unbiased=True).item())
    refused = (dict(mmd_kernel_weights="optimal"), dict(mmd_linear_time=True), dict(mmd_conditional=True))
    for kwargs in refused:
        with pytest.raises(ValueError, match="mmd_kernel"):
            VTLoss(mmd_kernel="linear", **kwargs)
    VTLoss(mmd_kernel="linear", mmd_linear_time=True, use_mmd=False)  # no MMD term: nothing to refuse
    with pytest.raises(ValueError, match="mmd_kernel: expected one of"):
        VTLoss(mmd_kernel="laplace")


@pytest.mark.parametrize(
    "kwargs,expect",
    [
        (dict(use_mmd=False, use_coral=False), "ce"),
        (dict(use_coral=False), "ce+mmd12"),
        (dict(use_mmd=False), "ce+coral12"),
        (dict(layers=("fc1",)), "ce+mmd1+coral1"),
        (dict(layers=("fc2",)), "ce+mmd2+coral2"),
    ],
)
def test_vtloss_ablation_switches(kwargs, expect):
    logits, labels, fs, ft = _feats(6)
    terms = {
        "ce": 10 * torch.nn.functional.cross_entropy(logits, labels),
        "mmd12": 10 * (mk_mmd(fs["fc1"], ft["fc1"]) + mk_mmd(fs["fc2"], ft["fc2"])),
        "coral12": 10 * (coral(fs["fc1"], ft["fc1"]) + coral(fs["fc2"], ft["fc2"])),
        "mmd1": 10 * mk_mmd(fs["fc1"], ft["fc1"]),
        "coral1": 10 * coral(fs["fc1"], ft["fc1"]),
        "mmd2": 10 * mk_mmd(fs["fc2"], ft["fc2"]),
        "coral2": 10 * coral(fs["fc2"], ft["fc2"]),
    }
    expected = sum(terms[t] for t in expect.split("+"))
    total, _ = VTLoss(**kwargs)(logits, labels, fs, ft)
    assert total.item() == pytest.approx(expected.item())


def test_vtloss_da_scale_multiplies_only_the_alignment_terms():
    logits, labels, fs, ft = _feats(8)
    loss = VTLoss(alpha=2.0, beta=3.0, lam=5.0)
    ce = torch.nn.functional.cross_entropy(logits, labels)
    mmd = mk_mmd(fs["fc1"], ft["fc1"]) + mk_mmd(fs["fc2"], ft["fc2"])
    cor = coral(fs["fc1"], ft["fc1"]) + coral(fs["fc2"], ft["fc2"])
    for s in (0.0, 0.25, 1.0):
        total, _ = loss(logits, labels, fs, ft, da_scale=s)
        assert total.item() == pytest.approx((2 * ce + s * (3 * mmd + 5 * cor)).item())
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="da_scale"):
            loss(logits, labels, fs, ft, da_scale=bad)


def test_vtloss_gradcheck_and_errors():
    logits, labels, fs, ft = _feats(7)
    loss = VTLoss(alpha=1.0, beta=2.0, lam=3.0, mmd_num_kernels=3)
    f1 = fs["fc1"].clone().requires_grad_(True)
    t1 = ft["fc1"].clone().requires_grad_(True)
    lg = logits.clone().requires_grad_(True)
    # VTLoss' MK-MMD uses the data-dependent (detached) bandwidth, which finite differences would
    # move, so the float64 gradcheck covers CE + CORAL here; mk_mmd has its own fixed-bandwidth gradcheck.
    loss_coral = VTLoss(alpha=1.0, lam=3.0, use_mmd=False, layers=("fc1",))
    assert torch.autograd.gradcheck(
        lambda a, b, c: loss_coral(a, labels, {"fc1": b}, {"fc1": c})[0], (lg, f1, t1)
    )
    with pytest.raises(ValueError, match="alpha"):
        VTLoss(alpha=-1)
    with pytest.raises(ValueError, match="layer 'fc3'"):
        VTLoss(layers=("fc3",))(logits, labels, fs, ft)
    with pytest.raises(ValueError, match="features_source"):
        loss(logits, labels)
    # before: accepted here, then refused inside the first step as "num_kernels"/"kernel_mul", or fc1's
    # terms counted twice
    with pytest.raises(ValueError, match="mmd_num_kernels"):
        VTLoss(mmd_num_kernels=0)
    with pytest.raises(ValueError, match="mmd_kernel_mul"):
        VTLoss(mmd_kernel_mul=0.0)
    with pytest.raises(ValueError, match=r"layers: \['fc1'\] named more than once"):
        VTLoss(layers=("fc1", "fc2", "fc1"))


def test_vtloss_lam_balance_keeps_coral_term_equal_to_the_weighted_ce():
    """Deep CORAL's balance rule online: λ_t = α·mean(CE) / mean(CORAL) over exponential means started at
    0, whose common factor cancels, so the first step's weighted CORAL term equals its α·CE exactly."""
    loss = VTLoss(alpha=2.0, beta=3.0, lam=5.0, lam_balance=0.5)
    steps = [_feats(seed) for seed in (11, 12, 13)]
    ce_means = cor_means = 0.0
    for i, (logits, labels, fs, ft) in enumerate(steps, start=1):
        ce = torch.nn.functional.cross_entropy(logits, labels)
        mmd = mk_mmd(fs["fc1"], ft["fc1"]) + mk_mmd(fs["fc2"], ft["fc2"])
        cor = coral(fs["fc1"], ft["fc1"]) + coral(fs["fc2"], ft["fc2"])
        ce_means = 0.5 * ce_means + 0.5 * ce.item()
        cor_means = 0.5 * cor_means + 0.5 * cor.item()
        lam = 2.0 * ce_means / cor_means
        total, parts = loss(logits, labels, fs, ft)
        assert parts["lam"].item() == pytest.approx(lam)
        assert total.item() == pytest.approx((2 * ce + 3 * mmd + lam * cor).item())
        if i == 1:  # one step: λ·CORAL is exactly α·CE, whatever the λ = 5 passed
            assert (lam * cor).item() == pytest.approx((2 * ce).item())
    # eval mode reads the last training λ and leaves the means alone
    state = loss.balance_state.clone()
    loss.eval()
    logits, labels, fs, ft = _feats(14)
    _, parts = loss(logits, labels, fs, ft)
    assert parts["lam"].item() == pytest.approx(lam)
    assert torch.equal(loss.balance_state, state)
    # the means travel with the state dict; the rows without the rule keep theirs as they were
    assert "balance_state" in loss.state_dict() and "balance_state" not in VTLoss().state_dict()
    # a CORAL sum of 0 caps λ rather than dividing by 0
    capped = VTLoss(lam_balance=0.0)
    same = {"fc1": fs["fc1"], "fc2": fs["fc2"]}
    _, parts = capped(logits, labels, same, same)
    assert parts["lam"].item() == VTLoss.LAM_BALANCE_MAX


@pytest.mark.parametrize("kwargs,match", [
    (dict(lam_balance=1.0), "lam_balance"),
    (dict(lam_balance=-0.1), "lam_balance"),
    (dict(lam_balance=float("nan")), "lam_balance"),
    (dict(lam_balance=0.9, use_coral=False), "lam_balance: sets the CORAL weight"),
])
def test_vtloss_lam_balance_rejects_bad_settings(kwargs, match):
    with pytest.raises(ValueError, match=match):
        VTLoss(**kwargs)


def naive_local_mmd(xs, ys, xt, pt, h):
    """DSAN's LMMD written out: per class present in both domains, a weighted V-statistic over pairs."""

    def k(a, b):
        d2 = sum((float(a[i]) - float(b[i])) ** 2 for i in range(len(a)))
        return sum(math.exp(-d2 / float(hu)) for hu in h) / len(h)

    ncls = len(pt[0])
    pred = {max(range(ncls), key=lambda c: row[c]) for row in pt}
    classes = [c for c in range(ncls) if c in set(ys) and c in pred]
    total = 0.0
    for c in classes:
        ws = [1.0 if y == c else 0.0 for y in ys]
        ws = [w / sum(ws) for w in ws]
        wt = [row[c] for row in pt]
        wt = [w / sum(wt) for w in wt]
        ss = sum(ws[i] * ws[j] * k(xs[i], xs[j]) for i in range(len(xs)) for j in range(len(xs)))
        tt = sum(wt[i] * wt[j] * k(xt[i], xt[j]) for i in range(len(xt)) for j in range(len(xt)))
        st = sum(ws[i] * wt[j] * k(xs[i], xt[j]) for i in range(len(xs)) for j in range(len(xt)))
        total += ss + tt - 2 * st
    return total / len(classes)


def test_local_mmd_matches_naive_loop_and_is_mk_mmd_for_one_class():
    g = torch.Generator().manual_seed(3)
    xs = torch.randn(8, 3, generator=g, dtype=torch.float64)
    xt = torch.randn(6, 3, generator=g, dtype=torch.float64) + 0.3
    ys = torch.tensor([0, 1, 2, 0, 1, 1, 0, 2])
    pt = torch.randn(6, 4, generator=g, dtype=torch.float64).softmax(-1)  # class 3 never in the source
    h = gaussian_bandwidths(torch.cat([xs, xt]))
    got = local_mmd(xs, xt, ys, pt)
    assert got.item() == pytest.approx(naive_local_mmd(xs.tolist(), ys.tolist(), xt.tolist(), pt.tolist(),
                                                       h.tolist()), rel=1e-10)
    one = local_mmd(xs, xt, torch.zeros(8, dtype=torch.long), torch.ones(6, 1, dtype=torch.float64))
    assert one.item() == pytest.approx(mk_mmd(xs, xt).item(), rel=1e-12)


def test_local_mmd_sees_a_class_swap_the_marginal_mmd_cannot():
    g = torch.Generator().manual_seed(4)
    a = torch.randn(20, 2, generator=g, dtype=torch.float64) * 0.1
    b = a + torch.tensor([3.0, 0.0], dtype=torch.float64)
    xs, ys = torch.cat([a, b]), torch.tensor([0] * 20 + [1] * 20)
    xt = xs.clone()  # the same marginal ...
    right = torch.nn.functional.one_hot(ys, 2).to(torch.float64)
    swapped = right.flip(1)  # ... with the classes the other way round
    assert mk_mmd(xs, xt).item() == pytest.approx(0.0, abs=1e-12)
    assert local_mmd(xs, xt, ys, right).item() == pytest.approx(0.0, abs=1e-12)
    assert local_mmd(xs, xt, ys, swapped).item() > 0.5
    # the gradient reaches the features, never the (detached) target probabilities
    feats = xt.clone().requires_grad_(True)
    probs = swapped.clone().requires_grad_(True)
    local_mmd(xs, feats, ys, probs).backward()
    assert feats.grad.abs().sum() > 0 and probs.grad is None


def test_local_mmd_in_vtloss_and_bad_input():
    logits, labels, fs, ft = _feats(9)
    g = torch.Generator().manual_seed(5)
    probs = torch.randn(ft["fc1"].shape[0], 3, generator=g, dtype=torch.float64).softmax(-1)
    total, parts = VTLoss(mmd_conditional=True, use_coral=False)(logits, labels, fs, ft, target_probs=probs)
    ce = torch.nn.functional.cross_entropy(logits, labels)
    lmmd = local_mmd(fs["fc1"], ft["fc1"], labels, probs) + local_mmd(fs["fc2"], ft["fc2"], labels, probs)
    assert total.item() == pytest.approx((10 * ce + 10 * lmmd).item())
    with pytest.raises(ValueError, match="target_probs"):
        VTLoss(mmd_conditional=True)(logits, labels, fs, ft)
    with pytest.raises(ValueError, match="mmd_unbiased"):
        VTLoss(mmd_conditional=True, mmd_unbiased=True)
    xs, xt = fs["fc1"], ft["fc1"]
    with pytest.raises(ValueError, match="target_probs"):
        local_mmd(xs, xt, labels, probs[:-1])
    with pytest.raises(ValueError, match="target_probs"):
        local_mmd(xs, xt, labels, -probs)
    with pytest.raises(ValueError, match="source_labels"):
        local_mmd(xs, xt, labels.double(), probs)
    with pytest.raises(ValueError, match="source_labels"):
        local_mmd(xs, xt, labels + 3, probs)
    with pytest.raises(ValueError, match="target"):
        local_mmd(xs, xt * float("nan"), labels, probs)


def test_grad_reverse_flips_and_scales_gradient():
    x = torch.randn(4, 3, dtype=torch.float64, requires_grad=True)
    y = grad_reverse(x, 0.5)
    assert torch.equal(y, x)
    y.sum().backward()
    assert torch.allclose(x.grad, torch.full_like(x, -0.5))
    layer = GradientReversal(2.0)
    assert "lambd=2.0" in repr(layer)
    with pytest.raises(ValueError, match="lambd"):
        grad_reverse(x, -1.0)


def test_dann_schedule_and_domain_loss():
    assert dann_lambda(0.0) == pytest.approx(0.0)
    assert dann_lambda(1.0) == pytest.approx(2 / (1 + math.exp(-10)) - 1)
    with pytest.raises(ValueError, match="progress"):
        dann_lambda(1.5)
    # zero logits: BCE = log 2 for each domain
    assert domain_adversarial_loss(torch.zeros(3), torch.zeros(5)).item() == pytest.approx(math.log(2))
    ls = torch.randn(3, dtype=torch.float64, requires_grad=True)
    lt = torch.randn(4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(domain_adversarial_loss, (ls, lt))


def test_weighted_domain_loss_is_each_domains_weighted_mean():
    """CDAN+E's weights: within each domain a weighted mean (weights normalised per domain), the two
    domains then averaged; equal weights give DANN's loss, and the weights carry no gradient."""
    ls = torch.tensor([0.5, -1.0, 2.0], dtype=torch.float64)
    lt = torch.tensor([1.5, 0.0], dtype=torch.float64)
    ws = torch.tensor([2.0, 1.0, 1.0], dtype=torch.float64, requires_grad=True)
    wt = torch.tensor([1.0, 3.0], dtype=torch.float64)

    def bce(z, label):  # −log σ(z) for the source label 1, −log(1 − σ(z)) for the target label 0
        s = 1 / (1 + math.exp(-z))
        return -math.log(s if label else 1 - s)

    src = (2 * bce(0.5, 1) + bce(-1.0, 1) + bce(2.0, 1)) / 4
    tgt = (bce(1.5, 0) + 3 * bce(0.0, 0)) / 4
    loss = domain_adversarial_loss(ls, lt, ws, wt)
    assert loss.item() == pytest.approx(0.5 * (src + tgt), rel=1e-12)
    assert not loss.requires_grad  # only the weights asked for a gradient, and they are detached
    same = domain_adversarial_loss(ls, lt, torch.full_like(ls, 0.7), torch.full_like(lt, 4.0))
    assert same.item() == pytest.approx(domain_adversarial_loss(ls, lt).item(), rel=1e-12)
    for bad, name in (((torch.ones(2), None), "weights_source"), ((None, -torch.ones(2)), "weights_target"),
                      ((torch.zeros(3), None), "weights_source"), ((None, torch.tensor([1.0, math.nan])),
                                                                  "weights_target")):
        with pytest.raises(ValueError, match=name):
            domain_adversarial_loss(ls, lt, *bad)


def test_multilinear_map_is_the_flattened_outer_product():
    """CDAN's map T⊗(f, g) = vec(f gᵀ): entry i·k + c of a row is f_i·g_c, so the discriminator sees which
    class each feature is predicted as (Long et al. 2018 eq. 4)."""
    f = torch.tensor([[1.0, -2.0, 0.5], [0.0, 3.0, 1.0]])
    g = torch.tensor([[0.25, 0.75], [1.0, 0.0]])
    m = multilinear_map(f, g)
    assert m.shape == (2, 6)
    for b in range(2):
        for i in range(3):
            for c in range(2):
                assert m[b, i * 2 + c].item() == pytest.approx(f[b, i].item() * g[b, c].item())
    # one feature, two predictions: the discriminator's inputs differ, as DANN's (f alone) would not
    assert not torch.equal(multilinear_map(f[:1], g[:1]), multilinear_map(f[:1], g[1:]))
    for args, name in (((torch.zeros(2, 0), g), "features"), ((f, g[:1]), "probs"),
                       ((f, torch.ones(2, 1)), "probs"), ((f.clone().fill_(math.nan), g), "features")):
        with pytest.raises(ValueError, match=name):
            multilinear_map(*args)


def test_entropy_weights_range_from_uniform_to_one_hot():
    k = 4
    probs = torch.tensor([[1.0, 0, 0, 0], [0.25] * 4, [0.5, 0.5, 0, 0]])
    w = entropy_weights(probs)
    assert w.tolist() == pytest.approx([2.0, 1 + 1 / k, 1.5])  # e^{−ln 2} = 1/2
    assert not w.requires_grad
    for bad in (torch.tensor([[0.5, 0.6]]), torch.tensor([[1.5, -0.5]]), torch.ones(2)):
        with pytest.raises(ValueError, match="probs"):
            entropy_weights(bad)


def test_information_maximization_hand_computed():
    logits = torch.tensor([[0.0, math.log(3.0)], [math.log(3.0), 0.0]], dtype=torch.float64)
    # p_1 = (1/4, 3/4), p_2 = (3/4, 1/4): H(p_i) = -(1/4 ln 1/4 + 3/4 ln 3/4), p̄ = (1/2, 1/2): H = ln 2
    h = -(0.25 * math.log(0.25) + 0.75 * math.log(0.75))
    loss, parts = information_maximization(logits)
    assert loss.item() == pytest.approx(h - math.log(2.0))
    assert parts["cond_entropy"].item() == pytest.approx(h)
    assert parts["marginal_entropy"].item() == pytest.approx(math.log(2.0))


def test_information_maximization_bounds_and_gradient():
    k = 4
    # identical predictions on every cloud, uniform or confident: L_IM = 0
    assert information_maximization(torch.zeros(5, k))[0].item() == pytest.approx(0.0, abs=1e-6)
    same = torch.tensor([[30.0, 0, 0, 0]]).repeat(5, 1)
    assert information_maximization(same)[0].item() == pytest.approx(0.0, abs=1e-6)
    # confident predictions using every class equally: the minimum, -log k
    spread = 30.0 * torch.eye(k).repeat(2, 1)
    assert information_maximization(spread)[0].item() == pytest.approx(-math.log(k), abs=1e-6)
    g = torch.Generator().manual_seed(0)
    x = torch.randn(6, k, generator=g, dtype=torch.float64)
    value = information_maximization(x)[0].item()
    assert -math.log(k) <= value <= 1e-12  # H(mean p) >= mean H(p): the entropy is concave
    assert torch.autograd.gradcheck(lambda z: information_maximization(z)[0], (x.requires_grad_(True),))


@pytest.mark.parametrize("bad,match", [(torch.zeros(3), "shape"), (torch.zeros(0, 3), "shape"),
                                       (torch.zeros(3, 1), "shape"),
                                       (torch.tensor([[0.0, float("nan")]]), "NaN"),
                                       ([[0.0, 1.0]], "torch.Tensor")])
def test_information_maximization_rejects_bad_input(bad, match):
    with pytest.raises(ValueError, match=match):
        information_maximization(bad)


def naive_mcc(logits, temperature):
    """Jin et al.'s eq. 1-6 written out entry by entry, with plain floats."""
    rows = [[math.exp(float(z) / temperature) for z in row] for row in logits]
    probs = [[e / sum(row) for e in row] for row in rows]
    n, k = len(probs), len(probs[0])
    raw = [1.0 + math.exp(sum(p * math.log(p) for p in row)) for row in probs]
    w = [n * r / sum(raw) for r in raw]
    c = [[sum(w[i] * probs[i][a] * probs[i][b] for i in range(n)) for b in range(k)] for a in range(k)]
    col = [sum(c[a][b] for a in range(k)) for b in range(k)]
    return sum(c[a][b] / col[b] for a in range(k) for b in range(k) if a != b) / k


def test_minimum_class_confusion_matches_the_entrywise_equations():
    g = torch.Generator().manual_seed(3)
    logits = 3.0 * torch.randn(7, 4, generator=g, dtype=torch.float64)
    for temperature in (1.0, 2.5):
        loss, parts = minimum_class_confusion(logits, temperature)
        assert loss.item() == pytest.approx(naive_mcc(logits.tolist(), temperature), rel=1e-10)
        # each normalised column sums to 1, so the mean diagonal and the loss add up to 1
        assert parts["mcc_diagonal"].item() + loss.item() == pytest.approx(1.0, rel=1e-10)
    # the entropy weights carry no gradient (Jin et al.'s code detaches them): a descent step lowers the loss
    z = logits.clone().requires_grad_(True)
    loss = minimum_class_confusion(z)[0]
    loss.backward()
    assert minimum_class_confusion(z.detach() - 0.5 * z.grad)[0] < loss


def test_minimum_class_confusion_bounds():
    k = 5
    # one-hot predictions that use every class, whatever their frequencies: no confusion
    confident = 200.0 * torch.eye(k)[[0, 0, 1, 2, 3, 3, 4]]
    assert minimum_class_confusion(confident)[0].item() == pytest.approx(0.0, abs=1e-6)
    # a class no cloud predicts has its whole normalised column off the diagonal: 1/k each
    unused = 200.0 * torch.eye(k)[[0, 0, 1, 3, 3, 3]]
    assert minimum_class_confusion(unused)[0].item() == pytest.approx(2 / k, abs=1e-6)
    # uniform predictions: every column is 1/k, so the off-diagonal sum over k is (k - 1)/k
    assert minimum_class_confusion(torch.zeros(4, k))[0].item() == pytest.approx((k - 1) / k, rel=1e-6)
    # a cloud torn between two classes confuses them more than one that has chosen
    torn = minimum_class_confusion(torch.tensor([[2.0, 2.0, -5.0], [-5.0, -5.0, 4.0]]))[0]
    chosen = minimum_class_confusion(torch.tensor([[6.0, -2.0, -5.0], [-5.0, -5.0, 4.0]]))[0]
    assert torn > chosen


@pytest.mark.parametrize("kwargs,match", [(dict(logits=torch.zeros(3)), "logits"),
                                          (dict(logits=torch.tensor([[0.0, float("inf")]])), "logits"),
                                          (dict(logits=torch.zeros(2, 3), temperature=0.0), "temperature"),
                                          (dict(logits=torch.zeros(2, 3), temperature=float("nan")),
                                           "temperature")])
def test_minimum_class_confusion_rejects_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        minimum_class_confusion(**kwargs)


def _naive_centroid_pseudo_labels(features, probs, fraction):
    """SHOT eqs. 4-6 and CBST's per-class selection, one sample and one class at a time."""
    n, k = probs.shape
    f = [features[i] / features[i].norm() for i in range(n)]

    def assign(weights):
        cents = []
        for c in range(k):
            v = sum(weights[i][c] * f[i] for i in range(n))
            cents.append(v / v.norm() if v.norm() > 0 else v)
        return [max(range(k), key=lambda c: float(f[i] @ cents[c])) for i in range(n)]

    labels = assign(probs)
    labels = assign([[1.0 if labels[i] == c else 0.0 for c in range(k)] for i in range(n)])
    out = [-1] * n
    for c in set(labels):
        members = sorted((i for i in range(n) if labels[i] == c), key=lambda i: -float(probs[i].max()))
        for i in members[: math.ceil(fraction * len(members))]:
            out[i] = c
    return torch.tensor(out)


@pytest.mark.parametrize("fraction", [1.0, 0.5, 0.2])
def test_centroid_pseudo_labels_match_a_naive_loop(fraction):
    from vtlearn.losses.pseudo_labels import centroid_pseudo_labels

    g = torch.Generator().manual_seed(3)
    features = torch.randn(40, 6, generator=g, dtype=torch.float64)
    probs = torch.softmax(2 * torch.randn(40, 4, generator=g, dtype=torch.float64), 1)
    got = centroid_pseudo_labels(features, probs, fraction)
    assert torch.equal(got, _naive_centroid_pseudo_labels(features, probs, fraction))
    labelled = got[got >= 0]
    assert (labelled < 4).all() and len(labelled) >= math.ceil(fraction * 40) - 4


def test_centroid_pseudo_labels_follow_the_feature_clusters():
    """Two tight clusters; the softmax calls two members of cluster 0 class 1. The centroids relabel
    them; with fraction 0.5 each cluster keeps its most confident half."""
    from vtlearn.losses.pseudo_labels import centroid_pseudo_labels

    g = torch.Generator().manual_seed(0)
    centres = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    truth = torch.tensor([0] * 6 + [1] * 6)
    features = centres[truth] + 0.05 * torch.randn(12, 3, generator=g)
    confident = torch.tensor([0.9, 0.8, 0.7, 0.6, 0.55, 0.52])
    p0 = torch.cat([confident, 1 - confident])  # P(class 0): cluster 1 is class 1 by the same margins
    p0[[4, 5]] = torch.tensor([0.25, 0.45])  # two wrong predictions in cluster 0, the first confident
    probs = torch.stack([p0, 1 - p0], 1)
    assert (probs.argmax(1) != truth).sum() == 2
    assert torch.equal(centroid_pseudo_labels(features, probs), truth)
    half = centroid_pseudo_labels(features, probs, 0.5)
    assert torch.equal(half, torch.tensor([0, 0, -1, -1, 0, -1, 1, 1, 1, -1, -1, -1]))


@pytest.mark.parametrize(
    "features, probs, fraction, match",
    [
        (torch.zeros(0, 3), torch.zeros(0, 2), 1.0, "features"),
        (torch.full((2, 3), math.nan), torch.full((2, 2), 0.5), 1.0, "features"),
        (torch.ones(3, 3), torch.full((2, 2), 0.5), 1.0, "same n"),
        (torch.ones(2, 3), torch.ones(2, 1), 1.0, "k >= 2"),
        (torch.ones(2, 3), torch.full((2, 2), 0.3), 1.0, "probs"),
        (torch.ones(2, 3), torch.full((2, 2), 0.5), 0.0, "fraction"),
        (torch.ones(2, 3), torch.full((2, 2), 0.5), 1.5, "fraction"),
    ],
)
def test_centroid_pseudo_labels_reject_bad_input(features, probs, fraction, match):
    from vtlearn.losses.pseudo_labels import centroid_pseudo_labels

    with pytest.raises(ValueError, match=match):
        centroid_pseudo_labels(features, probs, fraction)


def test_group_vote_pseudo_labels_label_each_group_by_its_mean_softmax():
    """Three groups of touches. Group 7's clouds disagree (0.9 for class 1 once, 0.2 and 0.3 after), and
    their mean (0.467) says class 0; each cloud of a group takes the group's label, and with fraction 0.5 each
    pseudo-class keeps its more confident group whole."""
    from vtlearn.losses.pseudo_labels import group_vote_pseudo_labels

    p1 = torch.tensor([0.9, 0.2, 0.3, 0.2, 0.3, 0.8, 0.7])  # P(class 1)
    probs = torch.stack([1 - p1, p1], 1).double()
    groups = torch.tensor([7, 7, 7, 3, 3, 9, 9])
    assert torch.equal(group_vote_pseudo_labels(probs, groups), torch.tensor([0, 0, 0, 0, 0, 1, 1]))
    # class 0: group 3 (0.75) is more confident than group 7 (0.533); class 1 has group 9 only
    assert torch.equal(group_vote_pseudo_labels(probs, groups, 0.5), torch.tensor([-1, -1, -1, 0, 0, 1, 1]))
    # one cloud per group is the per-cloud argmax with CBST's selection
    single = group_vote_pseudo_labels(probs, torch.arange(7))
    assert torch.equal(single, probs.argmax(1))


def test_group_vote_pseudo_labels_match_a_naive_loop():
    from vtlearn.losses.pseudo_labels import group_vote_pseudo_labels

    g = torch.Generator().manual_seed(5)
    probs = torch.softmax(torch.randn(60, 5, generator=g, dtype=torch.float64), 1)
    groups = torch.randint(100, 115, (60,), generator=g)
    got = group_vote_pseudo_labels(probs, groups, 0.5)
    means = {int(k): probs[groups == k].mean(0) for k in groups.unique()}
    label = {k: int(m.argmax()) for k, m in means.items()}
    kept = set()
    for c in set(label.values()):
        members = sorted((k for k in label if label[k] == c), key=lambda k: -float(means[k].max()))
        kept |= set(members[: math.ceil(0.5 * len(members))])
    expected = torch.tensor([label[int(k)] if int(k) in kept else -1 for k in groups])
    assert torch.equal(got, expected)


@pytest.mark.parametrize(
    "probs, groups, fraction, match",
    [
        (torch.zeros(0, 2), torch.zeros(0, dtype=torch.long), 1.0, "probs"),
        (torch.full((2, 2), math.nan), torch.tensor([0, 1]), 1.0, "probs"),
        (torch.ones(2, 1), torch.tensor([0, 1]), 1.0, "k >= 2"),
        (torch.full((2, 2), 0.3), torch.tensor([0, 1]), 1.0, "probs"),
        (torch.full((2, 2), 0.5), torch.tensor([0, 1, 2]), 1.0, "groups"),
        (torch.full((2, 2), 0.5), torch.tensor([0.0, 1.0]), 1.0, "groups"),
        (torch.full((2, 2), 0.5), torch.tensor([0, 1]), 0.0, "fraction"),
    ],
)
def test_group_vote_pseudo_labels_reject_bad_input(probs, groups, fraction, match):
    from vtlearn.losses.pseudo_labels import group_vote_pseudo_labels

    with pytest.raises(ValueError, match=match):
        group_vote_pseudo_labels(probs, groups, fraction)


def test_classifier_discrepancy_matches_eq_1_and_its_bounds():
    """Saito et al.'s d(p₁, p₂) = (1/K)·Σ_k |p₁ₖ − p₂ₖ|, averaged over the clouds, against plain floats; 0 for
    one classifier against itself, 2/K for different one-hot predictions."""
    g = torch.Generator().manual_seed(5)
    z1, z2 = (torch.randn(6, 4, generator=g, dtype=torch.float64) for _ in range(2))

    def softmax(row):
        e = [math.exp(v) for v in row]
        return [v / sum(e) for v in e]

    naive = sum(abs(a - b) for r1, r2 in zip(z1.tolist(), z2.tolist(), strict=True)
                for a, b in zip(softmax(r1), softmax(r2), strict=True)) / (6 * 4)
    assert classifier_discrepancy(z1, z2).item() == pytest.approx(naive, rel=1e-12)
    assert classifier_discrepancy(z1, z1).item() == 0.0
    one_hot = 100.0 * torch.eye(4, dtype=torch.float64)
    assert classifier_discrepancy(one_hot, one_hot.roll(1, 0)).item() == pytest.approx(2 / 4, abs=1e-12)
    for bad, match in ((z1[:, :3], "logits_2"), (z1[:0], "logits_1"), (z1 * float("nan"), "logits_1")):
        with pytest.raises(ValueError, match=match):
            classifier_discrepancy(bad, z1) if match == "logits_1" else classifier_discrepancy(z1, bad)


def test_mcd_adversarial_loss_reverses_the_discrepancy_between_features_and_classifiers():
    """−w·d behind the reversal: the classifiers' gradient is −w·∂d (a descent step raises d) and the
    features' +w·reversal·∂d (a descent step lowers d)."""
    torch.manual_seed(0)
    f1, f2 = torch.nn.Linear(5, 3), torch.nn.Linear(5, 3)
    z = torch.randn(8, 5, requires_grad=True)
    loss, d = mcd_adversarial_loss(z, f1, f2, weight=2.0, reversal=0.5)
    assert loss.item() == pytest.approx(-2.0 * d.item()) and d.item() > 0
    grads = torch.autograd.grad(loss, [z, f1.weight, f2.weight])
    plain = torch.autograd.grad(classifier_discrepancy(f1(z), f2(z)), [z, f1.weight, f2.weight])
    torch.testing.assert_close(grads[0], 2.0 * 0.5 * plain[0])
    torch.testing.assert_close(grads[1], -2.0 * plain[1])
    torch.testing.assert_close(grads[2], -2.0 * plain[2])
    g1, g2 = copy.deepcopy(f1), copy.deepcopy(f2)
    with torch.no_grad():  # descent on the classifiers raises d, on the features lowers it
        g1.weight -= 0.1 * grads[1]
        g2.weight -= 0.1 * grads[2]
        raised = classifier_discrepancy(g1(z), g2(z)).item()
    assert raised > d.item()
    lowered = classifier_discrepancy(f1(z - 0.1 * grads[0]), f2(z - 0.1 * grads[0])).item()
    assert lowered < d.item()
    for kwargs, match in ((dict(weight=-1.0), "weight"), (dict(weight=1.0, reversal=-1.0), "reversal")):
        with pytest.raises(ValueError, match=match):
            mcd_adversarial_loss(z, f1, f2, **kwargs)
    with pytest.raises(ValueError, match="features"):
        mcd_adversarial_loss(z[0], f1, f2, 1.0)


def test_adaptive_feature_norm_is_step_squared_and_raises_every_norm_by_the_step():
    """Xu et al.'s L_SAFN: its value is Δr² whatever the features; its gradient is −2Δr/n times each row's
    unit direction, so one descent step of size η lengthens every feature by 2ηΔr/n and leaves its direction
    alone; the mean norm it reports is the rows' own."""
    g = torch.Generator().manual_seed(3)
    x = torch.randn(5, 4, generator=g, dtype=torch.float64).requires_grad_()
    for step in (1.0, 0.3):
        loss, mean_norm = adaptive_feature_norm(x, step)
        assert loss.item() == pytest.approx(step**2, rel=1e-12)
        assert mean_norm.item() == pytest.approx(sum(math.hypot(*row) for row in x.tolist()) / 5, rel=1e-12)
        (grad,) = torch.autograd.grad(loss, x)
        unit = x.detach() / x.detach().norm(dim=1, keepdim=True)
        torch.testing.assert_close(grad, -2 * step / 5 * unit)
    moved = x.detach() - 0.5 * grad  # the last step, 0.3
    torch.testing.assert_close(moved.norm(dim=1), x.detach().norm(dim=1) + 2 * 0.5 * 0.3 / 5)
    torch.testing.assert_close(moved / moved.norm(dim=1, keepdim=True), unit)
    for bad, match in ((x[0], "features"), (x[:0], "features"), (x.detach() * float("nan"), "features")):
        with pytest.raises(ValueError, match=match):
            adaptive_feature_norm(bad)
    for step in (0.0, -1.0):
        with pytest.raises(ValueError, match="step"):
            adaptive_feature_norm(x, step)
