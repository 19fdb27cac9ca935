"""The pinhole camera renderer_gl draws with (``training.scene.camera.Camera``, numpy only) and what the renderer
derives from it.

Any object with ``world_to_camera`` (4x4, OpenCV axes: x right, y down, z forward), ``fx``, ``fy``, ``cx``,
``cy``, ``width`` and ``height`` is accepted; ``view()`` checks it and gives a ``Camera``. Pixel (x, y) is centred at
(x + 0.5, y + 0.5), as in the training rasterizer.
"""

from __future__ import annotations

import numpy as np

from training.scene.camera import Camera


def jacobian_limits(camera: Camera) -> tuple[float, float, float, float]:
    """The training rasterizer's clamp of x/z and y/z for the EWA Jacobian: 1.3x the field of view."""
    from renderer_gl.constants import FOV_CLAMP_MARGIN as m

    tan_x = 0.5 * camera.width / camera.fx
    tan_y = 0.5 * camera.height / camera.fy
    return (
        (camera.width - camera.cx) / camera.fx + m * tan_x,
        camera.cx / camera.fx + m * tan_x,
        (camera.height - camera.cy) / camera.fy + m * tan_y,
        camera.cy / camera.fy + m * tan_y,
    )


def view(camera=None, *, world_to_camera=None, K=None, width=None, height=None) -> Camera:
    """A checked ``Camera`` from a camera-like object, or from plain matrices (``world_to_camera`` 4x4, ``K``
    3x3)."""
    if camera is not None:
        w2c = camera.world_to_camera
        fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
        width, height = camera.width, camera.height
        name = getattr(camera, "name", "view")
    else:
        if world_to_camera is None or K is None or width is None or height is None:
            raise ValueError("view() needs a camera, or world_to_camera, K, width and height")
        w2c = world_to_camera
        K = np.asarray(K, dtype=np.float64)
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        name = "view"
    w2c = np.asarray(w2c, dtype=np.float64)
    if w2c.shape != (4, 4) or not np.isfinite(w2c).all():
        raise ValueError(f"world_to_camera must be a finite 4x4 matrix, got shape {w2c.shape}")
    if int(width) < 1 or int(height) < 1 or not (fx > 0 and fy > 0):
        raise ValueError(f"bad camera: {width}x{height}, fx={fx}, fy={fy}")
    return Camera(name, int(width), int(height), float(fx), float(fy), float(cx), float(cy), w2c)


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
