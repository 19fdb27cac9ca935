"""Rotations of the Gaussian model: quaternions (w, x, y, z) to rotation matrices, for the trainers (densification
splits Gaussians along their axes) and the rasterizers (the torch reference uses this function, the cpu kernels
the same formula and epsilon)."""

from __future__ import annotations

import torch

# A zero quaternion would normalise to 0/0; clamping its length makes it the identity rotation instead of NaN.
QUAT_NORM_EPS = 1e-12


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """(N, 4) wxyz (any norm) -> (N, 3, 3) rotation matrices."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(QUAT_NORM_EPS)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(-1, 3, 3)
