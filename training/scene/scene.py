"""The scene every loader produces and every trainer consumes: cameras, images, SfM points, split, normalisation.

Conventions (shared by the whole code base):
- Cameras are ``training.scene.camera.Camera`` (OpenCV axes, pinhole intrinsics in pixels), for the image as stored
  in ``Scene.images`` (so they are scaled together with ``--downscale``).
- Images are float32 RGB in [0, 1], shape (H, W, 3); masks, where present, float32 (H, W) in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from training.scene.camera import Camera

__all__ = ["Camera", "LLFF_HOLDOUT", "Scene", "camera_normalization", "llff_split", "over_background"]

LLFF_HOLDOUT = 8  # every 8th view is held out for testing (the LLFF / 3DGS convention)


@dataclass
class Scene:
    cameras: list[Camera]
    images: list[np.ndarray]  # each (H, W, 3) float32 in [0, 1], matching cameras[i].height/width
    masks: list[np.ndarray | None] = field(default_factory=list)  # each (H, W) float32 or None
    points: np.ndarray | None = None  # (P, 3) float32 SfM points, world coordinates
    point_colors: np.ndarray | None = None  # (P, 3) float32 in [0, 1]
    source: Path | None = None  # the folder or file the scene was loaded from
    train_indices: list[int] = field(default_factory=list)
    test_indices: list[int] = field(default_factory=list)
    center: np.ndarray | None = None  # (3,) world-space centre of the cameras; computed when None
    extent: float | None = None  # radius enclosing the cameras x1.1 (3DGS's cameras_extent); computed when None

    def __post_init__(self) -> None:
        if not self.masks:
            self.masks = [None] * len(self.cameras)
        if not self.train_indices and not self.test_indices:
            self.train_indices, self.test_indices = llff_split(len(self.cameras))
        if self.center is None or self.extent is None:
            center, extent = camera_normalization(self.cameras) if self.cameras else (np.zeros(3), 1.0)
            self.center = center if self.center is None else np.asarray(self.center, dtype=np.float64)
            self.extent = extent if self.extent is None else float(self.extent)

    @property
    def num_points(self) -> int:
        return 0 if self.points is None else int(len(self.points))


def llff_split(n: int, holdout: int = LLFF_HOLDOUT) -> tuple[list[int], list[int]]:
    """Every ``holdout``-th view (0, 8, 16, ...) is a test view; with fewer than 2 views, all train."""
    if n < 2:
        return list(range(n)), []
    test = [i for i in range(n) if i % holdout == 0]
    train = [i for i in range(n) if i % holdout != 0]
    return train, test


def camera_normalization(cameras: list[Camera]) -> tuple[np.ndarray, float]:
    """3DGS's getNerfppNorm: centre of the camera positions and 1.1 x the largest distance from it."""
    centers = np.stack([c.center for c in cameras])
    center = centers.mean(axis=0)
    radius = float(np.linalg.norm(centers - center, axis=1).max()) * 1.1
    if radius <= 1e-9:  # a single camera, or all at one point: keep a usable unit scale
        radius = 1.0
    return center, radius


def over_background(image, alpha, background=None):
    """An image with coverage ``alpha`` composited over ``background`` (black when None), as 3DGS trains on RGBA
    captures: ``image * alpha + background * (1 - alpha)``.

    image (H, W, 3), alpha (H, W) or None (then the image is returned as is), background (3,) or None; numpy
    arrays or torch tensors alike. The colour a file stores under alpha 0 is arbitrary, so it must never be a
    training target."""
    if alpha is None:
        return image
    if alpha.ndim == image.ndim - 1:
        alpha = alpha[..., None]
    if background is None:
        return image * alpha
    return image * alpha + background * (1 - alpha)
