"""CCFT loss (Algorithm 1) against POT, brute force and finite differences; numerical safety; the guide map."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from training.stylize.ccft import ccft_loss, gathered_row_dot, l2_normalise, transport_cost


def relu_features(n: int, c: int, seed: int, dtype=torch.float64) -> torch.Tensor:
    """ReLU-like non-negative features, as VGG's relu3_x are."""
    g = torch.Generator().manual_seed(seed)
    return torch.relu(torch.randn(n, c, generator=g, dtype=dtype) + 0.2)


@pytest.fixture
def ot():
    """POT, for the tests that compare with it: only they skip where it is not installed."""
    return pytest.importorskip("ot", reason="POT is the reference for the transport plan (pip install POT)")


def pot_plan(ot, result, n: int, epsilon: float, tau: float, iters: int,
             columns: np.ndarray | None = None) -> np.ndarray:
    """POT's semi-unbalanced Sinkhorn on the same support: dense cost with 1e3 off the support.

    columns: restrict the problem to these style features (the reachable ones): POT stops at a column with zero
    mass, while the unreachable columns carry no edge and change nothing in Algorithm 1."""
    idx = result.plan.indices.numpy()
    m = result.column_mass.shape[0]
    M = np.full((n, m), 1e3)
    np.put_along_axis(M, idx, result.cost.numpy().astype(np.float64), axis=1)
    reach = result.reachable.numpy()
    b = np.where(reach, 1.0 / reach.sum(), 1e-12)
    if columns is not None:
        M, b = M[:, columns], b[columns]
    a = np.full(n, 1.0 / n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # POT says it overwrites c for reg_type='entropy': expected
        return ot.unbalanced.sinkhorn_unbalanced(a, b, M, epsilon, (float("inf"), tau), reg_type="entropy",
                                                 numItermax=iters, stopThr=0, method="sinkhorn")


def dense_plan(result, n: int, m: int) -> np.ndarray:
    D = np.zeros((n, m))
    np.put_along_axis(D, result.plan.indices.numpy(), result.plan.values.numpy(), axis=1)
    return D


BACKENDS = ["numba", "torch"]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("epsilon,tau,iters", [(0.05, 0.5, 50), (0.01, 0.1, 50), (0.05, 1.0, 100), (0.1, 0.01, 30)])
def test_plan_equals_pot(epsilon, tau, iters, backend, ot):
    n, m, c = 300, 200, 64
    X, Y = relu_features(n, c, 1), relu_features(m, c, 2)
    r = ccft_loss(X, Y, k=16, epsilon=epsilon, tau=tau, iters=iters, sinkhorn_backend=backend)
    assert bool(r.reachable.all()), "this problem is meant to reach every column"
    P = pot_plan(ot, r, n, epsilon, tau, iters)
    D = dense_plan(r, n, m)
    assert np.abs(P - D).max() <= 1e-10
    assert P.max() > 1e-4  # a real plan, not two zero matrices
    # the loss is the transport cost under that plan
    assert abs(float(r.loss) - float((P * dense_cost(r, n, m)).sum())) <= 1e-10


def dense_cost(r, n, m):
    Cd = np.zeros((n, m))
    np.put_along_axis(Cd, r.plan.indices.numpy(), r.cost.numpy(), axis=1)
    return Cd


@pytest.mark.parametrize("backend", BACKENDS)
def test_plan_equals_pot_with_unreachable_columns_and_guide(backend, ot):
    n, m, c = 120, 400, 32
    X, Y = relu_features(n, c, 3), relu_features(m, c, 4)
    first = ccft_loss(X, Y, k=8, epsilon=0.05, tau=0.5, iters=50, sinkhorn_backend=backend)
    X2 = X + 0.3 * relu_features(n, c, 5)  # the "next view"
    r = ccft_loss(X2, Y, first.guide, k=8, epsilon=0.05, tau=0.5, lambda_guide=1.0, iters=50,
                  sinkhorn_backend=backend)
    reach = r.reachable.numpy()
    assert 0 < reach.sum() < m  # some style features are unreachable
    cols = np.flatnonzero(reach)
    P = pot_plan(ot, r, n, 0.05, 0.5, 50, columns=cols)
    D = dense_plan(r, n, m)
    assert np.abs(P - D[:, cols]).max() <= 1e-10
    assert np.all(D[:, ~reach] == 0)
    assert np.allclose(r.column_mass.numpy(), D.sum(axis=0), rtol=0, atol=1e-15)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("tau", [0.01, 0.5, 10.0, math.inf])
def test_no_nan_at_small_epsilon_with_unreachable_columns(tau, backend):
    n, m, c = 64, 1000, 48
    X = relu_features(n, c, 6, torch.float32).requires_grad_(True)
    Y = relu_features(m, c, 7, torch.float32)
    Y[:10] = 0  # all-zero style features (flat regions of a painting) must not break the normalisation
    r = ccft_loss(X, Y, k=4, epsilon=0.01, tau=tau, iters=200, sinkhorn_backend=backend)
    assert int(r.reachable.sum()) < m
    r.loss.backward()
    for name, t in [("loss", r.loss), ("plan", r.plan.values), ("guide", r.guide), ("column_mass", r.column_mass),
                    ("grad", X.grad)]:
        assert torch.isfinite(t).all(), name
    # a real plan: non-negative, about unit mass (rows are exact after a u update; the last update is v's)
    assert float(r.plan.values.min()) >= 0 and 0.8 < float(r.plan.values.sum()) < 1.25
    assert math.isfinite(r.column_entropy) and 0 <= r.utilisation <= 1


@pytest.mark.parametrize("backend", BACKENDS)
def test_far_costs_at_small_epsilon_stay_finite(backend):
    """Costs near 2 (opposite features) make exp(-C/eps) = exp(-200): float64 scalings or the log domain carry it."""
    n, m, c = 50, 60, 16
    X = relu_features(n, c, 8)
    Y = -relu_features(m, c, 9)  # every cosine <= 0: costs in [1, 2]
    Y[:, 0] = 1e-3
    r = ccft_loss(X, Y, k=16, epsilon=0.01, tau=0.1, iters=100, sinkhorn_backend=backend)
    assert torch.isfinite(r.plan.values).all() and torch.isfinite(r.loss)
    assert float(r.cost.min()) > 0.9
    np.testing.assert_allclose(r.plan.values.sum(dim=1).numpy(), 1.0 / n, rtol=0.05)


def test_compiled_kernel_falls_back_to_log_domain_beyond_float64():
    """At epsilon = 0.001 a cost gap of 1.9 is exp(-1900) = 0 in float64: a column reached only by such edges would
    get v = inf from the scalings; the log domain still gives its (tiny but exact) plan."""
    n, m = 40, 50  # K = 2 edges a row
    g = torch.Generator().manual_seed(23)
    indices = torch.stack([torch.arange(n) % 30, 30 + torch.arange(n) % 20], dim=1)  # columns 30.. only as 2nd edge
    cost = torch.stack([0.05 * torch.rand(n, generator=g, dtype=torch.float64),
                        1.95 + 0.05 * torch.rand(n, generator=g, dtype=torch.float64)], dim=1)
    reachable = torch.ones(m, dtype=torch.bool)
    from training.stylize.sinkhorn_cpu import sinkhorn_plan_cpu
    from training.stylize.ccft import semi_balanced_sinkhorn

    assert sinkhorn_plan_cpu(cost.numpy(), indices.numpy(), torch.full((m,), 1 / m, dtype=torch.float64).numpy(),
                             reachable.numpy(), 0.5 / 0.501, 0.001, 20) is None
    auto = semi_balanced_sinkhorn(cost, indices, reachable, 0.5, 0.001, 20, backend="auto")
    log = semi_balanced_sinkhorn(cost, indices, reachable, 0.5, 0.001, 20, backend="torch")
    assert torch.isfinite(auto).all() and torch.equal(auto, log)
    assert float(auto[:, 1].max()) > 0  # the far columns do receive mass


def test_gradient_matches_finite_differences_with_plan_fixed():
    n, m, c = 20, 30, 8
    X = relu_features(n, c, 10).requires_grad_(True)
    Y = relu_features(m, c, 11)
    r = ccft_loss(X, Y, k=5, epsilon=0.05, tau=0.5, iters=50)
    (grad,) = torch.autograd.grad(r.loss, X)
    # the loss equals the transport cost of the returned plan
    assert abs(float(r.loss.detach()) - float(transport_cost(X.detach(), Y, r.plan))) < 1e-14
    h = 1e-6
    fd = torch.zeros_like(X)
    with torch.no_grad():
        for i in range(n):
            for j in range(c):
                Xp, Xm = X.detach().clone(), X.detach().clone()
                Xp[i, j] += h
                Xm[i, j] -= h
                fd[i, j] = (transport_cost(Xp, Y, r.plan) - transport_cost(Xm, Y, r.plan)) / (2 * h)
    assert float(grad.abs().max()) > 1e-4
    torch.testing.assert_close(grad, fd, rtol=1e-6, atol=1e-8)


def test_gathered_row_dot_backward_matches_dense_autograd():
    n, m, c, k = 37, 23, 12, 6
    X = relu_features(n, c, 12).requires_grad_(True)
    Y = relu_features(m, c, 13).requires_grad_(True)
    idx = torch.randint(0, m, (n, k), generator=torch.Generator().manual_seed(0))
    w = relu_features(n, k, 14)
    (gX, gY) = torch.autograd.grad((gathered_row_dot(X, Y, idx) * w).sum(), (X, Y))
    (rX, rY) = torch.autograd.grad(((X.unsqueeze(1) * Y[idx]).sum(-1) * w).sum(), (X, Y))
    torch.testing.assert_close(gX, rX, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(gY, rY, rtol=1e-12, atol=1e-12)


def test_support_is_dense_top_k_and_chunking_changes_nothing():
    n, m, c, k = 90, 70, 24, 7
    X, Y = relu_features(n, c, 15), relu_features(m, c, 16)
    big = ccft_loss(X, Y, k=k)
    small = ccft_loss(X, Y, k=k, chunk_elements=m * 4 + 3)  # 4 rows a chunk, ragged last chunk
    S = l2_normalise(X) @ l2_normalise(Y).t()
    ref = torch.topk(S, k, dim=1).indices
    assert torch.equal(big.plan.indices, ref) and torch.equal(small.plan.indices, ref)
    torch.testing.assert_close(big.plan.values, small.plan.values, rtol=0, atol=1e-15)
    torch.testing.assert_close(big.guide, small.guide, rtol=1e-12, atol=1e-12)


def test_guide_map_is_the_plan_weighted_mean_and_changes_the_support():
    n, m, c, k = 200, 150, 32, 8
    X, Y = relu_features(n, c, 17), relu_features(m, c, 18)
    r = ccft_loss(X, Y, k=k)
    # brute force: G_j = normalise(sum_i T_ij x_i / |x_i|)
    D = torch.from_numpy(dense_plan(r, n, m))
    G = D.t() @ l2_normalise(X)
    G = G / G.norm(dim=1, keepdim=True).clamp_min(1e-12)
    torch.testing.assert_close(r.guide, G, rtol=1e-10, atol=1e-12)
    assert not r.guide.requires_grad
    # the next view: with guidance the support follows the previous view's matches
    X2 = X + 0.5 * relu_features(n, c, 19)
    plain = ccft_loss(X2, Y, r.guide, k=k, lambda_guide=0.0)
    guided = ccft_loss(X2, Y, r.guide, k=k, lambda_guide=1.0)
    nothing = ccft_loss(X2, Y, None, k=k, lambda_guide=1.0)
    assert torch.equal(plain.plan.indices, nothing.plan.indices)
    changed = (plain.plan.indices.sort(dim=1).values != guided.plan.indices.sort(dim=1).values).any(dim=1)
    assert int(changed.sum()) > n // 10
    S = l2_normalise(X2) @ (l2_normalise(Y) + r.guide).t()
    assert torch.equal(guided.plan.indices, torch.topk(S, k, dim=1).indices)


def test_bfloat16_search_finds_the_float32_top_k():
    """The bfloat16 product only proposes candidates: float32 scores decide and uncertain rows are searched again in
    float32, so the support is float32's, for features whose top scores are far apart and for near-ties (rows that
    take the float32 fallback), guided or not."""
    from training.stylize.ccft import topk_support

    g = torch.Generator().manual_seed(30)
    n, m, c, k = 300, 2000, 96, 8
    X = l2_normalise(relu_features(n, c, 31, torch.float32))
    Y = l2_normalise(relu_features(m, c, 32, torch.float32))
    near = l2_normalise(1.0 + 0.05 * torch.rand(m, c, generator=g))  # top scores within bfloat16's error
    G = l2_normalise(relu_features(m, c, 33, torch.float32))
    for Z in (Y, Y + G, near):
        S = X @ Z.t()
        ref = torch.topk(S, k + 1, dim=1).values
        clear = (ref[:, k - 1] - ref[:, k]) > 1e-5  # rows whose top k is not decided by a float32 tie
        a = topk_support(X, Z, k, precision="float32")
        b = topk_support(X, Z, k, precision="bfloat16", chunk_elements=m * 64 + 5)
        assert torch.equal(a.sort(dim=1).values[clear], b.sort(dim=1).values[clear])
        assert int(clear.sum()) > n // 2


def test_bfloat16_certificate_holds_on_a_constructed_near_tie():
    """Inputs that all round down by almost 2^-8 (each channel just below a bfloat16 midpoint, x and z alike) make a
    bfloat16 score 0.0078 |x| |z| low: more than a bound built on 2^-9 per input (0.0065) allows, within the one
    derived from 2^-8 (bf16_score_error). Among rows whose bfloat16 scores tie with it and whose exact scores are a
    hair lower, the truly best row drops out of the 64 candidates where the tie's order puts it last; it must then
    fail the certificate and be found by the float32 search. Several placements are tried, and at least one must
    drop it (else the construction no longer exercises the certificate); every one must give float32's support."""
    from training.stylize.ccft import BF16_UNIT, bf16_score_error, topk_support

    c, w = 768, 2.0 ** -5
    x = torch.full((1, c), w * (1 + BF16_UNIT * (1 - 1e-3)))  # rounds down to w
    best = torch.full((c,), w * (1 + BF16_UNIT * (1 - 1e-3)))
    dropped = 0
    for count in (65, 100, 200):
        # each rounds to w as well (the best's bfloat16 score, 0.75), with exact scores from 0.7549 to 0.7556
        others = [torch.full((c,), w * (1 + BF16_UNIT * (1 - f))) for f in torch.linspace(0.05, 0.6, count).tolist()]
        for at in (0, count // 2, count):
            Z = torch.stack(others[:at] + [best] + others[at:])
            exact = (x.double() @ Z.double().t())[0]
            low = (x.bfloat16() @ Z.bfloat16().t()).float()[0]
            assert int(exact.argmax()) == at and bool((low == low[at]).all())
            error = float(exact[at] - low[at]) / float(x.norm() * Z.norm(dim=1).max())
            assert 0.0065 < error <= bf16_score_error(c), error
            dropped += at not in torch.topk(low, 64).indices.tolist()
            assert topk_support(x, Z, 1, precision="bfloat16").tolist() == [[at]], (count, at)
    assert dropped, "no placement dropped the best row from the bfloat16 candidates"


def test_float32_row_kernels_match_the_dense_products():
    """On the CPU in float32 the support's row products (training/stylize/support_cpu.py: the costs, their gradient,
    the guide map) give the dense float64 products' numbers to float32 rounding, and ccft_loss in float32 (which
    runs on them) the float64 loss's support, costs and guide map."""
    from training.stylize.support_cpu import gather_add, gather_dot, scatter_add

    n, m, c, k = 120, 90, 40, 7
    X, Y = relu_features(n, c, 34), relu_features(m, c, 35)
    idx = torch.randint(0, m, (n, k), generator=torch.Generator().manual_seed(1))
    W = relu_features(n, k, 36)
    dots = np.empty((n, k), np.float32)
    gather_dot(X.float().numpy(), Y.float().numpy(), idx.numpy(), dots)
    np.testing.assert_allclose(dots, (X.unsqueeze(1) * Y[idx]).sum(-1).numpy(), rtol=1e-5, atol=1e-5)
    added = np.empty((n, c), np.float32)
    gather_add(W.float().numpy(), Y.float().numpy(), idx.numpy(), added)
    np.testing.assert_allclose(added, (W.unsqueeze(-1) * Y[idx]).sum(1).numpy(), rtol=1e-5, atol=1e-5)
    dense = torch.zeros(n, m, dtype=torch.float64).scatter_add_(1, idx, W)
    np.testing.assert_allclose(scatter_add(W.numpy(), X.numpy(), idx.numpy(), m), (dense.t() @ X).numpy(),
                               rtol=1e-5, atol=1e-5)
    r64 = ccft_loss(X, Y, k=k)
    r32 = ccft_loss(X.float().requires_grad_(True), Y.float(), k=k)
    assert torch.equal(r32.plan.indices, r64.plan.indices)
    torch.testing.assert_close(r32.cost.double(), r64.cost, rtol=0, atol=2e-6)
    torch.testing.assert_close(r32.guide.double(), r64.guide, rtol=0, atol=2e-6)


def test_bad_arguments():
    X, Y = relu_features(10, 4, 20), relu_features(12, 4, 21)
    with pytest.raises(ValueError):
        ccft_loss(X, relu_features(12, 5, 22))
    with pytest.raises(ValueError):
        ccft_loss(X, Y, epsilon=0.0)
    with pytest.raises(ValueError):
        ccft_loss(X, Y, guide=torch.zeros(11, 4))
    r = ccft_loss(X, Y, k=50)  # K larger than m: every style feature is on every row's support
    assert r.plan.indices.shape == (10, 12)
