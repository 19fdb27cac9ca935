"""SSIM against a float64 direct per-pixel computation; PSNR against its definition."""

import math

import numpy as np
import pytest
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


def test_cpu_ssim_kernels_match_the_direct_computation_and_autograd():
    """The numba path (a float32 render on the CPU against a photo) gives the float64 direct SSIM and the gradient
    autograd takes through the torch convolutions, at a training render's size and at sizes below the window."""
    from training.reconstruct.ssim import gaussian_window_1d
    from training.reconstruct.ssim_cpu import ssim_cpu

    rng = np.random.default_rng(3)
    for shape in [(17, 13, 3), (5, 4, 1), (96, 71, 4)]:
        a = rng.uniform(0, 1, shape)
        b = np.clip(a + rng.normal(0, 0.1, shape), 0, 1)
        x = torch.from_numpy(a).float().requires_grad_(True)
        y = torch.from_numpy(b).float()
        fast = ssim_cpu(x, y, gaussian_window_1d().numpy())
        fast.backward()
        if shape[0] < 20:
            assert abs(float(fast.detach()) - _ssim_direct(a, b).mean()) < 2e-6
        ref_x = torch.from_numpy(a).requires_grad_(True)  # float64 through torch's convolutions
        ssim_map(ref_x, torch.from_numpy(b)).mean().backward()
        assert abs(float(fast.detach()) - float(ssim_map(ref_x.detach(), torch.from_numpy(b)).mean())) < 2e-6
        scale = float(ref_x.grad.abs().max())
        assert float((x.grad.double() - ref_x.grad).abs().max()) < 1e-5 * scale
    # ssim() takes this path for such inputs, and the torch one where the target needs a gradient
    assert ssim(x.detach(), y).grad_fn is None and float(ssim(x.detach(), y)) == pytest.approx(float(fast.detach()), abs=1e-7)
    y.requires_grad_(True)
    assert "Mean" in type(ssim(x.detach(), y).grad_fn).__name__
