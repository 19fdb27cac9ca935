"""Per-Gaussian stages of the cpu rasterizer (numba): EWA projection and SH colours, forward and backward.

``_project_fwd`` and ``_project_bwd`` start from the same inlined prologue (``_camera``, ``_view_point``,
``_prologue``: intrinsics and field-of-view limits, the camera-space point, the rotation, M = R_q S and the
Jacobian at the clamped x/z, y/z), so the backward differentiates exactly the projection the forward computed.
Everything runs in float64 inside: in float32, det = ac - b^2 of thin Gaussians close to the camera cancels.
The SH kernels evaluate colours only for visible Gaussians; their backward can add the view-direction term to the
means' gradient or, when the means need no gradient, skip it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from training.model.rotation import QUAT_NORM_EPS
from training.model.sh_constants import SH_C0, SH_C1, SH_C2, SH_C3
from training.raster.constants import ALPHA_MIN, FOV_CLAMP_MARGIN
from training.raster.cpu_jit import JIT, PROJ_CHUNK


@njit(inline="always", **JIT)
def _rotmat(qw, qx, qy, qz, out):
    w, x, y, z = np.float64(qw), np.float64(qx), np.float64(qy), np.float64(qz)
    norm = max(math.sqrt(w * w + x * x + y * y + z * z), QUAT_NORM_EPS)
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


@njit(inline="always", **JIT)
def _camera(kmat, width, height):
    """fx, fy, cx, cy and the limits of x/z, y/z inside the Jacobian (the field of view widened by the margin)."""
    fx, fy, cx, cy = kmat[0, 0], kmat[1, 1], kmat[0, 2], kmat[1, 2]
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    lim_xp = (width - cx) / fx + FOV_CLAMP_MARGIN * tan_fovx
    lim_xn = cx / fx + FOV_CLAMP_MARGIN * tan_fovx
    lim_yp = (height - cy) / fy + FOV_CLAMP_MARGIN * tan_fovy
    lim_yn = cy / fy + FOV_CLAMP_MARGIN * tan_fovy
    return fx, fy, cx, cy, lim_xp, lim_xn, lim_yp, lim_yn


@njit(inline="always", **JIT)
def _view_point(view, means, i):
    """Camera-space position of Gaussian i (the forward needs its z before the prologue, to cull)."""
    m0, m1, m2 = np.float64(means[i, 0]), np.float64(means[i, 1]), np.float64(means[i, 2])
    x = view[0, 0] * m0 + view[0, 1] * m1 + view[0, 2] * m2 + view[0, 3]
    y = view[1, 0] * m0 + view[1, 1] * m1 + view[1, 2] * m2 + view[1, 3]
    z = view[2, 0] * m0 + view[2, 1] * m1 + view[2, 2] * m2 + view[2, 3]
    return x, y, z


@njit(inline="always", **JIT)
def _prologue(quats, scales, i, x, y, z, fx, fy, lim_xp, lim_xn, lim_yp, lim_yn, rot, M):
    """Fills rot (3x3) and M = rot S (3x3) for Gaussian i at camera point (x, y, z); returns x/z, y/z, their
    clamped values u, v and the Jacobian entries j00, j02, j11, j12 of the perspective map at (u, v)."""
    _rotmat(quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3], rot)
    for r in range(3):
        for c in range(3):
            M[r, c] = rot[r, c] * scales[i, c]
    xz, yz = x / z, y / z
    u = min(max(xz, -lim_xn), lim_xp)
    v = min(max(yz, -lim_yn), lim_yp)
    j00 = fx / z
    j02 = -fx * u / z
    j11 = fy / z
    j12 = -fy * v / z
    return xz, yz, u, v, j00, j02, j11, j12


@njit(parallel=True, **JIT)
def _project_fwd(means, quats, scales, opac, view, kmat, width, height, near, far, eps2d,
                 means2d, conics, depths, radii):
    """means (N,3), quats (N,4), scales (N,3), opac (N,) float32; view (4,4), kmat (3,3) float64. Writes
    means2d (N,2), conics (N,3) = (a, b, c) of the inverse 2D covariance, depths (N,) camera z, radii (N,2) int32
    (0 where culled; then means2d and conics are 0)."""
    n = means.shape[0]
    fx, fy, cx, cy, lim_xp, lim_xn, lim_yp, lim_yn = _camera(kmat, width, height)
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
            x, y, z = _view_point(view, means, i)
            depths[i] = z
            if not (z >= near and z <= far):
                continue
            o = np.float64(opac[i])
            if not (opac[i] >= np.float32(ALPHA_MIN)):
                continue
            xz, yz, u, v, j00, j02, j11, j12 = _prologue(quats, scales, i, x, y, z, fx, fy, lim_xp, lim_xn, lim_yp,
                                                        lim_yn, rot, M)
            # Mc = R_view M, so Sigma_cam = Mc Mc^T
            for r in range(3):
                for c in range(3):
                    Mc[r, c] = view[r, 0] * M[0, c] + view[r, 1] * M[1, c] + view[r, 2] * M[2, c]
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


@njit(parallel=True, **JIT)
def _project_bwd(means, quats, scales, view, kmat, width, height, eps2d, radii, v_means2d, v_conics, v_depths,
                 v_means, v_quats, v_scales):
    """Gradients of (means2d, conics, depths) to (means, quats, scales); culled Gaussians get zeros."""
    n = means.shape[0]
    fx, fy, cx, cy, lim_xp, lim_xn, lim_yp, lim_yn = _camera(kmat, width, height)
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
            x, y, z = _view_point(view, means, i)
            xz, yz, u, v, j00, j02, j11, j12 = _prologue(quats, scales, i, x, y, z, fx, fy, lim_xp, lim_xn, lim_yp,
                                                        lim_yn, rot, M)
            for r in range(3):
                for c in range(3):
                    S[r, c] = M[r, 0] * M[c, 0] + M[r, 1] * M[c, 1] + M[r, 2] * M[c, 2]
            for r in range(3):  # tmp = R S
                for c in range(3):
                    tmp[r, c] = view[r, 0] * S[0, c] + view[r, 1] * S[1, c] + view[r, 2] * S[2, c]
            for r in range(3):  # Sc = R S R^T
                for c in range(3):
                    Sc[r, c] = tmp[r, 0] * view[c, 0] + tmp[r, 1] * view[c, 1] + tmp[r, 2] * view[c, 2]
            # cov2 = J Sc J^T + eps: recompute a, b, c and the conic
            t00 = j00 * Sc[0, 0] + j02 * Sc[2, 0]
            t01 = j00 * Sc[0, 1] + j02 * Sc[2, 1]
            t02 = j00 * Sc[0, 2] + j02 * Sc[2, 2]
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
            if norm > QUAT_NORM_EPS:
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


@njit(inline="always", **JIT)
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


@njit(parallel=True, **JIT)
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


@njit(parallel=True, **JIT)
def _sh_bwd(coeffs, means, campos, degree, radii, rgb, v_rgb, with_means, v_coeffs, v_means):
    """v_coeffs (N, K, 3) overwritten; with_means: v_means (N, 3) accumulated into (view-direction term), else
    v_means is not touched (may be empty)."""
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
                if with_means:
                    for k in range(nk):
                        cf = g * coeffs[i, k, c]
                        gx += cf * db[k, 0]
                        gy += cf * db[k, 1]
                        gz += cf * db[k, 2]
            if with_means:
                dot = ux * gx + uy * gy + uz * gz
                v_means[i, 0] += (gx - ux * dot) / norm
                v_means[i, 1] += (gy - uy * dot) / norm
                v_means[i, 2] += (gz - uz * dot) / norm

