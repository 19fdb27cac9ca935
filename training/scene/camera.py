"""The one pinhole camera of splatstyler: a pose and intrinsics, and the projection math on them (points to pixels
and back). numpy only (no torch): the loaders, the trainers, renderer_gl, camera paths and the viewer's selections,
picks and gizmo all use it; the torch side turns it into tensors in one place
(``training.raster.rasterize.camera_matrices``). Pose maths (look-at, orbits, quaternions, interpolation between
cameras) is beside it in training/scene/pose.py.

Conventions (shared by the whole code base):
- ``world_to_camera`` is a 4x4 float64 matrix in the OpenCV/COLMAP camera convention: x right, y down, z forward
  (the camera looks along +z). A point p_w maps to p_c = R p_w + t.
- Intrinsics are pinhole (distortion already removed by the loader), in pixels, for an image of ``width`` x
  ``height``; they scale with it. The pixel centre convention is COLMAP's: the centre of the top-left pixel is
  (0.5, 0.5).

As a dict (camera paths, projects): ``{"world_to_camera": 4x4, "fx", "fy", "cx", "cy", "width", "height"}``;
``from_dict`` checks it once (a rigid pose, finite numbers, positive focal lengths, sizes 1..16384).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from training.core.errors import InputError

MAX_SIDE = 16384
ORTHONORMAL_TOLERANCE = 1e-4


@dataclass
class Camera:
    name: str  # image file name relative to the scene's image folder (or what the camera is: "keyframe", "view")
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_to_camera: np.ndarray  # (4, 4) float64, OpenCV convention

    # ------------------------------------------------------------------ pose
    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def camera_to_world(self) -> np.ndarray:
        return np.linalg.inv(self.world_to_camera)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) camera-to-world rotation."""
        return np.asarray(self.world_to_camera, np.float64)[:3, :3].T

    @property
    def center(self) -> np.ndarray:
        """(3,) camera position in world coordinates."""
        R = self.world_to_camera[:3, :3]
        t = self.world_to_camera[:3, 3]
        return -R.T @ t

    @property
    def forward(self) -> np.ndarray:
        """(3,) unit viewing direction (camera +z) in world coordinates."""
        return self.world_to_camera[2, :3] / np.linalg.norm(self.world_to_camera[2, :3])

    # ------------------------------------------------------------------ other image sizes
    def scaled(self, factor: float) -> "Camera":
        """The same camera for an image resized by ``factor`` (e.g. 0.5 for ``--downscale 2``)."""
        w = max(1, int(round(self.width * factor)))
        h = max(1, int(round(self.height * factor)))
        return self.resized(w, h)

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera for an image of ``width`` x ``height``: the intrinsics scale with each side."""
        sx, sy = width / self.width, height / self.height
        return replace(self, width=int(width), height=int(height), fx=self.fx * sx, fy=self.fy * sy,
                       cx=self.cx * sx, cy=self.cy * sy, world_to_camera=np.array(self.world_to_camera, np.float64))

    # ------------------------------------------------------------------ projection
    def camera_points(self, points) -> np.ndarray:
        """(N, 3) camera coordinates (x right, y down, z forward: the depth) of world points (N, 3)."""
        w2c = np.asarray(self.world_to_camera, dtype=np.float64)
        return np.asarray(points, np.float64).reshape(-1, 3) @ w2c[:3, :3].T + w2c[:3, 3]

    def pixels(self, camera_points, near: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) of camera-space points (N, 3), and whether each is in front of the camera (z >
        ``near``); a point that is not lands where it would at depth 1."""
        pc = np.asarray(camera_points, np.float64).reshape(-1, 3)
        z = pc[:, 2]
        front = z > near
        zs = np.where(front, z, 1.0)
        uv = np.stack([self.fx * pc[:, 0] / zs + self.cx, self.fy * pc[:, 1] / zs + self.cy], axis=1)
        return uv, front

    def project(self, points, near: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) of world points (N, 3), and whether each is in front of the camera."""
        return self.pixels(self.camera_points(points), near)

    def rays(self, x, y) -> np.ndarray:
        """Camera-space points at depth 1 seen at pixel positions (x, y) (continuous, from the top-left corner):
        numbers give (3,), arrays of one shape (..., 3)."""
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        return np.stack(np.broadcast_arrays((x - self.cx) / self.fx, (y - self.cy) / self.fy, 1.0), axis=-1)

    def unproject(self, x, y, depth) -> np.ndarray:
        """The world points seen at pixel positions (x, y) at camera depth ``depth`` (along the camera's z axis, as
        the renderer's depth output): numbers give (3,), arrays of one shape (..., 3)."""
        p = self.rays(x, y) * np.asarray(depth, np.float64)[..., None]
        w2c = np.asarray(self.world_to_camera, np.float64)
        return (p - w2c[:3, 3]) @ w2c[:3, :3]

    def gl_view_projection(self, near: float, far: float) -> tuple[np.ndarray, np.ndarray]:
        """OpenGL view and projection matrices: OpenCV's x right, y down, z forward becomes GL's x right, y up,
        looking down -z; the principal point off centre shifts the frustum. Pixel (u, v) of this camera lands where
        the splats put it."""
        flip = np.diag([1.0, -1.0, -1.0, 1.0])
        view = flip @ np.asarray(self.world_to_camera, np.float64)
        w, h = float(self.width), float(self.height)
        proj = np.array([[2 * self.fx / w, 0.0, 1 - 2 * self.cx / w, 0.0],
                         [0.0, 2 * self.fy / h, 2 * self.cy / h - 1, 0.0],
                         [0.0, 0.0, -(far + near) / (far - near), -2 * far * near / (far - near)],
                         [0.0, 0.0, -1.0, 0.0]])
        return view, proj

    def clip_from_world(self, near: float, far: float) -> np.ndarray:
        """(4, 4) OpenGL clip-space matrix (projection after view)."""
        view, proj = self.gl_view_projection(near, far)
        return proj @ view

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        return {"world_to_camera": np.asarray(self.world_to_camera, dtype=float).tolist(), "fx": float(self.fx),
                "fy": float(self.fy), "cx": float(self.cx), "cy": float(self.cy), "width": int(self.width),
                "height": int(self.height)}

    @classmethod
    def from_dict(cls, d, where: str = "camera", file=None, name: str = "keyframe") -> "Camera":
        """The camera a dict describes, checked once: InputError naming ``file`` and ``where`` otherwise."""
        if not isinstance(d, dict):
            raise InputError(file, f"{where} is not an object")
        try:
            m = np.array(d["world_to_camera"], dtype=np.float64)
        except KeyError:
            raise InputError(file, f"{where} has no 'world_to_camera'") from None
        except (TypeError, ValueError):
            raise InputError(file, f"{where}: 'world_to_camera' is not a 4x4 matrix of numbers") from None
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise InputError(file, f"{where}: 'world_to_camera' must be a finite 4x4 matrix, got shape {m.shape}")
        r = m[:3, :3]
        if (np.abs(r @ r.T - np.eye(3)).max() > ORTHONORMAL_TOLERANCE
                or abs(np.linalg.det(r) - 1) > ORTHONORMAL_TOLERANCE or np.abs(m[3] - [0, 0, 0, 1]).max() > 0):
            raise InputError(file, f"{where}: 'world_to_camera' is not a rigid transform (rotation and translation)")
        missing = [key for key in ("fx", "fy", "cx", "cy", "width", "height") if key not in d]
        if missing:
            raise InputError(file, f"{where} lacks {', '.join(missing)}")
        values = {}
        for key in ("fx", "fy", "cx", "cy"):
            v = d[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise InputError(file, f"'{key}' must be a finite number, got {v!r}")
            values[key] = float(v)
        w, h = d["width"], d["height"]
        if not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_SIDE for v in (w, h)):
            raise InputError(file, f"{where}: width and height must be whole numbers 1..{MAX_SIDE}, got {w!r}x{h!r}")
        if values["fx"] <= 0 or values["fy"] <= 0:
            raise InputError(file, f"{where}: fx and fy must be positive")
        return cls(name, w, h, values["fx"], values["fy"], values["cx"], values["cy"], m)


def camera_of(camera, name: str | None = None) -> Camera:
    """A Camera (a copy) from any camera-like object: a dataset camera, the viewer's view, a keyframe."""
    return Camera(name if name is not None else getattr(camera, "name", "camera"), int(camera.width),
                  int(camera.height), float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy),
                  np.array(camera.world_to_camera, dtype=np.float64))


def pinhole(width: int, height: int, fx: float, fy: float, cx: float, cy: float, name: str = "pinhole") -> Camera:
    """Intrinsics alone (what an undistorter maps a lens to): the pose is the identity."""
    return Camera(name, int(width), int(height), float(fx), float(fy), float(cx), float(cy), np.eye(4))
