"""The painting a scene is stylized after: read, checked, and prepared at the resolution the features need.

Reading goes through ``training.scene.image_io`` (grey becomes RGB, 8/16-bit and float are scaled to [0, 1], a file that
cannot be decoded is an ``InputError``). Here we add what stylization needs: enough pixels for VGG features to hold
any texture, and ARF's preparation for the loss: resized so that its long side matches the render's long side, then
halved together with the render.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from training.core.errors import InputError

MIN_STYLE_SIDE = 64  # below this, relu3 features (1/4 resolution, then halved) are a handful of vectors


def check_style_array(image: np.ndarray, path: str | Path | None = None) -> np.ndarray:
    """Validate an in-memory style image; returns it as contiguous float32 (H, W, 3) in [0, 1]."""
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] not in (1, 3, 4):
        raise InputError(path, f"style image must be (H, W, 3) RGB, got shape {tuple(arr.shape)}")
    if arr.shape[2] == 1:
        arr = np.repeat(arr, 3, axis=2)
    arr = arr[..., :3]
    if np.issubdtype(arr.dtype, np.integer):
        arr = arr.astype(np.float64) / float(np.iinfo(arr.dtype).max)
    arr = np.ascontiguousarray(np.clip(np.nan_to_num(arr.astype(np.float32), nan=0.0), 0.0, 1.0))
    h, w = arr.shape[:2]
    if min(h, w) < MIN_STYLE_SIDE:
        raise InputError(path, f"style image is only {w}x{h} pixels; at least {MIN_STYLE_SIDE} pixels on each "
                               "side are needed for its texture to show")
    return arr


def load_style_image(path: str | Path) -> np.ndarray:
    """Read and check a painting: float32 (H, W, 3) in [0, 1]."""
    from training.scene.image_io import read_image

    path = Path(path)
    if path.is_dir():
        raise InputError(path, "style image is a folder, expected an image file")
    return check_style_array(read_image(path), path)


def style_for_render(style: np.ndarray, render_long_side: int) -> torch.Tensor:
    """(1, 3, h, w) style image whose long side equals ``render_long_side`` (area-averaged when shrinking)."""
    t = torch.from_numpy(np.ascontiguousarray(style, dtype=np.float32)).permute(2, 0, 1)[None]
    h, w = t.shape[-2:]
    scale = render_long_side / max(h, w)
    size = (max(1, int(round(h * scale))), max(1, int(round(w * scale))))
    if size == (h, w):
        return t
    return F.interpolate(t, size=size, mode="bilinear", align_corners=False, antialias=scale < 1).clamp(0, 1)


def halve(image: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W) -> (B, C, H/2, W/2), bilinear at scale 0.5 (a 2x2 average), as ARF before VGG."""
    return F.interpolate(image, scale_factor=0.5, mode="bilinear", align_corners=False)
