"""Structural similarity (SSIM) as 3DGS computes it: an 11x11 Gaussian window (sigma 1.5), zero padding, mean map.

Differentiable in both arguments. The 2D window is separable, so it is applied as two 1D convolutions (the same
numbers as 3DGS's outer-product window, in fewer operations). ``ssim`` of a CPU float32 (H, W, C) image against one
that needs no gradient (a training step's render against its photo) runs on numba kernels (ssim_cpu.py, several
times faster); everything else on torch's convolutions.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

C1 = 0.01**2  # (K1 * L)^2 with L = 1
C2 = 0.03**2  # (K2 * L)^2


def gaussian_window_1d(size: int = 11, sigma: float = 1.5, dtype=torch.float32, device=None) -> torch.Tensor:
    """(size,) normalised Gaussian weights centred on the middle tap."""
    x = torch.arange(size, dtype=torch.float64) - size // 2
    w = torch.exp(-(x**2) / (2.0 * sigma**2))
    return (w / w.sum()).to(dtype=dtype, device=device)


def _as_bchw(img: torch.Tensor) -> torch.Tensor:
    if img.dim() == 3:  # (H, W, C), the rasterizer's layout
        return img.permute(2, 0, 1).unsqueeze(0)
    if img.dim() == 4:  # (B, C, H, W)
        return img
    raise ValueError(f"ssim expects (H, W, C) or (B, C, H, W) images, got shape {tuple(img.shape)}")


def _blur(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Depthwise Gaussian blur of (B, C, H, W) with zero padding (same size out)."""
    c = x.shape[1]
    k = w.numel()
    wx = w.view(1, 1, 1, k).expand(c, 1, 1, k)
    wy = w.view(1, 1, k, 1).expand(c, 1, k, 1)
    x = F.conv2d(x, wx, padding=(0, k // 2), groups=c)
    return F.conv2d(x, wy, padding=(k // 2, 0), groups=c)


def ssim_map(a: torch.Tensor, b: torch.Tensor, window_size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Per-pixel SSIM, (B, C, H, W), for images in [0, 1] given as (H, W, C) or (B, C, H, W)."""
    x, y = _as_bchw(a), _as_bchw(b)
    if x.shape != y.shape:
        raise ValueError(f"ssim: shapes differ: {tuple(x.shape)} vs {tuple(y.shape)}")
    w = gaussian_window_1d(window_size, sigma, dtype=x.dtype, device=x.device)
    mu_x, mu_y = _blur(x, w), _blur(y, w)
    mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
    s_xx = _blur(x * x, w) - mu_xx
    s_yy = _blur(y * y, w) - mu_yy
    s_xy = _blur(x * y, w) - mu_xy
    return ((2 * mu_xy + C1) * (2 * s_xy + C2)) / ((mu_xx + mu_yy + C1) * (s_xx + s_yy + C2))


def ssim(a: torch.Tensor, b: torch.Tensor, window_size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM (scalar tensor) of two images in [0, 1], (H, W, C) or (B, C, H, W)."""
    if (a.dim() == 3 and a.shape == b.shape and a.device.type == "cpu" and b.device.type == "cpu"
            and a.dtype == torch.float32 and b.dtype == torch.float32 and not b.requires_grad and window_size % 2):
        from training.reconstruct.ssim_cpu import ssim_cpu

        return ssim_cpu(a, b, gaussian_window_1d(window_size, sigma).numpy())
    return ssim_map(a, b, window_size, sigma).mean()
