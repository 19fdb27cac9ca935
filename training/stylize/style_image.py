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
FLOAT_FORMATS = (".exr", ".hdr", ".tif", ".tiff", ".pfm")  # the ones that can hold NaN and inf


def _nonfinite_pixels(path: Path) -> int:
    """Pixels with a NaN or infinite channel in a float image file. The reader maps them to 0 (black) for the
    scenes' photos; a painting made of them would be stylized toward black without a word, so we look first."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        return 0  # the reader below reports the file's real problem
    try:
        spec = inp.spec()
        data = inp.read_image(0, 0, 0, spec.nchannels, "float")
    finally:
        inp.close()
    if data is None:
        return 0
    data = np.asarray(data, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    return int((~np.isfinite(data)).any(axis=2).sum())


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
    bad = ~np.isfinite(arr)
    if bad.any():
        # zeroing them would stylize toward a black painting without a word (an EXR with NaN or inf pixels)
        n = int(bad.any(axis=2).sum())
        raise InputError(path, f"style image has {n} pixels that are NaN or infinite; give a painting with "
                               "finite colours (e.g. an 8-bit PNG or JPEG)")
    arr = np.ascontiguousarray(np.clip(arr.astype(np.float32), 0.0, 1.0))
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
    image = read_image(path)  # first: a missing or corrupt file gets the reader's message
    if path.suffix.lower() in FLOAT_FORMATS and (n := _nonfinite_pixels(path)):
        raise InputError(path, f"style image has {n} pixels that are NaN or infinite; give a painting with "
                               "finite colours (e.g. an 8-bit PNG or JPEG)")
    return check_style_array(image, path)


def painting_side(render_long_side: int, style_scale: float) -> int:
    """The painting's long side for a render's: ``style_scale`` times it (neural-style's ``-style_scale``; 1 is
    ARF's and the paper's, the painting as large as the render)."""
    return max(1, int(round(render_long_side * style_scale)))


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
