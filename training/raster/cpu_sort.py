"""Depth order and tile binning for the cpu rasterizer (numba).

The visible Gaussians are put in global depth order by a stable LSD radix sort on the float bits (ties keep their
index order, as the reference's stable sort), then counted and scattered into per-tile lists of depth ranks, so
every tile's list comes out sorted front to back without a per-pair sort. ``_pack`` lays the Gaussians'
screen-space records out in that order for the compositing kernels.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from training.raster.constants import ALPHA_MIN
from training.raster.cpu_jit import JIT

# The exp() is skipped when the exponent is this far below log(1/(255 o)): alpha is then certainly under
# 1/255 whatever the rounding of exp, so skipping cannot change which Gaussians composite.
SKIP_MARGIN = 1e-3


@njit(**JIT)
def _radix_argsort(keys, values):
    """values reordered by increasing uint32 keys, stable (ties keep their order): two 16-bit LSD passes."""
    n = keys.shape[0]
    k_a, v_a = keys.copy(), values.copy()
    k_b = np.empty_like(keys)
    v_b = np.empty_like(values)
    for shift in (0, 16):
        counts = np.zeros(65537, np.int64)
        for i in range(n):
            counts[((k_a[i] >> shift) & 0xFFFF) + 1] += 1
        for d in range(65536):
            counts[d + 1] += counts[d]
        for i in range(n):
            d = (k_a[i] >> shift) & 0xFFFF
            pos = counts[d]
            counts[d] = pos + 1
            k_b[pos] = k_a[i]
            v_b[pos] = v_a[i]
        k_a, k_b = k_b, k_a
        v_a, v_b = v_b, v_a
    return v_a


def depth_order(depths: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Indices ``visible`` sorted by float32 depth, stable: the same order as a stable argsort."""
    bits = (depths[visible] + np.float32(0.0)).view(np.uint32)  # + 0 turns -0.0 into 0.0, which sort as equal
    # IEEE floats order like integers once negatives have all bits flipped and positives their sign bit set.
    keys = np.where(bits >> 31, ~bits, bits | np.uint32(0x80000000)).astype(np.uint32)
    return _radix_argsort(keys, visible.astype(np.int64))


@njit(**JIT)
def _bin(order, means2d, radii, tile_size, tiles_x, tiles_y):
    """Per-tile lists of depth ranks k (Gaussian order[k]), front to back. Returns (offsets, ranks)."""
    n_tiles = tiles_x * tiles_y
    counts = np.zeros(n_tiles + 1, np.int64)
    n = order.shape[0]
    rect = np.empty((n, 4), np.int64)
    for k in range(n):
        g = order[k]
        mx, my = np.float64(means2d[g, 0]), np.float64(means2d[g, 1])
        rx, ry = np.float64(radii[g, 0]), np.float64(radii[g, 1])
        x0 = min(max(int(math.floor((mx - rx) / tile_size)), 0), tiles_x)
        x1 = min(max(int(math.ceil((mx + rx) / tile_size)), 0), tiles_x)
        y0 = min(max(int(math.floor((my - ry) / tile_size)), 0), tiles_y)
        y1 = min(max(int(math.ceil((my + ry) / tile_size)), 0), tiles_y)
        rect[k, 0], rect[k, 1], rect[k, 2], rect[k, 3] = x0, x1, y0, y1
        for ty in range(y0, y1):
            for tx in range(x0, x1):
                counts[ty * tiles_x + tx + 1] += 1
    offsets = np.cumsum(counts)
    cursor = offsets[:-1].copy()
    ids = np.empty(offsets[-1], np.int32)
    for k in range(n):
        for ty in range(rect[k, 2], rect[k, 3]):
            for tx in range(rect[k, 0], rect[k, 1]):
                t = ty * tiles_x + tx
                ids[cursor[t]] = k
                cursor[t] += 1
    return offsets, ids


def _pack(order, means2d, conics, opac, radii):
    """(V, 8) float32 records in depth order: mx, my, conic a, b, c, opacity, log(1/(255 o)) - margin, radius y.

    The kernels read Gaussians through their depth rank, so a tile's list walks this array forwards instead of
    gathering from five arrays at random (which cost a cache miss each at 200k Gaussians)."""
    rec = np.empty((order.shape[0], 8), np.float32)
    rec[:, 0:2] = means2d[order]
    rec[:, 2:5] = conics[order]
    o = opac[order]
    rec[:, 5] = o
    rec[:, 6] = np.log(ALPHA_MIN / o.astype(np.float64)) - SKIP_MARGIN
    rec[:, 7] = radii[order, 1]
    return rec
