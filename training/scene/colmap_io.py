"""COLMAP sparse models through pycolmap: reading (binary or text, classic 3 files or pycolmap 4 with rigs and
frames) and writing.

Reading gives one ``RawView`` per registered image (pose from ``Image.cam_from_world()``, which composes rig and
frame poses) with its pycolmap camera, distortion included; ``scene_loader`` undistorts. Perspective models of any
kind are accepted (they are undistorted to a pinhole image the way COLMAP's image_undistorter does); spherical
models are refused with an error saying how to convert the data.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from training.core.errors import InputError
from training.scene.raw_view import RawView, copy_lens
from training.scene.scene import Camera
from training.scene.undistort import can_undistort

MODEL_FILES = ("cameras", "images", "points3D", "rigs", "frames")


@dataclass
class ColmapModel:
    views: list[RawView]  # registered images, sorted by name
    points: np.ndarray | None  # (P, 3) float32, None when the model has no 3D points
    point_colors: np.ndarray | None  # (P, 3) float32 in [0, 1]
    folder: Path  # the folder holding cameras/images/points3D


def is_model_folder(folder: Path) -> bool:
    return any((folder / f"{name}.{ext}").is_file() for name in ("cameras", "images") for ext in ("bin", "txt"))


def find_model_folder(path: Path) -> Path | None:
    """The model folder for a scene folder: the folder itself, ``sparse/0`` or ``sparse``; None if there is none."""
    for candidate in (path, path / "sparse" / "0", path / "sparse"):
        if candidate.is_dir() and is_model_folder(candidate):
            return candidate
    return None


def _one_line(exc: BaseException) -> str:
    """The gist of a pycolmap exception: its last line, without glog's "[file.cc:123] " prefix."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return re.sub(r"^\[[^\]]*\]\s*", "", lines[-1]) if lines else type(exc).__name__


def read_colmap_model(folder: str | Path) -> ColmapModel:
    """Read the COLMAP model in ``folder`` (binary preferred when both are present)."""
    import pycolmap

    folder = Path(folder)
    # pycolmap reads binary when cameras.bin exists, else text; check that format's files for a precise message
    ext = "bin" if (folder / "cameras.bin").is_file() else "txt"
    for name in ("cameras", "images", "points3D"):
        if not (folder / f"{name}.{ext}").is_file():
            raise InputError(folder / f"{name}.{ext}", "COLMAP model file missing")
    rig_files = [(folder / f"{name}.{ext}").is_file() for name in ("rigs", "frames")]
    if any(rig_files) and not all(rig_files):
        missing = "frames" if rig_files[0] else "rigs"
        raise InputError(folder / f"{missing}.{ext}", "COLMAP model file missing (pycolmap 4 models need both "
                                                      "rigs and frames, classic ones neither)")
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except Exception as exc:  # pycolmap raises plain RuntimeError/ValueError on malformed files
        raise InputError(folder, f"cannot read COLMAP model ({_one_line(exc)})") from exc

    for camera_id, camera in rec.cameras.items():
        if not can_undistort(camera):
            raise InputError(folder, f"camera {camera_id} uses the {camera.model.name} model, which has no pinhole "
                                     "image; convert it to perspective images first (e.g. cubemap faces) and run "
                                     "`splatstyler sfm` on those")

    views: list[RawView] = []
    for image in rec.images.values():
        if not image.has_pose:
            continue  # registered images only: an unregistered image has no usable camera
        w2c = np.eye(4)
        w2c[:3, :4] = image.cam_from_world().matrix()
        views.append(RawView(image.name, w2c, copy_lens(rec.cameras[image.camera_id])))
    if not views:
        raise InputError(folder, "COLMAP model has no registered images")
    views.sort(key=lambda v: v.name)

    points = colors = None
    if rec.num_points3D() > 0:
        pts = [point for _, point in sorted(rec.points3D.items())]  # by id: the order they were written in
        points = np.array([p.xyz for p in pts], dtype=np.float32)
        colors = np.array([p.color for p in pts], dtype=np.float32) / 255.0
    return ColmapModel(views, points, colors, folder)


def write_colmap_model(folder: str | Path, cameras: list[Camera], points: np.ndarray | None = None,
                       point_colors: np.ndarray | None = None, binary: bool = True) -> None:
    """Write pinhole ``cameras`` (and optional points (P, 3) with colours (P, 3) in [0, 1] or uint8) as a COLMAP
    model in ``folder``: cameras, images, points3D plus pycolmap 4's rigs and frames (trivial: one camera each).

    Views with identical intrinsics share one COLMAP camera. Points carry no tracks (we have no observations).
    The files are written to a temporary folder and moved in one by one; files of the other format are removed
    so a reader cannot pick up a stale model."""
    import pycolmap

    folder = Path(folder)
    rec = pycolmap.Reconstruction()
    camera_ids: dict[tuple, int] = {}
    for cam in cameras:
        key = (cam.width, cam.height, float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy))
        if key not in camera_ids:
            camera_ids[key] = len(camera_ids) + 1
            rec.add_camera_with_trivial_rig(pycolmap.Camera(
                camera_id=camera_ids[key], model="PINHOLE", width=cam.width, height=cam.height,
                params=[cam.fx, cam.fy, cam.cx, cam.cy]))
    for image_id, cam in enumerate(cameras, start=1):
        w2c = np.asarray(cam.world_to_camera, dtype=np.float64)
        image = pycolmap.Image(name=cam.name, camera_id=camera_ids[(cam.width, cam.height, float(cam.fx),
                                                                     float(cam.fy), float(cam.cx), float(cam.cy))],
                               image_id=image_id)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(w2c[:3, :4]))
    if points is not None and len(points):
        points = np.asarray(points, dtype=np.float64)
        if point_colors is None:
            colors = np.full((len(points), 3), 128, dtype=np.uint8)
        else:
            colors = np.asarray(point_colors)
            if colors.dtype != np.uint8:
                colors = np.clip(np.round(colors.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
        for xyz, rgb in zip(points, colors):
            rec.add_point3D(xyz, pycolmap.Track(), rgb)

    folder.mkdir(parents=True, exist_ok=True)
    ext, other = ("bin", "txt") if binary else ("txt", "bin")
    tmp = Path(tempfile.mkdtemp(prefix=".colmap-", dir=folder))
    try:
        (rec.write_binary if binary else rec.write_text)(str(tmp))
        for name in MODEL_FILES:
            written = tmp / f"{name}.{ext}"
            if written.exists():
                os.replace(written, folder / written.name)
            stale = folder / f"{name}.{other}"
            if stale.exists():
                stale.unlink()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
