"""Tile compositing for the cpu rasterizer (numba): forward, full backward and colour-only backward.

- ``_composite_fwd`` (parallel over tiles): Gaussian-outer, pixel-inner over the exact span of the Gaussian's
  ellipse in each row of the tile, per-pixel transmittance/accumulators in tile-local arrays; stores each pixel's
  final T and the count of list entries it consumed ("last").
- ``_composite_bwd`` (parallel over tiles): walks each tile's list back to front, recovering T before each
  Gaussian as T_after / (1 - alpha) like the CUDA kernels, with per-pixel state in float64. Per-Gaussian gradients
  are summed per tile in float64 and written to that tile-Gaussian pair's own row, summed per Gaussian afterwards
  (``_reduce_pairs``): no two threads ever write the same memory, whatever the thread count, and memory grows with
  the pairs rather than threads x Gaussians.
- ``_composite_bwd_rgb``: the same walk when only the colours need gradients (stylization): the colour gradient
  of a pair is its weight a T times the pixel's incoming gradient, so the suffix colours, dL/dalpha and the
  geometric terms are not computed at all. Its T recovery and weights are the same float operations as
  ``_composite_bwd``'s, so the colour gradients are bit-identical to the full backward's.

The helpers (``_rows``, ``_row_span``, ``_row_terms``, ``_power``) are shared by all three kernels so they decide
identically which pixels a Gaussian reaches.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from training.raster.constants import ALPHA_MAX, ALPHA_MIN, T_MIN
from training.raster.cpu_jit import JIT

TILE_CHUNK = 4  # tiles per work item in the compositing kernels (dynamic scheduling)


@njit(inline="always", **JIT)
def _rows(my, ry, y0, y1):
    """Pixel rows of a Gaussian's screen box inside a tile (a superset of where alpha >= 1/255)."""
    by0 = max(y0, int(math.floor(my - ry)) - 1)
    by1 = min(y1, int(math.ceil(my + ry)) + 1)
    return by0, by1


@njit(inline="always", **JIT)
def _row_span(mx, my, ca, cb, cc, log_thr, py, x0, x1):
    """Pixel columns [lo, hi) of row py where the exponent can reach log_thr, widened by a pixel each side.

    Solves A dx^2 + 2 B dy dx + C dy^2 + 2 L <= 0 (power >= L) for dx in float64; pixels outside the span have
    power below log_thr (which already carries cpu_sort.SKIP_MARGIN), so the per-pixel test would skip them anyway.
    """
    a = np.float64(ca)
    b = np.float64(cb)
    dy = np.float64(my) - (py + 0.5)
    bd = b * dy
    disc = bd * bd - a * (np.float64(cc) * dy * dy + 2.0 * log_thr)
    if disc < 0.0 or a <= 0.0:
        return 0, 0
    r = math.sqrt(disc)
    # dx = mx - (px + 0.5) in [(-bd - r)/a, (-bd + r)/a]
    lo = np.float64(mx) - 0.5 - (-bd + r) / a
    hi = np.float64(mx) - 0.5 - (-bd - r) / a
    if not (hi >= x0 - 2 and lo <= x1 + 2):
        return 0, 0
    return max(x0, int(math.floor(lo)) - 1), min(x1, int(math.ceil(hi)) + 2)


@njit(inline="always", **JIT)
def _row_terms(my, cb, cc, py):
    """Per-row constants of the exponent: dy, B dy and -C dy^2 / 2 (float32, shared by forward and backward)."""
    dy = my - (np.float32(py) + np.float32(0.5))
    return dy, cb * dy, np.float32(-0.5) * cc * dy * dy


@njit(inline="always", **JIT)
def _power(mx, ca, bdy, cdy, px):
    """Exponent -0.5 d^T Q d at pixel px of a row, and dx."""
    dx = mx - (np.float32(px) + np.float32(0.5))
    return np.float32(-0.5) * ca * dx * dx - bdy * dx + cdy, dx


@njit(parallel=True, **JIT)
def _composite_fwd(offsets, ids, rec, feats, width, height, tile_size, tiles_x, out_feat, out_t, out_last,
                   tile_pairs, record, rec_off, rec_p, rec_g, rec_w):
    """ids: depth ranks; rec (V, 8) and feats (V, C) are packed in depth order (see _pack). tile_pairs[t]: how
    many (pixel, Gaussian) pairs tile t composited.

    With ``record``, also writes every composited pair, in compositing order, as (tile-local pixel, depth rank,
    weight a T) from rec_off[t] on (cpu_replay replays them); otherwise those arrays are not touched (may be
    empty)."""
    n_tiles = offsets.shape[0] - 1
    n_ch = feats.shape[1]
    for t in prange(n_tiles):
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * tile_size, ty * tile_size
        x1, y1 = min(x0 + tile_size, width), min(y0 + tile_size, height)
        tw = x1 - x0
        n_pix = tw * (y1 - y0)
        T = np.ones(n_pix, np.float32)
        acc = np.zeros((n_pix, n_ch), np.float32)
        last = np.zeros(n_pix, np.int32)
        done = np.zeros(n_pix, np.bool_)
        remaining = n_pix
        k = rec_off[t] if record else 0
        composited = 0
        s = offsets[t]
        for j in range(s, offsets[t + 1]):
            g = ids[j]
            mx, my, ca, cb, cc, o, log_thr = rec[g, 0], rec[g, 1], rec[g, 2], rec[g, 3], rec[g, 4], rec[g, 5], \
                rec[g, 6]
            by0, by1 = _rows(my, rec[g, 7], y0, y1)
            for py in range(by0, by1):
                bx0, bx1 = _row_span(mx, my, ca, cb, cc, log_thr, py, x0, x1)
                dy, bdy, cdy = _row_terms(my, cb, cc, py)
                row = (py - y0) * tw - x0
                for px in range(bx0, bx1):
                    p = row + px
                    if done[p]:
                        continue
                    power, dx = _power(mx, ca, bdy, cdy, px)
                    if power > 0 or power < log_thr:
                        continue
                    alpha = min(np.float32(ALPHA_MAX), o * np.exp(power))
                    if alpha < np.float32(ALPHA_MIN):
                        continue
                    tp = T[p]
                    next_t = tp * (np.float32(1.0) - alpha)
                    if next_t <= np.float32(T_MIN):
                        done[p] = True
                        remaining -= 1
                        continue
                    w = alpha * tp
                    for c in range(n_ch):
                        acc[p, c] += feats[g, c] * w
                    T[p] = next_t
                    last[p] = j - s + 1
                    composited += 1
                    if record:
                        rec_p[k] = p
                        rec_g[k] = g
                        rec_w[k] = w
                        k += 1
            if remaining == 0:
                break
        tile_pairs[t] = composited
        for py in range(y0, y1):
            for px in range(x0, x1):
                p = (py - y0) * tw + (px - x0)
                for c in range(n_ch):
                    out_feat[py, px, c] = acc[p, c]
                out_t[py, px] = T[p]
                out_last[py, px] = last[p]


@njit(parallel=True, **JIT)
def _composite_bwd(offsets, ids, rec, feats, width, height, tile_size, tiles_x, out_t, out_last, g_feat, g_t,
                   pair_grad):
    """pair_grad: (P, 6 + C) float32, zeroed, one row per list entry j (a tile-Gaussian pair), receiving that
    pair's gradient [mx, my, conic a, b, c, opacity, feats...]. Each row belongs to one tile, so no two threads
    write the same memory; ``_reduce_pairs`` sums the rows per Gaussian afterwards."""
    n_tiles = offsets.shape[0] - 1
    n_ch = feats.shape[1]
    for t in prange(n_tiles):
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * tile_size, ty * tile_size
        x1, y1 = min(x0 + tile_size, width), min(y0 + tile_size, height)
        tw = x1 - x0
        n_pix = tw * (y1 - y0)
        T = np.empty(n_pix)
        gT = np.empty(n_pix)  # dL/dT_final * T_final
        gf = np.empty((n_pix, n_ch))
        buf = np.zeros((n_pix, n_ch))
        last = np.empty(n_pix, np.int32)
        max_last = 0
        for py in range(y0, y1):
            for px in range(x0, x1):
                p = (py - y0) * tw + (px - x0)
                T[p] = out_t[py, px]
                gT[p] = np.float64(g_t[py, px]) * np.float64(out_t[py, px])
                for c in range(n_ch):
                    gf[p, c] = g_feat[py, px, c]
                last[p] = out_last[py, px]
                max_last = max(max_last, last[p])
        s = offsets[t]
        vf = np.empty(n_ch)
        for j in range(s + max_last - 1, s - 1, -1):
            g = ids[j]
            mx, my, ca, cb, cc, o, log_thr = rec[g, 0], rec[g, 1], rec[g, 2], rec[g, 3], rec[g, 4], rec[g, 5], \
                rec[g, 6]
            by0, by1 = _rows(my, rec[g, 7], y0, y1)
            vmx = 0.0
            vmy = 0.0
            va = 0.0
            vb = 0.0
            vc = 0.0
            vo = 0.0
            for c in range(n_ch):
                vf[c] = 0.0
            touched = False
            jl = j - s
            for py in range(by0, by1):
                bx0, bx1 = _row_span(mx, my, ca, cb, cc, log_thr, py, x0, x1)
                dy, bdy, cdy = _row_terms(my, cb, cc, py)
                dy64 = np.float64(dy)
                row = (py - y0) * tw - x0
                for px in range(bx0, bx1):
                    p = row + px
                    if jl >= last[p]:
                        continue
                    power, dx = _power(mx, ca, bdy, cdy, px)
                    if power > 0 or power < log_thr:
                        continue
                    gauss = np.exp(power)
                    alpha = min(np.float32(ALPHA_MAX), o * gauss)
                    if alpha < np.float32(ALPHA_MIN):
                        continue
                    touched = True
                    a64 = np.float64(alpha)
                    one_minus = 1.0 - a64
                    inv = 1.0 / one_minus
                    t_before = T[p] * inv
                    T[p] = t_before
                    w = a64 * t_before
                    v_alpha = -gT[p] * inv
                    for c in range(n_ch):
                        f = np.float64(feats[g, c])
                        vf[c] += w * gf[p, c]
                        v_alpha += (f - buf[p, c]) * t_before * gf[p, c]
                        buf[p, c] = a64 * f + one_minus * buf[p, c]
                    if o * gauss <= np.float32(ALPHA_MAX):
                        vo += v_alpha * gauss
                        vpow = v_alpha * a64
                        dx64 = np.float64(dx)
                        vmx -= vpow * (ca * dx64 + cb * dy64)
                        vmy -= vpow * (cc * dy64 + cb * dx64)
                        va -= 0.5 * vpow * dx64 * dx64
                        vb -= vpow * dx64 * dy64
                        vc -= 0.5 * vpow * dy64 * dy64
            if touched:
                pair_grad[j, 0] = vmx
                pair_grad[j, 1] = vmy
                pair_grad[j, 2] = va
                pair_grad[j, 3] = vb
                pair_grad[j, 4] = vc
                pair_grad[j, 5] = vo
                for c in range(n_ch):
                    pair_grad[j, 6 + c] = vf[c]


@njit(parallel=True, **JIT)
def _composite_bwd_rgb(offsets, ids, rec, width, height, tile_size, tiles_x, out_t, out_last, g_feat, pair_rgb,
                       record, rec_off, j_start, j_count, rec_pix, rec_w):
    """The colour part of ``_composite_bwd`` alone. g_feat (H, W, C >= 3): its first three channels are the RGB
    gradients; pair_rgb: (P, 3) float32, zeroed, one row per list entry, receiving that pair's RGB gradient.

    With ``record``, also writes each list entry j's pixel weights, in this walk's order, as (pixel y * W + x,
    float64 weight) at j_start[j] .. + j_count[j], tile t's from rec_off[t] on (cpu_replay replays them)."""
    n_tiles = offsets.shape[0] - 1
    for t in prange(n_tiles):
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * tile_size, ty * tile_size
        x1, y1 = min(x0 + tile_size, width), min(y0 + tile_size, height)
        tw = x1 - x0
        n_pix = tw * (y1 - y0)
        T = np.empty(n_pix)
        gf = np.empty((n_pix, 3))
        last = np.empty(n_pix, np.int32)
        max_last = 0
        for py in range(y0, y1):
            for px in range(x0, x1):
                p = (py - y0) * tw + (px - x0)
                T[p] = out_t[py, px]
                for c in range(3):
                    gf[p, c] = g_feat[py, px, c]
                last[p] = out_last[py, px]
                max_last = max(max_last, last[p])
        s = offsets[t]
        k = rec_off[t] if record else 0
        for j in range(s + max_last - 1, s - 1, -1):
            g = ids[j]
            mx, my, ca, cb, cc, o, log_thr = rec[g, 0], rec[g, 1], rec[g, 2], rec[g, 3], rec[g, 4], rec[g, 5], \
                rec[g, 6]
            by0, by1 = _rows(my, rec[g, 7], y0, y1)
            if record:
                j_start[j] = k
            vr = 0.0
            vg = 0.0
            vb = 0.0
            touched = False
            jl = j - s
            for py in range(by0, by1):
                bx0, bx1 = _row_span(mx, my, ca, cb, cc, log_thr, py, x0, x1)
                dy, bdy, cdy = _row_terms(my, cb, cc, py)
                row = (py - y0) * tw - x0
                for px in range(bx0, bx1):
                    p = row + px
                    if jl >= last[p]:
                        continue
                    power, dx = _power(mx, ca, bdy, cdy, px)
                    if power > 0 or power < log_thr:
                        continue
                    gauss = np.exp(power)
                    alpha = min(np.float32(ALPHA_MAX), o * gauss)
                    if alpha < np.float32(ALPHA_MIN):
                        continue
                    touched = True
                    a64 = np.float64(alpha)
                    inv = 1.0 / (1.0 - a64)
                    t_before = T[p] * inv
                    T[p] = t_before
                    w = a64 * t_before
                    vr += w * gf[p, 0]
                    vg += w * gf[p, 1]
                    vb += w * gf[p, 2]
                    if record:
                        rec_pix[k] = py * width + px
                        rec_w[k] = w
                        k += 1
            if record:
                j_count[j] = k - j_start[j]
            if touched:
                pair_rgb[j, 0] = vr
                pair_rgb[j, 1] = vg
                pair_rgb[j, 2] = vb


@njit(**JIT)
def _reduce_pairs(ids, pair_grad, n_ranks):
    """(V, 6 + C) float64 per-depth-rank sums of the per-pair gradients."""
    out = np.zeros((n_ranks, pair_grad.shape[1]))
    for j in range(ids.shape[0]):
        k = ids[j]
        for c in range(pair_grad.shape[1]):
            out[k, c] += pair_grad[j, c]
    return out
