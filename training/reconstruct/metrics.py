"""Image quality metrics (PSNR, SSIM) and the evaluation of a Gaussian model on a set of views."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import torch

from training.model.gaussians import Gaussians
from training.scene.scene import Camera, Scene, over_background
from training.reconstruct.ssim import ssim

__all__ = ["psnr", "ssim", "render_view", "evaluate_views", "constant_color_psnr"]


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """Peak signal-to-noise ratio in dB of two images in [0, 1] (any equal shapes); inf when identical."""
    mse = float(torch.mean((a.detach().double() - b.detach().double()) ** 2))
    return math.inf if mse == 0.0 else -10.0 * math.log10(mse)


def render_view(
    gaussians: Gaussians,
    camera: Camera,
    *,
    sh_degree: int | None = None,
    background: torch.Tensor | None = None,
    backend: str = "auto",
    render_mode: str = "RGB",
):
    """Render ``gaussians`` from ``camera``; returns rasterize()'s (image (H,W,C), alpha (H,W,1), info)."""
    from training.raster.rasterize import camera_matrices, rasterize

    dev = gaussians.device
    deg = gaussians.sh_degree if sh_degree is None else sh_degree
    ncoef = (deg + 1) ** 2
    return rasterize(
        gaussians.means,
        gaussians.quats,
        gaussians.scales,
        gaussians.opacities,
        gaussians.sh[:, :ncoef],
        *camera_matrices(camera, torch.float32, dev),
        camera.width,
        camera.height,
        sh_degree=deg,
        background=background,
        render_mode=render_mode,
        backend=backend,
    )


@torch.no_grad()
def evaluate_views(
    gaussians: Gaussians,
    scene: Scene,
    indices: Sequence[int],
    *,
    sh_degree: int | None = None,
    background: torch.Tensor | None = None,
    backend: str = "auto",
) -> dict:
    """Mean PSNR and SSIM of the renders of ``gaussians`` against ``scene.images`` at ``indices`` (images with
    alpha composited over the same ``background`` as the renders).

    Returns {"psnr": float | None, "ssim": float | None, "views": int}; None when ``indices`` is empty."""
    from training.core import stop

    psnrs, ssims = [], []
    for i in indices:
        stop.check()
        image, _, _ = render_view(gaussians, scene.cameras[i], sh_degree=sh_degree, background=background,
                                  backend=backend)
        mask = None if scene.masks[i] is None else torch.as_tensor(scene.masks[i], device=image.device)
        target = over_background(torch.as_tensor(scene.images[i], device=image.device), mask, background)
        image = image.clamp(0.0, 1.0)
        psnrs.append(psnr(image, target))
        ssims.append(float(ssim(image, target)))
    if not psnrs:
        return {"psnr": None, "ssim": None, "views": 0}
    return {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims)), "views": len(psnrs)}


def constant_color_psnr(scene: Scene, train_indices: Sequence[int], eval_indices: Sequence[int]) -> float | None:
    """The baseline a model must beat: PSNR of the best single colour (the train images' mean) on eval views."""
    if not eval_indices or not train_indices:
        return None
    mean = np.mean([scene.images[i].reshape(-1, 3).mean(axis=0) for i in train_indices], axis=0)
    vals = [psnr(torch.from_numpy(scene.images[i]), torch.from_numpy(np.broadcast_to(mean, scene.images[i].shape)
                                                                       .astype(np.float32)))
            for i in eval_indices]
    return float(np.mean(vals))
