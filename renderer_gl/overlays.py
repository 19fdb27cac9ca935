"""World-space line overlays drawn over the splats: camera frustums and a polyline through camera centres.

They are drawn after the splats without a depth test, so they stay visible in front of them (the splats write
no depth: a splat's depth is spread over its whole footprint and has no single value to test against).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Lines:
    """Line segments: ``segments`` (M, 2, 3) world endpoints, ``colors`` (M, 4) RGBA in [0, 1]."""

    segments: np.ndarray
    colors: np.ndarray

    def __post_init__(self) -> None:
        self.segments = np.asarray(self.segments, dtype=np.float32).reshape(-1, 2, 3)
        colors = np.asarray(self.colors, dtype=np.float32)
        if colors.ndim == 1:
            colors = np.broadcast_to(colors, (len(self.segments), colors.shape[0]))
        if colors.shape[-1] == 3:
            colors = np.concatenate([colors, np.ones((len(colors), 1), np.float32)], axis=1)
        self.colors = np.ascontiguousarray(colors.reshape(-1, 4))
        if len(self.colors) != len(self.segments):
            raise ValueError(f"{len(self.segments)} segments but {len(self.colors)} colours")

    def vertex_data(self) -> np.ndarray:
        """(2M, 7) float32 interleaved position and colour."""
        pos = self.segments.reshape(-1, 3)
        col = np.repeat(self.colors, 2, axis=0)
        return np.ascontiguousarray(np.concatenate([pos, col], axis=1), dtype=np.float32)

    @staticmethod
    def join(parts: "list[Lines]") -> "Lines":
        if not parts:
            return Lines(np.zeros((0, 2, 3)), np.zeros((0, 4)))
        return Lines(np.concatenate([p.segments for p in parts]), np.concatenate([p.colors for p in parts]))


def frustum(camera, size: float, color=(1.0, 0.8, 0.1, 1.0)) -> Lines:
    """A pyramid from the camera centre to its image corners at depth ``size``, with a tick above the top edge
    so that the image's up is visible. ``camera`` is any camera-like object (see renderer_gl.camera)."""
    from renderer_gl.camera import view

    v = view(camera)
    # the image's corners and the tick's tip (above the top edge's middle) at depth size
    k = v.unproject([0, v.width, v.width, 0], [0, 0, v.height, v.height], size)
    tip, c = v.unproject(v.width / 2, -0.15 * v.height, size), v.center
    segs = [(c, k[i]) for i in range(4)] + [(k[i], k[(i + 1) % 4]) for i in range(4)] + [(k[0], tip), (tip, k[1])]
    return Lines(np.array(segs), color)


def frustums(cameras, size: float, colors=None) -> Lines:
    """Frustums of several cameras; ``colors`` one RGBA per camera (default: one colour for all)."""
    parts = []
    for i, cam in enumerate(cameras):
        parts.append(frustum(cam, size) if colors is None else frustum(cam, size, colors[i]))
    return Lines.join(parts)


def polyline(points, color=(0.2, 0.9, 1.0, 1.0)) -> Lines:
    """Segments joining consecutive ``points`` (P, 3); ``color`` one RGBA, or one per segment (P - 1, 4)."""
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    if len(p) < 2:
        return Lines(np.zeros((0, 2, 3)), np.zeros((0, 4)))
    return Lines(np.stack([p[:-1], p[1:]], axis=1), color)
