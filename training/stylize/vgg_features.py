"""VGG-16 style features: relu3_1 | relu3_2 | relu3_3 (768 channels at 1/4 resolution), as ARF uses them.

Only ``features[:16]`` of torchvision's VGG-16 is built (conv1_1 .. relu3_3), with torchvision's layer indices so that
a torchvision state dict loads as is. Frozen and in eval mode; gradients still flow to the input image.
"""

from __future__ import annotations

import torch
from torch import nn

from training.stylize.vgg_weights import VGGWeights, resolve_vgg_weights

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
# Indices in features[:16] whose outputs are relu3_1, relu3_2, relu3_3.
STYLE_LAYERS = (11, 13, 15)
FEATURE_CHANNELS = 768


def _vgg16_features16() -> nn.Sequential:
    """torchvision's ``vgg16().features[:16]``: conv3x3/ReLU blocks 64-64, pool, 128-128, pool, 256-256-256."""
    layers: list[nn.Module] = []
    in_ch = 3
    for out_ch in (64, 64, "M", 128, 128, "M", 256, 256, 256):
        if out_ch == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(in_ch, int(out_ch), kernel_size=3, padding=1), nn.ReLU(inplace=False)]
            in_ch = int(out_ch)
    return nn.Sequential(*layers)


class VGGFeatures(nn.Module):
    """``feats = vgg(img)``: img (B, 3, H, W) RGB in [0, 1] -> (B, 768, H // 4, W // 4).

    ImageNet mean/std normalisation happens inside. ``weights_source`` says where the weights came from."""

    def __init__(self, weights: VGGWeights):
        super().__init__()
        self.features = _vgg16_features16()
        self.features.load_state_dict({k.removeprefix("features."): v for k, v in weights.state_dict.items()})
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN, dtype=torch.float32).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(IMAGENET_STD, dtype=torch.float32).view(1, 3, 1, 1))
        self.weights_source = weights.source
        self.requires_grad_(False)
        self.eval()
        # NHWC: oneDNN's CPU convolutions run faster on it (the forward ~20 %, forward and backward ~12 % at the
        # quick preset's 72x128, docs/performance.md); the features come out the same to float32 rounding
        self.to(memory_format=torch.channels_last)

    def train(self, mode: bool = True) -> "VGGFeatures":
        # Always eval: there is no dropout/batch-norm here, but a caller's model.train() must not change that.
        return super().train(False)

    def forward(self, img: torch.Tensor) -> torch.Tensor:
        """img (B, 3, H, W) in [0, 1] -> (B, 768, H // 4, W // 4)."""
        if img.dim() != 4 or img.shape[1] != 3:
            raise ValueError(f"expected an image batch (B, 3, H, W), got {tuple(img.shape)}")
        if img.shape[2] < 4 or img.shape[3] < 4:
            raise ValueError(f"image {tuple(img.shape[2:])} is too small for VGG features (at least 4x4)")
        x = ((img - self.mean.to(img.dtype)) / self.std.to(img.dtype)).contiguous(memory_format=torch.channels_last)
        outs = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in STYLE_LAYERS:
                outs.append(x)
        return torch.cat(outs, dim=1).contiguous()


def load_vgg16_features(weights: str | None = None) -> VGGFeatures:
    """VGG-16 features[:16] with ImageNet weights (see ``training.stylize.vgg_weights`` for where they are found)."""
    return VGGFeatures(resolve_vgg_weights(weights))
