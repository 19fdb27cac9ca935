"""Pictures made of pictures: photo | render pairs and contact sheets, as float (H, W, 3) arrays in [0, 1].

Images of different sizes are letterboxed onto the cell size of their column (grey background), so a sheet of
views with slightly different sizes still lines up. No text is drawn: the files beside a sheet name its views.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

GAP = 4
BACKGROUND = 0.2


def as_rgb(image: np.ndarray) -> np.ndarray:
    """(H, W), (H, W, 1), (H, W, 3) or (H, W, 4) -> (H, W, 3) float32 in [0, 1] (alpha dropped)."""
    a = np.asarray(image, dtype=np.float32)
    if a.ndim == 2:
        a = a[..., None]
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return np.clip(np.nan_to_num(a[..., :3]), 0.0, 1.0)


def _fit(image: np.ndarray, height: int, width: int) -> np.ndarray:
    cell = np.full((height, width, 3), BACKGROUND, dtype=np.float32)
    h, w = min(height, image.shape[0]), min(width, image.shape[1])
    y, x = (height - h) // 2, (width - w) // 2
    cell[y:y + h, x:x + w] = image[:h, :w]
    return cell


def grid(rows: Sequence[Sequence[np.ndarray]], gap: int = GAP) -> np.ndarray:
    """The images laid out row by row with ``gap`` pixels between them; rows may have different lengths."""
    rows = [[as_rgb(im) for im in row] for row in rows if len(row)]
    if not rows:
        raise ValueError("nothing to lay out")
    ncols = max(len(r) for r in rows)
    widths = [max(r[c].shape[1] for r in rows if c < len(r)) for c in range(ncols)]
    heights = [max(im.shape[0] for im in r) for r in rows]
    out = np.full((sum(heights) + gap * (len(rows) + 1), sum(widths) + gap * (ncols + 1), 3), BACKGROUND,
                  dtype=np.float32)
    y = gap
    for r, row in enumerate(rows):
        x = gap
        for c in range(ncols):
            if c < len(row):
                out[y:y + heights[r], x:x + widths[c]] = _fit(row[c], heights[r], widths[c])
            x += widths[c] + gap
        y += heights[r] + gap
    return out


def side_by_side(*images: np.ndarray, gap: int = GAP) -> np.ndarray:
    return grid([list(images)], gap=gap)


def shrink_to(image: np.ndarray, max_side: int) -> np.ndarray:
    """The image scaled down (area average over whole-pixel blocks) until its long side is at most max_side."""
    image = as_rgb(image)
    f = int(np.ceil(max(image.shape[:2]) / max(1, max_side)))
    if f <= 1:
        return image
    h, w = image.shape[0] // f * f, image.shape[1] // f * f
    return image[:h, :w].reshape(h // f, f, w // f, f, 3).mean(axis=(1, 3))


def depth_image(depth: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Depth as grey, near bright: inverse depth stretched between its 2nd and 98th percentiles; invalid black."""
    depth = np.asarray(depth, dtype=np.float64)
    ok = np.isfinite(depth) & (depth > 0)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    inv = np.zeros_like(depth)
    inv[ok] = 1.0 / depth[ok]
    if ok.any():
        lo, hi = np.percentile(inv[ok], [2, 98])
        inv = np.where(ok, (inv - lo) / max(hi - lo, 1e-12), 0.0)
    return as_rgb(np.clip(inv, 0.0, 1.0).astype(np.float32))
