"""Linear colour transfer (as ARF): an affine map of RGB that gives a set of content colours the mean and covariance
of the style image's colours.

With content colours of mean mu_c and covariance S_c, and style colours mu_s, S_s, the map
    x -> A (x - mu_c) + mu_s,   A = S_s^(1/2) S_c^(-1/2)
(symmetric square roots from the eigendecompositions) gives covariance A S_c A^T = S_s^(1/2) S_c^(-1/2) S_c
S_c^(-1/2) S_s^(1/2) = S_s and mean mu_s. Of all matrices with that property, this A is the one that moves the
colours least when the two covariances share eigenvectors, which is why it is the usual choice.

Applied to Gaussians it must act on the colour the SH evaluates to, rgb = SH_C0 * sh0 + 0.5 + sum_k Y_k shN_k:
the affine part goes into the DC term (computed in colour space, then converted back), the higher orders take
the 3x3 matrix alone, so every view direction sees A rgb + b. Alpha blending is linear too, so a render of the
transformed model equals A image + alpha * b wherever no colour is clamped at 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np
import torch

from training.model.gaussians import SH_C0, Gaussians

# Eigenvalues of the content covariance below this (relative to the largest, or absolutely) are raised to it:
# a grey or single-colour content set has a singular covariance, and its inverse square root must stay finite.
_EIG_FLOOR_REL = 1e-6
_EIG_FLOOR_ABS = 1e-10


@dataclass
class ColorTransform:
    """rgb' = A @ rgb + b, float64."""

    A: np.ndarray  # (3, 3)
    b: np.ndarray  # (3,)

    def as_matrix(self) -> np.ndarray:
        """(4, 4) homogeneous form."""
        m = np.eye(4)
        m[:3, :3] = self.A
        m[:3, 3] = self.b
        return m

    def to_dict(self) -> dict:
        return {"A": self.A.tolist(), "b": self.b.tolist()}


def _sym_power(cov: np.ndarray, power: float, floor: bool) -> np.ndarray:
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    vals = np.maximum(vals, 0.0)
    if floor:
        vals = np.maximum(vals, max(_EIG_FLOOR_ABS, _EIG_FLOOR_REL * float(vals.max(initial=0.0))))
    return (vecs * vals ** power) @ vecs.T


def colour_stats(pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (3,) and covariance (3, 3) of (P, 3) colours, float64, population normalisation (1/P)."""
    x = np.asarray(pixels, dtype=np.float64).reshape(-1, 3)
    mu = x.mean(axis=0)
    d = x - mu
    return mu, d.T @ d / max(len(x), 1)


def fit_color_transfer(content_pixels: np.ndarray | Iterable[np.ndarray], style_pixels: np.ndarray) -> ColorTransform:
    """The map that gives ``content_pixels`` (P, 3) — or a list of images, pooled — the style's colour statistics."""
    if not isinstance(content_pixels, np.ndarray):
        content_pixels = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in content_pixels])
    return transfer_between(colour_stats(content_pixels), colour_stats(style_pixels))


def transfer_between(content: tuple[np.ndarray, np.ndarray], style: tuple[np.ndarray, np.ndarray]) -> ColorTransform:
    """The map that gives colours of the statistics ``content`` (mean, covariance) those of ``style``."""
    (mu_c, cov_c), (mu_s, cov_s) = content, style
    A = _sym_power(cov_s, 0.5, floor=False) @ _sym_power(cov_c, -0.5, floor=True)
    return ColorTransform(A=A, b=mu_s - A @ mu_c)


def apply_to_render(image: torch.Tensor, alpha: torch.Tensor, transform: ColorTransform) -> torch.Tensor:
    """(H, W, 3) render over black and its (H, W, 1) alpha -> the render of the model ``apply_to_gaussians`` maps,
    A image + alpha b, clipped to [0, 1] as the measures clip renders."""
    A = torch.as_tensor(transform.A.T, dtype=image.dtype, device=image.device)
    b = torch.as_tensor(transform.b, dtype=image.dtype, device=image.device)
    return (image @ A + alpha * b).clamp(0, 1)


def apply_to_colors(colors: np.ndarray, transform: ColorTransform, clip: bool = False) -> np.ndarray:
    """(..., 3) colours mapped by the transform (float32 out); ``clip`` keeps them in [0, 1]."""
    c = np.asarray(colors, dtype=np.float64)
    out = c @ transform.A.T + transform.b
    if clip:
        out = np.clip(out, 0.0, 1.0)
    return out.astype(np.float32)


def apply_to_image(image: np.ndarray, transform: ColorTransform) -> np.ndarray:
    """(H, W, 3) image in [0, 1] mapped and clipped to [0, 1] (as ARF does for the content images)."""
    return apply_to_colors(image, transform, clip=True)


def apply_to_gaussians(gaussians: Gaussians, transform: ColorTransform) -> Gaussians:
    """A new model whose SH colours evaluate to A rgb + b in every direction; geometry tensors are shared, untouched.

    sh0 (N,1,3): rgb0 = SH_C0 sh0 + 0.5 -> A rgb0 + b -> back to sh0. shN (N,k,3): each coefficient's colour vector
    times A (no offset: the higher orders carry no constant term).
    """
    A = torch.as_tensor(transform.A, dtype=torch.float64, device=gaussians.device)
    b = torch.as_tensor(transform.b, dtype=torch.float64, device=gaussians.device)
    with torch.no_grad():
        rgb0 = gaussians.sh0.double() * SH_C0 + 0.5
        sh0 = ((rgb0 @ A.T + b - 0.5) / SH_C0).to(gaussians.sh0.dtype)
        shN = (gaussians.shN.double() @ A.T).to(gaussians.shN.dtype)
    return Gaussians(means=gaussians.means, log_scales=gaussians.log_scales, quats=gaussians.quats,
                     opacity_logits=gaussians.opacity_logits, sh0=sh0.contiguous(), shN=shN.contiguous(),
                     sh_degree=gaussians.sh_degree)


def foreground_pixels(image: np.ndarray, alpha: np.ndarray | None, min_alpha: float = 0.5) -> np.ndarray:
    """(P, 3) colours of a render where it is covered (alpha >= min_alpha), un-premultiplied by alpha.

    Renders over a black background would otherwise pull the statistics towards black wherever the scene is thin.
    """
    img = np.asarray(image, dtype=np.float64).reshape(-1, 3)
    if alpha is None:
        return img
    a = np.asarray(alpha, dtype=np.float64).reshape(-1)
    keep = a >= min_alpha
    return img[keep] / a[keep, None]
