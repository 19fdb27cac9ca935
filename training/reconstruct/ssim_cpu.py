"""SSIM of a float32 (H, W, C) render against a fixed target on the CPU, with its gradient: numba kernels.

The same numbers as ``ssim.ssim`` (11x11 Gaussian window, sigma 1.5, zero padding, mean map), computed as 3DGS
training needs them, at about a sixth of the time of the torch version at 378x212 (docs/performance.md): the
render's five blurred maps in one pass of separable 11-tap blurs over planar channels, the per-pixel SSIM and its
derivatives with respect to the three blurred maps that depend on the render (mean, mean of squares, mean of the
product with the target) in the same pass, and the backward as three blurs of those derivatives (the blur with
zero padding and a symmetric window is its own adjoint):

    d ssim / d x = G * dS/dmu_x + 2 x (G * dS/dE[x^2]) + y (G * dS/dE[xy])        (each dS scaled by 1 / #values)

Only the first argument gets a gradient; ``ssim.ssim`` uses this path for CPU float32 (H, W, C) images where the
second needs none, the torch one otherwise.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

_JIT = dict(cache=True, nogil=True)
C1 = 0.01**2
C2 = 0.03**2


@njit(parallel=True, **_JIT)
def _blur(src, w, out):
    """out[p] = the separable blur of plane src[p] by window w (odd length), zero padding, same size. Each row is
    accumulated tap by tap over a zero-padded copy, loops that vectorise."""
    n_planes, h, wd = src.shape
    n_taps = w.shape[0]
    r = n_taps // 2
    tmp = np.empty_like(src)
    for job in prange(n_planes * h):
        p, y = job // h, job % h
        pad = np.zeros(wd + 2 * r, np.float32)
        pad[r:r + wd] = src[p, y]
        acc = np.zeros(wd, np.float32)
        for k in range(n_taps):
            wk = w[k]
            for x in range(wd):
                acc[x] += wk * pad[x + k]
        tmp[p, y] = acc
    for job in prange(n_planes * h):
        p, y = job // h, job % h
        acc = np.zeros(wd, np.float32)
        for k in range(n_taps):
            yy = y + k - r
            if 0 <= yy < h:
                wk = w[k]
                for x in range(wd):
                    acc[x] += wk * tmp[p, yy, x]
        out[p, y] = acc


@njit(parallel=True, **_JIT)
def _ssim_terms(blurred, n_ch, scale, s_map, grads):
    """From blurred = [mu_x, mu_y, E[x^2], E[y^2], E[xy]] per channel (5 C planes): s_map (C, H, W) the SSIM
    map, grads (3 C planes) its derivatives by mu_x, E[x^2] and E[xy], times ``scale``."""
    _, h, wd = s_map.shape
    for job in prange(n_ch * h):
        c, y = job // h, job % h
        for x in range(wd):
            mx = blurred[c, y, x]
            my = blurred[n_ch + c, y, x]
            mxx = mx * mx
            myy = my * my
            mxy = mx * my
            sxx = blurred[2 * n_ch + c, y, x] - mxx
            syy = blurred[3 * n_ch + c, y, x] - myy
            sxy = blurred[4 * n_ch + c, y, x] - mxy
            a1 = 2.0 * mxy + C1
            a2 = 2.0 * sxy + C2
            b1 = mxx + myy + C1
            b2 = sxx + syy + C2
            inv = 1.0 / (b1 * b2)
            s = a1 * a2 * inv
            s_map[c, y, x] = s
            grads[c, y, x] = scale * 2.0 * inv * (my * (a2 - a1) - mx * s * (b2 - b1))
            grads[n_ch + c, y, x] = -scale * s / b2
            grads[2 * n_ch + c, y, x] = scale * 2.0 * a1 * inv


@njit(parallel=True, **_JIT)
def _combine(gb, x, y, n_ch, out):
    """out (C, H, W) = gb[mu] + 2 x gb[E x^2] + y gb[E xy] (the blurred derivatives, planar)."""
    _, h, wd = out.shape
    for job in prange(n_ch * h):
        c, r = job // h, job % h
        for i in range(wd):
            out[c, r, i] = gb[c, r, i] + 2.0 * x[c, r, i] * gb[n_ch + c, r, i] + y[c, r, i] * gb[2 * n_ch + c, r, i]


class _SSIM(torch.autograd.Function):
    @staticmethod
    def forward(ctx, img, target, window):
        x = np.ascontiguousarray(img.detach().numpy().transpose(2, 0, 1))
        y = np.ascontiguousarray(target.detach().numpy().transpose(2, 0, 1))
        n_ch, h, wd = x.shape
        maps = np.concatenate([x, y, x * x, y * y, x * y])
        blurred = np.empty_like(maps)
        _blur(maps, window, blurred)
        s_map = np.empty_like(x)
        grads = np.empty((3 * n_ch, h, wd), np.float32)
        _ssim_terms(blurred, n_ch, np.float32(1.0 / x.size), s_map, grads)
        ctx.saved = (x, y, grads, window)
        # the mean in float64, as torch's float32 mean is pairwise: within float32 rounding of it
        return torch.tensor(float(s_map.mean(dtype=np.float64)), dtype=torch.float32)

    @staticmethod
    def backward(ctx, g):
        x, y, grads, window = ctx.saved
        gb = np.empty_like(grads)
        _blur(grads, window, gb)
        out = np.empty_like(x)
        _combine(gb, x, y, x.shape[0], out)
        dx = torch.from_numpy(out.transpose(1, 2, 0).copy()) * g
        return dx, None, None


def ssim_cpu(img: torch.Tensor, target: torch.Tensor, window: np.ndarray) -> torch.Tensor:
    """Mean SSIM (scalar float32 tensor) of img (H, W, C) float32 on the CPU against target (same shape, no
    gradient); differentiable in img. ``window``: the 1D float32 Gaussian window."""
    return _SSIM.apply(img, target, window)
