"""The pinhole camera renderer_gl draws with (``training.scene.camera.Camera``, numpy only; its pose maths, look-at
and orbits among them, is training/scene/pose.py's).

Any object with ``world_to_camera`` (4x4, OpenCV axes: x right, y down, z forward), ``fx``, ``fy``, ``cx``,
``cy``, ``width`` and ``height`` is accepted; ``view()`` checks it and gives a ``Camera``. Pixel (x, y) is centred at
(x + 0.5, y + 0.5), as in the training rasterizer.
"""

from __future__ import annotations

import numpy as np

from training.scene.camera import Camera


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

