"""VGG-16 features at relu1_1, relu2_1, relu3_1 and relu4_1 for the style and content metrics.

The weights are the 13 ImageNet VGG-16 convolutions of the offline LPIPS weights
(``training.reconstruct.lpips.load_lpips_weights``: conv0 .. conv12 in torchvision's ``vgg16().features`` order);
only conv0 .. conv7 (conv1_1 .. conv4_1) are used. Inputs are RGB in [0, 1] with the ImageNet mean/std
normalisation the network was trained with (LPIPS's scaling layer is the same map written for inputs in [-1, 1]).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from training.core import stop

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
# vgg16().features up to conv4_1: conv widths, "M" a 2x2 max-pool
_CFG = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512]
# conv index (0..7) whose ReLU output is a tap -> its name
TAPS = {0: "relu1", 2: "relu2", 4: "relu3", 7: "relu4"}
LAYERS = tuple(TAPS.values())  # ("relu1", "relu2", "relu3", "relu4") = relu1_1, relu2_1, relu3_1, relu4_1
CHANNELS = {"relu1": 64, "relu2": 128, "relu3": 256, "relu4": 512}


def as_batch(image) -> torch.Tensor:
    """(H, W, 3) numpy/tensor or (B, 3, H, W) tensor -> float32 (B, 3, H, W)."""
    x = torch.as_tensor(np.asarray(image) if isinstance(image, np.ndarray) else image)
    if x.dim() == 3:
        x = x[..., :3].permute(2, 0, 1)[None]
    if x.dim() != 4 or x.shape[1] < 3:
        raise ValueError(f"expected an (H, W, 3) image or a (B, 3, H, W) batch, got {tuple(x.shape)}")
    return x[:, :3].float()


class VGGTaps:
    """``taps(image) -> {"relu1": (B, 64, H, W), "relu2": (B, 128, H/2, W/2), "relu3": (B, 256, H/4, W/4),
    "relu4": (B, 512, H/8, W/8)}``; image (H, W, 3) or (B, 3, H, W) in [0, 1]. No gradient unless ``grad=True``.

    ``state_dict``: the LPIPS weights (``load_lpips_weights()`` when None; an ``LPIPS`` object's ``weights`` may be
    passed to share them)."""

    def __init__(self, state_dict: dict[str, torch.Tensor] | None = None, device: str | torch.device = "cpu"):
        if state_dict is None:
            from training.reconstruct.lpips import load_lpips_weights

            state_dict = load_lpips_weights()
        self.device = torch.device(device)
        self.weights = [(state_dict[f"conv{i}.weight"].detach().float().to(self.device),
                         state_dict[f"conv{i}.bias"].detach().float().to(self.device)) for i in range(8)]
        self.mean = torch.tensor(IMAGENET_MEAN, device=self.device).view(1, 3, 1, 1)
        self.std = torch.tensor(IMAGENET_STD, device=self.device).view(1, 3, 1, 1)

    def __call__(self, image, grad: bool = False, upto: str = "relu4") -> dict[str, torch.Tensor]:
        """Features up to and including the tap ``upto`` (the later ones are not computed)."""
        if upto not in LAYERS:
            raise ValueError(f"unknown tap {upto!r}; expected one of {', '.join(LAYERS)}")
        x = as_batch(image).to(self.device)
        if min(x.shape[-2:]) < 8:
            raise ValueError(f"image {tuple(x.shape[-2:])} is too small for relu4_1 features (at least 8x8)")
        with torch.set_grad_enabled(grad and torch.is_grad_enabled()):
            x = (x - self.mean) / self.std
            out: dict[str, torch.Tensor] = {}
            conv = 0
            for v in _CFG:
                stop.check()  # a pass over a large painting takes seconds on CPU
                if v == "M":
                    x = F.max_pool2d(x, 2, 2)
                    continue
                w, b = self.weights[conv]
                x = F.relu(F.conv2d(x, w, b, padding=1))
                if conv in TAPS:
                    out[TAPS[conv]] = x
                    if TAPS[conv] == upto:
                        break
                conv += 1
        return out
