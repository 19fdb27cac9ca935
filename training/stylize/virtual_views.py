"""Virtual cameras between consecutive views, so that sparse captures still give the guidance overlapping views.

The paper (supplementary, view order) names camera interpolation as the remedy for sparse or irregular
trajectories. Between two consecutive cameras of the stylization order we insert N cameras: rotation by slerp of
the camera-to-world rotations, centre by linear interpolation, intrinsics (and image size) by linear interpolation.
A virtual view has no photo; its content target is the scene rendered before stylization.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from training.scene.scene import Camera


@dataclass
class ViewItem:
    """One entry of the stylization trajectory: a camera and, for a real view, the index of its photo."""

    camera: Camera
    source_index: int | None  # index into Scene.cameras/images; None for a virtual view

    @property
    def is_virtual(self) -> bool:
        return self.source_index is None


def rotation_to_quat(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix to a unit quaternion (w, x, y, z) with w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = np.empty(4)
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def quat_to_rotation(q: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z), normalised here, to a (3, 3) rotation matrix."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions along the shorter arc; t=0 gives q0, t=1 gives q1 (up to
    sign, which is the same rotation)."""
    q0 = np.asarray(q0, dtype=np.float64) / np.linalg.norm(q0)
    q1 = np.asarray(q1, dtype=np.float64) / np.linalg.norm(q1)
    dot = float(np.dot(q0, q1))
    if dot < 0.0:  # q and -q are the same rotation: take the short way round
        q1, dot = -q1, -dot
    if dot > 0.9995:  # nearly parallel: the sine ratio is ill-conditioned, and lerp is exact to first order
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    s = np.sin(theta)
    return (np.sin((1 - t) * theta) * q0 + np.sin(t * theta) * q1) / s


def interpolate_camera(c0: Camera, c1: Camera, t: float, name: str | None = None) -> Camera:
    """The camera a fraction ``t`` of the way from c0 to c1 (slerp rotation, lerp centre, lerp intrinsics)."""
    R0 = c0.camera_to_world[:3, :3]
    R1 = c1.camera_to_world[:3, :3]
    R = quat_to_rotation(slerp(rotation_to_quat(R0), rotation_to_quat(R1), t))
    center = (1 - t) * c0.center + t * c1.center
    w2c = np.eye(4)
    w2c[:3, :3] = R.T
    w2c[:3, 3] = -R.T @ center
    lerp = lambda a, b: (1 - t) * a + t * b  # noqa: E731
    return Camera(
        name=name or f"virtual_{c0.name}_{c1.name}_{t:.3f}",
        width=int(round(lerp(c0.width, c1.width))),
        height=int(round(lerp(c0.height, c1.height))),
        fx=lerp(c0.fx, c1.fx), fy=lerp(c0.fy, c1.fy), cx=lerp(c0.cx, c1.cx), cy=lerp(c0.cy, c1.cy),
        world_to_camera=w2c,
    )


def trajectory(cameras: Sequence[Camera], order: Sequence[int], virtual_views: int = 0) -> list[ViewItem]:
    """The views in ``order`` with ``virtual_views`` interpolated cameras between each consecutive pair."""
    items: list[ViewItem] = []
    for pos, idx in enumerate(order):
        items.append(ViewItem(cameras[idx], int(idx)))
        if virtual_views > 0 and pos + 1 < len(order):
            nxt = order[pos + 1]
            for k in range(1, virtual_views + 1):
                t = k / (virtual_views + 1)
                cam = interpolate_camera(cameras[idx], cameras[nxt], t,
                                         name=f"virtual_{idx:04d}_{int(nxt):04d}_{k}")
                items.append(ViewItem(cam, None))
    return items
