"""Content preservation: a self-similarity structure distance and the PSNR of a blurred luminance.

Structure distance (after STROTSS, Kolkin et al. 2019, eq. 3, with VGG-16 in place of the paper's DINO-ViT keys;
docs/evaluation.md): at ``STRUCTURE_POSITIONS`` positions drawn once (uniform over the image, torch generator
seeded with ``STRUCTURE_SEED``, the same positions for the stylized and the original render), the relu3_1 and
relu4_1 features are sampled bilinearly; per layer, the cosine self-distance D_ij = 1 - cos(f_i, f_j) of the n
positions; each column normalised to mean 1, A_ij = D_ij / mean_i D_ij (Kolkin et al. divide by the column sum,
which makes the value shrink as 1/n; ours is theirs times n); the distance is mean_ij |A^X_ij - A^C_ij| between
the stylized render X and the original C, averaged over the two layers. 0 for identical images; it reads the
arrangement of features (what resembles what across the image), not their values, so a change of palette or
texture that keeps the layout scores low and a scrambled layout high.

Blurred-luminance PSNR: Rec. 709 luminance Y = 0.2126 R + 0.7152 G + 0.0722 B of each image, blurred with a
Gaussian of sigma = ``BLUR_SIGMA_FRACTION`` x the image's long side (4 px at 256 px; kernel radius 3 sigma,
reflected borders), PSNR = 10 log10(1 / mean (Y_X - Y_C)^2) in dB (peak 1; infinite for identical images). The
blur takes away the painting's texture: what is left is the shading and layout of the scene.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

STRUCTURE_POSITIONS = 1024
STRUCTURE_SEED = 0
STRUCTURE_LAYERS = ("relu3", "relu4")
BLUR_SIGMA_FRACTION = 1 / 64
REC709 = (0.2126, 0.7152, 0.0722)


def sample_positions(n: int = STRUCTURE_POSITIONS, seed: int = STRUCTURE_SEED) -> torch.Tensor:
    """(n, 2) positions in grid_sample's [-1, 1] coordinates, the same for a given n and seed."""
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 2, generator=g, dtype=torch.float64) * 2 - 1


def _sampled(feats: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
    """(1, C, h, w) features at (n, 2) positions -> (n, C) float64."""
    grid = positions.to(feats.device, torch.float32)[None, None]
    s = F.grid_sample(feats.float(), grid, mode="bilinear", align_corners=False)  # (1, C, 1, n)
    return s[0, :, 0].t().double()


def self_distance(rows: torch.Tensor) -> torch.Tensor:
    """(n, C) -> (n, n) cosine distance 1 - cos, each column divided by its mean."""
    unit = rows / rows.norm(dim=1, keepdim=True).clamp_min(1e-12)
    d = (1 - unit @ unit.t()).clamp_min(0)
    return d / d.mean(dim=0, keepdim=True).clamp_min(1e-12)


def structure_distance(stylized_taps: dict[str, torch.Tensor], original_taps: dict[str, torch.Tensor],
                       positions: torch.Tensor | None = None, layers=STRUCTURE_LAYERS) -> float:
    """Mean over ``layers`` of mean_ij |A^X_ij - A^C_ij| (module docstring); taps from ``VGGTaps``."""
    positions = sample_positions() if positions is None else positions
    values = []
    for layer in layers:
        a = self_distance(_sampled(stylized_taps[layer], positions))
        b = self_distance(_sampled(original_taps[layer], positions))
        values.append(float((a - b).abs().mean()))
    return float(np.mean(values))


def luminance(image) -> torch.Tensor:
    """(H, W, 3) -> (H, W) Rec. 709 luminance, float64."""
    x = torch.as_tensor(np.asarray(image) if not isinstance(image, torch.Tensor) else image).double()[..., :3]
    return x @ torch.tensor(REC709, dtype=torch.float64)


def gaussian_blur(y: torch.Tensor, sigma: float) -> torch.Tensor:
    """(H, W) blurred by a separable Gaussian (radius ceil(3 sigma), reflected borders)."""
    if sigma <= 0:
        return y
    radius = max(1, math.ceil(3 * sigma))
    radius = min(radius, y.shape[0] - 1, y.shape[1] - 1)  # reflect padding needs fewer than the side
    if radius < 1:
        return y
    t = torch.arange(-radius, radius + 1, dtype=torch.float64)
    k = torch.exp(-0.5 * (t / sigma) ** 2)
    k = k / k.sum()
    x = y[None, None]
    x = F.conv2d(F.pad(x, (radius, radius, 0, 0), mode="reflect"), k.view(1, 1, 1, -1))
    x = F.conv2d(F.pad(x, (0, 0, radius, radius), mode="reflect"), k.view(1, 1, -1, 1))
    return x[0, 0]


def blurred_luminance_psnr(image, reference, sigma_fraction: float = BLUR_SIGMA_FRACTION) -> float:
    """PSNR (dB, peak 1) between the blurred luminances of two (H, W, 3) images in [0, 1]; inf when equal."""
    a, b = luminance(image), luminance(reference)
    if a.shape != b.shape:
        raise ValueError(f"images differ in size: {tuple(a.shape)} and {tuple(b.shape)}")
    sigma = sigma_fraction * max(a.shape)
    mse = float(((gaussian_blur(a, sigma) - gaussian_blur(b, sigma)) ** 2).mean())
    return math.inf if mse <= 0 else 10 * math.log10(1.0 / mse)
