"""Float64 per-pixel brute-force Gaussian renderer: the ground truth for the rasterizer tests.

No tiles, no screen boxes, no frustum culling: every pixel visits every Gaussian in front of the near plane, in
increasing depth, one after the other, exactly as the compositing rule reads. Written separately from the
backends (rotations via scipy, covariances via einsum) so the two implementations share no code except the SH
basis formulas and the numbers in training/raster/constants.py.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from training.model.sh import sh_to_rgb
from training.raster.constants import ALPHA_MAX, ALPHA_MIN, EPS2D, FAR_PLANE, FOV_CLAMP_MARGIN, NEAR_PLANE, T_MIN


def bruteforce_render(
    means, quats, scales, opacities, colors, viewmat, K, width, height,
    sh_degree=None, background=None, near_plane=NEAR_PLANE, far_plane=FAR_PLANE, eps2d=EPS2D,
):
    """All inputs as arrays/tensors (any float dtype). Returns float64 arrays rgb (H,W,3), depth (H,W,1) = sum
    d_i a_i T_i, alpha (H,W,1), and slack (H,W) >= 0, nonzero only for pixels "at the alpha threshold": where
    some Gaussian's alpha lies within 1e-4 (relative) of the 1/255 cut or its transmittance within 1e-4 of the
    1e-4 stop, so that float32 rounding may legitimately flip whether it composites. The slack bounds what such
    flips can change in any channel: the sum of a_i T_i max(1, |c_i|, z_i) over those Gaussians."""
    f64 = lambda t: np.asarray(t.detach().cpu().numpy() if isinstance(t, torch.Tensor) else t, dtype=np.float64)
    means, quats, scales, opacities, viewmat, K = map(f64, (means, quats, scales, opacities, viewmat, K))
    n = means.shape[0]
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    if sh_degree is None:
        rgb = f64(colors)
    else:
        campos = -R.T @ t
        rgb = sh_to_rgb(sh_degree, torch.from_numpy(f64(colors)), torch.from_numpy(means),
                        torch.from_numpy(campos)).numpy()
    pc = np.einsum("ij,nj->ni", R, means) + t
    z = pc[:, 2]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]

    norms = np.linalg.norm(quats, axis=1)
    # scipy wants (x, y, z, w); a zero quaternion is not a rotation, treat as identity like a normalised eps would.
    q = np.where(norms[:, None] > 0, quats / np.maximum(norms, 1e-300)[:, None], [1.0, 0, 0, 0])
    rot = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix() if n else np.zeros((0, 3, 3))
    cov_w = np.einsum("nij,nj,nkj->nik", rot, scales**2, rot)
    cov_c = np.einsum("ij,njk,lk->nil", R, cov_w, R)

    with np.errstate(divide="ignore", invalid="ignore"):
        limx_p = (width - cx) / fx + FOV_CLAMP_MARGIN * (0.5 * width / fx)
        limx_n = cx / fx + FOV_CLAMP_MARGIN * (0.5 * width / fx)
        limy_p = (height - cy) / fy + FOV_CLAMP_MARGIN * (0.5 * height / fy)
        limy_n = cy / fy + FOV_CLAMP_MARGIN * (0.5 * height / fy)
        u = np.clip(pc[:, 0] / z, -limx_n, limx_p)
        v = np.clip(pc[:, 1] / z, -limy_n, limy_p)
        J = np.zeros((n, 2, 3))
        J[:, 0, 0] = fx / z
        J[:, 0, 2] = -fx * u / z
        J[:, 1, 1] = fy / z
        J[:, 1, 2] = -fy * v / z
        cov2 = np.einsum("nij,njk,nlk->nil", J, cov_c, J) + eps2d * np.eye(2)
        inv = np.linalg.inv(cov2) if n else cov2
        mx = fx * pc[:, 0] / z + cx
        my = fy * pc[:, 1] / z + cy
    det = np.linalg.det(cov2) if n else np.zeros(0)
    keep = (z >= near_plane) & (z <= far_plane) & (det > 0)

    ys, xs = np.mgrid[0:height, 0:width]
    px, py = xs.ravel() + 0.5, ys.ravel() + 0.5
    T = np.ones(px.shape)
    done = np.zeros(px.shape, bool)
    out_rgb = np.zeros((px.size, 3))
    out_d = np.zeros(px.size)
    slack = np.zeros(px.size)
    c_max = max([1.0, float(np.abs(rgb).max(initial=0))] + ([float(np.abs(z[keep]).max())] if keep.any() else []))
    if background is not None:
        c_max = max(c_max, float(np.abs(f64(background)).max()))
    # The depth order is defined on the float32 camera z, ties by index (as every backend sorts): Gaussians at
    # equal depth (the test scenes put a slice exactly on the near plane) composite in the same order here.
    for i in np.argsort(z.astype(np.float32), kind="stable"):
        if not keep[i]:
            continue
        dx, dy = mx[i] - px, my[i] - py
        power = -0.5 * (inv[i, 0, 0] * dx * dx + inv[i, 1, 1] * dy * dy) - inv[i, 0, 1] * dx * dy
        alpha = np.minimum(ALPHA_MAX, opacities[i] * np.exp(power))
        use = (~done) & (power <= 0) & (alpha >= ALPHA_MIN)
        next_T = T * (1.0 - alpha)
        near_cut = (~done) & (power <= 0) & (np.abs(alpha / ALPHA_MIN - 1.0) < 1e-4)
        near_stop = (~done) & (power <= 0) & (alpha >= ALPHA_MIN) & (np.abs(next_T / T_MIN - 1.0) < 1e-4)
        # Flipping the 1/255 cut changes this Gaussian's term and scales everything behind it by (1 - a): at most
        # 2 a T c_max. Flipping the stop at T = 1e-4 changes at most T c_max.
        slack += c_max * T * (2.0 * alpha * near_cut + near_stop)
        stop = use & (next_T <= T_MIN)
        done |= stop
        use &= ~stop
        w = np.where(use, alpha * T, 0.0)
        out_rgb += w[:, None] * rgb[i]
        out_d += w * z[i]
        T = np.where(use, next_T, T)
    if background is not None:
        out_rgb += T[:, None] * f64(background)
    return (out_rgb.reshape(height, width, 3), out_d.reshape(height, width, 1), (1.0 - T).reshape(height, width, 1),
            slack.reshape(height, width))


def check_close(got, ref, slack, atol, label, scale=1.0):
    """max |got - ref| <= atol except at alpha-threshold pixels (slack > 0, see bruteforce_render), which may be
    off by 1e-3, or by more where a Gaussian at the 1/255 cut can account for it (a flip there costs ~T/255)."""
    err = np.abs(np.asarray(got, np.float64) - ref).max(axis=-1)
    at = slack > 0
    assert err[~at].max(initial=0) <= atol, f"{label}: max error {err[~at].max(initial=0):.3g} off-threshold"
    bound = np.maximum(1e-3, atol + slack / scale)
    assert (err <= bound).all(), f"{label}: max error {err.max():.3g} at threshold pixels"
