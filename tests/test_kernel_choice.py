"""Tests for vtlearn.losses.kernel_choice: Gretton et al.'s optimal MK-MMD kernel weights (thesis eq. 7.6),
and their use in mk_mmd and VTLoss."""

import math

import numpy as np
import pytest
import torch
from scipy.optimize import minimize

from vtlearn.losses import (
    VTLoss,
    coral,
    gaussian_bandwidths,
    linear_time_statistics,
    mk_mmd,
    optimal_kernel_weights,
)
from vtlearn.losses.kernel_choice import MAX_KERNELS


def _scipy_weights(eta, q, ridge=1e-3):
    """The same programme solved by a general solver: min βᵀ(Q + εI)β s.t. ηᵀβ = 1, β ≥ 0, then Σβ = 1."""
    a = q.numpy() + ridge * float(np.diag(q.numpy()).mean()) * np.eye(len(eta))
    e = eta.numpy()
    res = minimize(lambda x: x @ a @ x, np.full(len(e), 1.0 / e.max()), jac=lambda x: 2 * a @ x,
                   constraints=[{"type": "eq", "fun": lambda x: e @ x - 1, "jac": lambda x: e}],
                   bounds=[(0, None)] * len(e), method="SLSQP", options={"ftol": 1e-15, "maxiter": 1000})
    assert res.success, res.message
    return res.x / res.x.sum()


@pytest.mark.parametrize("seed", range(6))
def test_optimal_weights_solve_the_quadratic_programme(seed):
    g = torch.Generator().manual_seed(seed)
    b = 5
    m = torch.randn(b, 3 * b, generator=g, dtype=torch.float64)
    q = m @ m.T / (3 * b)
    eta = torch.randn(b, generator=g, dtype=torch.float64).abs() * torch.tensor([1, -1, 1, 1, -1.0])
    w = optimal_kernel_weights(eta, q)
    assert w.dtype == torch.float64 and bool((w >= 0).all()) and float(w.sum()) == pytest.approx(1.0)
    np.testing.assert_allclose(w.numpy(), _scipy_weights(eta, q), atol=1e-6)


def _exhaustive_weights(eta, q, ridge=1e-3):
    """The programme solved support by support, every one of the 2^b − 1 in turn (the first on a tie): the
    reference that optimal_kernel_weights's batched screen must reproduce bit for bit."""
    import itertools

    eta, q = eta.to(torch.float64), q.to(torch.float64)
    q = 0.5 * (q + q.T)
    scale = float(q.diagonal().clamp_min(0.0).mean())
    a = q + (ridge * scale if scale > 0 else ridge) * torch.eye(len(eta), dtype=torch.float64)
    best, best_obj = None, math.inf
    for size in range(1, len(eta) + 1):
        for s in map(list, itertools.combinations(range(len(eta)), size)):
            if not bool((eta[s] > 0).any()):
                continue
            g = torch.linalg.solve(a[s][:, s], eta[s])
            denom = float(eta[s] @ g)
            if denom > 0 and bool((g >= 0).all()) and 1.0 / denom < best_obj:
                best_obj, best = 1.0 / denom, torch.zeros(len(eta), dtype=torch.float64)
                best[s] = g / denom
    return torch.full((len(eta),), 1.0 / len(eta), dtype=torch.float64) if best is None else best / best.sum()


@pytest.mark.parametrize("b", [1, 2, 5, 9, MAX_KERNELS])
def test_optimal_weights_match_trying_every_support_alone_bit_for_bit(b):
    g = torch.Generator().manual_seed(b)

    def draw(*shape, uniform=False):
        return (torch.rand if uniform else torch.randn)(*shape, generator=g, dtype=torch.float64)

    cases = []
    for _ in range(40 if b <= 9 else 3):  # the reference tries 4,095 supports one by one at b = 12
        # statistics as the training takes them: 16 quadruples of b kernels, correlated, some η_u < 0
        h = draw(16, 1) * draw(b, uniform=True) + 0.3 * draw(16, b) + 0.2 * draw(b)
        cases.append((h.mean(0), torch.cov(h.T).reshape(b, b)))
    eye = torch.eye(b, dtype=torch.float64)
    cases += [(torch.ones(b, dtype=torch.float64), eye),  # alike and independent: the whole family
              # alike and fully correlated: the supports differ by the ridge alone (a near tie)
              (torch.ones(b, dtype=torch.float64), torch.ones(b, b, dtype=torch.float64)),
              (torch.linspace(-1, 1, b, dtype=torch.float64), torch.zeros(b, b, dtype=torch.float64)),
              (-torch.ones(b, dtype=torch.float64), eye)]  # no kernel tells the samples apart
    for eta, q in cases:
        w = optimal_kernel_weights(eta, q)
        assert torch.equal(w, _exhaustive_weights(eta, q)), (eta, q)
        assert bool((w >= 0).all()) and float(w.sum()) == pytest.approx(1.0)


def test_optimal_weights_hand_computed():
    # two kernels with the same MMD², the second 100 times as variable: β ∝ (Q + εI)⁻¹ η
    eta = torch.tensor([1.0, 1.0], dtype=torch.float64)
    q = torch.diag(torch.tensor([1.0, 100.0], dtype=torch.float64))
    eps = 1e-3 * 50.5
    raw = [1 / (1 + eps), 1 / (100 + eps)]
    expected = [r / sum(raw) for r in raw]
    assert optimal_kernel_weights(eta, q).tolist() == pytest.approx(expected)
    # uncorrelated kernels with equal variance: the weights follow η
    eye = torch.eye(2, dtype=torch.float64)
    w = optimal_kernel_weights(torch.tensor([3.0, 1.0], dtype=torch.float64), eye)
    assert w.tolist() == pytest.approx([0.75, 0.25])
    # an uncorrelated kernel whose MMD² is negative only adds variance: it gets no weight (a correlated one
    # may, as a control variate)
    w = optimal_kernel_weights(torch.tensor([3.0, -1.0, 1.0], dtype=torch.float64),
                               torch.eye(3, dtype=torch.float64))
    assert w.tolist() == pytest.approx([0.75, 0.0, 0.25])
    # one kernel: its weight is 1; a zero covariance still has a solution (the ridge alone)
    assert optimal_kernel_weights(torch.tensor([0.5]), torch.zeros(1, 1)).tolist() == [1.0]


def test_optimal_weights_are_equal_when_no_kernel_tells_the_samples_apart():
    # ηᵀβ = 1 has no solution with β ≥ 0 when every η_u ≤ 0
    w = optimal_kernel_weights(torch.tensor([-0.1, 0.0, -2.0]), torch.eye(3))
    assert w.tolist() == pytest.approx([1 / 3] * 3)


@pytest.mark.parametrize("eta,q,ridge,match", [
    (torch.ones(2, 2), torch.eye(2), 1e-3, "eta"),
    (torch.ones(MAX_KERNELS + 1), torch.eye(MAX_KERNELS + 1), 1e-3, "eta"),
    (torch.tensor([]), torch.zeros(0, 0), 1e-3, "eta"),
    (torch.ones(3), torch.eye(2), 1e-3, "q"),
    (torch.tensor([1.0, float("nan")]), torch.eye(2), 1e-3, "NaN"),
    (torch.ones(2), torch.eye(2), 0.0, "ridge"),
    ([1.0, 2.0], torch.eye(2), 1e-3, "eta"),
])
def test_optimal_weights_reject_bad_input(eta, q, ridge, match):
    with pytest.raises(ValueError, match=match):
        optimal_kernel_weights(eta, q, ridge)


def test_linear_time_statistics_match_a_naive_loop_and_vanish_for_identical_samples():
    g = torch.Generator().manual_seed(3)
    x = torch.randn(9, 4, generator=g, dtype=torch.float64)  # the ninth row is left out: 4 quadruples
    y = torch.randn(8, 4, generator=g, dtype=torch.float64) + 0.5
    h = torch.tensor([0.5, 2.0, 8.0], dtype=torch.float64)
    got = linear_time_statistics(x, y, h)
    assert got.shape == (4, 3)

    def k(a, b, hu):
        return math.exp(-float(((a - b) ** 2).sum()) / hu)

    for i in range(4):
        x0, x1, y0, y1 = x[2 * i], x[2 * i + 1], y[2 * i], y[2 * i + 1]
        for u, hu in enumerate(h.tolist()):
            expected = k(x0, x1, hu) + k(y0, y1, hu) - k(x0, y1, hu) - k(x1, y0, hu)
            assert got[i, u].item() == pytest.approx(expected, rel=1e-12, abs=1e-14)
    assert torch.equal(linear_time_statistics(x, x.clone(), h), torch.zeros(4, 3, dtype=torch.float64))
    assert not linear_time_statistics(x.requires_grad_(), y, h).requires_grad


def test_linear_time_statistics_reject_bad_input():
    x = torch.randn(4, 2)
    with pytest.raises(ValueError, match="target needs at least 2 rows"):
        linear_time_statistics(x, torch.randn(1, 2), torch.ones(2))
    with pytest.raises(ValueError, match="bandwidths"):
        linear_time_statistics(x, x, torch.tensor([1.0, 0.0]))
    with pytest.raises(ValueError, match="same feature size"):
        linear_time_statistics(x, torch.randn(4, 3), torch.ones(2))


def test_mk_mmd_with_kernel_weights():
    g = torch.Generator().manual_seed(4)
    xs = torch.randn(6, 3, generator=g, dtype=torch.float64)
    xt = torch.randn(5, 3, generator=g, dtype=torch.float64) + 0.3
    h = [0.5, 1.0, 4.0]
    # equal weights are the default; one-hot weights are that kernel's MMD²
    assert mk_mmd(xs, xt, bandwidths=h, kernel_weights=[1 / 3] * 3).item() == pytest.approx(
        mk_mmd(xs, xt, bandwidths=h).item(), rel=1e-12)
    assert mk_mmd(xs, xt, bandwidths=h, kernel_weights=[0.0, 1.0, 0.0]).item() == pytest.approx(
        mk_mmd(xs, xt, bandwidths=[1.0]).item(), rel=1e-12)
    # a convex combination of the one-kernel MMD²s, in either estimator
    for unbiased in (False, True):
        single = [mk_mmd(xs, xt, bandwidths=[hu], unbiased=unbiased).item() for hu in h]
        got = mk_mmd(xs, xt, bandwidths=h, kernel_weights=[0.2, 0.3, 0.5], unbiased=unbiased).item()
        assert got == pytest.approx(0.2 * single[0] + 0.3 * single[1] + 0.5 * single[2], rel=1e-12)
    for bad in ([0.5, 0.5], [0.5, 0.6, -0.1], [0.5, 0.5, 0.5], [float("nan"), 0.5, 0.5]):
        with pytest.raises(ValueError, match="kernel_weights"):
            mk_mmd(xs, xt, bandwidths=h, kernel_weights=bad)


def _feats(seed, n_s=8, n_t=8):
    g = torch.Generator().manual_seed(seed)
    fs = {"fc1": torch.randn(n_s, 6, generator=g, dtype=torch.float64),
          "fc2": torch.randn(n_s, 3, generator=g, dtype=torch.float64)}
    ft = {"fc1": torch.randn(n_t, 6, generator=g, dtype=torch.float64) + 1,
          "fc2": 2 * torch.randn(n_t, 3, generator=g, dtype=torch.float64)}
    logits = torch.randn(n_s, 3, generator=g, dtype=torch.float64)
    labels = torch.randint(0, 3, (n_s,), generator=g)
    return logits, labels, fs, ft


def test_vtloss_optimal_kernel_weights_follow_running_means_of_the_batches():
    """Two training steps written out by hand: bias-corrected exponential means of each layer's η and Q,
    Gretton's weights from them, and eq. 7.8 with those weights in MK-MMD."""
    loss = VTLoss(alpha=2.0, beta=3.0, lam=5.0, mmd_kernel_weights="optimal", mmd_kernel_momentum=0.5)
    eta = {"fc1": torch.zeros(5, dtype=torch.float64), "fc2": torch.zeros(5, dtype=torch.float64)}
    q = {"fc1": torch.zeros(5, 5, dtype=torch.float64), "fc2": torch.zeros(5, 5, dtype=torch.float64)}
    for t, seed in enumerate((21, 22), start=1):
        logits, labels, fs, ft = _feats(seed)
        expected = 2.0 * torch.nn.functional.cross_entropy(logits, labels)
        total, parts = loss(logits, labels, fs, ft)
        for layer in ("fc1", "fc2"):
            h = gaussian_bandwidths(torch.cat([fs[layer], ft[layer]]))
            stats = linear_time_statistics(fs[layer], ft[layer], h)
            eta[layer] = 0.5 * eta[layer] + 0.5 * stats.mean(0)
            q[layer] = 0.5 * q[layer] + 0.5 * torch.cov(stats.T)
            corr = 1 - 0.5**t
            w = optimal_kernel_weights(eta[layer] / corr, q[layer] / corr)
            assert [parts[f"kernel_beta_{layer}_{u}"].item() for u in range(5)] == pytest.approx(w.tolist())
            mmd = mk_mmd(fs[layer], ft[layer], bandwidths=h, kernel_weights=w)
            assert parts[f"mmd_{layer}"].item() == pytest.approx(mmd.item(), rel=1e-10)
            expected = expected + 3.0 * mmd + 5.0 * coral(fs[layer], ft[layer])
        assert total.item() == pytest.approx(expected.item(), rel=1e-10)
    # the weights are not equal on these batches, so the option changes the loss
    assert parts["mmd"].item() != pytest.approx(VTLoss()(logits, labels, fs, ft)[1]["mmd"].item(), rel=1e-6)
    # eval mode uses the last training means and leaves them alone; they travel with the state dict
    state = {k: v.clone() for k, v in loss.state_dict().items()}
    loss.eval()
    _, again = loss(*_feats(23))
    assert [again[f"kernel_beta_fc1_{u}"].item() for u in range(5)] == pytest.approx(
        [parts[f"kernel_beta_fc1_{u}"].item() for u in range(5)])
    assert all(torch.equal(v, loss.state_dict()[k]) for k, v in state.items())
    assert {"kernel_eta", "kernel_q", "kernel_updates"} <= set(state) and not set(VTLoss().state_dict())
    fresh = VTLoss(mmd_kernel_weights="optimal")
    fresh.load_state_dict(state)
    assert torch.equal(fresh.kernel_eta, loss.kernel_eta)


def test_vtloss_optimal_kernel_weights_are_equal_before_any_update():
    # eval mode before training, and batches too small for a covariance of quadruples, give equal weights
    loss = VTLoss(mmd_kernel_weights="optimal").eval()
    _, parts = loss(*_feats(24))
    assert [parts[f"kernel_beta_fc2_{u}"].item() for u in range(5)] == pytest.approx([0.2] * 5)
    loss.train()
    logits, labels, fs, ft = _feats(25, n_s=3, n_t=3)
    _, parts = loss(logits, labels, fs, ft)
    assert float(loss.kernel_updates.sum()) == 0
    assert parts["mmd_fc1"].item() == pytest.approx(mk_mmd(fs["fc1"], ft["fc1"]).item(), rel=1e-12)


@pytest.mark.parametrize("kwargs,match", [
    (dict(mmd_kernel_weights="best"), "mmd_kernel_weights: expected one of"),
    (dict(mmd_kernel_weights="optimal", use_mmd=False), "needs use_mmd"),
    (dict(mmd_kernel_weights="optimal", mmd_conditional=True), "without mmd_conditional"),
    (dict(mmd_kernel_weights="optimal", mmd_num_kernels=MAX_KERNELS + 1), "at most"),
    (dict(mmd_kernel_momentum=1.0), "mmd_kernel_momentum"),
    (dict(mmd_kernel_momentum=-0.5), "mmd_kernel_momentum"),
])
def test_vtloss_optimal_kernel_weights_reject_bad_settings(kwargs, match):
    with pytest.raises(ValueError, match=match):
        VTLoss(**kwargs)
