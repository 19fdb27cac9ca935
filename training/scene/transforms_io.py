"""NeRF / instant-ngp / nerfstudio ``transforms.json`` scenes.

Each frame has ``file_path`` (relative to the json's folder; NeRF-synthetic paths without extension get ``.png``)
and ``transform_matrix``, a camera-to-world matrix in the OpenGL camera convention (x right, y up, the camera looks
along -z). We convert it to our OpenCV world-to-camera: flipping the camera's y and z axes turns an OpenGL camera
frame into an OpenCV one with the same optical axis, so ``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)`` and
``world_to_camera = inverse(c2w_cv)``. The world frame is kept as it is.

Intrinsics: ``fl_x``/``fl_y``/``cx``/``cy``/``w``/``h`` and the distortion ``k1 k2 (k3 k4) p1 p2`` at the top level,
each of which a frame may override; ``camera_angle_x``/``camera_angle_y`` only when there is no ``fl_x``; ``w``/``h``
from the image header when absent; ``cx``/``cy`` default to the image centre. Distortion becomes a pycolmap camera
(OPENCV, FULL_OPENCV with k3/k4, OPENCV_FISHEYE when ``camera_model`` says so or ``is_fisheye`` is set) that the
loader undistorts. ``aabb_scale`` and other training hints are ignored.

transforms.json carries no SfM points: the loaded scene has ``points = None``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from training.core.errors import InputError
from training.scene.image_io import image_size
from training.scene.raw_view import RawView

OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y", "k1", "k2", "k3", "k4",
                  "p1", "p2", "camera_model", "is_fisheye")


def opengl_c2w_to_opencv_w2c(c2w: np.ndarray) -> np.ndarray:
    """(4, 4) camera-to-world in the OpenGL convention -> (4, 4) world-to-camera in the OpenCV convention."""
    c2w_cv = np.asarray(c2w, dtype=np.float64) @ OPENGL_TO_OPENCV
    R = c2w_cv[:3, :3]
    t = c2w_cv[:3, 3]
    w2c = np.eye(4)
    w2c[:3, :3] = R.T  # the rotation is orthonormal (checked by the reader), so its inverse is its transpose
    w2c[:3, 3] = -R.T @ t
    return w2c


def resolve_frame_path(root: Path, file_path: str) -> Path:
    """The image file a frame names, relative to ``root``; a path without extension tries .png then .jpg."""
    path = Path(file_path)
    path = path if path.is_absolute() else root / path
    if path.suffix == "" and not path.exists():
        for ext in (".png", ".jpg", ".jpeg", ".exr"):
            if path.with_name(path.name + ext).exists():
                return path.with_name(path.name + ext)
        return path.with_name(path.name + ".png")
    return path


def _lens(params: dict, json_path: Path, image_path: Path, index: int):
    """A pycolmap.Camera for one frame's intrinsics (already merged with the top-level ones)."""
    import pycolmap

    def number(key: str, default=None):
        value = params.get(key, default)
        if value is None:
            return None
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise InputError(json_path, f"frame {index}: {key!r} is not a number ({value!r})") from None
        if not math.isfinite(value):
            raise InputError(json_path, f"frame {index}: {key!r} is not finite")
        return value

    w, h = number("w"), number("h")
    if w is None or h is None:
        if not image_path.exists():
            raise InputError(image_path, f"image of frame {index} not found (and the json gives no w/h)")
        w, h = image_size(image_path)
    w, h = int(round(w)), int(round(h))
    if w <= 0 or h <= 0:
        raise InputError(json_path, f"frame {index}: image size {w}x{h} is not positive")

    fx, fy = number("fl_x"), number("fl_y")
    if fx is None:
        angle_x = number("camera_angle_x")
        if angle_x is None:
            if fy is None:
                raise InputError(json_path, f"frame {index}: no focal length (fl_x/fl_y or camera_angle_x)")
            fx = fy
        else:
            fx = 0.5 * w / math.tan(0.5 * angle_x)
    if fy is None:
        angle_y = number("camera_angle_y") if number("fl_x") is None else None
        fy = 0.5 * h / math.tan(0.5 * angle_y) if angle_y is not None else fx
    if fx <= 0 or fy <= 0:
        raise InputError(json_path, f"frame {index}: focal length must be positive")
    cx, cy = number("cx", w / 2.0), number("cy", h / 2.0)
    k1, k2, k3, k4 = (number(k, 0.0) for k in ("k1", "k2", "k3", "k4"))
    p1, p2 = number("p1", 0.0), number("p2", 0.0)

    model = str(params.get("camera_model", "")).upper()
    if model == "OPENCV_FISHEYE" or bool(params.get("is_fisheye", False)):
        return pycolmap.Camera(model="OPENCV_FISHEYE", width=w, height=h, params=[fx, fy, cx, cy, k1, k2, k3, k4])
    if model not in ("", "OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
        raise InputError(json_path, f"camera_model {params.get('camera_model')!r} is not supported (OPENCV, "
                                    "OPENCV_FISHEYE or pinhole); undistort the images first")
    if k3 != 0.0 or k4 != 0.0:
        return pycolmap.Camera(model="FULL_OPENCV", width=w, height=h,
                               params=[fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, 0.0, 0.0])
    if any(v != 0.0 for v in (k1, k2, p1, p2)):
        return pycolmap.Camera(model="OPENCV", width=w, height=h, params=[fx, fy, cx, cy, k1, k2, p1, p2])
    return pycolmap.Camera(model="PINHOLE", width=w, height=h, params=[fx, fy, cx, cy])


def read_transforms(json_path: str | Path) -> list[tuple[RawView, Path]]:
    """Read a transforms.json: one (RawView, image path) per frame, in file order.

    RawView.name is the frame's ``file_path`` as written (without a leading ``./``)."""
    json_path = Path(json_path)
    try:
        data = json.loads(json_path.read_text())
    except FileNotFoundError:
        raise InputError(json_path, "file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(json_path, f"not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise InputError(json_path, "expected a JSON object with a 'frames' list")
    frames = data.get("frames")
    if not isinstance(frames, list) or not frames:
        raise InputError(json_path, "transforms.json has no frames")

    root = json_path.parent
    shared = {k: data[k] for k in INTRINSIC_KEYS if k in data}
    views = []
    for index, frame in enumerate(frames):
        if not isinstance(frame, dict) or "file_path" not in frame or "transform_matrix" not in frame:
            raise InputError(json_path, f"frame {index} needs 'file_path' and 'transform_matrix'")
        try:
            c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(json_path, f"frame {index}: transform_matrix is not a matrix of numbers") from None
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
        if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w)):
            raise InputError(json_path, f"frame {index}: transform_matrix must be a finite 4x4 matrix")
        R = c2w[:3, :3]
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
            raise InputError(json_path, f"frame {index}: transform_matrix rotation is not a rotation "
                                        "(not orthonormal or mirrored)")
        file_path = str(frame["file_path"])
        image_path = resolve_frame_path(root, file_path)
        name = file_path[2:] if file_path.startswith("./") else file_path
        if image_path.name != Path(name).name:  # an extension was added
            name = str(Path(name).with_name(image_path.name))
        params = dict(shared)
        params.update({k: frame[k] for k in INTRINSIC_KEYS if k in frame})
        lens = _lens(params, json_path, image_path, index)
        views.append((RawView(name, opengl_c2w_to_opencv_w2c(c2w), lens), image_path))
    return views
