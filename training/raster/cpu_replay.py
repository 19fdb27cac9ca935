"""Frozen geometry: what the cpu rasterizer can reuse while only the colours change (stylization).

With geometry that needs no gradient, everything but the colours is a function of the geometry and the camera:
projection, depth order, tile lists, each pixel's final transmittance, and every composited pair's weight a T
(forward, float32) and its recovered weight (backward, float64). A stylization step renders the same view
15 to 50 times in a row, so ``FrozenCache`` keeps one entry: the inputs it was computed from (compared bit for bit
on every call, so a changed model or camera is never served stale results), the screen-space state, and, from
the second call on, the composited pairs' weights. Then the forward is a weighted sum of the colours over those
pairs and the colour backward its transpose: the same float operations in the same order as the compositing
kernels, so images and gradients are bit-identical to a render without the cache (tests/test_raster_cpu.py).

The weights cost 12 bytes per composited pair and direction; past ``MAX_PAIRS`` they are not kept.
"""

from __future__ import annotations

import threading

import numpy as np
from numba import njit, prange

from training.raster.cpu_jit import JIT

MAX_PAIRS = 8_000_000  # per direction: at most ~100 MB of forward and ~100 MB of backward weights


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Bit-for-bit equality (NaN equal to itself, -0.0 different from 0.0): the kernels' results can only be
    reused for exactly the inputs they came from."""
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a.view(np.uint8), b.view(np.uint8))


class FrozenEntry:
    """One (geometry, camera): the inputs' copies, the projection and binning, then what later calls record."""

    def __init__(self, key_arrays, params, proj):
        self.key_arrays = [np.array(a, copy=True) for a in key_arrays]
        self.params = params
        self.proj = proj  # (means2d, conics, depths, radii, order, offsets, ids, rec)
        self.out_t = None  # (H, W) float32 final transmittance, after the first forward
        self.out_last = None
        self.tile_pairs = None  # composited pairs per tile, after the first forward
        self.fwd = None  # (rec_off, rec_p, rec_g, rec_w) once recorded
        self.bwd = None  # (j_start, j_count, rec_pix, rec_w) once recorded

    def matches(self, key_arrays, params) -> bool:
        return params == self.params and all(_same(a, b) for a, b in zip(key_arrays, self.key_arrays))

    def record_offsets(self):
        """Where each tile's records start, and their total, or None before the first forward or when the
        records would take too much memory. The backward touches exactly the pairs the forward composited
        (same float operations decide), so both directions need this many."""
        if self.tile_pairs is None:
            return None
        off = np.zeros(self.tile_pairs.size + 1, np.int64)
        np.cumsum(self.tile_pairs, out=off[1:])
        return (off, int(off[-1])) if off[-1] <= MAX_PAIRS else None


class FrozenCache:
    """A single-entry cache, safe to share between threads (an entry's fields are written once, then read)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._entry: FrozenEntry | None = None

    def lookup(self, key_arrays, params) -> FrozenEntry | None:
        with self._lock:
            entry = self._entry
        return entry if entry is not None and entry.matches(key_arrays, params) else None

    def store(self, key_arrays, params, proj) -> FrozenEntry:
        entry = FrozenEntry(key_arrays, params, proj)
        with self._lock:
            self._entry = entry
        return entry

    def clear(self) -> None:
        with self._lock:
            self._entry = None


@njit(parallel=True, **JIT)
def _replay_fwd(rec_off, rec_p, rec_g, rec_w, feats, width, height, tile_size, tiles_x, out_feat):
    """out_feat (H, W, C) = sum over the recorded pairs of feats[rank] * weight, per pixel in compositing order
    (as ``_composite_fwd`` accumulates)."""
    n_ch = feats.shape[1]
    for t in prange(rec_off.shape[0] - 1):
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * tile_size, ty * tile_size
        x1, y1 = min(x0 + tile_size, width), min(y0 + tile_size, height)
        tw = x1 - x0
        acc = np.zeros((tw * (y1 - y0), n_ch), np.float32)
        for k in range(rec_off[t], rec_off[t + 1]):
            p = rec_p[k]
            g = rec_g[k]
            w = rec_w[k]
            for c in range(n_ch):
                acc[p, c] += feats[g, c] * w
        for py in range(y0, y1):
            for px in range(x0, x1):
                p = (py - y0) * tw + (px - x0)
                for c in range(n_ch):
                    out_feat[py, px, c] = acc[p, c]


@njit(parallel=True, **JIT)
def _replay_bwd_rgb(j_start, j_count, rec_pix, rec_w, g_feat, pair_rgb):
    """pair_rgb[j] (zeroed) = sum over entry j's recorded pixels of weight * dL/d(rgb), in the recorded order
    (as ``_composite_bwd_rgb`` accumulates); g_feat (H * W, C >= 3)."""
    for j in prange(j_start.shape[0]):
        n = j_count[j]
        if n == 0:
            continue
        vr = 0.0
        vg = 0.0
        vb = 0.0
        for k in range(j_start[j], j_start[j] + n):
            p = rec_pix[k]
            w = rec_w[k]
            vr += w * np.float64(g_feat[p, 0])
            vg += w * np.float64(g_feat[p, 1])
            vb += w * np.float64(g_feat[p, 2])
        pair_rgb[j, 0] = vr
        pair_rgb[j, 1] = vg
        pair_rgb[j, 2] = vb
