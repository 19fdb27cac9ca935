"""The VGG-16 features a stylization step compares: the render's, the painting's and the content's, the last two
kept so that a new view at every iteration costs no extra VGG pass. Every image is halved before VGG, as ARF does.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Callable

import numpy as np
import torch

from training.stylize.style_image import halve, painting_side, style_for_render

# The content features of the views: about 2.4 MB a view at 256 px, 40-60 MB at 1600 px. Beyond this the least
# recently used view is dropped and computed again when its turn comes.
CONTENT_CACHE_BYTES = 1 << 30


def vgg_in_bfloat16(precision: str, device: torch.device) -> bool:
    """Whether VGG runs in bfloat16 for ``precision`` (StylizeConfig.vgg_precision): "auto" picks it on a CPU that
    multiplies bfloat16 natively (ccft.bf16_matmul_is_faster), where VGG's forward and backward take about 0.6x the
    time of float32's at the quick preset (docs/performance.md)."""
    if precision == "auto":
        from training.stylize.ccft import bf16_matmul_is_faster

        return device.type == "cpu" and bf16_matmul_is_faster()
    return precision == "bfloat16"


class FeatureCache:
    """``vgg`` (an (1, 3, H, W) -> (1, 768, h, w) module on ``device``) over the painting ``style_image`` (H, W, 3).
    ``bfloat16``: VGG's convolutions (and their backward) run in bfloat16, the features come out in float32."""

    def __init__(self, vgg: torch.nn.Module, style_image: np.ndarray, device: torch.device, bfloat16: bool = False):
        self.vgg, self.style_image, self.device, self.bfloat16 = vgg, style_image, device, bfloat16
        self.style: dict[int, torch.Tensor] = {}  # the painting's long side -> features
        self.content: OrderedDict[int, torch.Tensor] = OrderedDict()  # trajectory position -> features
        self.original: OrderedDict[int, torch.Tensor] = OrderedDict()  # the same, of the input's own colours

    def features(self, image_hwc: torch.Tensor) -> torch.Tensor:
        """(H, W, 3) image -> (1, 768, h, w) VGG features of the image halved (ARF)."""
        return self._vgg(halve(image_hwc.permute(2, 0, 1)[None].float()))

    def _vgg(self, x: torch.Tensor) -> torch.Tensor:
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.bfloat16):
            return self.vgg(x).float()

    def style_features(self, width: int, height: int, style_scale: float) -> torch.Tensor:
        """(1, 768, h, w) features of the painting resized so its long side is ``style_scale`` times a
        ``width`` x ``height`` render's, then halved."""
        side = painting_side(max(width, height), style_scale)
        if side not in self.style:
            with torch.no_grad():
                self.style[side] = self._vgg(halve(style_for_render(self.style_image, side).to(self.device)))
        return self.style[side]

    def content_features(self, position: int, content_image: Callable[[], torch.Tensor]) -> torch.Tensor:
        """(1, 768, h, w) content features of trajectory position ``position``; ``content_image()`` gives its
        (H, W, 3) content image when they are not kept (``CONTENT_CACHE_BYTES``)."""
        return self._kept(self.content, position, content_image)

    def original_features(self, position: int, original_image: Callable[[], torch.Tensor]) -> torch.Tensor:
        """(1, 768, h, w) features of the input model's render in its own colours at trajectory position
        ``position`` (the structure budget's "output" measure), kept as the content features are."""
        return self._kept(self.original, position, original_image)

    def forget_renders(self) -> None:
        """Drop the features made from renders of the model (its geometry or state changed)."""
        self.content.clear()
        self.original.clear()

    def _kept(self, cache: OrderedDict, position: int, image: Callable[[], torch.Tensor]) -> torch.Tensor:
        if position in cache:
            cache.move_to_end(position)
            return cache[position]
        with torch.no_grad():
            feats = self.features(image())
        cache[position] = feats
        size = feats.numel() * feats.element_size()
        while len(cache) > 1 and len(cache) * size > CONTENT_CACHE_BYTES:
            cache.popitem(last=False)
        return feats
