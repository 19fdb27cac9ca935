"""Selections by what Gaussians are rather than where they project: similar colour, opacity range, size range,
grown or shrunk by neighbours, and a brush that takes only the visible surface. numpy (and scipy's k-d tree); the
Edit panel's "More selections" section (select_tools_panel.py) calls these and combines their masks by the mode.

Colours are the base (view-independent) colour a Gaussian shows, ``SH_C0 * dc + 0.5`` in 0..1 RGB, compared by
Euclidean distance (so a tolerance of 0.1 is a tenth of the way from black to a pure primary). Sizes are the
largest of a Gaussian's three standard deviations (world units): what a user sees as a splat's extent.

"Colour pick" takes the Gaussian that gives the pixel under the cursor most of its colour (each Gaussian's alpha
there times the transmittance in front of it, as the renderer composites): the splat a user sees there.

The surface brush needs the depth the renderer composited at each pixel (``render_arrays``'s expected depth,
sum z a T / alpha): a Gaussian under the brush is on the visible surface when its centre's camera depth is within
``tolerance`` (a fraction) of the depth drawn at its pixel, so Gaussians behind a wall, or inside an object, stay
unselected where a plain brush takes every centre that projects under it.
"""

from __future__ import annotations

import numpy as np

from training.model.sh_constants import SH_C0


def base_colours(sh: np.ndarray) -> np.ndarray:
    """(N, 3) base RGB in 0..1 from (N, K, 3) SH."""
    return np.clip(SH_C0 * np.asarray(sh[:, 0], np.float64) + 0.5, 0.0, 1.0)


def similar_colour(sh: np.ndarray, reference, tolerance: float) -> np.ndarray:
    """(N,) bool: base colour within ``tolerance`` of ``reference`` (RGB 0..1)."""
    d = base_colours(sh) - np.asarray(reference, np.float64)[None, :]
    return np.einsum("ij,ij->i", d, d) <= float(tolerance) ** 2


def sizes(scales: np.ndarray) -> np.ndarray:
    return np.asarray(scales, np.float64).max(axis=1)


def in_range(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    lo, hi = sorted((float(lo), float(hi)))
    v = np.asarray(values, np.float64)
    return (v >= lo) & (v <= hi)


def camera_depths(means: np.ndarray, camera) -> np.ndarray:
    w2c = np.asarray(camera.world_to_camera, np.float64)
    return means.astype(np.float64) @ w2c[2, :3] + w2c[2, 3]


def on_surface(means: np.ndarray, camera, depth: np.ndarray, tolerance: float) -> np.ndarray:
    """(N,) bool: centres in front of ``camera`` whose depth is within ``tolerance`` (a fraction) of the depth
    image ``depth`` (H, W, top row first, 0 where nothing was drawn) at their pixel."""
    uv, front = camera.project(means)
    h, w = depth.shape
    px, py = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
    inside = front & (px >= 0) & (px < w) & (py >= 0) & (py < h)
    out = np.zeros(len(means), bool)
    rows = np.nonzero(inside)[0]
    surface = depth[py[rows], px[rows]].astype(np.float64)
    z = camera_depths(means[rows], camera)
    out[rows] = (surface > 0) & (np.abs(z - surface) <= float(tolerance) * surface)
    return out


def surface_brush(means, camera, points, radius: float, depth: np.ndarray, tolerance: float) -> np.ndarray:
    """The brush's stroke (pixel points, ``radius`` in pixels), visible surface only."""
    uv, front = camera.project(means)
    under = np.zeros(len(means), bool)
    for x, y in points:
        under |= (uv[:, 0] - x) ** 2 + (uv[:, 1] - y) ** 2 <= radius ** 2
    under &= front
    out = np.zeros(len(means), bool)
    rows = np.nonzero(under)[0]
    out[rows] = on_surface(means[rows], camera, depth, tolerance)
    return out


def weights_at(model, camera, x: float, y: float, visible: np.ndarray | None = None,
               chunk: int = 1 << 18) -> np.ndarray:
    """(N,) each Gaussian's share of pixel (x, y)'s colour, alpha times the transmittance left in front of it, as
    the renderer composites (EWA projection with its low-pass, ALPHA_MIN and ALPHA_MAX; training/raster)."""
    from training.raster.constants import ALPHA_MAX, ALPHA_MIN, EPS2D, FOV_CLAMP_MARGIN, NEAR_PLANE
    from training.scene.pose import splat_footprints

    n = len(model.means)
    alpha = np.zeros(n)
    z_all = np.full(n, np.inf)
    for lo in range(0, n, chunk):
        sl = slice(lo, min(lo + chunk, n))
        z = camera_depths(np.asarray(model.means[sl]), camera)
        ok = z > NEAR_PLANE
        if visible is not None:
            ok &= visible[sl]
        rows = np.nonzero(ok)[0]
        if len(rows) == 0:
            continue
        zr = z[rows]
        uv, cov = splat_footprints(camera, model.means[sl][rows], model.quats[sl][rows], model.scales[sl][rows],
                                   EPS2D, FOV_CLAMP_MARGIN)
        a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
        det = a * c - b * b
        dx = x - uv[:, 0]
        dy = y - uv[:, 1]
        power = -0.5 * (c * dx * dx - 2 * b * dx * dy + a * dy * dy) / np.maximum(det, 1e-30)
        al = np.minimum(ALPHA_MAX, np.asarray(model.opacities[sl][rows], np.float64) * np.exp(power))
        al[(al < ALPHA_MIN) | (det <= 0)] = 0.0
        alpha[lo + rows] = al
        z_all[lo + rows] = zr
    order = np.argsort(z_all, kind="stable")  # front to back
    a_sorted = alpha[order]
    transmittance = np.concatenate([[1.0], np.cumprod(1.0 - a_sorted)[:-1]])
    weights = np.zeros(n)
    weights[order] = a_sorted * transmittance
    return weights


def pick(model, camera, x: float, y: float, visible: np.ndarray | None = None) -> int | None:
    """The Gaussian under pixel (x, y): the one that gives the pixel most of its colour; None over the
    background (no Gaussian gives it a visible share)."""
    w = weights_at(model, camera, x, y, visible)
    best = int(np.argmax(w)) if len(w) else 0
    return best if len(w) and w[best] >= 1.0 / 255.0 else None


class Neighbours:
    """k nearest neighbours of the model's centres (scipy's cKDTree), built once per geometry."""

    def __init__(self):
        self._key = None
        self._tree = None

    def tree(self, means: np.ndarray, key):
        if key != self._key:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(np.asarray(means, np.float64))
            self._key = key
        return self._tree

    def of(self, means, key, rows: np.ndarray, k: int) -> np.ndarray:
        """(len(rows), k) indices of each row's k nearest other centres."""
        tree = self.tree(means, key)
        k_all = min(int(k) + 1, len(means))
        _, idx = tree.query(np.asarray(means, np.float64)[rows], k=k_all)
        return np.asarray(idx).reshape(len(rows), k_all)[:, 1:]


def grow(selected: np.ndarray, neighbours: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The selection plus the neighbours of its rows (``neighbours`` from ``Neighbours.of(rows)``)."""
    out = selected.copy()
    out[neighbours.ravel()] = True
    return out


def shrink(selected: np.ndarray, neighbours: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The selection less its rows with an unselected neighbour (its border)."""
    out = selected.copy()
    border = ~selected[neighbours].all(axis=1)
    out[rows[border]] = False
    return out
