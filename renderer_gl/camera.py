"""The pinhole camera renderer_gl draws with, and the matrices derived from it.

Any object with ``world_to_camera`` (4x4, OpenCV axes: x right, y down, z forward), ``fx``, ``fy``, ``cx``,
``cy``, ``width`` and ``height`` is accepted (the project's ``training.scene.scene.Camera`` is one); ``view()``
turns it into a ``View``. Pixel (x, y) is centred at (x + 0.5, y + 0.5), as in the training rasterizer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class View:
    world_to_camera: np.ndarray  # (4, 4) float64
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @property
    def center(self) -> np.ndarray:
        R, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -R.T @ t

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def forward(self) -> np.ndarray:
        f = self.world_to_camera[2, :3]
        return f / np.linalg.norm(f)

    def scaled(self, factor: float) -> "View":
        """The same camera for an image resized by ``factor`` (a lower resolution while the camera moves)."""
        w = max(1, int(round(self.width * factor)))
        h = max(1, int(round(self.height * factor)))
        sx, sy = w / self.width, h / self.height
        return View(self.world_to_camera, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, w, h)

    def jacobian_limits(self) -> tuple[float, float, float, float]:
        """The training rasterizer's clamp of x/z and y/z for the EWA Jacobian: 1.3x the field of view."""
        from renderer_gl.constants import FOV_CLAMP_MARGIN as m

        tan_x = 0.5 * self.width / self.fx
        tan_y = 0.5 * self.height / self.fy
        return (
            (self.width - self.cx) / self.fx + m * tan_x,
            self.cx / self.fx + m * tan_x,
            (self.height - self.cy) / self.fy + m * tan_y,
            self.cy / self.fy + m * tan_y,
        )

    def clip_from_world(self, near: float, far: float) -> np.ndarray:
        """(4, 4) OpenGL clip-space matrix: pixel (u, v) of this camera lands where the splats put it."""
        W, H = float(self.width), float(self.height)
        proj = np.array([
            [2 * self.fx / W, 0.0, 2 * self.cx / W - 1.0, 0.0],
            [0.0, -2 * self.fy / H, 1.0 - 2 * self.cy / H, 0.0],
            [0.0, 0.0, (far + near) / (far - near), -2 * far * near / (far - near)],
            [0.0, 0.0, 1.0, 0.0],
        ])
        return proj @ self.world_to_camera


def view(camera=None, *, world_to_camera=None, K=None, width=None, height=None) -> View:
    """A ``View`` from a camera-like object, or from plain matrices (``world_to_camera`` 4x4, ``K`` 3x3)."""
    if isinstance(camera, View):
        return camera
    if camera is not None:
        w2c = camera.world_to_camera
        fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
        width, height = camera.width, camera.height
    else:
        if world_to_camera is None or K is None or width is None or height is None:
            raise ValueError("view() needs a camera, or world_to_camera, K, width and height")
        w2c = world_to_camera
        K = np.asarray(K, dtype=np.float64)
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    w2c = np.asarray(w2c, dtype=np.float64)
    if w2c.shape != (4, 4) or not np.isfinite(w2c).all():
        raise ValueError(f"world_to_camera must be a finite 4x4 matrix, got shape {w2c.shape}")
    if int(width) < 1 or int(height) < 1 or not (fx > 0 and fy > 0):
        raise ValueError(f"bad camera: {width}x{height}, fx={fx}, fy={fy}")
    return View(w2c, float(fx), float(fy), float(cx), float(cy), int(width), int(height))


def look_at(eye, target, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """(4, 4) world-to-camera (OpenCV axes) for a camera at ``eye`` looking at ``target``; ``up`` is the world
    direction that should appear up in the image (OpenCV's y axis points down, hence the default)."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(-up, z)  # image right; -up because image y points down
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return w2c


def orbit(center, radius: float, count: int, up, elevation_deg: float = 20.0, start=None) -> list[np.ndarray]:
    """``count`` world-to-camera matrices evenly spaced on a circle around ``center`` (perpendicular to ``up``),
    raised by ``elevation_deg``, all looking at ``center``. ``start`` (a world direction) fixes the first one."""
    center, up = np.asarray(center, dtype=np.float64), np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    a = np.asarray(start, dtype=np.float64) if start is not None else np.array([1.0, 0.0, 0.0])
    a = a - up * (a @ up)
    if np.linalg.norm(a) < 1e-9:
        a = np.cross(up, [0.0, 0.0, 1.0]) if abs(up[2]) < 0.9 else np.cross(up, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    el = np.radians(elevation_deg)
    mats = []
    for k in range(count):
        th = 2 * np.pi * k / count
        d = np.cos(el) * (np.cos(th) * a + np.sin(th) * b) + np.sin(el) * up
        mats.append(look_at(center + radius * d, center, up))
    return mats
