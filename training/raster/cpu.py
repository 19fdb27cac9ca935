"""CPU rasterizer: numba kernels for projection, tile binning, compositing and their hand-written backward.

Same semantics as the reference (training/raster/reference.py). Pipeline, all on float32 arrays shared with torch
without copies (``tensor.numpy()``):

1. ``_project_fwd`` (parallel over Gaussians, float64 inside): EWA covariance + low-pass, conic, pixel mean,
   screen box where alpha can reach 1/255, culling (near/far, opacity, off-screen, degenerate).
2. ``depth_order`` + ``_bin``: the visible Gaussians in global depth order (a stable radix sort on the float
   bits) are counted and then scattered into per-tile lists of depth ranks, so every list comes out sorted front
   to back without a per-pair sort; ``_pack`` lays their screen-space records out in that order.
3. ``_composite_fwd`` (parallel over tiles): Gaussian-outer, pixel-inner over the exact span of the Gaussian's
   ellipse in each row of the tile, per-pixel transmittance/accumulators in tile-local arrays; stores each
   pixel's final T and the count of list entries it consumed ("last").
4. ``_composite_bwd`` (parallel over tiles): walks each tile's list back to front, recovering T before each
   Gaussian as T_after / (1 - alpha) like the CUDA kernels, with per-pixel state in float64. Per-Gaussian
   gradients are summed per tile in float64 and written to that tile-Gaussian pair's own row, summed per
   Gaussian afterwards (``_reduce_pairs``): no two threads ever write the same memory, whatever the thread
   count, and memory grows with the pairs rather than threads x Gaussians.
5. ``_project_bwd`` (parallel over Gaussians): screen-space gradients to means, quats, scales.

SH colours (``_sh_fwd`` / ``_sh_bwd``) are evaluated only for visible Gaussians; their backward adds the
view-direction term to the means' gradient.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch
from numba import njit, prange

from training.model.sh import SH_C0, SH_C1, SH_C2, SH_C3

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
# The exp() is skipped when the exponent is this far below log(1/(255 o)): alpha is then certainly under
# 1/255 whatever the rounding of exp, so skipping cannot change which Gaussians composite.
SKIP_MARGIN = 1e-3
PROJ_CHUNK = 512
TILE_CHUNK = 4  # tiles per work item in the compositing kernels (dynamic scheduling)

# No fastmath on anything that decides whether a Gaussian composites: forward and backward must take the very
# same decisions from the same float operations.
_jit = dict(cache=True, nogil=True)


@njit(parallel=True, **_jit)
def _project_fwd(means, quats, scales, opac, view, kmat, width, height, near, far, eps2d,
                 means2d, conics, depths, radii):
    """means (N,3), quats (N,4), scales (N,3), opac (N,) float32; view (4,4), kmat (3,3) float64. Writes
    means2d (N,2), conics (N,3) = (a, b, c) of the inverse 2D covariance, depths (N,) camera z, radii (N,2) int32
    (0 where culled; then means2d and conics are 0)."""
    n = means.shape[0]
    fx, fy, cx, cy = kmat[0, 0], kmat[1, 1], kmat[0, 2], kmat[1, 2]
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    lim_xp = (width - cx) / fx + 0.3 * tan_fovx
    lim_xn = cx / fx + 0.3 * tan_fovx
    lim_yp = (height - cy) / fy + 0.3 * tan_fovy
    lim_yn = cy / fy + 0.3 * tan_fovy
    nchunks = (n + PROJ_CHUNK - 1) // PROJ_CHUNK
    for ch in prange(nchunks):
        rot = np.empty((3, 3))
        M = np.empty((3, 3))
        Mc = np.empty((3, 3))
        for i in range(ch * PROJ_CHUNK, min(n, (ch + 1) * PROJ_CHUNK)):
            radii[i, 0] = 0
            radii[i, 1] = 0
            means2d[i, 0] = 0.0
            means2d[i, 1] = 0.0
            conics[i, 0] = 0.0
            conics[i, 1] = 0.0
            conics[i, 2] = 0.0
            m0, m1, m2 = np.float64(means[i, 0]), np.float64(means[i, 1]), np.float64(means[i, 2])
            x = view[0, 0] * m0 + view[0, 1] * m1 + view[0, 2] * m2 + view[0, 3]
            y = view[1, 0] * m0 + view[1, 1] * m1 + view[1, 2] * m2 + view[1, 3]
            z = view[2, 0] * m0 + view[2, 1] * m1 + view[2, 2] * m2 + view[2, 3]
            depths[i] = z
            if not (z >= near and z <= far):
                continue
            o = np.float64(opac[i])
            if not (opac[i] >= np.float32(ALPHA_MIN)):
                continue
            _rotmat(quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3], rot)
            # M = R_view * rot * S, so Sigma_cam = M M^T
            for r in range(3):
                for c in range(3):
                    M[r, c] = rot[r, c] * scales[i, c]
            for r in range(3):
                for c in range(3):
                    Mc[r, c] = view[r, 0] * M[0, c] + view[r, 1] * M[1, c] + view[r, 2] * M[2, c]
            u = min(max(x / z, -lim_xn), lim_xp)
            v = min(max(y / z, -lim_yn), lim_yp)
            j00 = fx / z
            j02 = -fx * u / z
            j11 = fy / z
            j12 = -fy * v / z
            # rows of J Mc: cov2 = (J Mc)(J Mc)^T
            a0 = j00 * Mc[0, 0] + j02 * Mc[2, 0]
            a1 = j00 * Mc[0, 1] + j02 * Mc[2, 1]
            a2 = j00 * Mc[0, 2] + j02 * Mc[2, 2]
            b0 = j11 * Mc[1, 0] + j12 * Mc[2, 0]
            b1 = j11 * Mc[1, 1] + j12 * Mc[2, 1]
            b2 = j11 * Mc[1, 2] + j12 * Mc[2, 2]
            ca = a0 * a0 + a1 * a1 + a2 * a2 + eps2d
            cb = a0 * b0 + a1 * b1 + a2 * b2
            cc = b0 * b0 + b1 * b1 + b2 * b2 + eps2d
            det = ca * cc - cb * cb
            if not det > 0.0:
                continue
            px = fx * x / z + cx
            py = fy * y / z + cy
            extend = math.sqrt(2.0 * math.log(max(o, ALPHA_MIN) / ALPHA_MIN))
            rx = math.ceil(extend * math.sqrt(ca))
            ry = math.ceil(extend * math.sqrt(cc))
            if not (rx > 0 and ry > 0 and rx < 2.0**30 and ry < 2.0**30):
                continue
            if not (px + rx > 0 and px - rx < width and py + ry > 0 and py - ry < height):
                continue
            means2d[i, 0] = px
            means2d[i, 1] = py
            conics[i, 0] = cc / det
            conics[i, 1] = -cb / det
            conics[i, 2] = ca / det
            radii[i, 0] = np.int32(rx)
            radii[i, 1] = np.int32(ry)


@njit(inline="always", **_jit)
def _rotmat(qw, qx, qy, qz, out):
    w, x, y, z = np.float64(qw), np.float64(qx), np.float64(qy), np.float64(qz)
    norm = max(math.sqrt(w * w + x * x + y * y + z * z), 1e-12)
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    out[0, 0] = 1 - 2 * (y * y + z * z)
    out[0, 1] = 2 * (x * y - w * z)
    out[0, 2] = 2 * (x * z + w * y)
    out[1, 0] = 2 * (x * y + w * z)
    out[1, 1] = 1 - 2 * (x * x + z * z)
    out[1, 2] = 2 * (y * z - w * x)
    out[2, 0] = 2 * (x * z - w * y)
    out[2, 1] = 2 * (y * z + w * x)
    out[2, 2] = 1 - 2 * (x * x + y * y)


@njit(parallel=True, **_jit)
def _project_bwd(means, quats, scales, view, kmat, width, height, eps2d, radii, v_means2d, v_conics, v_depths,
                 v_means, v_quats, v_scales):
    """Gradients of (means2d, conics, depths) to (means, quats, scales); culled Gaussians get zeros."""
    n = means.shape[0]
    fx, fy, cx, cy = kmat[0, 0], kmat[1, 1], kmat[0, 2], kmat[1, 2]
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    lim_xp = (width - cx) / fx + 0.3 * tan_fovx
    lim_xn = cx / fx + 0.3 * tan_fovx
    lim_yp = (height - cy) / fy + 0.3 * tan_fovy
    lim_yn = cy / fy + 0.3 * tan_fovy
    nchunks = (n + PROJ_CHUNK - 1) // PROJ_CHUNK
    for ch in prange(nchunks):
        rot = np.empty((3, 3))
        M = np.empty((3, 3))  # rot S
        Sc = np.empty((3, 3))  # Sigma_cam
        S = np.empty((3, 3))  # Sigma_world
        tmp = np.empty((3, 3))
        VSc = np.empty((3, 3))
        VS = np.empty((3, 3))
        VM = np.empty((3, 3))
        for i in range(ch * PROJ_CHUNK, min(n, (ch + 1) * PROJ_CHUNK)):
            for k in range(3):
                v_means[i, k] = 0.0
                v_scales[i, k] = 0.0
            for k in range(4):
                v_quats[i, k] = 0.0
            if radii[i, 0] <= 0:
                continue
            m0, m1, m2 = np.float64(means[i, 0]), np.float64(means[i, 1]), np.float64(means[i, 2])
            x = view[0, 0] * m0 + view[0, 1] * m1 + view[0, 2] * m2 + view[0, 3]
            y = view[1, 0] * m0 + view[1, 1] * m1 + view[1, 2] * m2 + view[1, 3]
            z = view[2, 0] * m0 + view[2, 1] * m1 + view[2, 2] * m2 + view[2, 3]
            _rotmat(quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3], rot)
            for r in range(3):
                for c in range(3):
                    M[r, c] = rot[r, c] * scales[i, c]
            for r in range(3):
                for c in range(3):
                    S[r, c] = M[r, 0] * M[c, 0] + M[r, 1] * M[c, 1] + M[r, 2] * M[c, 2]
            for r in range(3):  # tmp = R S
                for c in range(3):
                    tmp[r, c] = view[r, 0] * S[0, c] + view[r, 1] * S[1, c] + view[r, 2] * S[2, c]
            for r in range(3):  # Sc = R S R^T
                for c in range(3):
                    Sc[r, c] = tmp[r, 0] * view[c, 0] + tmp[r, 1] * view[c, 1] + tmp[r, 2] * view[c, 2]
            xz, yz = x / z, y / z
            u = min(max(xz, -lim_xn), lim_xp)
            v = min(max(yz, -lim_yn), lim_yp)
            j00 = fx / z
            j02 = -fx * u / z
            j11 = fy / z
            j12 = -fy * v / z
            # cov2 = J Sc J^T + eps: recompute a, b, c and the conic
            t00 = j00 * Sc[0, 0] + j02 * Sc[2, 0]
            t01 = j00 * Sc[0, 1] + j02 * Sc[2, 1]
            t02 = j00 * Sc[0, 2] + j02 * Sc[2, 2]
            t10 = j11 * Sc[1, 0] + j12 * Sc[2, 0]
            t11 = j11 * Sc[1, 1] + j12 * Sc[2, 1]
            t12 = j11 * Sc[1, 2] + j12 * Sc[2, 2]
            # the conic in float64 (the stored one is float32)
            ca = t00 * j00 + t02 * j02 + eps2d
            cb = t01 * j11 + t02 * j12
            cc = t11 * j11 + t12 * j12 + eps2d
            det = ca * cc - cb * cb
            qa, qb, qc = cc / det, -cb / det, ca / det
            ga, gb, gc = np.float64(v_conics[i, 0]), 0.5 * np.float64(v_conics[i, 1]), np.float64(v_conics[i, 2])
            # V2 = -Q G Q (symmetric gradient of the 2D covariance)
            h00 = qa * ga + qb * gb
            h01 = qa * gb + qb * gc
            h10 = qb * ga + qc * gb
            h11 = qb * gb + qc * gc
            w00 = -(h00 * qa + h01 * qb)
            w01 = -(h00 * qb + h01 * qc)
            w11 = -(h10 * qb + h11 * qc)
            # v_Sc = J^T V2 J ; J = [[j00, 0, j02], [0, j11, j12]]
            p0 = w00 * j00  # (V2 J) row 0
            p1 = w01 * j11
            p2 = w00 * j02 + w01 * j12
            q0 = w01 * j00  # (V2 J) row 1
            q1 = w11 * j11
            q2 = w01 * j02 + w11 * j12
            VSc[0, 0] = j00 * p0
            VSc[0, 1] = j00 * p1
            VSc[0, 2] = j00 * p2
            VSc[1, 0] = j11 * q0
            VSc[1, 1] = j11 * q1
            VSc[1, 2] = j11 * q2
            VSc[2, 0] = j02 * p0 + j12 * q0
            VSc[2, 1] = j02 * p1 + j12 * q1
            VSc[2, 2] = j02 * p2 + j12 * q2
            # v_J = 2 V2 J Sc, only the four non-constant entries
            vj00 = 2.0 * (p0 * Sc[0, 0] + p1 * Sc[1, 0] + p2 * Sc[2, 0])
            vj02 = 2.0 * (p0 * Sc[0, 2] + p1 * Sc[1, 2] + p2 * Sc[2, 2])
            vj11 = 2.0 * (q0 * Sc[0, 1] + q1 * Sc[1, 1] + q2 * Sc[2, 1])
            vj12 = 2.0 * (q0 * Sc[0, 2] + q1 * Sc[1, 2] + q2 * Sc[2, 2])
            # v_S = R^T v_Sc R
            for r in range(3):
                for c in range(3):
                    tmp[r, c] = view[0, r] * VSc[0, c] + view[1, r] * VSc[1, c] + view[2, r] * VSc[2, c]
            for r in range(3):
                for c in range(3):
                    VS[r, c] = tmp[r, 0] * view[0, c] + tmp[r, 1] * view[1, c] + tmp[r, 2] * view[2, c]
            # v_M = (v_S + v_S^T) M
            for r in range(3):
                for c in range(3):
                    VM[r, c] = ((VS[r, 0] + VS[0, r]) * M[0, c] + (VS[r, 1] + VS[1, r]) * M[1, c]
                                + (VS[r, 2] + VS[2, r]) * M[2, c])
            for c in range(3):
                v_scales[i, c] = VM[0, c] * rot[0, c] + VM[1, c] * rot[1, c] + VM[2, c] * rot[2, c]
            for r in range(3):  # v_rot, stored in tmp
                for c in range(3):
                    tmp[r, c] = VM[r, c] * scales[i, c]
            qw, qx, qy, qz = np.float64(quats[i, 0]), np.float64(quats[i, 1]), np.float64(quats[i, 2]), \
                np.float64(quats[i, 3])
            norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            if norm > 1e-12:
                w_, x_, y_, z_ = qw / norm, qx / norm, qy / norm, qz / norm
                gw = 2 * (-z_ * tmp[0, 1] + y_ * tmp[0, 2] + z_ * tmp[1, 0] - x_ * tmp[1, 2]
                          - y_ * tmp[2, 0] + x_ * tmp[2, 1])
                gx = 2 * (y_ * tmp[0, 1] + z_ * tmp[0, 2] + y_ * tmp[1, 0] - 2 * x_ * tmp[1, 1]
                          - w_ * tmp[1, 2] + z_ * tmp[2, 0] + w_ * tmp[2, 1] - 2 * x_ * tmp[2, 2])
                gy = 2 * (-2 * y_ * tmp[0, 0] + x_ * tmp[0, 1] + w_ * tmp[0, 2] + x_ * tmp[1, 0]
                          + z_ * tmp[1, 2] - w_ * tmp[2, 0] + z_ * tmp[2, 1] - 2 * y_ * tmp[2, 2])
                gz = 2 * (-2 * z_ * tmp[0, 0] - w_ * tmp[0, 1] + x_ * tmp[0, 2] + w_ * tmp[1, 0]
                          - 2 * z_ * tmp[1, 1] + y_ * tmp[1, 2] + x_ * tmp[2, 0] + y_ * tmp[2, 1])
                dot = w_ * gw + x_ * gx + y_ * gy + z_ * gz
                v_quats[i, 0] = (gw - w_ * dot) / norm
                v_quats[i, 1] = (gx - x_ * dot) / norm
                v_quats[i, 2] = (gy - y_ * dot) / norm
                v_quats[i, 3] = (gz - z_ * dot) / norm
            # camera-space point gradient: from J, from the pixel mean, from the depth channel
            iz2 = 1.0 / (z * z)
            vx = 0.0
            vy = 0.0
            vz = -vj00 * fx * iz2 - vj11 * fy * iz2 + np.float64(v_depths[i])
            if -lim_xn < xz < lim_xp:  # J02 = -fx x / z^2
                vx += -vj02 * fx * iz2
                vz += vj02 * 2.0 * fx * x * iz2 / z
            else:  # J02 = -fx u / z with u clamped (constant)
                vz += vj02 * fx * u * iz2
            if -lim_yn < yz < lim_yp:
                vy += -vj12 * fy * iz2
                vz += vj12 * 2.0 * fy * y * iz2 / z
            else:
                vz += vj12 * fy * v * iz2
            gmx, gmy = np.float64(v_means2d[i, 0]), np.float64(v_means2d[i, 1])
            vx += gmx * fx / z
            vy += gmy * fy / z
            vz -= (gmx * fx * x + gmy * fy * y) * iz2
            for k in range(3):
                v_means[i, k] = view[0, k] * vx + view[1, k] * vy + view[2, k] * vz


@njit(**_jit)
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


@njit(**_jit)
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


@njit(inline="always", **_jit)
def _rows(my, ry, y0, y1):
    """Pixel rows of a Gaussian's screen box inside a tile (a superset of where alpha >= 1/255)."""
    by0 = max(y0, int(math.floor(my - ry)) - 1)
    by1 = min(y1, int(math.ceil(my + ry)) + 1)
    return by0, by1


@njit(inline="always", **_jit)
def _row_span(mx, my, ca, cb, cc, log_thr, py, x0, x1):
    """Pixel columns [lo, hi) of row py where the exponent can reach log_thr, widened by a pixel each side.

    Solves A dx^2 + 2 B dy dx + C dy^2 + 2 L <= 0 (power >= L) for dx in float64; pixels outside the span have
    power below log_thr (which already carries SKIP_MARGIN), so the per-pixel test would skip them anyway.
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


@njit(inline="always", **_jit)
def _row_terms(my, cb, cc, py):
    """Per-row constants of the exponent: dy, B dy and -C dy^2 / 2 (float32, shared by forward and backward)."""
    dy = my - (np.float32(py) + np.float32(0.5))
    return dy, cb * dy, np.float32(-0.5) * cc * dy * dy


@njit(inline="always", **_jit)
def _power(mx, ca, bdy, cdy, px):
    """Exponent -0.5 d^T Q d at pixel px of a row, and dx."""
    dx = mx - (np.float32(px) + np.float32(0.5))
    return np.float32(-0.5) * ca * dx * dx - bdy * dx + cdy, dx


@njit(parallel=True, **_jit)
def _composite_fwd(offsets, ids, rec, feats, width, height, tile_size, tiles_x, out_feat, out_t, out_last):
    """ids: depth ranks; rec (V, 8) and feats (V, C) are packed in depth order (see _pack)."""
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
            if remaining == 0:
                break
        for py in range(y0, y1):
            for px in range(x0, x1):
                p = (py - y0) * tw + (px - x0)
                for c in range(n_ch):
                    out_feat[py, px, c] = acc[p, c]
                out_t[py, px] = T[p]
                out_last[py, px] = last[p]


@njit(parallel=True, **_jit)
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


@njit(inline="always", **_jit)
def _sh_basis(x, y, z, degree, b, db):
    """Basis values b[k] and their derivatives db[k, :] w.r.t. the (unit) direction components."""
    for k in range(b.shape[0]):
        b[k] = 0.0
        db[k, 0] = 0.0
        db[k, 1] = 0.0
        db[k, 2] = 0.0
    b[0] = SH_C0
    if degree >= 1:
        b[1] = -SH_C1 * y
        b[2] = SH_C1 * z
        b[3] = -SH_C1 * x
        db[1, 1] = -SH_C1
        db[2, 2] = SH_C1
        db[3, 0] = -SH_C1
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        b[4] = SH_C2[0] * x * y
        b[5] = SH_C2[1] * y * z
        b[6] = SH_C2[2] * (2.0 * zz - xx - yy)
        b[7] = SH_C2[3] * x * z
        b[8] = SH_C2[4] * (xx - yy)
        db[4, 0], db[4, 1] = SH_C2[0] * y, SH_C2[0] * x
        db[5, 1], db[5, 2] = SH_C2[1] * z, SH_C2[1] * y
        db[6, 0], db[6, 1], db[6, 2] = -2.0 * SH_C2[2] * x, -2.0 * SH_C2[2] * y, 4.0 * SH_C2[2] * z
        db[7, 0], db[7, 2] = SH_C2[3] * z, SH_C2[3] * x
        db[8, 0], db[8, 1] = 2.0 * SH_C2[4] * x, -2.0 * SH_C2[4] * y
        if degree >= 3:
            b[9] = SH_C3[0] * y * (3.0 * xx - yy)
            b[10] = SH_C3[1] * x * y * z
            b[11] = SH_C3[2] * y * (4.0 * zz - xx - yy)
            b[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
            b[13] = SH_C3[4] * x * (4.0 * zz - xx - yy)
            b[14] = SH_C3[5] * z * (xx - yy)
            b[15] = SH_C3[6] * x * (xx - 3.0 * yy)
            db[9, 0], db[9, 1] = 6.0 * SH_C3[0] * x * y, SH_C3[0] * (3.0 * xx - 3.0 * yy)
            db[10, 0], db[10, 1], db[10, 2] = SH_C3[1] * y * z, SH_C3[1] * x * z, SH_C3[1] * x * y
            db[11, 0] = -2.0 * SH_C3[2] * x * y
            db[11, 1] = SH_C3[2] * (4.0 * zz - xx - 3.0 * yy)
            db[11, 2] = 8.0 * SH_C3[2] * y * z
            db[12, 0] = -6.0 * SH_C3[3] * x * z
            db[12, 1] = -6.0 * SH_C3[3] * y * z
            db[12, 2] = SH_C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy)
            db[13, 0] = SH_C3[4] * (4.0 * zz - 3.0 * xx - yy)
            db[13, 1] = -2.0 * SH_C3[4] * x * y
            db[13, 2] = 8.0 * SH_C3[4] * x * z
            db[14, 0], db[14, 1], db[14, 2] = 2.0 * SH_C3[5] * x * z, -2.0 * SH_C3[5] * y * z, SH_C3[5] * (xx - yy)
            db[15, 0], db[15, 1] = SH_C3[6] * (3.0 * xx - 3.0 * yy), -6.0 * SH_C3[6] * x * y


@njit(parallel=True, **_jit)
def _sh_fwd(coeffs, means, campos, degree, radii, out_rgb):
    """out_rgb (N, 3) = max(SH(dir) + 0.5, 0) for visible Gaussians, 0 for culled ones."""
    n = means.shape[0]
    nk = (degree + 1) ** 2
    nchunks = (n + PROJ_CHUNK - 1) // PROJ_CHUNK
    for ch in prange(nchunks):
        b = np.empty(16)
        db = np.empty((16, 3))
        for i in range(ch * PROJ_CHUNK, min(n, (ch + 1) * PROJ_CHUNK)):
            if radii[i, 0] <= 0:
                for c in range(3):
                    out_rgb[i, c] = 0.0
                continue
            dx = np.float64(means[i, 0]) - campos[0]
            dy = np.float64(means[i, 1]) - campos[1]
            dz = np.float64(means[i, 2]) - campos[2]
            norm = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
            _sh_basis(dx / norm, dy / norm, dz / norm, degree, b, db)
            for c in range(3):
                acc = 0.5
                for k in range(nk):
                    acc += b[k] * coeffs[i, k, c]
                out_rgb[i, c] = max(acc, 0.0)


@njit(parallel=True, **_jit)
def _sh_bwd(coeffs, means, campos, degree, radii, rgb, v_rgb, v_coeffs, v_means):
    """v_coeffs (N, K, 3) overwritten; v_means (N, 3) accumulated into (view-direction term)."""
    n = means.shape[0]
    nk = (degree + 1) ** 2
    nchunks = (n + PROJ_CHUNK - 1) // PROJ_CHUNK
    for ch in prange(nchunks):
        b = np.empty(16)
        db = np.empty((16, 3))
        for i in range(ch * PROJ_CHUNK, min(n, (ch + 1) * PROJ_CHUNK)):
            for k in range(coeffs.shape[1]):
                for c in range(3):
                    v_coeffs[i, k, c] = 0.0
            if radii[i, 0] <= 0:
                continue
            dx = np.float64(means[i, 0]) - campos[0]
            dy = np.float64(means[i, 1]) - campos[1]
            dz = np.float64(means[i, 2]) - campos[2]
            norm = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
            ux, uy, uz = dx / norm, dy / norm, dz / norm
            _sh_basis(ux, uy, uz, degree, b, db)
            gx = 0.0
            gy = 0.0
            gz = 0.0
            for c in range(3):
                if rgb[i, c] <= 0.0:  # clamped at 0 (torch's clamp_min passes the gradient at exactly 0)
                    acc = 0.5
                    for k in range(nk):
                        acc += b[k] * coeffs[i, k, c]
                    if acc < 0.0:
                        continue
                g = np.float64(v_rgb[i, c])
                for k in range(nk):
                    v_coeffs[i, k, c] = b[k] * g
                    cf = g * coeffs[i, k, c]
                    gx += cf * db[k, 0]
                    gy += cf * db[k, 1]
                    gz += cf * db[k, 2]
            dot = ux * gx + uy * gy + uz * gz
            v_means[i, 0] += (gx - ux * dot) / norm
            v_means[i, 1] += (gy - uy * dot) / norm
            v_means[i, 2] += (gz - uz * dot) / norm


@njit(**_jit)
def _reduce_pairs(ids, pair_grad, n_ranks):
    """(V, 6 + C) float64 per-depth-rank sums of the per-pair gradients."""
    out = np.zeros((n_ranks, pair_grad.shape[1]))
    for j in range(ids.shape[0]):
        k = ids[j]
        for c in range(pair_grad.shape[1]):
            out[k, c] += pair_grad[j, c]
    return out


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


class _CompositeState:
    """What the forward pass keeps for the backward pass (numpy arrays, float32 unless noted)."""

    def __init__(self, **kw):
        self.__dict__.update(kw)


class _RasterizeCPU(torch.autograd.Function):
    """(means, quats, scales, opacities, colors or SH, means2d leaf) -> (features (H,W,C), T_final (H,W,1))."""

    @staticmethod
    def forward(ctx, means, quats, scales, opacities, colors, means2d_leaf, st):
        n = st.means.shape[0]
        H, W = st.height, st.width
        feats = np.empty((n, st.n_ch), np.float32)
        if st.use_rgb:
            if st.sh_degree is None:
                feats[:, :3] = st.colors
            else:
                rgb = np.empty((n, 3), np.float32)
                _sh_fwd(st.colors, st.means, st.campos, st.sh_degree, st.radii, rgb)
                feats[:, :3] = rgb
                st.rgb = rgb
        if st.use_depth:
            feats[:, -1] = st.depths
        st.feats = feats
        out_feat = np.empty((H, W, st.n_ch), np.float32)
        out_t = np.empty((H, W), np.float32)
        out_last = np.empty((H, W), np.int32)
        st.packed_feats = np.ascontiguousarray(feats[st.order])
        # Tiles differ a lot in cost (sky vs detail): hand them out dynamically, a few at a time.
        with numba.parallel_chunksize(TILE_CHUNK):
            _composite_fwd(st.offsets, st.ids, st.rec, st.packed_feats, W, H, st.tile_size, st.tiles_x, out_feat,
                           out_t, out_last)
        st.out_t, st.out_last = out_t, out_last
        ctx.st = st
        return torch.from_numpy(out_feat), torch.from_numpy(out_t).unsqueeze(-1)

    @staticmethod
    def backward(ctx, g_feat, g_t):
        st = ctx.st
        n, n_ch = st.feats.shape
        H, W = st.height, st.width
        g_feat_np = (g_feat if g_feat is not None else torch.zeros(H, W, n_ch)).float().contiguous().numpy()
        g_t_np = (g_t if g_t is not None else torch.zeros(H, W, 1)).float().contiguous().numpy()[..., 0]
        pair_grad = np.zeros((st.ids.shape[0], 6 + n_ch), np.float32)
        with numba.parallel_chunksize(TILE_CHUNK):
            _composite_bwd(st.offsets, st.ids, st.rec, st.packed_feats, W, H, st.tile_size, st.tiles_x, st.out_t,
                           st.out_last, g_feat_np, g_t_np, pair_grad)
        gsum = np.zeros((n, 6 + n_ch))
        gsum[st.order] = _reduce_pairs(st.ids, pair_grad, st.order.shape[0])
        v_means2d = gsum[:, 0:2].astype(np.float32)
        v_conics = gsum[:, 2:5].astype(np.float32)
        v_opac = gsum[:, 5].astype(np.float32)
        v_depths = gsum[:, 5 + n_ch].astype(np.float32) if st.use_depth else np.zeros(n, np.float32)
        v_means = np.empty((n, 3), np.float32)
        v_quats = np.empty((n, 4), np.float32)
        v_scales = np.empty((n, 3), np.float32)
        _project_bwd(st.means, st.quats, st.scales, st.view, st.kmat, W, H, st.eps2d, st.radii, v_means2d,
                     v_conics, v_depths, v_means, v_quats, v_scales)
        v_colors = None
        if st.use_rgb:
            v_rgb = np.ascontiguousarray(gsum[:, 6:9], dtype=np.float32)
            if st.sh_degree is None:
                v_colors = v_rgb
            else:
                v_colors = np.empty(st.colors.shape, np.float32)
                _sh_bwd(st.colors, st.means, st.campos, st.sh_degree, st.radii, st.rgb, v_rgb, v_colors, v_means)
            v_colors = torch.from_numpy(v_colors)
        return (torch.from_numpy(v_means), torch.from_numpy(v_quats), torch.from_numpy(v_scales),
                torch.from_numpy(v_opac), v_colors, torch.from_numpy(v_means2d), None)


def render_features_cpu(
    means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor, colors: torch.Tensor,
    viewmat: torch.Tensor, K: torch.Tensor, width: int, height: int, sh_degree: int | None, use_rgb: bool,
    use_depth: bool, near_plane: float, far_plane: float, eps2d: float, tile_size: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The cpu backend of ``training.raster.rasterize.rasterize``: returns (features (H,W,C) without background,
    final transmittance (H,W,1), means2d (N,2) whose .grad receives the screen-space gradient, radii (N,) int32,
    depths (N,)). Gradients flow to means, quats, scales, opacities and colors (not to viewmat or K).
    Inputs in another float dtype are converted to float32 (autograd converts their gradients back)."""
    ins = [t.to(torch.float32) for t in (means, quats, scales, opacities, colors)]
    m_np, q_np, s_np, o_np, c_np = (t.detach().contiguous().numpy() for t in ins)
    n = m_np.shape[0]
    view = viewmat.detach().to(torch.float64).contiguous().numpy()
    kmat = K.detach().to(torch.float64).contiguous().numpy()
    means2d = np.empty((n, 2), np.float32)
    conics = np.empty((n, 3), np.float32)
    depths = np.empty(n, np.float32)
    radii = np.empty((n, 2), np.int32)
    _project_fwd(m_np, q_np, s_np, o_np, view, kmat, width, height, near_plane, far_plane, eps2d,
                 means2d, conics, depths, radii)
    visible = np.flatnonzero(radii[:, 0] > 0)
    order = depth_order(depths, visible)
    tiles_x = (width + tile_size - 1) // tile_size
    tiles_y = (height + tile_size - 1) // tile_size
    offsets, ids = _bin(order, means2d, radii, tile_size, tiles_x, tiles_y)

    needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in ins)
    means2d_t = torch.from_numpy(means2d).clone()
    if needs_grad:
        means2d_t.requires_grad_(True)
    st = _CompositeState(
        means=m_np, quats=q_np, scales=s_np, opac=o_np, colors=c_np, view=view, kmat=kmat, eps2d=eps2d,
        campos=-view[:3, :3].T @ view[:3, 3], sh_degree=sh_degree, use_rgb=use_rgb, use_depth=use_depth,
        n_ch=3 * use_rgb + use_depth, means2d=means2d, conics=conics, depths=depths, radii=radii,
        offsets=offsets, ids=ids, order=order, rec=_pack(order, means2d, conics, o_np, radii), width=width, height=height, tile_size=tile_size, tiles_x=tiles_x)
    feat_img, trans = _RasterizeCPU.apply(*ins, means2d_t, st)
    radii_out = torch.from_numpy(radii.max(axis=1))
    return feat_img, trans, means2d_t, radii_out, torch.from_numpy(depths)
