"""The Gaussians a stylization works on, in one place: the model being stylized, the input model it started from
(its colours, and under ``params="all"`` its geometry), the colours after the pre colour transfer (the content of
virtual views), the selection and the colours its unselected Gaussians are held to; and their renders.

Under ``params="colour"`` the activated geometry is computed once (it never changes and needs no gradient); under
``params="all"`` it is activated from the trained parameters at every render, so gradients reach them.
"""

from __future__ import annotations

import numpy as np
import torch

from training.core.messages import check_cancel
from training.model.gaussians import Gaussians
from training.scene.scene import Camera
from training.stylize.optimizer import GEOMETRY


class StylizedModel:
    """A copy of ``gaussians`` on ``device`` sharing its geometry tensors (detached) with new colour tensors;
    ``mask``: the selection ((N,) bool CPU tensor, None: all)."""

    def __init__(self, gaussians: Gaussians, device: torch.device, trains_geometry: bool, mask: torch.Tensor | None):
        geometry = {k: getattr(gaussians, k).detach().to(device) for k in GEOMETRY}
        colour = {k: getattr(gaussians, k).detach().to(device).clone() for k in ("sh0", "shN")}
        self.gaussians = Gaussians(**geometry, **colour, sh_degree=gaussians.sh_degree)
        self.original_sh = torch.cat([colour["sh0"], colour["shN"]], dim=1)  # the input model's colours
        self.device, self.trains_geometry, self.mask = device, trains_geometry, mask
        g = self.gaussians
        self.input_geometry = {k: getattr(g, k).clone() for k in GEOMETRY} if trains_geometry else None  # raw
        self.scales = None if trains_geometry else g.scales.detach()
        self.opacities = None if trains_geometry else g.opacities.detach()
        self.settle()

    def settle(self) -> None:
        """Take the current colours as the pre-stylization ones and as those unselected Gaussians are held to."""
        self.initial_sh = self.gaussians.sh.detach().clone()
        self.frozen = self.gaussians.detached()

    def render(self, camera: Camera, config, sh: torch.Tensor | None = None, input_geometry: bool = False,
               render_mode: str = "RGB") -> tuple[torch.Tensor, torch.Tensor]:
        """Render at ``camera`` (over ``config.background``, with ``config.backend``) with the current colours (or ``sh`` (N, K, 3)) -> image (H, W, 3), alpha (H, W, 1).
        ``input_geometry``: with the input model's geometry (differs from the current one only under "all");
        ``render_mode`` "RGB+ED": the image's fourth channel is the expected depth."""
        from training.raster.rasterize import rasterize

        g, dt, dev = self.gaussians, self.gaussians.means.dtype, self.device
        if input_geometry and self.input_geometry is not None:
            raw = self.input_geometry
            means, quats, scales, opacities = (raw["means"], raw["quats"], torch.exp(raw["log_scales"]),
                                               torch.sigmoid(raw["opacity_logits"]))
        else:
            means, quats = g.means, g.quats
            scales, opacities = (g.scales, g.opacities) if self.trains_geometry else (self.scales, self.opacities)
        image, alpha, _ = rasterize(
            means, quats, scales, opacities, g.sh if sh is None else sh,
            torch.as_tensor(camera.world_to_camera, dtype=dt, device=dev),
            torch.as_tensor(camera.K, dtype=dt, device=dev), camera.width, camera.height, sh_degree=g.sh_degree,
            background=torch.tensor(config.background, dtype=dt, device=dev), render_mode=render_mode,
            backend=config.backend)
        return image, alpha

    def render_views(self, cameras: list[Camera], config, cancel=None, sh: torch.Tensor | None = None,
                     input_geometry: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
        """(image (H, W, 3), alpha (H, W, 1)) numpy renders of ``cameras`` (``render``'s options); ``cancel()`` is
        asked before each view (Cancelled)."""
        out = []
        with torch.no_grad():
            for cam in cameras:
                check_cancel(cancel)
                img, alpha = self.render(cam, config, sh=sh, input_geometry=input_geometry)
                out.append((img.clamp(0, 1).float().cpu().numpy(), alpha.float().cpu().numpy()))
        return out

    def snapshot_geometry(self):
        """(means, scales, rotations, opacities), activated."""
        g = self.gaussians
        if self.trains_geometry:
            return g.means, g.scales, g.rotations, g.opacities
        return g.means, self.scales, g.rotations, self.opacities

    def keep_rows(self, keep: torch.Tensor) -> None:
        """Keep only the Gaussians where ``keep`` ((N,) bool CPU tensor, checked by the caller) in every tensor."""
        index = keep.nonzero()[:, 0].to(self.device)
        self.gaussians = self.gaussians.detached().subset(index)
        if self.trains_geometry:
            self.input_geometry = {k: t[index] for k, t in self.input_geometry.items()}
        else:
            self.scales, self.opacities = self.scales[index], self.opacities[index]
        self.initial_sh, self.original_sh = self.initial_sh[index], self.original_sh[index]
        self.frozen = self.frozen.subset(index)
        self.mask = None if self.mask is None else self.mask[keep]

    def input_gaussians(self) -> Gaussians:
        """The input model (its geometry and colours, the rows ``keep_rows`` left), detached, on the CPU."""
        g, sh = self.gaussians, self.original_sh
        raw = self.input_geometry or {k: getattr(g, k) for k in GEOMETRY}
        return Gaussians(**{k: v.detach().clone() for k, v in raw.items()}, sh0=sh[:, :1].clone(),
                         shN=sh[:, 1:].clone(), sh_degree=g.sh_degree).to("cpu")
