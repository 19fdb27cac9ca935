"""Row products on CCFT's top-K support on the CPU (numba): what torch's sparse CSR products did, at a fraction of
their time at the paper's sizes (n x K = 65k edges of 768 channels: 23 -> 4 ms for the costs, 82 -> 9 ms for the
guide map, docs/performance.md).

- ``gather_dot``: out[i, k] = <X[i], Y[idx[i, k]]> (the costs, and the float32 scores of the bfloat16 search's
  candidates);
- ``gather_add``: out[i] = sum_k G[i, k] Y[idx[i, k]] (the costs' gradient with respect to X);
- ``scatter_add``: out[j] = sum over the edges (i, k) with idx[i, k] = j of W[i, k] X[i] (the guide map), through
  the edges grouped by column, so that each thread owns the rows it writes.

Each dot product is a float32 sum the compiler may reassociate into vector lanes (fixed at compile time, so the
results are deterministic), within float32 rounding of the sparse products'.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

_JIT = dict(cache=True, nogil=True)


@njit(inline="always", fastmath={"reassoc"}, **_JIT)
def _dot(x, y):
    total = np.float32(0.0)
    for ch in range(x.shape[0]):  # reassociated into vector lanes (the one liberty taken)
        total += x[ch] * y[ch]
    return total


@njit(parallel=True, fastmath={"reassoc"}, **_JIT)
def gather_dot(X, Y, idx, out):
    """out (n, K) float32 = <X[i], Y[idx[i, k]]>; X (n, C), Y (m, C) float32."""
    n, k = idx.shape
    for i in prange(n):
        x = X[i]
        for kk in range(k):
            out[i, kk] = _dot(x, Y[idx[i, kk]])


@njit(parallel=True, **_JIT)
def gather_add(G, Y, idx, out):
    """out (n, C) float32 = sum_k G[i, k] Y[idx[i, k]]."""
    n, k = idx.shape
    c = Y.shape[1]
    for i in prange(n):
        row = out[i]
        for ch in range(c):
            row[ch] = 0.0
        for kk in range(k):
            g = G[i, kk]
            y = Y[idx[i, kk]]
            for ch in range(c):
                row[ch] += g * y[ch]


@njit(parallel=True, **_JIT)
def _scatter_by_column(col_start, edge_row, edge_w, X, out):
    m = col_start.shape[0] - 1
    c = X.shape[1]
    for j in prange(m):
        row = out[j]
        for ch in range(c):
            row[ch] = 0.0
        for e in range(col_start[j], col_start[j + 1]):
            w = edge_w[e]
            x = X[edge_row[e]]
            for ch in range(c):
                row[ch] += w * x[ch]


def scatter_add(W: np.ndarray, X: np.ndarray, idx: np.ndarray, m: int) -> np.ndarray:
    """(m, C) float32: out[j] = sum over the edges (i, k) with idx[i, k] = j of W[i, k] X[i], in increasing i."""
    n, k = idx.shape
    flat = idx.reshape(-1)
    order = np.argsort(flat, kind="stable")
    col_start = np.zeros(m + 1, np.int64)
    np.cumsum(np.bincount(flat, minlength=m), out=col_start[1:])
    out = np.empty((m, X.shape[1]), np.float32)
    _scatter_by_column(col_start, (order // k).astype(np.int64), np.ascontiguousarray(W.reshape(-1)[order],
                                                                                        dtype=np.float32),
                       np.ascontiguousarray(X, dtype=np.float32), out)
    return out
