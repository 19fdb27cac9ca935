"""Camera paths for videos: keyframes (pinhole cameras, training/scene/camera.py), a smooth path through them,
ready-made paths (an orbit, the dataset's trajectory), and JSON files; the viewer's Camera path panel, a project and
``splatstyler video`` share it. The maths (orbit, spline, slerp) is training/scene/pose.py's.

Conventions: a keyframe's ``world_to_camera`` is a 4x4 in OpenCV axes (x right, y down, z forward), as everywhere in
this project; intrinsics are pixels for the keyframe's own ``width`` x ``height`` and are rescaled when frames are
asked for at another size. Between keyframes the camera centre follows a Catmull-Rom spline (centripetal, so it
neither overshoots nor loops at unevenly spaced keys), the rotation is slerped, and the intrinsics (relative to the
image size) are interpolated linearly. Each keyframe-to-keyframe segment takes the same time. A ``loop`` path
returns from the last keyframe to the first (orbits) and its last frame stops one step short of the first.

JSON (``save``/``load``; a bad file is an InputError naming it)::

    {"version": 1, "duration": 8.0, "fps": 30, "loop": false,
     "keyframes": [{"world_to_camera": [[...], [...], [...], [0, 0, 0, 1]], "fx": 500, "fy": 500, "cx": 320,
                    "cy": 180, "width": 640, "height": 360}, ...]}
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from training.core.atomic_write import atomic_open
from training.core.errors import InputError
from training.core.json_numbers import NumberOutOfRange, parse_json
from training.scene.camera import Camera, camera_of
from training.scene.pose import orbit, path_camera

FORMAT_VERSION = 1
MAX_FPS = 240.0
MAX_FRAMES = 100_000


def keyframe_from(camera) -> Camera:
    """A keyframe (a copy) from any camera-like object (a dataset camera, the viewer's current view)."""
    return camera_of(camera, "keyframe")


# ------------------------------------------------------------------------------------------- the path
@dataclass
class CameraPath:
    keyframes: list[Camera] = field(default_factory=list)
    duration: float = 8.0  # seconds
    fps: float = 30.0
    loop: bool = False

    def validate(self, name=None) -> None:
        """A path a video can be made of: keyframes, and ``validate_timing``'s limits."""
        if not self.keyframes:
            raise InputError(name, "a camera path needs at least one keyframe")
        self.validate_timing(name)

    def validate_timing(self, name=None) -> None:
        """Duration and fps within the limits, checked whether or not there are keyframes yet (a project's empty
        path gets keyframes in the viewer and is rendered with the timing it came with)."""
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise InputError(name, f"duration must be a positive number of seconds, got {self.duration}")
        if not (math.isfinite(self.fps) and 0 < self.fps <= MAX_FPS):
            raise InputError(name, f"fps must be in (0, {MAX_FPS:g}], got {self.fps}")
        if not 1 <= self.frame_count <= MAX_FRAMES:
            raise InputError(name, f"{self.duration:g} s at {self.fps:g} fps is {self.frame_count} frames; "
                                   f"1..{MAX_FRAMES} are allowed")

    def copy(self) -> "CameraPath":
        return CameraPath(list(self.keyframes), self.duration, self.fps, self.loop)

    @property
    def frame_count(self) -> int:
        return max(1, int(round(self.duration * self.fps)))

    def _segments(self) -> int:
        n = len(self.keyframes)
        return n if self.loop and n > 1 else max(n - 1, 0)

    def camera_at(self, t: float, width: int | None = None, height: int | None = None) -> Camera:
        """The camera at ``t`` seconds (clamped to the path), at ``width`` x ``height`` (default: the first
        keyframe's size)."""
        keys = self.keyframes
        w = int(width or keys[0].width)
        h = int(height or keys[0].height)
        s = min(max(t / self.duration, 0.0), 1.0) * self._segments()
        return path_camera(keys, s, "path", self.loop, size=(w, h))

    def frame_times(self) -> np.ndarray:
        """Seconds of each frame: the path's start to its end, or, for a loop, up to one step before the start."""
        count = self.frame_count
        if self.loop or count == 1:
            return np.arange(count) * (self.duration / count)
        return np.linspace(0.0, self.duration, count)

    def cameras(self, width: int | None = None, height: int | None = None) -> list[Camera]:
        """Every frame's camera."""
        return list(self.iter_cameras(width, height))

    def iter_cameras(self, width: int | None = None, height: int | None = None) -> Iterator[Camera]:
        """Every frame's camera, one at a time (the viewer's video makes each as its frame is rendered)."""
        for t in self.frame_times():
            yield self.camera_at(float(t), width, height)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        return {"version": FORMAT_VERSION, "duration": float(self.duration), "fps": float(self.fps),
                "loop": bool(self.loop), "keyframes": [k.to_dict() for k in self.keyframes]}

    def save(self, path: str | Path) -> None:
        with atomic_open(path, "w") as f:
            json.dump(self.to_dict(), f, indent=1)
            f.write("\n")

    @classmethod
    def from_dict(cls, data, name=None) -> "CameraPath":
        if not isinstance(data, dict):
            raise InputError(name, "a camera path file holds a JSON object")
        if data.get("version", FORMAT_VERSION) != FORMAT_VERSION:
            raise InputError(name, f"camera path version {data.get('version')!r}; this splatstyler reads "
                                   f"version {FORMAT_VERSION}")
        keys = data.get("keyframes")
        if not isinstance(keys, list) or not keys:
            raise InputError(name, "'keyframes' must be a non-empty list")
        path = cls([Camera.from_dict(k, f"keyframe {i}", name) for i, k in enumerate(keys)],
                   duration=_number(data, "duration", 8.0, name), fps=_number(data, "fps", 30.0, name),
                   loop=bool(data.get("loop", False)))
        path.validate(name)
        return path

    @classmethod
    def load(cls, path: str | Path) -> "CameraPath":
        path = Path(path)
        if not path.is_file():
            raise InputError(path, "file does not exist" if not path.exists() else "is not a file")
        try:
            data = parse_json(path.read_text())
        except NumberOutOfRange as exc:
            raise InputError(path, str(exc)) from None
        except (ValueError, UnicodeDecodeError) as exc:
            raise InputError(path, f"not valid JSON ({str(exc).splitlines()[0]})") from None
        except RecursionError:
            raise InputError(path, "nests its JSON too deeply to be a camera path") from None
        except OSError as exc:
            raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
        return cls.from_dict(data, path)


def _number(data: dict, key: str, default, name) -> float:
    value = data.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(name, f"'{key}' must be a finite number, got {value!r}")
    return float(value)


# ------------------------------------------------------------------------------------------- ready-made paths
def orbit_path(center, radius: float, up, width: int = 640, height: int = 360, fov_deg: float = 50.0,
               elevation_deg: float = 20.0, start=None, seconds: float = 8.0, fps: float = 30.0,
               keyframes: int = 12) -> CameraPath:
    """A loop around ``center`` at ``radius``, raised ``elevation_deg`` above the plane perpendicular to ``up``,
    always looking at the centre; ``start`` (a world direction from the centre) places the first keyframe."""
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    keys = [Camera("keyframe", width, height, f, f, width / 2, height / 2, m)
            for m in orbit(center, radius, keyframes, up, elevation_deg=elevation_deg, start=start)]
    return CameraPath(keys, duration=seconds, fps=fps, loop=True)


def orbit_around(means, opacities=None, cameras=None, **kwargs) -> CameraPath:
    """An orbit fitted to a model: centred on its opaque Gaussians' median; with the dataset's ``cameras``, at
    their median distance, around their mean up direction, starting at the first camera; without, at 2.5 times
    the model's 90th-percentile spread, y-down up (COLMAP and 3DGS scenes are mostly y-down)."""
    means = np.asarray(means, dtype=np.float64)
    keep = np.ones(len(means), bool)
    if opacities is not None and (np.asarray(opacities) > 0.5).sum() >= 10:
        keep = np.asarray(opacities) > 0.5
    target = np.median(means[keep], axis=0)
    if cameras:
        centres = np.stack([keyframe_from(c).center for c in cameras])
        kwargs.setdefault("up", -np.mean([np.asarray(c.world_to_camera)[1, :3] for c in cameras], axis=0))
        kwargs.setdefault("start", centres[0] - target)
        radius = float(np.median(np.linalg.norm(centres - target, axis=1)))
    else:
        kwargs.setdefault("up", np.array([0.0, -1.0, 0.0]))
        radius = 2.5 * max(float(np.percentile(np.linalg.norm(means[keep] - target, axis=1), 90)), 1e-3)
    return orbit_path(target, radius, **kwargs)


def dataset_path(cameras, seconds: float | None = None, fps: float = 30.0, seconds_per_camera: float = 0.25,
                 width: int | None = None, height: int | None = None) -> CameraPath:
    """The dataset's cameras in their order as keyframes (optionally resized), ``seconds_per_camera`` each unless
    ``seconds`` is given."""
    keys = [keyframe_from(c) for c in cameras]
    if width or height:
        keys = [k.resized(int(width or k.width), int(height or k.height)) for k in keys]
    duration = seconds if seconds is not None else max(1, len(keys) - 1) * seconds_per_camera
    return CameraPath(keys, duration=duration, fps=fps, loop=False)
