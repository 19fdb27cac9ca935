"""SSIM against a float64 direct per-pixel computation; PSNR against its definition."""

import math

import numpy as np
import torch

from training.reconstruct.metrics import psnr
from training.reconstruct.ssim import ssim, ssim_map


def _ssim_direct(x: np.ndarray, y: np.ndarray, size: int = 11, sigma: float = 1.5) -> np.ndarray:
    """(H, W, C) float64 -> per-pixel SSIM, looping over every window explicitly with zero padding."""
    r = size // 2
    g = np.exp(-((np.arange(size) - r) ** 2) / (2 * sigma**2))
    w2 = np.outer(g, g) / np.outer(g, g).sum()
    h, wd, c = x.shape
    xp = np.pad(x, ((r, r), (r, r), (0, 0)))
    yp = np.pad(y, ((r, r), (r, r), (0, 0)))
    out = np.empty_like(x)
    c1, c2 = 0.01**2, 0.03**2
    for i in range(h):
        for j in range(wd):
            for k in range(c):
                px = xp[i:i + size, j:j + size, k]
                py = yp[i:i + size, j:j + size, k]
                mx, my = (w2 * px).sum(), (w2 * py).sum()
                vx = (w2 * px * px).sum() - mx * mx
                vy = (w2 * py * py).sum() - my * my
                cxy = (w2 * px * py).sum() - mx * my
                out[i, j, k] = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return out


def test_ssim_matches_direct_float64():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 1, (17, 13, 3))
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1)
    ref = _ssim_direct(a, b)
    got = ssim_map(torch.from_numpy(a), torch.from_numpy(b))[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(got, ref, atol=1e-10)
    got32 = float(ssim(torch.from_numpy(a).float(), torch.from_numpy(b).float()))
    assert abs(got32 - ref.mean()) < 1e-5


def test_ssim_identity_and_batch_layout():
    rng = np.random.default_rng(1)
    a = torch.from_numpy(rng.uniform(0, 1, (12, 10, 3)))
    assert abs(float(ssim(a, a)) - 1.0) < 1e-12
    b = a.flip(0)
    assert float(ssim(a, b)) < 0.5
    assert abs(float(ssim(a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None])) - float(ssim(a, b))) < 1e-12


def test_ssim_gradient_matches_finite_differences():
    rng = np.random.default_rng(2)
    a = torch.from_numpy(rng.uniform(0, 1, (8, 9, 1))).requires_grad_(True)
    b = torch.from_numpy(rng.uniform(0, 1, (8, 9, 1)))
    assert torch.autograd.gradcheck(lambda x: ssim(x, b), (a,), eps=1e-6, atol=1e-6)


def test_psnr_definition():
    a = torch.zeros(4, 4, 3)
    b = torch.full((4, 4, 3), 0.1)
    assert abs(psnr(a, b) - 20.0) < 1e-5  # mse 0.01 -> 20 dB (0.1 in float32)
    assert psnr(a, a) == math.inf
