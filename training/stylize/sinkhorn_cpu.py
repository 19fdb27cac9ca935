"""The CCFT Sinkhorn loop on the CPU as one compiled kernel (numba): float64 scalings on a row-stabilised kernel.

Torch runs the loop as a dozen small tensor operations per iteration; on a CPU each pays a parallel region's start-up
and barrier, which dominates at these sizes and becomes dreadful when other processes share the cores. Here one
sequential pass over the support per half-iteration does it, without exp or log in the inner loops.

Numerics: each row of the Gibbs kernel is divided by its largest entry, K'_ik = exp(-(C_ik - min_k C_ik) / eps).
That factor is absorbed exactly by u (u' = u / c_i), so the iterates v and the plan u K v are Algorithm 1's, and
each row keeps an entry of 1, so K v never vanishes. Costs lie in [0, 2], so the other entries are at least
exp(-2 / eps) (1e-87 at eps = 0.01) and the scalings stay far inside float64's range. Should anything still
overflow or vanish (much smaller epsilon), the caller falls back to the log-domain loop.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")  # x / 0 gives inf (caught below), not an exception
def _sinkhorn_kernel(K, indices, b, reachable, alpha, a, iters, u, v, colsum):
    n, k = K.shape
    m = v.shape[0]
    for j in range(m):
        v[j] = 1.0
    for _ in range(iters):
        for i in range(n):  # u = a / (K v)
            s = 0.0
            for kk in range(k):
                s += K[i, kk] * v[indices[i, kk]]
            u[i] = a / s
        for j in range(m):
            colsum[j] = 0.0
        for i in range(n):  # K^T u, row-major scatter (sequential: no atomics)
            ui = u[i]
            for kk in range(k):
                colsum[indices[i, kk]] += K[i, kk] * ui
        for j in range(m):  # v = (b / K^T u)^alpha; unreachable columns carry no edge
            if reachable[j]:
                v[j] = (b[j] / colsum[j]) ** alpha


@njit(cache=True, nogil=True, error_model="numpy")  # x / 0 gives inf (caught below), not an exception
def _plan(K, indices, u, v, out):
    n, k = K.shape
    for i in range(n):
        for kk in range(k):
            out[i, kk] = u[i] * K[i, kk] * v[indices[i, kk]]


def sinkhorn_plan_cpu(cost: np.ndarray, indices: np.ndarray, b: np.ndarray, reachable: np.ndarray,
                      alpha: float, epsilon: float, iters: int) -> np.ndarray | None:
    """Plan (n, K) float64 of Algorithm 1's Sinkhorn (u = v = 1, then u, v updates ``iters`` times).

    cost (n, K) >= 0, indices (n, K) int64, b (m,), reachable (m,) bool. None if float64 could not carry it."""
    cost = np.ascontiguousarray(cost, dtype=np.float64)
    K = np.exp(-(cost - cost.min(axis=1, keepdims=True)) / epsilon)
    n = cost.shape[0]
    m = b.shape[0]
    u = np.empty(n, dtype=np.float64)
    v = np.empty(m, dtype=np.float64)
    colsum = np.empty(m, dtype=np.float64)
    idx = np.ascontiguousarray(indices, dtype=np.int64)
    _sinkhorn_kernel(K, idx, np.ascontiguousarray(b, dtype=np.float64), np.ascontiguousarray(reachable),
                     float(alpha), 1.0 / n, int(iters), u, v, colsum)
    if not (np.isfinite(u).all() and np.isfinite(v).all() and (v[reachable] > 0).all()):
        return None
    plan = np.empty_like(K)
    _plan(K, idx, u, v, plan)
    if not np.isfinite(plan).all():
        return None
    return plan
