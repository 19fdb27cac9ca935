"""Removing lens distortion: any COLMAP camera model to an ideal pinhole camera, images resampled to match.

The pinhole camera is the one pycolmap's undistorter chooses (``pycolmap.undistort_camera``: same focal length,
image cropped to the region without blank pixels), and the distortion model is pycolmap's own
(``Camera.img_from_cam``), so every COLMAP model is handled the way COLMAP's ``image_undistorter`` handles it. The
resampling is ours (bilinear, float32) so that 16-bit and float images keep their precision and alpha is resampled
the same way; pycolmap's Bitmap path is 8-bit only.

Pixel convention: COLMAP's, the centre of the top-left pixel is (0.5, 0.5).
"""

from __future__ import annotations

import numpy as np

from training.scene.camera import Camera, pinhole

# Models whose projection is an exact pinhole: nothing to undistort.
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")


def pinhole_of(camera) -> Camera | None:
    """The pinhole parameters of a pycolmap camera that needs no undistortion, or None if it does."""
    p = list(camera.params)
    name = camera.model.name
    if name == "SIMPLE_PINHOLE":
        return pinhole(camera.width, camera.height, p[0], p[0], p[1], p[2])
    if name == "PINHOLE":
        return pinhole(camera.width, camera.height, p[0], p[1], p[2], p[3])
    extra = [p[i] for i in camera.extra_params_idxs()]
    if name in ("SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV") and all(v == 0.0 for v in extra):
        return pinhole(camera.width, camera.height, camera.focal_length_x, camera.focal_length_y,
                       camera.principal_point_x, camera.principal_point_y)
    return None


def can_undistort(camera) -> bool:
    """Whether COLMAP's undistorter can map ``camera`` to a pinhole image (perspective models; spherical models such
    as EQUIRECTANGULAR have no pinhole image)."""
    perspective = camera.is_perspective
    return bool(perspective() if callable(perspective) else perspective)


def undistorted_pinhole(camera) -> Camera:
    """The pinhole camera pycolmap's undistorter makes for ``camera`` (a pycolmap.Camera)."""
    import pycolmap

    direct = pinhole_of(camera)
    if direct is not None:
        return direct
    out = pycolmap.undistort_camera(pycolmap.UndistortCameraOptions(), camera)
    p = list(out.params)
    return pinhole(out.width, out.height, p[0], p[1], p[2], p[3])


def undistortion_map(camera, target: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Source pixel coordinates for every target pixel.

    Returns (rows, cols), each (target.height, target.width) float32: the array indices (pixel centres at integer
    positions) in the distorted image to sample for each pixel of the undistorted one."""
    ys, xs = np.meshgrid(np.arange(target.height, dtype=np.float64) + 0.5,
                         np.arange(target.width, dtype=np.float64) + 0.5, indexing="ij")
    rays = target.rays(xs.ravel(), ys.ravel())
    src = np.asarray(camera.img_from_cam(rays), dtype=np.float64).reshape(target.height, target.width, 2)
    return (src[..., 1] - 0.5).astype(np.float32), (src[..., 0] - 0.5).astype(np.float32)


def remap(image: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear resampling of (H, W, C) or (H, W) float32 at (rows, cols) (h, w); samples outside are clamped to
    the border (the undistorter crops to valid pixels, so only sub-pixel overshoot can occur)."""
    from scipy.ndimage import map_coordinates

    coords = np.stack([rows, cols])
    if image.ndim == 2:
        return map_coordinates(image, coords, order=1, mode="nearest").astype(np.float32)
    channels = [map_coordinates(image[..., c], coords, order=1, mode="nearest") for c in range(image.shape[2])]
    return np.stack(channels, axis=-1).astype(np.float32)
