"""What a user looks at after a reconstruction: OUT/renders/ and OUT/contact_sheet.png, with PSNR, SSIM and LPIPS
per test view.

For every evaluation view (the test views; the training views when there are none): ``NNN_<name>.png`` holds the
photo and the render side by side, ``NNN_<name>_depth.png`` the rendered depth (near bright). The contact sheet
stacks up to ``SHEET_VIEWS`` of them, one row per view (photo | render | depth), shrunk to ``SHEET_CELL`` px.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from training.core import stop
from training.reconstruct.metrics import psnr, render_view
from training.reconstruct.ssim import ssim
from training.scene.image_grid import depth_image, grid, shrink_to, side_by_side
from training.scene.image_io import write_image
from training.scene.scene import over_background

SHEET_VIEWS = 8
SHEET_CELL = 320
CONTACT_SHEET = "contact_sheet.png"


def _safe_name(name: str) -> str:
    stem = Path(name).stem
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in stem) or "view"


@torch.no_grad()
def write_view_results(trainer, out: Path, indices: Sequence[int], lpips=None,
                       log: Callable[[str], None] | None = None) -> dict:
    """Render ``indices`` with the trainer's model, write renders and the contact sheet, return the metrics:
    {"views": [{"index", "name", "psnr", "ssim", "lpips"}], "psnr", "ssim", "lpips" (means), "contact_sheet"}."""
    scene = trainer.scene
    background = trainer.eval_background()
    renders = out / "renders"
    rows, views = [], []
    for k, i in enumerate(indices):
        stop.check()
        cam = scene.cameras[i]
        image, alpha, _ = render_view(trainer.gaussians, cam, sh_degree=trainer.active_sh_degree,
                                      background=background, backend=trainer.config.backend,
                                      render_mode="RGB+ED")
        rgb = image[..., :3].clamp(0.0, 1.0)
        mask = None if scene.masks[i] is None else torch.as_tensor(scene.masks[i], device=rgb.device)
        target = over_background(torch.as_tensor(scene.images[i], device=rgb.device), mask, background)
        entry = {"index": int(i), "name": cam.name, "psnr": psnr(rgb, target), "ssim": float(ssim(rgb, target))}
        if lpips is not None:
            entry["lpips"] = float(lpips(rgb.cpu(), target.cpu())[0])
        views.append(entry)
        photo_np, render_np = target.cpu().numpy(), rgb.cpu().numpy()
        depth_np = depth_image(image[..., 3].cpu().numpy(), alpha[..., 0].cpu().numpy() > 0.5)
        base = f"{k:03d}_{_safe_name(cam.name)}"
        write_image(renders / f"{base}.png", side_by_side(photo_np, render_np))
        write_image(renders / f"{base}_depth.png", depth_np)
        if len(rows) < SHEET_VIEWS:
            rows.append([shrink_to(a, SHEET_CELL) for a in (photo_np, render_np, depth_np)])
    result: dict = {"views": views}
    for key in ("psnr", "ssim", "lpips"):
        vals = [v[key] for v in views if key in v]
        result[key] = float(np.mean(vals)) if vals else None
    if rows:
        write_image(out / CONTACT_SHEET, grid(rows))
        result["contact_sheet"] = CONTACT_SHEET
    if log is not None:
        log(f"wrote {len(views)} views to {renders} and {out / CONTACT_SHEET}")
    return result
