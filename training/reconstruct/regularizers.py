"""The paper's geometric regularizers for the enhanced reconstruction (Method, "Enhanced Scene Reconstruction").

Units. The paper's bounds (beta1 = 0.1, beta2 = 0.001) are absolute lengths, so they need a fixed unit. We use
the *normalised scene unit*: world length divided by ``Scene.extent`` (3DGS's ``cameras_extent``, 1.1 x the
largest distance of a camera from the cameras' centre). In those units the cameras lie within the unit ball
whatever the capture's scale, so beta1 = 0.1 is "a tenth of the camera rig's radius". The scales given to these
functions are the *activated* standard deviations exp(log_scales) divided by the extent. The rendered and the
target depth are divided by the extent too, so lambda_depth does not depend on the capture's scale either.
"""

from __future__ import annotations

import math

import torch

LAMBDA_S = 3.5  # expected largest ratio S_max / S_min
BETA1 = 0.1  # upper bound of S_max (normalised units)
BETA2 = 0.001  # lower bound of S_max (normalised units)


def shape_loss(scales: torch.Tensor, lambda_s: float = LAMBDA_S) -> torch.Tensor:
    """L_shape = mean_i [S_max^i - lambda_s S_min^i]_+ for (N, 3) activated scales; scalar (0 when N = 0)."""
    if scales.shape[0] == 0:
        return scales.sum() * 0.0
    smax = scales.max(dim=1).values
    smin = scales.min(dim=1).values
    return torch.relu(smax - lambda_s * smin).mean()


def size_loss(scales: torch.Tensor, beta1: float = BETA1, beta2: float = BETA2) -> torch.Tensor:
    """L_size = mean_i ([S_max^i - beta1]_+ + [beta2 - S_max^i]_+) for (N, 3) activated scales; scalar."""
    if scales.shape[0] == 0:
        return scales.sum() * 0.0
    smax = scales.max(dim=1).values
    return (torch.relu(smax - beta1) + torch.relu(beta2 - smax)).mean()


def depth_loss(rendered: torch.Tensor, target: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """L_depth = mean |D_render - D_target| over the valid pixels.

    rendered (H, W) or (H, W, 1) expected depth; target (H, W); valid (H, W) bool. Zero when nothing is valid."""
    r = rendered.reshape(target.shape)
    if not bool(valid.any()):
        return r.sum() * 0.0
    return (r[valid] - target[valid]).abs().mean()


def depth_weight(step: int, total_steps: int, start: float = 1.0, end: float = 0.01) -> float:
    """lambda_depth at ``step`` of ``total_steps``: exponential (log-linear) decay from ``start`` to ``end``."""
    t = min(max(step / max(total_steps, 1), 0.0), 1.0)
    return float(math.exp((1.0 - t) * math.log(start) + t * math.log(end)))


def scale_stats(scales: torch.Tensor) -> dict:
    """95th percentiles of S_max / S_min and of S_max for (N, 3) scales (normalised units for the latter)."""
    if scales.shape[0] == 0:
        return {"aniso_p95": None, "smax_p95": None}
    s = scales.detach().double()
    smax = s.max(dim=1).values
    smin = s.min(dim=1).values.clamp_min(1e-30)
    return {
        "aniso_p95": float(torch.quantile(smax / smin, 0.95)),
        "smax_p95": float(torch.quantile(smax, 0.95)),
    }
