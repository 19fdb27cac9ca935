"""Is this model a reconstruction of this scene? A model from another scene or coordinate frame mostly lies outside
the cameras' views, and its renders of them are empty: both are refused with one line before any stylization."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from training.core.errors import InputError
from training.model.gaussians import Gaussians
from training.scene.scene import Camera

MATCH_MIN_INSIDE = 0.5  # at least this fraction of the Gaussians must lie inside some camera's view
MATCH_MIN_ALPHA = 0.02  # a render whose mean coverage is below this shows (nearly) nothing


def check_model_matches_scene(gaussians: Gaussians, cameras: list[Camera], model_name: str | Path | None = None,
                              near: float = 0.01) -> float:
    """Fraction of Gaussians inside at least one camera's view frustum; InputError when most are outside.

    A model reconstructed from these photos lies in front of the cameras that saw it; a model from another scene
    (or in another coordinate frame) mostly does not."""
    means = gaussians.means.detach().to("cpu", torch.float64).numpy()
    if len(means) == 0:
        raise InputError(model_name, "the model holds no Gaussians")
    inside = np.zeros(len(means), dtype=bool)
    for cam in cameras:
        (u, v), front = (a.T for a in cam.project(means, near))
        mx, my = 0.1 * cam.width, 0.1 * cam.height  # a small margin: splats just outside still reach the image
        inside |= front & (u > -mx) & (u < cam.width + mx) & (v > -my) & (v < cam.height + my)
    fraction = float(inside.mean())
    if fraction < MATCH_MIN_INSIDE:
        raise InputError(model_name, f"only {fraction:.0%} of its {len(means)} Gaussians lie inside any camera's "
                                     "view: the model does not belong to this scene (or to its coordinate frame)")
    return fraction


def check_renders_not_empty(render, cameras: list[Camera], model_name: str | Path | None = None) -> None:
    """InputError when small renders (``render(camera)`` -> (image, alpha)) of the first, middle and last of
    ``cameras`` all show (nearly) nothing."""
    from training.stylize.config import render_camera

    picks = sorted({0, len(cameras) // 2, len(cameras) - 1})
    with torch.no_grad():
        coverage = [float(render(render_camera(cameras[i], 96))[1].mean()) for i in picks]
    if max(coverage) < MATCH_MIN_ALPHA:
        raise InputError(model_name, f"renders of the scene's views are empty (coverage at most "
                                     f"{max(coverage):.1%}): the model does not match this scene")
