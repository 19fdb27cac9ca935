"""Per-view target depth maps for L_depth: sparse from the SfM points, or dense from a monocular estimator.

Depths are camera z (OpenCV: along the viewing direction), in world units, the quantity the rasterizer's "ED"
mode renders. Every map comes with a boolean validity mask; L_depth only looks where it is True.

- ``sfm``: every SfM point is projected into every view; a pixel takes the depth of the *nearest* point that lands
  in it (a z-buffer), and only those pixels are valid. Pixel (x, y) covers [x, x+1) x [y, y+1) in the COLMAP
  convention the scene uses, so a point at image coordinates (u, v) lands in pixel (floor(u), floor(v)).
- ``mono``: Depth Anything V2 Small (``depth-anything/Depth-Anything-V2-Small-hf`` through ``transformers``)
  predicts relative inverse depth; per image, a least-squares scale and shift map it onto the inverse depth of the
  SfM points visible in that view, and its inverse is the target (valid where that inverse is positive).
- ``none``: no targets.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from training.core.errors import InputError
from training.scene.scene import Camera, Scene


MONO_MODEL_ID = "depth-anything/Depth-Anything-V2-Small-hf"
DEPTH_MODES = ("sfm", "mono", "none")


@dataclass
class DepthTarget:
    depth: np.ndarray  # (H, W) float32, camera z in world units (0 where invalid)
    valid: np.ndarray  # (H, W) bool


def project_points(points: np.ndarray, camera: Camera, near: float = 1e-6) -> tuple[np.ndarray, np.ndarray,
                                                                                       np.ndarray]:
    """Project (P, 3) world points; returns (pixel x (P,) int, pixel y (P,) int, z (P,)) for the points in front
    of the camera that land inside the image."""
    pc = camera.camera_points(points)
    uv, front = camera.pixels(pc, near)
    z = pc[front, 2]
    px = np.floor(uv[front, 0]).astype(np.int64)
    py = np.floor(uv[front, 1]).astype(np.int64)
    inside = (px >= 0) & (px < camera.width) & (py >= 0) & (py < camera.height)
    return px[inside], py[inside], z[inside]


def sparse_depth(points: np.ndarray, camera: Camera) -> DepthTarget:
    """Z-buffered sparse depth of ``points`` (P, 3) in ``camera``: the nearest point's z per pixel."""
    px, py, z = project_points(points, camera)
    flat = np.full(camera.width * camera.height, np.inf)
    np.minimum.at(flat, py * camera.width + px, z)
    valid = np.isfinite(flat)
    depth = np.where(valid, flat, 0.0).astype(np.float32)
    return DepthTarget(depth.reshape(camera.height, camera.width), valid.reshape(camera.height, camera.width))


def align_inverse_depth(rel_inv: np.ndarray, sparse: DepthTarget, min_points: int = 10) -> DepthTarget | None:
    """Fit s, t minimising sum over the SfM pixels of (s * rel_inv + t - 1 / z_sfm)^2 and return depth
    1 / (s * rel_inv + t) where that is positive; None when fewer than ``min_points`` SfM pixels exist.

    rel_inv (H, W) relative inverse depth (larger = nearer), as Depth Anything predicts."""
    m = sparse.valid
    if int(m.sum()) < min_points:
        return None
    x = rel_inv[m].astype(np.float64)
    y = 1.0 / sparse.depth[m].astype(np.float64)
    A = np.stack([x, np.ones_like(x)], axis=1)
    (s, t), *_ = np.linalg.lstsq(A, y, rcond=None)
    inv = s * rel_inv.astype(np.float64) + t
    valid = inv > 1e-8
    depth = np.where(valid, 1.0 / np.where(valid, inv, 1.0), 0.0).astype(np.float32)
    return DepthTarget(depth, valid)


def _load_mono_model(model: str | None):
    """Depth Anything V2 Small via transformers, from a local folder or the hub id; InputError if unavailable."""
    source = model or MONO_MODEL_ID
    try:
        from transformers import AutoImageProcessor, AutoModelForDepthEstimation
    except ImportError:
        raise InputError(model, "--depth mono needs the 'transformers' package (pip install transformers) and "
                                f"the weights of {MONO_MODEL_ID}: download that model folder on a machine with "
                                "internet and pass it with --mono-depth-model PATH, or use --depth sfm") from None
    if model is not None and not Path(model).is_dir():
        raise InputError(model, "--mono-depth-model must be a folder holding a transformers depth model "
                                f"(config.json and weights of {MONO_MODEL_ID})")
    try:
        processor = AutoImageProcessor.from_pretrained(source)
        net = AutoModelForDepthEstimation.from_pretrained(source).eval()
    except OSError as exc:
        raise InputError(source, f"cannot load the monocular depth model ({exc.__class__.__name__}): pass a "
                                 f"local copy of {MONO_MODEL_ID} with --mono-depth-model PATH, or use --depth sfm"
                         ) from None
    return processor, net


def _predict_inverse_depth(processor, net, image: np.ndarray) -> np.ndarray:
    """(H, W, 3) float image -> (H, W) relative inverse depth at the image's size."""
    import torch

    with torch.no_grad():
        inputs = processor(images=(image * 255).astype(np.uint8), return_tensors="pt")
        pred = net(**inputs).predicted_depth  # (1, h, w)
        pred = torch.nn.functional.interpolate(pred[:, None], size=image.shape[:2], mode="bicubic",
                                               align_corners=False)[0, 0]
    return pred.numpy().astype(np.float32)


def compute_depth_targets(scene: Scene, mode: str, mono_model: str | None = None,
                          progress: bool = False) -> tuple[list[DepthTarget | None] | None, str]:
    """Targets for every view of ``scene`` (None entries where a view has none) and the mode actually used.

    ``sfm`` on a scene without SfM points (e.g. a transforms.json capture) falls back to no depth term, with a
    warning, and reports the mode as "none"; ``mono`` there is an error, since there is nothing to align to."""
    if mode not in DEPTH_MODES:
        raise InputError(None, f"unknown depth mode {mode!r} (choose from {', '.join(DEPTH_MODES)})")
    if mode == "none":
        return None, "none"
    if scene.num_points == 0:
        if mode == "sfm":
            warnings.warn(f"{scene.source}: the scene has no SfM points, so --depth sfm has nothing to supervise "
                          "with; training without the depth term", stacklevel=2)
            return None, "none"
        raise InputError(scene.source, "--depth mono aligns the predicted depth to the SfM points, and this "
                                       "scene has none; use --depth none")
    sparse = [sparse_depth(scene.points, cam) for cam in scene.cameras]
    if mode == "sfm":
        return [s if s.valid.any() else None for s in sparse], "sfm"
    processor, net = _load_mono_model(mono_model)
    targets: list[DepthTarget | None] = []
    it = range(len(scene.cameras))
    if progress:
        from tqdm import tqdm
        it = tqdm(it, desc="mono depth", unit="view")
    for i in it:
        if not scene.images:
            raise InputError(scene.source, "--depth mono needs the scene's images loaded")
        rel = _predict_inverse_depth(processor, net, scene.images[i])
        targets.append(align_inverse_depth(rel, sparse[i]))
    return targets, "mono"
