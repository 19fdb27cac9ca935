"""The Gaussian model: raw (pre-activation) parameters as torch tensors, with the activations in one place.

Parameters, as 3DGS and gsplat store them:
- ``means``          (N, 3)  world-space centres
- ``log_scales``     (N, 3)  log of the per-axis standard deviations
- ``quats``          (N, 4)  rotation quaternions, (w, x, y, z), not necessarily normalised
- ``opacity_logits`` (N,)    inverse-sigmoid of the opacity
- ``sh0``            (N, 1, 3)        degree-0 SH coefficient (the "DC" term)
- ``shN``            (N, (d+1)^2-1, 3) SH coefficients of degrees 1..d, coefficient-major (as gsplat)

``sh_degree`` is the largest degree this model holds (0..3); trainers may render with fewer.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from training.model.sh_constants import SH_C0


def num_sh_coeffs(degree: int) -> int:
    return (degree + 1) ** 2


def rgb_to_sh0(rgb: torch.Tensor) -> torch.Tensor:
    """RGB in [0,1] to the DC coefficient whose degree-0 evaluation gives that colour."""
    return (rgb - 0.5) / SH_C0


def sh0_to_rgb(sh0: torch.Tensor) -> torch.Tensor:
    return sh0 * SH_C0 + 0.5


@dataclass
class Gaussians:
    means: torch.Tensor
    log_scales: torch.Tensor
    quats: torch.Tensor
    opacity_logits: torch.Tensor
    sh0: torch.Tensor
    shN: torch.Tensor
    sh_degree: int

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        expect = {
            "means": (n, 3),
            "log_scales": (n, 3),
            "quats": (n, 4),
            "opacity_logits": (n,),
            "sh0": (n, 1, 3),
            "shN": (n, num_sh_coeffs(self.sh_degree) - 1, 3),
        }
        for name, shape in expect.items():
            got = tuple(getattr(self, name).shape)
            if got != shape:
                raise ValueError(f"Gaussians.{name} has shape {got}, expected {shape}")

    # --- activations: the only place where raw parameters become render parameters ---
    @property
    def scales(self) -> torch.Tensor:
        """(N, 3) standard deviations along the local axes."""
        return torch.exp(self.log_scales)

    @property
    def rotations(self) -> torch.Tensor:
        """(N, 4) unit quaternions (w, x, y, z)."""
        return torch.nn.functional.normalize(self.quats, dim=-1)

    @property
    def opacities(self) -> torch.Tensor:
        """(N,) opacities in (0, 1)."""
        return torch.sigmoid(self.opacity_logits)

    @property
    def sh(self) -> torch.Tensor:
        """(N, (d+1)^2, 3) all SH coefficients, DC first."""
        return torch.cat([self.sh0, self.shN], dim=1)

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def device(self) -> torch.device:
        return self.means.device

    def parameters(self) -> dict[str, torch.Tensor]:
        return {
            "means": self.means,
            "log_scales": self.log_scales,
            "quats": self.quats,
            "opacity_logits": self.opacity_logits,
            "sh0": self.sh0,
            "shN": self.shN,
        }

    def detached(self) -> "Gaussians":
        """A copy whose tensors share nothing with this model and carry no autograd history."""
        return Gaussians(**{k: v.detach().clone() for k, v in self.parameters().items()}, sh_degree=self.sh_degree)

    def subset(self, mask_or_index: torch.Tensor) -> "Gaussians":
        return Gaussians(**{k: v[mask_or_index] for k, v in self.parameters().items()}, sh_degree=self.sh_degree)

    def to(self, device: str | torch.device) -> "Gaussians":
        return Gaussians(**{k: v.to(device) for k, v in self.parameters().items()}, sh_degree=self.sh_degree)
