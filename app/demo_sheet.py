"""The demo's contact sheet: for a few evenly spaced views, the photo, the reconstruction's render and the stylized
render side by side, with the painting closing the first row: the whole pipeline in one picture."""

from __future__ import annotations

from pathlib import Path

import numpy as np

SHEET_VIEWS = 3
CELL = 256


def render_model(model, camera) -> np.ndarray:
    """(H, W, 3) float32 render of a Gaussians model at ``camera``."""
    import torch

    from training.reconstruct.metrics import render_view

    with torch.no_grad():
        image, _, _ = render_view(model, camera)
    return image.clamp(0, 1).numpy()


def demo_contact_sheet(data: Path, reconstruction: Path, stylized: Path, painting: Path, out: Path,
                       views: int = SHEET_VIEWS) -> Path:
    """Write ``out`` (photo | reconstruction | stylized per row, the painting after the first row)."""
    from training.model.model_io import read_model
    from training.scene.image_grid import grid, shrink_to
    from training.scene.image_io import read_image, write_image
    from training.scene.loader import load_scene
    from training.stylize.config import render_camera
    from training.stylize.pipeline import choose_downscale

    scene = load_scene(data, downscale=choose_downscale(data, CELL))
    recon, styled = read_model(reconstruction), read_model(stylized)
    n = len(scene.cameras)
    picks = sorted({round(k * (n - 1) / max(1, views - 1)) for k in range(min(views, n))})
    rows = []
    for i in picks:
        cam = render_camera(scene.cameras[i], CELL)
        photo = scene.images[i][..., :3]
        rows.append([shrink_to(photo, CELL), render_model(recon, cam), render_model(styled, cam)])
    rows[0].append(shrink_to(read_image(painting), CELL))
    write_image(out, grid(rows))  # atomic
    return out
