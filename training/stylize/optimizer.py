"""The stylization's optimiser: Adam over the SH colours (``params="colour"``, the paper's method), and under
``params="all"`` (the paper's ablation) the geometry too at the original 3DGS learning rates (defaults.py). The
colours' rate decays exponentially over the schedule; the geometry's rates are fixed.
"""

from __future__ import annotations

import torch

from training.model.gaussians import Gaussians
from training.stylize.config import StylizeConfig
from training.stylize.defaults import MEANS_LR, OPACITY_LR, QUATS_LR, SCALES_LR, SHN_LR_FACTOR

GEOMETRY = ("means", "log_scales", "quats", "opacity_logits")


def geometry_learning_rates(extent: float) -> dict[str, float]:
    """The 3DGS rates of the raw geometry parameters (the means' scaled by the scene's extent)."""
    return {"means": MEANS_LR * float(extent), "log_scales": SCALES_LR, "quats": QUATS_LR, "opacity_logits": OPACITY_LR}


def make_optimizer(g: Gaussians, config: StylizeConfig, geometry_lrs: dict[str, float] | None) -> torch.optim.Adam:
    """Adam over new leaves put in ``g`` (the caller's, possibly shared, tensors are never written): sh0, shN unless
    ``config.dc_only``, and the geometry when ``geometry_lrs`` is given. Each group is named; ``lr_scale`` is the
    colour group's share of the colours' rate (None: a fixed geometry rate)."""
    sh0 = g.sh0.detach().clone().requires_grad_(True)
    shN = g.shN.detach().clone().requires_grad_(not config.dc_only)
    g.sh0, g.shN = sh0, shN
    lr = config.learning_rate
    groups = [{"params": [sh0], "lr_scale": 1.0, "lr": lr, "name": "sh0"}]
    if not config.dc_only and shN.numel() > 0:
        groups.append({"params": [shN], "lr_scale": SHN_LR_FACTOR, "lr": lr * SHN_LR_FACTOR, "name": "shN"})
    for name, rate in (geometry_lrs or {}).items():
        leaf = getattr(g, name).detach().clone().requires_grad_(True)
        setattr(g, name, leaf)
        groups.append({"params": [leaf], "lr_scale": None, "lr": rate, "name": name})
    return torch.optim.Adam(groups, eps=1e-15)


def colour_learning_rate(config: StylizeConfig, iteration: int, total_iters: int) -> float:
    """The colours' learning rate at ``iteration``: ``lr`` decayed exponentially to ``lr * lr_final`` at the last
    iteration of the schedule (constant with lr_final 1)."""
    progress = min(1.0, iteration / max(1, total_iters - 1))
    return config.learning_rate * config.lr_final ** progress


def set_colour_learning_rate(optimizer: torch.optim.Optimizer, lr: float) -> None:
    for group in optimizer.param_groups:
        if group["lr_scale"] is not None:  # the geometry's rates (params="all") are fixed
            group["lr"] = lr * group["lr_scale"]
