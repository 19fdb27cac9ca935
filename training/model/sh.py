"""Real spherical harmonics up to degree 3, in the basis and sign convention of 3DGS / gsplat.

Colours are ``max(sum_k coeff_k * Y_k(dir) + 0.5, 0)`` with ``dir`` the unit vector from the camera centre to the
Gaussian. The constants are the standard real SH normalisations; the order of the basis functions inside a degree
is the one the 3DGS PLY files use, so models read from disk evaluate identically.
"""

from __future__ import annotations

import torch

from training.model.sh_constants import SH_C0, SH_C1, SH_C2, SH_C3


def sh_basis(degree: int, dirs: torch.Tensor) -> torch.Tensor:
    """Basis values Y_k(dir).

    dirs: (N, 3) unit vectors. Returns (N, (degree+1)^2), same dtype/device.
    """
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        xy, yz, xz = x * y, y * z, x * z
        out += [
            SH_C2[0] * xy,
            SH_C2[1] * yz,
            SH_C2[2] * (2.0 * zz - xx - yy),
            SH_C2[3] * xz,
            SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * xy * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)


def sh_to_rgb(degree: int, coeffs: torch.Tensor, means: torch.Tensor, camera_center: torch.Tensor) -> torch.Tensor:
    """Colours seen from ``camera_center``: SH evaluation + 0.5, clamped below at 0 (3DGS).

    coeffs: (N, K, 3) with K >= (degree+1)^2 (extra coefficients are ignored); means: (N, 3) world;
    camera_center: (3,). Returns (N, 3). Differentiable w.r.t. coeffs and means.
    """
    k = (degree + 1) ** 2
    if coeffs.dim() != 3 or coeffs.shape[-1] != 3 or coeffs.shape[1] < k:
        raise ValueError(f"SH coefficients must be (N, >= {k}, 3) for degree {degree}, got {tuple(coeffs.shape)}")
    dirs = means - camera_center
    # Normalising a zero vector gives 0/0; the eps keeps a Gaussian sitting on the camera centre finite.
    dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    basis = sh_basis(degree, dirs)  # (N, k)
    rgb = (basis.unsqueeze(-1) * coeffs[:, :k, :]).sum(dim=1)
    return torch.clamp_min(rgb + 0.5, 0.0)
