"""Small Gaussian scenes and helpers for the renderer_gl tests (numpy only; torch where a test compares with the
training rasterizer)."""

from __future__ import annotations

import numpy as np

from renderer_gl import look_at, view

BG = (0.2, 0.3, 0.4)


def camera(width=128, height=96, eye=(0.1, 0.05, -4.0), target=(0.0, 0.0, 0.0), f=150.0, principal=(0.5, 0.5)):
    w2c = look_at(eye, target)
    K = np.array([[f, 0, principal[0] * width + 0.3], [0, f * 1.05, principal[1] * height - 0.3], [0, 0, 1.0]])
    return view(world_to_camera=w2c, K=K, width=width, height=height), w2c, K


def separated_grid(rng, cols=8, rows=6, sh_degree=3, half=(1.2, 0.9), scale=(0.01, 0.05)):
    """Gaussians on a grid in front of ``camera()``, far enough apart that none overlaps another where its
    alpha is at least 1/255 (so draw order cannot matter)."""
    gx, gy = np.meshgrid(np.linspace(-half[0], half[0], cols), np.linspace(-half[1], half[1], rows))
    n = gx.size
    means = np.stack([gx.ravel(), gy.ravel(), rng.uniform(-0.3, 0.3, n)], 1).astype(np.float32)
    scales = rng.uniform(scale[0], scale[1], (n, 3)).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    opac = rng.uniform(0.2, 0.99, n).astype(np.float32)
    sh = (rng.normal(size=(n, (sh_degree + 1) ** 2, 3)) * 0.3).astype(np.float32)
    return means, scales, quats, opac, sh


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def reference_render(means, scales, quats, opac, sh, sh_degree, w2c, K, width, height, background=BG,
                     mode="RGB", backend="torch"):
    """The training rasterizer's image (H, W, C) and alpha (H, W) as numpy. The torch backend: the reference
    every backend is held to, and independent of the numba kernels' state."""
    import torch

    from training.raster.rasterize import rasterize

    t = lambda a: torch.as_tensor(np.array(a, np.float32))  # a copy: snapshots are read-only  # noqa: E731
    img, alpha, _ = rasterize(t(means), t(quats), t(scales), t(opac), t(sh), t(w2c), t(K), width, height,
                              sh_degree=sh_degree, background=t(background), render_mode=mode, backend=backend)
    return img.numpy(), alpha[..., 0].numpy()
