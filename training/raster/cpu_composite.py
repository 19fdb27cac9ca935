"""Tile compositing for the cpu rasterizer (numba): forward, full backward and colour-only backward.

- ``_composite_fwd`` (parallel over tiles): Gaussian-outer, pixel-inner, per-pixel transmittance/accumulators in
  tile-local arrays. For each row of a Gaussian's box inside the tile, the exponent and alpha of the whole tile row
  are computed in a branch-free loop that LLVM vectorises (the exponential is ``_exp_neg``: exp's own polynomial,
  because a call to libm's expf cannot be vectorised), for all the Gaussian's rows first, then the pixels of each
  row's span (``_row_span``: where the exponent can reach the 1/255 cut) are composited in order. Optionally it *records* every composited
  pair: the pixel (its row and column inside the tile, ``(row << 8) | column``) and its alpha (negated where alpha
  was clamped at ALPHA_MAX), in compositing order, with the count per tile-list entry (``pair_n``).
- ``_composite_bwd`` (parallel over tiles): walks each tile's *records* back to front, recovering T before each
  Gaussian as T_after / (1 - alpha) like the CUDA kernels, with per-pixel state in float64. It evaluates no
  exponential and visits no pixel that did not composite: the records say which pixels, and with what alpha.
  Per-Gaussian gradients are summed per tile in float64 and written to that tile-Gaussian pair's own row, summed per
  Gaussian afterwards (``_reduce_pairs``): no two threads ever write the same memory, whatever the thread count.
- ``_composite_bwd_rgb``: the same walk when only the colours need gradients (stylization): the colour gradient
  of a pair is its weight a T times the pixel's incoming gradient, so the suffix colours, dL/dalpha and the
  geometric terms are not computed at all. Its T recovery and weights are the same float operations as
  ``_composite_bwd``'s, so the colour gradients are bit-identical to the full backward's.

The records hold at most ``_record_capacity``'s bound per tile: each list entry's rows in the tile times the widest
span a row of its ellipse can have. The helpers (``_rows``, ``_row_span``, ``_row_terms``) are shared by the
kernels so they decide identically which pixels a Gaussian reaches; cpu_replay replays the records.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from training.raster.constants import ALPHA_MAX, ALPHA_MIN, T_MIN
from training.raster.cpu_jit import JIT

TILE_CHUNK = 4  # tiles per work item in the compositing kernels (dynamic scheduling)
# A recorded pixel is (row << 8) | column inside its tile, in a uint16: tiles up to 256 pixels a side.
MAX_TILE_SIZE = 256


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
def _exp_neg(x):
    """exp(x) in float32 for the compositing exponents (x <= 0; clamped to [-20, 0]), within 2 ulp of the true value
    (libm's expf: 1 ulp): x = -m ln2 + r with |r| <= ln2 / 2, a degree-7 Taylor polynomial for exp(r), and the
    exact division by 2^m. Branch-free, so the loop that calls it vectorises."""
    x = min(max(x, np.float32(-20.0)), np.float32(0.0))
    m = np.int32(x * np.float32(-1.4426950408889634) + np.float32(0.5))
    mf = np.float32(m)
    r = x + mf * np.float32(0.693145751953125) + mf * np.float32(1.428606765330187e-06)  # ln2 in two parts
    p = np.float32(1.0 / 5040.0)
    p = p * r + np.float32(1.0 / 720.0)
    p = p * r + np.float32(1.0 / 120.0)
    p = p * r + np.float32(1.0 / 24.0)
    p = p * r + np.float32(1.0 / 6.0)
    p = p * r + np.float32(0.5)
    p = p * r + np.float32(1.0)
    p = p * r + np.float32(1.0)
    return p / np.float32(np.int32(1) << m)


@njit(parallel=True, **JIT)
def _record_capacity(offsets, ids, rec, width, height, tile_size, tiles_x, caps):
    """caps[t]: at most how many pairs tile t can composite: per list entry, its rows inside the tile times the
    widest span ``_row_span`` can give one of its rows (its discriminant is largest at the ellipse's centre row,
    where the span is 2 sqrt(-2 L / A) wide, widened by at most 5 pixels; plus a margin), capped at the tile's
    width."""
    n_tiles = offsets.shape[0] - 1
    for t in prange(n_tiles):
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * tile_size, ty * tile_size
        x1, y1 = min(x0 + tile_size, width), min(y0 + tile_size, height)
        tw = x1 - x0
        total = 0
        for j in range(offsets[t], offsets[t + 1]):
            g = ids[j]
            by0, by1 = _rows(rec[g, 1], rec[g, 7], y0, y1)
            if by1 <= by0:
                continue
            a, b, c = np.float64(rec[g, 2]), np.float64(rec[g, 3]), np.float64(rec[g, 4])
            cols = tw
            if a > 0.0 and a * c - b * b > 0.0:  # else (rounding made it no ellipse) the whole tile row
                half = math.sqrt(-2.0 * np.float64(rec[g, 6]) / a)
                if 2.0 * half + 8.0 < tw:  # false for NaN too
                    cols = int(math.ceil(2.0 * half)) + 8
            total += (by1 - by0) * cols
        caps[t] = total


@njit(parallel=True, **JIT)
def _composite_fwd(offsets, ids, rec, feats, width, height, tile_size, tiles_x, out_feat, out_t,
                   record, rec_off, tile_n, pair_n, rec_pix, rec_a):
    """ids: depth ranks; rec (V, 8) and feats (V, C <= 4) are packed in depth order (see cpu_sort._pack).

    With ``record``: tile t's composited pairs go to rec_pix / rec_a from rec_off[t] on (at most up to
    rec_off[t + 1]), their number to tile_n[t] (-1 if the capacity was too small, which _record_capacity rules
    out), and pair_n[j] (zeroed by the caller) counts list entry j's; otherwise those arrays are not touched."""
    n_tiles = offsets.shape[0] - 1
    n_ch = feats.shape[1]
    for t in prange(n_tiles):
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * tile_size, ty * tile_size
        x1, y1 = min(x0 + tile_size, width), min(y0 + tile_size, height)
        tw = x1 - x0
        n_pix = tw * (y1 - y0)
        T = np.ones(n_pix, np.float32)
        acc = np.zeros((n_pix, 4), np.float32)
        done = np.zeros(n_pix, np.bool_)
        # per row of the current Gaussian inside the tile: its span, and its alphas (negated where clamped, 0 where
        # none composites)
        spans = np.empty((y1 - y0, 2), np.int64)
        lanes = np.empty((y1 - y0, tw), np.float32)
        remaining = n_pix
        k = rec_off[t] if record else 0
        k_cap = rec_off[t + 1] if record else 0
        overflow = False
        fx0 = np.float32(x0) + np.float32(0.5)
        for j in range(offsets[t], offsets[t + 1]):
            g = ids[j]
            k_pair = k
            mx, my, ca, cb, cc, o, log_thr = rec[g, 0], rec[g, 1], rec[g, 2], rec[g, 3], rec[g, 4], rec[g, 5], \
                rec[g, 6]
            f0 = feats[g, 0]
            f1 = feats[g, 1] if n_ch > 1 else np.float32(0.0)
            f2 = feats[g, 2] if n_ch > 2 else np.float32(0.0)
            f3 = feats[g, 3] if n_ch > 3 else np.float32(0.0)
            by0, by1 = _rows(my, rec[g, 7], y0, y1)
            # Three passes over the Gaussian's rows, so that neither the spans' float64 solves nor the vectorised
            # alphas wait behind the compositing loop's unpredictable branches (18 % of the forward).
            for r in range(by1 - by0):
                spans[r, 0], spans[r, 1] = _row_span(mx, my, ca, cb, cc, log_thr, by0 + r, x0, x1)
            for r in range(by1 - by0):
                if spans[r, 1] <= spans[r, 0]:
                    continue
                dy, bdy, cdy = _row_terms(my, cb, cc, by0 + r)
                for i in range(tw):  # vectorised: no branch, no store but the lane's
                    dx = mx - (fx0 + np.float32(i))
                    power = np.float32(-0.5) * ca * dx * dx - bdy * dx + cdy
                    ag = o * _exp_neg(power)
                    alpha = min(np.float32(ALPHA_MAX), ag)
                    hit = (power <= np.float32(0.0)) and (power >= log_thr) and (alpha >= np.float32(ALPHA_MIN))
                    lanes[r, i] = (alpha if ag <= np.float32(ALPHA_MAX) else -alpha) if hit else np.float32(0.0)
            for r in range(by1 - by0):
                py = by0 + r
                row = (py - y0) * tw - x0
                code_row = (py - y0) << 8
                for px in range(spans[r, 0], spans[r, 1]):
                    a = lanes[r, px - x0]
                    if a == np.float32(0.0):
                        continue
                    p = row + px
                    if done[p]:
                        continue
                    alpha = abs(a)
                    tp = T[p]
                    next_t = tp * (np.float32(1.0) - alpha)
                    if next_t <= np.float32(T_MIN):
                        done[p] = True
                        remaining -= 1
                        continue
                    w = alpha * tp
                    acc[p, 0] += f0 * w
                    acc[p, 1] += f1 * w
                    acc[p, 2] += f2 * w
                    acc[p, 3] += f3 * w
                    T[p] = next_t
                    if record:
                        if k < k_cap:
                            rec_pix[k] = code_row | (px - x0)
                            rec_a[k] = a
                            k += 1
                        else:
                            overflow = True
            if record:
                pair_n[j] = k - k_pair
            if remaining == 0:
                break
        if record:
            tile_n[t] = -1 if overflow else k - rec_off[t]
        for py in range(y0, y1):
            for px in range(x0, x1):
                p = (py - y0) * tw + (px - x0)
                for c in range(n_ch):
                    out_feat[py, px, c] = acc[p, c]
                out_t[py, px] = T[p]


@njit(parallel=True, **JIT)
def _composite_bwd(offsets, ids, rec, feats, width, height, tile_size, tiles_x, out_t, g_feat, g_t,
                   rec_off, tile_n, pair_n, rec_pix, rec_a, pair_grad):
    """From ``_composite_fwd``'s records. pair_grad: (P, 6 + C) float32, zeroed, one row per list entry j (a
    tile-Gaussian pair), receiving that pair's gradient [mx, my, conic a, b, c, opacity, feats...]. Each row
    belongs to one tile, so no two threads write the same memory; ``_reduce_pairs`` sums the rows per Gaussian."""
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
        for py in range(y0, y1):
            for px in range(x0, x1):
                p = (py - y0) * tw + (px - x0)
                T[p] = out_t[py, px]
                gT[p] = np.float64(g_t[py, px]) * np.float64(out_t[py, px])
                for c in range(n_ch):
                    gf[p, c] = g_feat[py, px, c]
        vf = np.empty(n_ch)
        k_end = rec_off[t] + tile_n[t]
        j = offsets[t + 1] - 1
        while k_end > rec_off[t]:
            n = pair_n[j]
            if n == 0:
                j -= 1
                continue
            k0 = k_end - n
            g = ids[j]
            mx, my, ca, cb, cc, o = rec[g, 0], rec[g, 1], rec[g, 2], rec[g, 3], rec[g, 4], rec[g, 5]
            inv_o = 1.0 / np.float64(o)
            vmx = 0.0
            vmy = 0.0
            va = 0.0
            vb = 0.0
            vc = 0.0
            vo = 0.0
            for c in range(n_ch):
                vf[c] = 0.0
            for k in range(k0, k_end):
                code = np.int64(rec_pix[k])
                ly = code >> 8
                lx = code & 255
                p = ly * tw + lx
                a = rec_a[k]
                a64 = np.float64(abs(a))
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
                if a > np.float32(0.0):  # not clamped: alpha = o exp(power)
                    dx64 = np.float64(mx - (np.float32(x0 + lx) + np.float32(0.5)))
                    dy64 = np.float64(my - (np.float32(y0 + ly) + np.float32(0.5)))
                    vo += v_alpha * a64 * inv_o
                    vpow = v_alpha * a64
                    vmx -= vpow * (ca * dx64 + cb * dy64)
                    vmy -= vpow * (cc * dy64 + cb * dx64)
                    va -= 0.5 * vpow * dx64 * dx64
                    vb -= vpow * dx64 * dy64
                    vc -= 0.5 * vpow * dy64 * dy64
            pair_grad[j, 0] = vmx
            pair_grad[j, 1] = vmy
            pair_grad[j, 2] = va
            pair_grad[j, 3] = vb
            pair_grad[j, 4] = vc
            pair_grad[j, 5] = vo
            for c in range(n_ch):
                pair_grad[j, 6 + c] = vf[c]
            k_end = k0
            j -= 1


@njit(parallel=True, **JIT)
def _composite_bwd_rgb(offsets, ids, width, height, tile_size, tiles_x, out_t, g_feat, rec_off, tile_n, pair_n,
                       rec_pix, rec_a, pair_rgb):
    """The colour part of ``_composite_bwd`` alone, from the same records. g_feat (H, W, C >= 3): its first three
    channels are the RGB gradients; pair_rgb: (P, 3) float32, zeroed, one row per list entry, receiving that pair's
    RGB gradient."""
    n_tiles = offsets.shape[0] - 1
    for t in prange(n_tiles):
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * tile_size, ty * tile_size
        x1, y1 = min(x0 + tile_size, width), min(y0 + tile_size, height)
        tw = x1 - x0
        n_pix = tw * (y1 - y0)
        T = np.empty(n_pix)
        gf = np.empty((n_pix, 3))
        for py in range(y0, y1):
            for px in range(x0, x1):
                p = (py - y0) * tw + (px - x0)
                T[p] = out_t[py, px]
                for c in range(3):
                    gf[p, c] = g_feat[py, px, c]
        k_end = rec_off[t] + tile_n[t]
        j = offsets[t + 1] - 1
        while k_end > rec_off[t]:
            n = pair_n[j]
            if n == 0:
                j -= 1
                continue
            k0 = k_end - n
            vr = 0.0
            vg = 0.0
            vb = 0.0
            for k in range(k0, k_end):
                code = np.int64(rec_pix[k])
                p = (code >> 8) * tw + (code & 255)
                a64 = np.float64(abs(rec_a[k]))
                inv = 1.0 / (1.0 - a64)
                t_before = T[p] * inv
                T[p] = t_before
                w = a64 * t_before
                vr += w * gf[p, 0]
                vg += w * gf[p, 1]
                vb += w * gf[p, 2]
            pair_rgb[j, 0] = vr
            pair_rgb[j, 1] = vg
            pair_rgb[j, 2] = vb
            k_end = k0
            j -= 1


@njit(parallel=True, **JIT)
def _compact_records(rec_off, tile_n, rec_pix, rec_a, new_off, out_pix, out_a):
    """Copy each tile's records to new_off[t] (the prefix sums of tile_n), closing the gaps the capacities left."""
    for t in prange(tile_n.shape[0]):
        s, d = rec_off[t], new_off[t]
        for i in range(tile_n[t]):
            out_pix[d + i] = rec_pix[s + i]
            out_a[d + i] = rec_a[s + i]


@njit(**JIT)
def _reduce_pairs(ids, pair_grad, n_ranks):
    """(V, 6 + C) float64 per-depth-rank sums of the per-pair gradients."""
    out = np.zeros((n_ranks, pair_grad.shape[1]))
    for j in range(ids.shape[0]):
        k = ids[j]
        for c in range(pair_grad.shape[1]):
            out[k, c] += pair_grad[j, c]
    return out
