"""Move, turn and scale a Gaussian model by a similarity transform ``x -> s R x + t`` (4x4 matrix, uniform scale,
no mirror): centres move, rotations compose with R, log-scales shift by log s, and the SH bands of degree 1..3 are
rotated so each Gaussian shows the same colour from the same relative direction as before.

Non-uniform scale, shear and mirrors are refused: a Gaussian stays a Gaussian under them, but its axes and its SH
(a function on directions) would have to be refitted, not transformed.

The SH rotation of each degree l is the (2l+1)x(2l+1) matrix D_l with Y_l(R^T d) = D_l Y_l(d) for every direction d
(rotations keep each degree's functions among themselves). It is found from our own basis (training/model/sh.py) at
64 fixed directions by least squares, in float64, which needs no Wigner-matrix recurrences and cannot disagree
with the basis's order and signs; the residual is at rounding level (checked by the tests against evaluation).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from training.model.gaussians import Gaussians, num_sh_coeffs
from training.model.sh import sh_basis
from training.scene.pose import matrix_to_quat

SIMILARITY_TOLERANCE = 1e-5  # relative: R^T R = I, det R = 1 after the scale is divided out


def split_similarity(matrix) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R (3, 3), t (3,)) of a 4x4 similarity; ValueError for anything else (non-uniform scale, shear, mirror,
    projective last row, non-finite values)."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise ValueError(f"a transform must be a finite 4x4 matrix, got shape {m.shape}")
    if np.abs(m[3] - [0, 0, 0, 1]).max() > 0:
        raise ValueError("a transform's last row must be 0 0 0 1")
    a = m[:3, :3]
    det = float(np.linalg.det(a))
    if det <= 0:
        raise ValueError("a transform must not mirror or flatten the model (its determinant is not positive)")
    s = det ** (1.0 / 3.0)
    r = a / s
    if np.abs(r.T @ r - np.eye(3)).max() > SIMILARITY_TOLERANCE:
        raise ValueError("a transform must be a rotation, a uniform scale and a translation (no shear or "
                         "non-uniform scale)")
    return s, r, m[:3, 3].copy()


def _directions(count: int = 64) -> np.ndarray:
    """Fixed, well-spread unit vectors (a Fibonacci sphere)."""
    i = np.arange(count) + 0.5
    phi = np.arccos(1 - 2 * i / count)
    theta = math.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)


def sh_rotation(rotation, degree: int) -> np.ndarray:
    """((d+1)^2 - 1) square float64 matrix X with ``shN' = X @ shN`` (per Gaussian, per channel) for a model turned
    by ``rotation`` (3x3): block diagonal, one block per degree 1..d."""
    r = np.asarray(rotation, dtype=np.float64)
    k = num_sh_coeffs(degree) - 1
    out = np.zeros((k, k))
    if degree == 0:
        return out
    d = _directions()
    basis = sh_basis(degree, torch.from_numpy(d)).numpy()  # (J, K)
    turned = sh_basis(degree, torch.from_numpy(d @ r)).numpy()  # Y(R^T d): rows of d times R
    for level in range(1, degree + 1):
        lo, hi = level * level, (level + 1) * (level + 1)
        # basis @ D^T = turned within the degree; the coefficients take c' = D^T c
        x, *_ = np.linalg.lstsq(basis[:, lo:hi], turned[:, lo:hi], rcond=None)
        out[lo - 1:hi - 1, lo - 1:hi - 1] = x
    return out


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (w, x, y, z) quaternions, broadcasting."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def transform_gaussians(g: Gaussians, matrix) -> Gaussians:
    """``g`` moved by the similarity ``matrix`` (4x4). The identity returns ``g`` itself (bit for bit); a pure
    translation changes only the centres."""
    s, r, t = split_similarity(matrix)
    if s == 1.0 and np.array_equal(r, np.eye(3)) and not t.any():
        return g
    dtype, device = g.means.dtype, g.means.device

    def back(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a)).to(device, dtype)

    means = g.means.detach().cpu().double().numpy()
    params = g.parameters()
    params["means"] = back(s * means @ r.T + t)
    if not (s == 1.0 and np.array_equal(r, np.eye(3))):
        if s != 1.0:
            params["log_scales"] = back(g.log_scales.detach().cpu().double().numpy() + math.log(s))
        if not np.array_equal(r, np.eye(3)):
            q = quat_multiply(matrix_to_quat(r)[None], g.quats.detach().cpu().double().numpy())
            params["quats"] = back(q)
            if g.sh_degree > 0:
                x = sh_rotation(r, g.sh_degree)
                rest = g.shN.detach().cpu().double().numpy()  # (N, K, 3)
                k = rest.shape[1]
                # one (K, K) x (K, 3N) product: a single BLAS call instead of N small ones
                turned = x @ rest.transpose(1, 0, 2).reshape(k, -1)
                params["shN"] = back(turned.reshape(k, -1, 3).transpose(1, 0, 2))
    return Gaussians(**params, sh_degree=g.sh_degree)
