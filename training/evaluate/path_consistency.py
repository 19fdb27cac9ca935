"""The stylization papers' consistency protocol on a smooth camera path (docs/evaluation.md, "The path protocol").

StyleRF, ARF and StyleGaussian render a video along a smooth camera path, warp each frame into a later one (at a
frame gap of 1, "short range", and 7, "long range") with the optical flow between them, and report the RMSE and the
LPIPS over the pixels the warp maps validly (occlusions masked out). We render the stylized model along a path
through the dataset's cameras and take the flow from the model's own expected depth and the known cameras (the
depth warp of ``consistency.py``, exact for a surface where an optical-flow network would estimate it; none could be
loaded offline anyway).

The path (``smooth_path``): the cameras in the given order (the cameras' nearest path) are keyframes of
training/scene/pose.py's ``path_camera``, as ``app/camera_path.py``'s video paths: between them the camera centre
follows a centripetal Catmull-Rom spline (C1, no overshoot or loops at unevenly spaced keys), the rotation is
slerped and the intrinsics are interpolated linearly. ``PATH_FRAMES`` (60) frames are spaced evenly in the spline's
parameter, one keyframe interval per unit, first and last frame on the first and last camera.

Unlike the camera-pair measure, every frame here is a new view of the model (none was a training view), so it also
sees what the model shows between the cameras it was stylized at.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from training.evaluate.consistency import consistency_metrics
from training.scene.scene import Camera
from training.scene.pose import path_camera

PATH_FRAMES = 60  # frames along the path (a 2-second clip at 30 fps)
SHORT_GAP = 1
LONG_GAP = 7


def smooth_path(cameras: Sequence[Camera], order: Sequence[int], frames: int = PATH_FRAMES) -> list[Camera]:
    """``frames`` cameras along the smooth path through ``cameras`` in ``order`` (at least 2 of them)."""
    keys = [cameras[int(i)] for i in order]
    if len(keys) < 2:
        raise ValueError(f"a camera path needs at least 2 cameras, got {len(keys)}")
    if frames < 2:
        raise ValueError(f"a camera path needs at least 2 frames, got {frames}")
    return [path_camera(keys, float(u), f"path_{k:03d}")
            for k, u in enumerate(np.linspace(0.0, len(keys) - 1, frames))]


Renderer = Callable[[Sequence[Camera]], tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]]


def path_consistency(render: Renderer, cameras: Sequence[Camera], order: Sequence[int], lpips=None,
                     frames: int = PATH_FRAMES, long_gap: int = LONG_GAP,
                     lpips_pairs: int | None = 8) -> dict[str, float | None]:
    """The protocol's figures for a model: ``render(path_cameras) -> (images, depths, alphas)`` (RGB in [0, 1],
    expected depth and alpha, (H, W, 3) / (H, W, 1) / (H, W, 1)) renders it. Returns ``path_short_rmse``,
    ``_lpips``, ``_valid`` (frames 1 apart), ``path_long_*`` (``long_gap`` apart) and ``path_frames``; RMSE and
    the valid fraction over every pair, LPIPS over ``lpips_pairs`` of them evenly spaced (None: all; no ``lpips``:
    None)."""
    path = smooth_path(cameras, order, frames)
    images, depths, alphas = render(path)
    out: dict[str, float | None] = {"path_frames": float(len(path))}
    for label, gap in (("short", SHORT_GAP), ("long", long_gap)):
        c = consistency_metrics(images, depths, alphas, path, list(range(len(path))), gap, lpips,
                                lpips_pairs=lpips_pairs) or {}
        out[f"path_{label}_rmse"] = c.get("rmse")
        out[f"path_{label}_lpips"] = c.get("lpips")
        out[f"path_{label}_valid"] = c.get("valid_fraction")
    return out
