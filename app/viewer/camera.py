"""The viewer's camera: orbit, pan, zoom, fly, roll and field of view, as a pose plus a look-at target.

The pose is kept as camera-to-world axes in the OpenCV convention the whole project uses (x right, y down, z
forward) and a position; ``camera(width, height)`` gives a ``training.scene.scene.Camera`` that the renderer and
the trainers both understand. The scene's "up" comes from the dataset cameras (the mean of their -y axes): photos
are mostly taken upright, whatever the world frame of the SfM that placed them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from training.scene.pose import look_at
from training.scene.scene import Camera


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about the unit ``axis`` (Rodrigues)."""
    x, y, z = axis / max(np.linalg.norm(axis), 1e-12)
    c, s = math.cos(angle), math.sin(angle)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def _orthonormal(R: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(R)
    return u @ vt


@dataclass
class ViewerCamera:
    rotation: np.ndarray  # (3, 3) camera-to-world: columns are the right, down and forward axes in the world
    position: np.ndarray  # (3,) world
    target_distance: float  # orbit centre = position + forward * target_distance
    fov_y_degrees: float = 50.0
    up: np.ndarray | None = None  # (3,) the scene's up; orbiting keeps it vertical

    def __post_init__(self) -> None:
        self.rotation = np.asarray(self.rotation, dtype=np.float64)
        self.position = np.asarray(self.position, dtype=np.float64)
        self.up = np.array([0.0, -1.0, 0.0]) if self.up is None else np.asarray(self.up, dtype=np.float64)
        self.up = self.up / max(np.linalg.norm(self.up), 1e-12)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_dataset(cls, cameras: list[Camera], target: np.ndarray | None = None,
                     up: np.ndarray | None = None) -> "ViewerCamera":
        """At the first dataset camera, looking at ``target`` (default: the point the cameras look at most), upright:
        ``up``, when the scene's up is known (levelled), else the cameras' mean up (a photo held at a slant does not
        tilt the first view)."""
        if up is None:
            up = -np.mean([c.camera_to_world[:3, 1] for c in cameras], axis=0)
        if np.linalg.norm(up) < 1e-6:
            up = np.array([0.0, -1.0, 0.0])
        first = cls.from_camera(cameras[0], up=up)
        if target is None:
            target = look_at_point(cameras)
        if float(np.dot(target - first.position, first.forward)) <= 1e-3:  # the point is behind: keep the photo's
            first.target_distance = 1.0
            return first
        return cls.looking_at(first.position, target, up=up, fov_y_degrees=first.fov_y_degrees)

    @classmethod
    def from_camera(cls, camera: Camera, up: np.ndarray | None = None, target_distance: float = 1.0) -> "ViewerCamera":
        c2w = np.linalg.inv(np.asarray(camera.world_to_camera, np.float64))
        fov = math.degrees(2 * math.atan(camera.height / (2 * camera.fy)))
        return cls(_orthonormal(c2w[:3, :3]), c2w[:3, 3].copy(), target_distance, fov, up)

    @classmethod
    def looking_at(cls, position, target, up=(0.0, 0.0, 1.0), fov_y_degrees: float = 50.0) -> "ViewerCamera":
        position, target = np.asarray(position, dtype=np.float64), np.asarray(target, dtype=np.float64)
        rotation = look_at(position, target, up)[:3, :3].T
        return cls(rotation, position, float(np.linalg.norm(target - position)), fov_y_degrees, up)

    # ------------------------------------------------------------------ axes
    @property
    def right(self) -> np.ndarray:
        return self.rotation[:, 0]

    @property
    def down(self) -> np.ndarray:
        return self.rotation[:, 1]

    @property
    def forward(self) -> np.ndarray:
        return self.rotation[:, 2]

    @property
    def target(self) -> np.ndarray:
        return self.position + self.forward * self.target_distance

    # ------------------------------------------------------------------ moves (pixels and seconds in, world out)
    def orbit(self, dx: float, dy: float, speed: float = 0.005) -> None:
        """Turn around the target: ``dx`` about the scene's up, ``dy`` about the camera's right (pixels)."""
        target = self.target
        R = _rotation(self.up, -dx * speed) @ _rotation(self.right, -dy * speed)
        new_rotation = _orthonormal(R @ self.rotation)
        # stop short of the poles, where "up" no longer tells left from right
        if abs(float(np.dot(new_rotation[:, 2], self.up))) < 0.995:
            self.rotation = new_rotation
        self.position = target - self.forward * self.target_distance

    def pan(self, dx: float, dy: float, viewport_height: int) -> None:
        """Slide sideways so the point under the cursor follows it (at the target's depth)."""
        per_pixel = 2 * self.target_distance * math.tan(math.radians(self.fov_y_degrees) / 2) / max(viewport_height, 1)
        self.position = self.position - self.right * dx * per_pixel - self.down * dy * per_pixel

    def zoom(self, wheel: float) -> None:
        """Move toward the target (wheel > 0) by a fixed fraction per notch; the target stays."""
        target = self.target
        self.target_distance = float(np.clip(self.target_distance * 0.85 ** wheel, 1e-4, 1e6))
        self.position = target - self.forward * self.target_distance

    def fly(self, forward: float, right: float, up: float, distance: float) -> None:
        """Move along the view (WASD, Q/E) by ``distance`` world units per unit of input; the target moves too."""
        self.position = (self.position + self.forward * forward * distance + self.right * right * distance
                         - self.down * up * distance)

    def roll(self, angle: float) -> None:
        self.rotation = _orthonormal(_rotation(self.forward, angle) @ self.rotation)

    def set_fov(self, degrees: float) -> None:
        self.fov_y_degrees = float(np.clip(degrees, 10.0, 120.0))

    # ------------------------------------------------------------------ output
    def world_to_camera(self) -> np.ndarray:
        m = np.eye(4)
        m[:3, :3] = self.rotation.T
        m[:3, 3] = -self.rotation.T @ self.position
        return m

    def camera(self, width: int, height: int, name: str = "viewer") -> Camera:
        f = height / (2 * math.tan(math.radians(self.fov_y_degrees) / 2))
        return Camera(name, int(width), int(height), f, f, width / 2, height / 2, self.world_to_camera())

    def copy(self) -> "ViewerCamera":
        return ViewerCamera(self.rotation.copy(), self.position.copy(), self.target_distance, self.fov_y_degrees,
                            self.up.copy())


def look_at_point(cameras: list[Camera]) -> np.ndarray:
    """The point closest, in least squares, to every camera's optical axis: what a capture looks at."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        d = cam.forward
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.center
    if np.linalg.matrix_rank(A) < 3:  # all axes parallel (a forward-facing rig): look ahead of the cameras
        centers = np.array([c.center for c in cameras])
        return centers.mean(axis=0) + np.mean([c.forward for c in cameras], axis=0)
    return np.linalg.solve(A, b)


def nearest_camera(view: ViewerCamera, cameras: list[Camera]) -> int:
    """Index of the dataset camera closest to the view: position, plus the viewing direction weighted by the
    scene's size so that a camera behind the viewer does not win on position alone."""
    centers = np.array([c.center for c in cameras])
    span = max(float(np.ptp(centers, axis=0).max()), 1e-6)
    dist = np.linalg.norm(centers - view.position, axis=1) / span
    angle = np.array([1.0 - float(np.dot(c.forward, view.forward)) for c in cameras])
    return int(np.argmin(dist + angle))


def span(points) -> float:
    """The largest extent of a set of points along an axis (1 for fewer than two)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 2:
        return 1.0
    return max(float(np.ptp(pts, axis=0).max()), 1e-6)


def camera_span(cameras) -> float:
    """The dataset cameras' span: the scale of flying, of the frustums drawn, of "near a camera"."""
    return span([c.center for c in cameras]) if cameras else 1.0
