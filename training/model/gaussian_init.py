"""Initial Gaussian models: from SfM points (as 3DGS does) or, without points, random within the cameras' view.

From points (3DGS): one Gaussian per point, isotropic, with its standard deviation set to the local point spacing:
the root of the mean squared distance to the 3 nearest other points. That is what 3DGS's ``distCUDA2`` computes
(``scales = log(sqrt(mean_k d_k^2))``) and what gsplat copies; it is often described loosely as "the mean distance
to the 3 nearest neighbours". Identity rotation, opacity 0.1, DC colour from the point colour, higher SH zero.

Random (no SfM points): points are drawn inside the union of the training cameras' view frustums, between a near
and a far depth derived from the scene's camera sphere (``Scene.center``, ``Scene.extent``); see
:func:`gaussians_random`. The scales then follow from these points exactly as above.

Empty or degenerate point clouds (no points, NaN/inf coordinates, all points at one place) raise InputError; there
is no silent fallback to random initialisation, because a broken SfM result is something the user must hear about.
A caller that wants the fallback can catch the error and call :func:`gaussians_random` itself.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from training.core.errors import InputError
from training.model.gaussians import Gaussians, num_sh_coeffs, rgb_to_sh0
from training.scene.scene import Scene

INITIAL_OPACITY = 0.1
NUM_NEIGHBOURS = 3
# Smallest initial standard deviation, relative to the point cloud's bounding-box diagonal: about 10 float32 ulps
# of the coordinates, below which a size means nothing. It matters where 4+ points coincide (the 3-NN distance is
# then 0 and log(0) would be -inf). It must stay far below real spacings even when a few SfM outliers blow up the
# diagonal. 3DGS clamps the squared distance at an absolute 1e-7, which is not scale-invariant.
MIN_SCALE_RELATIVE = 1e-6
# Random init depth range, in units of Scene.extent (the camera sphere's radius): from NEAR x extent in front of
# each camera to the far side of the camera sphere (distance to the centre + extent).
RANDOM_NEAR = 0.05


def knn_scale(points: np.ndarray, k: int = NUM_NEIGHBOURS) -> np.ndarray:
    """(P,) root-mean-square distance from each point to its ``k`` nearest other points (fewer if P <= k).

    points: (P, 3) float, P >= 2, not all identical. Clamped below at MIN_SCALE_RELATIVE x bounding-box diagonal.
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64)
    k = min(k, len(pts) - 1)
    dist, _ = cKDTree(pts).query(pts, k=k + 1)  # the first neighbour is the point itself
    dist = np.asarray(dist).reshape(len(pts), k + 1)[:, 1:]
    rms = np.sqrt((dist**2).mean(axis=1))
    diag = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    return np.maximum(rms, MIN_SCALE_RELATIVE * diag)


def gaussians_from_points(points: np.ndarray | torch.Tensor, colors: np.ndarray | torch.Tensor | None,
                          sh_degree: int = 3, source: str | Path | None = None,
                          device: str | torch.device = "cpu") -> Gaussians:
    """One isotropic Gaussian per point (3DGS initialisation).

    points: (P, 3) world coordinates. colors: (P, 3) RGB in [0, 1] (uint8 0..255 also accepted), or None for
    mid-grey. ``source`` names the file the points came from in error messages. Returns float32 tensors on
    ``device`` with sh_degree ``sh_degree`` (shN all zero). Raises InputError for an empty point cloud, NaN/inf
    coordinates, or fewer than 2 distinct positions.
    """
    if not 0 <= sh_degree <= 3:
        raise ValueError(f"sh_degree must be 0..3, got {sh_degree}")
    pts = _as_numpy(points).astype(np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (P, 3), got {pts.shape}")
    p = len(pts)
    if p == 0:
        raise InputError(source, "the point cloud is empty; Gaussians cannot be initialised from it")
    bad = int((~np.isfinite(pts)).any(axis=1).sum())
    if bad:
        raise InputError(source, f"{bad} of {p} points have NaN or infinite coordinates")
    if p < 2 or not np.ptp(pts, axis=0).any():
        raise InputError(source, f"all {p} points lie at one position; the point cloud is degenerate")

    if colors is None:
        rgb = np.full((p, 3), 0.5)
    else:
        c = _as_numpy(colors)
        if c.shape != (p, 3):
            raise ValueError(f"colors must have shape ({p}, 3), got {c.shape}")
        rgb = c.astype(np.float64) / 255.0 if c.dtype == np.uint8 else c.astype(np.float64)
        if not np.isfinite(rgb).all():
            raise InputError(source, "point colours hold NaN or infinite values")
        rgb = rgb.clip(0.0, 1.0)

    log_scale = np.log(knn_scale(pts))
    quats = np.zeros((p, 4))
    quats[:, 0] = 1.0
    logit = np.log(INITIAL_OPACITY / (1.0 - INITIAL_OPACITY))

    def t(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)).to(device)

    return Gaussians(
        means=t(pts),
        log_scales=t(np.repeat(log_scale[:, None], 3, axis=1)),
        quats=t(quats),
        opacity_logits=t(np.full(p, logit)),
        sh0=rgb_to_sh0(t(rgb))[:, None, :],
        shN=torch.zeros((p, num_sh_coeffs(sh_degree) - 1, 3), dtype=torch.float32, device=device),
        sh_degree=sh_degree,
    )


def random_view_points(scene: Scene, n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) float64 points, each inside the view frustum of at least one training camera.

    Each point picks a training camera uniformly (all cameras when the scene has no split), a pixel position
    uniformly over the image, and a depth z in [near, far] along that pixel's ray, with
    near = RANDOM_NEAR x extent and far = |camera centre - scene centre| + extent (the far side of the sphere that
    encloses all cameras). The depth is drawn with density ~ z^2 so that points are uniform in the frustum's volume
    (what a uniform box init, as 3DGS does for synthetic scenes, gives in the region the cameras see); regions that
    many cameras see get proportionally more points. Forward-facing captures whose content lies beyond that far
    bound need SfM points instead (``splatstyler sfm``).
    """
    if n <= 0:
        raise ValueError(f"number of random Gaussians must be positive, got {n}")
    if not scene.cameras:
        raise InputError(scene.source, "the scene has no cameras; random Gaussians need camera frustums")
    cams = [scene.cameras[i] for i in scene.train_indices] if scene.train_indices else list(scene.cameras)
    rng = np.random.default_rng(seed)
    which = rng.integers(0, len(cams), size=n)
    out = np.empty((n, 3))
    extent = float(scene.extent)
    center = np.asarray(scene.center, dtype=np.float64)
    for i, cam in enumerate(cams):
        idx = np.nonzero(which == i)[0]
        if len(idx) == 0:
            continue
        m = len(idx)
        near = RANDOM_NEAR * extent
        far = max(float(np.linalg.norm(cam.center - center)) + extent, 2.0 * near)
        u = rng.uniform(0.0, cam.width, m)
        v = rng.uniform(0.0, cam.height, m)
        z = np.cbrt(near**3 + rng.uniform(0.0, 1.0, m) * (far**3 - near**3))
        out[idx] = cam.unproject(u, v, z)
    return out


def gaussians_random(scene: Scene, n: int, sh_degree: int = 3, seed: int = 0,
                     device: str | torch.device = "cpu") -> Gaussians:
    """``n`` Gaussians at random points inside the cameras' view volume (:func:`random_view_points`), random
    colours, scales from their 3-NN spacing, identity rotation, opacity 0.1. Deterministic for a given seed."""
    if n < 2:
        raise ValueError(f"random initialisation needs at least 2 Gaussians (scales come from their spacing), got {n}")
    pts = random_view_points(scene, n, seed)
    colors = np.random.default_rng(seed + 1).uniform(0.0, 1.0, (n, 3))
    return gaussians_from_points(pts, colors, sh_degree, scene.source, device)


def _as_numpy(a: np.ndarray | torch.Tensor) -> np.ndarray:
    if isinstance(a, torch.Tensor):
        return a.detach().cpu().numpy()
    return np.asarray(a)
