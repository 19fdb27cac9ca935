"""Capacity-Controlled Feature Transport (CCFT) loss: Algorithm 1 of the paper, sparse throughout.

Rendered features X (n, C) and style features Y (m, C) are L2-normalised. A top-K support per rendered feature is
found on the guided similarity S = X (Y + lambda_guide G)^T, computed a chunk of rows at a time so that no n x m
matrix is ever held beyond one chunk. On that support, the cost is C = max(1 - <x_i, y_j>, 0) and a semi-balanced
entropic transport (rows exact, columns softly pulled toward uniform over the reachable style features by a KL term
of strength tau) is solved with Sinkhorn in float64 (on the CPU a compiled kernel on a row-stabilised Gibbs kernel,
``training.stylize.sinkhorn_cpu``, with the log domain as fallback; elsewhere the log domain): epsilon down to 0.01 and
columns no rendered feature reaches give neither NaN nor inf. The loss <T, C> has its gradient through C only (the
plan is held fixed), and the guide map for the next view is the plan-weighted mean of the rendered features landing
on each style feature.

Memory is O(nK + mC) plus one similarity chunk.
"""

from __future__ import annotations

import functools
import math
import time
import warnings
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

from training.stylize import defaults

# A similarity chunk holds at most this many entries (64 MB in float32).
DEFAULT_CHUNK_ELEMENTS = 1 << 24
# b_j for style features that no rendered feature reaches (Algorithm 1); they carry no edges, so it never matters
# beyond keeping the formula total.
UNREACHABLE_B = 1e-12


@dataclass
class SparsePlan:
    indices: torch.Tensor  # (n, K) int64: style feature j of each support edge
    values: torch.Tensor  # (n, K) float64: transported mass T_ij on that edge (rows sum to ~1/n: exactly
    # after a u update, and Sinkhorn ends on a v update)


@dataclass
class CCFTResult:
    loss: torch.Tensor  # scalar, differentiable w.r.t. X (through the cost only)
    guide: torch.Tensor  # (m, C) detached, unit rows (zero where no mass arrived): the next view's guide map
    plan: SparsePlan
    column_mass: torch.Tensor  # (m,) float64: mass received by each style feature (sums to ~1)
    cost: torch.Tensor  # (n, K) detached cost on the support
    reachable: torch.Tensor  # (m,) bool: style features on at least one support edge
    utilisation: float  # fraction of reachable style features with column mass >= half of uniform (1 / |J|)
    column_entropy: float  # entropy (nats) of the column marginal normalised to sum 1
    column_entropy_normalised: float  # column_entropy / log|J|, in [0, 1]
    timings: dict[str, float] = field(default_factory=dict)  # seconds: similarity_topk, cost, sinkhorn, guide


def l2_normalise(x: torch.Tensor) -> torch.Tensor:
    """(N, C) -> (N, C) unit rows; all-zero rows stay zero (ReLU features can be all zero in flat regions)."""
    return F.normalize(x, p=2.0, dim=1, eps=1e-12)


def _chunk_rows(chunk_elements: int, row_size: int) -> int:
    return max(1, chunk_elements // max(1, row_size))


# The bfloat16 search: each row's CANDIDATES_PER_K * k best by a bfloat16 product are scored again in float32, and
# the row is certified when its k-th float32 score beats the last candidate's bfloat16 score by more than the worst
# error of the two, bf16_score_error(C) * |x| * max |z|: no feature outside the candidates can then be in the top k.
# Rows that are not certified are searched again in float32.
CANDIDATES_PER_K = 4
MIN_CANDIDATES = 64
BF16_UNIT = 2.0 ** -8  # bfloat16 keeps 8 significant bits: rounding moves a value by at most 2^-8 of itself
F32_UNIT = 2.0 ** -24


def bf16_score_error(channels: int) -> float:
    """The worst |bfloat16 score - exact score| of two C-channel vectors over |x| |z|, for a product whose inputs
    are rounded to bfloat16, whose sum is kept in float32 and whose result is rounded to bfloat16 (torch's CPU
    matmul), plus the float32 rescoring's own error. Each rounded input is off by at most u = 2^-8 of itself, so a
    product of two by 2u + u^2; a float32 sum of C terms by gamma_C = C 2^-24 / (1 - C 2^-24) of the sum of their
    magnitudes (at most |x| |z|, Cauchy-Schwarz); the result's rounding by u of the result. 0.01186 for C = 768
    (a bound built on 2^-9 per input, 0.0065, was exceeded by inputs that all round the same way: 0.0078)."""
    gamma = channels * F32_UNIT / (1 - channels * F32_UNIT)
    inputs = 2 * BF16_UNIT + BF16_UNIT ** 2
    return inputs + gamma * (1 + BF16_UNIT) ** 2 + BF16_UNIT * (1 + inputs + gamma) + gamma


@functools.lru_cache(maxsize=None)
def bf16_matmul_is_faster() -> bool:
    """Whether this CPU multiplies bfloat16 matrices at least 1.5x faster than float32 (AVX512-BF16 or AMX: 3.7x on
    such 2-core machines). Where Linux says the CPU has neither, no: torch then emulates bfloat16, about 70x slower
    than float32 on an AMD EPYC here (2 s for one 256x768x2048 product), so even timing it would cost seconds.
    Otherwise measured once, on a small product."""
    flags = _cpu_flags()
    if flags is not None and not ({"avx512_bf16", "amx_bf16"} & flags):
        return False
    a, b = torch.rand(128, 384), torch.rand(384, 1024)
    ab, bb = a.bfloat16(), b.bfloat16()

    def best(x, y) -> float:
        times = []
        for _ in range(4):
            t = time.perf_counter()
            x @ y
            times.append(time.perf_counter() - t)
        return min(times[1:])

    return best(ab, bb) * 1.5 < best(a, b)


def _cpu_flags() -> set[str] | None:
    """The CPU's feature flags as Linux lists them, or None where it does not (another system)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        return None
    return None


@torch.no_grad()
def topk_support(Xn: torch.Tensor, Z: torch.Tensor, k: int,
                 chunk_elements: int = DEFAULT_CHUNK_ELEMENTS, precision: str = "auto") -> torch.Tensor:
    """Indices (n, k) of the k largest entries of each row of Xn @ Z^T, computed chunk by chunk.

    Xn (n, C), Z (m, C). Peak extra memory: one (chunk, m) block. ``precision``: "float32" (one float32 product),
    "bfloat16" (a bfloat16 product picks candidates, float32 scores decide, certified row by row, see
    CANDIDATES_PER_K: the same indices as float32, about 3x faster on CPUs with native bfloat16), or "auto"
    (bfloat16 for float32 CPU inputs where ``bf16_matmul_is_faster``)."""
    n, m = Xn.shape[0], Z.shape[0]
    if precision == "auto":
        precision = "bfloat16" if (Xn.device.type == "cpu" and Xn.dtype == torch.float32
                                   and k * CANDIDATES_PER_K < m and bf16_matmul_is_faster()) else "float32"
    rows = _chunk_rows(chunk_elements, m)
    out = torch.empty((n, k), dtype=torch.int64, device=Xn.device)
    Zt = Z.t().contiguous()
    if precision == "float32":
        for s in range(0, n, rows):
            e = min(n, s + rows)
            out[s:e] = torch.topk(Xn[s:e] @ Zt, k, dim=1, largest=True, sorted=True).indices
        return out
    if precision != "bfloat16":
        raise ValueError(f"unknown precision {precision!r} (auto, float32, bfloat16)")
    k2 = min(m, max(CANDIDATES_PER_K * k, MIN_CANDIDATES))
    Xb, Ztb = Xn.bfloat16(), Zt.bfloat16()
    margin = bf16_score_error(Xn.shape[1]) * float(Z.norm(dim=1).max()) * Xn.norm(dim=1)
    for s in range(0, n, rows):
        e = min(n, s + rows)
        cand = torch.topk(Xb[s:e] @ Ztb, k2, dim=1, largest=True, sorted=True)
        exact = gathered_row_dot(Xn[s:e], Z, cand.indices)  # (rows, k2) float32 scores of the candidates
        top = torch.topk(exact, k, dim=1, largest=True, sorted=True)
        out[s:e] = cand.indices.gather(1, top.indices)
        doubt = torch.nonzero(top.values[:, -1] <= cand.values[:, -1].float() + margin[s:e]).flatten()
        if doubt.numel():
            out[s + doubt] = torch.topk(Xn[s + doubt] @ Zt, k, dim=1, largest=True, sorted=True).indices
    return out


def support_matrix(indices: torch.Tensor, values: torch.Tensor, m: int) -> torch.Tensor:
    """The (n, m) sparse CSR matrix with values (n, K) at [i, indices[i, k]] (K entries a row, order kept)."""
    n, k = indices.shape
    crow = torch.arange(0, n * k + 1, k, dtype=torch.int64, device=indices.device)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torch calls its sparse CSR support beta
        return torch.sparse_csr_tensor(crow, indices.reshape(-1), values.reshape(-1), size=(n, m))


def _numba_rows(*tensors: torch.Tensor) -> bool:
    """Whether the support's row products run on support_cpu's kernels: float32 CPU tensors."""
    return all(t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors)


class _GatheredRowDot(torch.autograd.Function):
    """V[i, k] = <X[i], Y[idx[i, k]]> without materialising Y[idx] (n, K, C).

    Forward: the dot products on the support; backward: dX = A Y and dY = A^T X with A the (n, m) sparse matrix of
    the incoming gradient on the support. On the CPU in float32: support_cpu's kernels, else sparse products."""

    @staticmethod
    def forward(ctx, X: torch.Tensor, Y: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        n, k = idx.shape
        ctx.save_for_backward(X, Y, idx)
        if _numba_rows(X, Y):
            from training.stylize.support_cpu import gather_dot

            out = torch.empty((n, k), dtype=torch.float32)
            gather_dot(X.detach().numpy(), Y.detach().numpy(), idx.numpy(), out.numpy())
            return out
        pattern = support_matrix(idx, torch.zeros(n * k, dtype=X.dtype, device=X.device), Y.shape[0])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return torch.sparse.sampled_addmm(pattern, X, Y.t(), beta=0.0).values().view(n, k)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        X, Y, idx = ctx.saved_tensors
        grad = grad.contiguous()
        gX = gY = None
        if ctx.needs_input_grad[0] and _numba_rows(grad, Y):
            from training.stylize.support_cpu import gather_add

            gX = torch.empty_like(X)
            gather_add(grad.numpy(), Y.detach().numpy(), idx.numpy(), gX.numpy())
        elif ctx.needs_input_grad[0]:
            gX = support_matrix(idx, grad, Y.shape[0]) @ Y
        if ctx.needs_input_grad[1]:
            gY = support_matrix(idx, grad, Y.shape[0]).t() @ X
        return gX, gY, None


def gathered_row_dot(X: torch.Tensor, Y: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """X (n, C), Y (m, C), idx (n, K) -> (n, K) with [i, k] = <X[i], Y[idx[i, k]]>; differentiable in X and Y.

    Memory O(nK + (n + m) C)."""
    return _GatheredRowDot.apply(X.contiguous(), Y.contiguous(), idx.contiguous())


def _scatter_logsumexp(values: torch.Tensor, index: torch.Tensor, size: int) -> torch.Tensor:
    """out[j] = log sum_{e : index[e] = j} exp(values[e]); -inf where no e maps to j. values, index: (E,)."""
    colmax = torch.full((size,), -math.inf, dtype=values.dtype, device=values.device)
    colmax.scatter_reduce_(0, index, values, reduce="amax", include_self=True)
    shift = colmax.clamp_min(torch.finfo(values.dtype).min)  # finite shift also for empty columns
    sums = torch.zeros(size, dtype=values.dtype, device=values.device)
    sums.index_add_(0, index, torch.exp(values - shift.index_select(0, index)))
    return torch.log(sums) + shift


def _sinkhorn_log_torch(log_kernel: torch.Tensor, indices: torch.Tensor, log_b: torch.Tensor,
                        reachable: torch.Tensor, alpha: float, iters: int) -> torch.Tensor:
    """Algorithm 1's Sinkhorn in the log domain with tensor operations (any device); returns the plan (n, K)."""
    n = log_kernel.shape[0]
    m = log_b.shape[0]
    log_a = -math.log(n)
    flat = indices.reshape(-1)
    log_u = torch.zeros(n, dtype=log_kernel.dtype, device=log_kernel.device)
    log_v = torch.zeros(m, dtype=log_kernel.dtype, device=log_kernel.device)
    for _ in range(iters):
        log_u = log_a - torch.logsumexp(log_kernel + log_v.index_select(0, flat).view_as(log_kernel), dim=1)
        log_col = _scatter_logsumexp((log_u.unsqueeze(1) + log_kernel).reshape(-1), flat, m)
        log_v = torch.where(reachable, alpha * (log_b - log_col), torch.zeros_like(log_col))
    return torch.exp(log_u.unsqueeze(1) + log_kernel + log_v.index_select(0, flat).view_as(log_kernel))


def semi_balanced_sinkhorn(cost: torch.Tensor, indices: torch.Tensor, reachable: torch.Tensor, tau: float,
                           epsilon: float, iters: int, backend: str = "auto") -> torch.Tensor:
    """Transport plan (n, K) float64 of Algorithm 1 on a top-K support.

    cost (n, K) float64 >= 0 (no gradient); indices (n, K); reachable (m,) bool. With the Gibbs kernel
    K = exp(-cost / epsilon), a = 1/n, b = 1/|J| on the reachable columns (1e-12 elsewhere) and u = v = 1, each
    iteration sets u = a / (K v), then v = (b / K^T u)^(tau / (tau + epsilon)); the plan is u K v.
    backend: "numba" (compiled CPU kernel, float64 scalings; falls back to the log domain if float64 cannot carry
    them), "torch" (log domain, tensor ops, any device), "auto" (numba on the CPU, torch elsewhere).
    """
    cost = cost.detach()
    alpha = 1.0 if math.isinf(tau) else tau / (tau + epsilon)
    n_reach = int(reachable.sum())
    m = reachable.shape[0]
    b = torch.full((m,), UNREACHABLE_B, dtype=torch.float64, device=cost.device)
    b[reachable] = 1.0 / n_reach
    if backend == "auto":
        backend = "numba" if cost.device.type == "cpu" else "torch"
    if backend == "numba":
        from training.stylize.sinkhorn_cpu import sinkhorn_plan_cpu

        plan = sinkhorn_plan_cpu(cost.numpy(), indices.numpy(), b.numpy(), reachable.numpy(), alpha, epsilon,
                                 iters)
        if plan is not None:
            return torch.from_numpy(plan)
    elif backend != "torch":
        raise ValueError(f"unknown Sinkhorn backend '{backend}' (auto, numba, torch)")
    return _sinkhorn_log_torch(-cost / epsilon, indices, torch.log(b), reachable, alpha, iters)


def column_statistics(column_mass: torch.Tensor, reachable: torch.Tensor) -> tuple[float, float, float]:
    """(utilisation, entropy, entropy / log|J|) of a column marginal (m,) over the reachable set (m,) bool.

    Utilisation: fraction of reachable columns whose mass is at least half of the uniform share total / |J|."""
    n_reach = int(reachable.sum())
    if n_reach == 0:
        return 0.0, 0.0, 0.0
    mass = column_mass.to(torch.float64)
    total = float(mass.sum())
    util = float((mass[reachable] >= 0.5 * total / n_reach).to(torch.float64).mean())
    p = mass[mass > 0] / total
    entropy = float(-(p * torch.log(p)).sum())
    norm = entropy / math.log(n_reach) if n_reach > 1 else 1.0
    return util, entropy, norm


def ccft_loss(X: torch.Tensor, Y: torch.Tensor, guide: torch.Tensor | None = None, k: int = defaults.K,
              epsilon: float = defaults.EPSILON, tau: float = defaults.TAU,
              lambda_guide: float = defaults.LAMBDA_GUIDE, iters: int = defaults.SINKHORN_ITERS,
              chunk_elements: int = DEFAULT_CHUNK_ELEMENTS, sinkhorn_backend: str = "auto") -> CCFTResult:
    """CCFT loss of rendered features X (n, C) against style features Y (m, C) (Algorithm 1).

    guide (m, C) is the previous view's ``CCFTResult.guide`` (None: no guidance yet, i.e. G = 0). Y is treated as a
    constant. The Sinkhorn runs in float64 whatever X's dtype; the loss has X's dtype. sinkhorn_backend: see
    ``semi_balanced_sinkhorn``. A direct caller's parameters are checked here, where they enter."""
    if not (epsilon > 0 and tau > 0 and k >= 1 and iters >= 1 and lambda_guide >= 0):
        raise ValueError(f"need epsilon > 0, tau > 0, k >= 1, iters >= 1, lambda_guide >= 0 "
                         f"(got {epsilon}, {tau}, {k}, {iters}, {lambda_guide})")
    return _ccft(X, Y, guide, k, epsilon, tau, lambda_guide, iters, chunk_elements, sinkhorn_backend)


def _ccft(X, Y, guide, k, epsilon, tau, lambda_guide, iters, chunk_elements, sinkhorn_backend) -> CCFTResult:
    """``ccft_loss`` with parameters already checked (by ``ccft_loss``, or where a stylizer's config entered)."""
    if X.dim() != 2 or Y.dim() != 2 or X.shape[1] != Y.shape[1]:
        raise ValueError(f"expected X (n, C) and Y (m, C) with the same C, got {tuple(X.shape)} and {tuple(Y.shape)}")
    if X.shape[0] == 0 or Y.shape[0] == 0:
        raise ValueError("CCFT needs at least one rendered and one style feature")
    m = Y.shape[0]
    k = min(int(k), m)
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    Xn = l2_normalise(X)
    Yn = l2_normalise(Y.detach())
    if guide is not None and lambda_guide > 0:
        if guide.shape != Y.shape:
            raise ValueError(f"guide map {tuple(guide.shape)} does not match the style features {tuple(Y.shape)}")
        Z = Yn + lambda_guide * guide.detach().to(Yn.dtype)
    else:
        Z = Yn
    indices = topk_support(Xn.detach(), Z, k, chunk_elements)
    timings["similarity_topk"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    cost = torch.clamp(1.0 - gathered_row_dot(Xn, Yn, indices), min=0.0)  # (n, K), grad to X
    reachable = torch.bincount(indices.reshape(-1), minlength=m) > 0
    timings["cost"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    plan = semi_balanced_sinkhorn(cost.detach().to(torch.float64), indices, reachable, tau, epsilon, iters,
                                  sinkhorn_backend)  # (n, K) float64
    loss = (plan.to(cost.dtype) * cost).sum()
    timings["sinkhorn"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    column_mass = torch.zeros(m, dtype=torch.float64, device=X.device).index_add_(0, indices.reshape(-1),
                                                                                   plan.reshape(-1))
    if _numba_rows(Xn):
        from training.stylize.support_cpu import scatter_add

        landed = torch.from_numpy(scatter_add(plan.numpy(), Xn.detach().numpy(), indices.numpy(), m))
    else:
        landed = support_matrix(indices, plan.to(Xn.dtype), m).t() @ Xn.detach()
    guide_next = l2_normalise(landed).detach()  # (m, C): sum_i T_ij x_i, normalised
    timings["guide"] = time.perf_counter() - t0

    util, entropy, entropy_norm = column_statistics(column_mass, reachable)
    return CCFTResult(loss=loss, guide=guide_next, plan=SparsePlan(indices, plan), column_mass=column_mass,
                      cost=cost.detach(), reachable=reachable, utilisation=util, column_entropy=entropy,
                      column_entropy_normalised=entropy_norm, timings=timings)


def flatten_features(feats: torch.Tensor, what: str) -> torch.Tensor:
    """(1, C, h, w) -> (h*w, C)."""
    if feats.dim() != 4 or feats.shape[0] != 1:
        raise ValueError(f"{what} features must be (1, C, h, w), got {tuple(feats.shape)}")
    return feats[0].flatten(1).t()


class CCFTStyleLoss:
    """Capacity-controlled feature transport with cross-view guidance, as a style loss (training/stylize/
    style_losses.py's interface). Its parameters are read at each call from ``settings`` (anything with ``k``,
    ``epsilon``, ``tau``, ``lambda_guide`` and ``sinkhorn_iters``: the stylizer passes its live ``StylizeConfig``,
    validated where it entered), or from the loss's own attributes when none is given; the formula reads them
    unchecked.

    stats: loss, utilisation, column_entropy, column_entropy_normalised, reachable_fraction, and the timings
    (seconds) similarity_topk_s, cost_s, sinkhorn_s, guide_s."""

    name = "ccft"

    def __init__(self, k: int = defaults.K, epsilon: float = defaults.EPSILON, tau: float = defaults.TAU,
                 lambda_guide: float = defaults.LAMBDA_GUIDE, sinkhorn_iters: int = defaults.SINKHORN_ITERS,
                 chunk_elements: int = DEFAULT_CHUNK_ELEMENTS):
        self.k = k
        self.epsilon = epsilon
        self.tau = tau
        self.lambda_guide = lambda_guide
        self.sinkhorn_iters = sinkhorn_iters
        self.chunk_elements = chunk_elements
        self.guide: torch.Tensor | None = None  # (m, C) from the previous call
        self.guide_source = None  # the ``source`` of the call that built ``guide``
        self.used_guide_source = None  # the source of the guide the last call used (None: unguided)
        self.last_result = None  # the last CCFTResult (plan, column mass) for reports

    def reset_guide(self) -> None:
        self.guide = self.guide_source = None

    def __call__(self, render_feats: torch.Tensor, style_feats: torch.Tensor, source=None,
                 settings=None) -> tuple[torch.Tensor, dict]:
        """``source``: the view the render came from; the guide map this call builds is recorded as its.
        ``settings``: where this call's parameters are read (default: this loss's attributes)."""
        p = self if settings is None else settings
        X = flatten_features(render_feats, "render")
        Y = flatten_features(style_feats, "style").detach()
        guide = self.guide
        if guide is not None and (guide.shape != Y.shape or guide.device != Y.device):
            guide = None  # the style features changed size (another resolution): the old guide does not apply
        result = _ccft(X, Y, guide, p.k, p.epsilon, p.tau, p.lambda_guide, p.sinkhorn_iters, self.chunk_elements,
                       "auto")
        self.used_guide_source = self.guide_source if guide is not None and p.lambda_guide > 0 else None
        self.guide, self.guide_source = result.guide, source
        self.last_result = result
        stats = {
            "loss": float(result.loss.detach()),
            "utilisation": result.utilisation,
            "column_entropy": result.column_entropy,
            "column_entropy_normalised": result.column_entropy_normalised,
            "reachable_fraction": float(result.reachable.to(torch.float64).mean()),
        }
        stats.update({f"{k}_s": v for k, v in result.timings.items()})
        return result.loss, stats


def transport_cost(X: torch.Tensor, Y: torch.Tensor, plan: SparsePlan) -> torch.Tensor:
    """<T, C> for a fixed sparse plan: sum_ik T_ik max(1 - <x_i/|x_i|, y_j/|y_j|>, 0), j = plan.indices[i, k].

    The loss of ``ccft_loss`` as a function of X with the plan held fixed (for checking its gradient)."""
    cost = torch.clamp(1.0 - gathered_row_dot(l2_normalise(X), l2_normalise(Y), plan.indices), min=0.0)
    return (plan.values.to(cost.dtype) * cost).sum()
