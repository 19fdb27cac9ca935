"""The stylization report's own style figure: the Gram distance between the renders' VGG relu3 features and the
painting's, prepared exactly as the loss sees them, before, after the pre colour transfer and at the end of a run.

It stays beside the trainer rather than in training/evaluate (whose measures use VGG-16 relu1_1..relu4_1 from the
LPIPS weights, docs/evaluation.md): the stylize pipeline takes it before the first step, and this package sits
below training/evaluate.
"""

from __future__ import annotations

import numpy as np
import torch

from training.core.messages import check_cancel


def gram_distance(features: torch.Tensor, style_features: torch.Tensor) -> float:
    """The Gram loss (Gatys; ``training.stylize.style_losses.GramStyleLoss``) between two (1, C, h, w) feature maps:
    the style distance of the acceptance figures."""
    from training.stylize.style_losses import GramStyleLoss

    return float(GramStyleLoss()(features, style_features)[0])


def style_distance(stylizer, sh: torch.Tensor | None = None, max_views: int | None = 8,
                   cancel=None) -> dict[str, float]:
    """Mean over a ``Stylizer``'s views (at most ``max_views`` of them, evenly spaced: the report's figure should not
    cost as much as the stylization itself) of the Gram distance between the render's features and the painting's
    (both prepared as for the loss): ``gram`` on the raw relu3 features, ``gram_normalised`` on features scaled to
    unit length per position (blind to overall activation strength, i.e. contrast, which cosine-based losses leave
    free). ``sh``: colours to render with (default: the current ones); ``cancel()`` is asked before each view."""
    from training.stylize.ccft import l2_normalise

    totals = {"gram": 0.0, "gram_normalised": 0.0}
    cameras = stylizer.cameras
    if max_views is not None and len(cameras) > max_views:
        cameras = [cameras[int(i)] for i in np.linspace(0, len(cameras) - 1, max_views).round()]
    with torch.no_grad():
        for cam in cameras:
            check_cancel(cancel)
            image, _ = stylizer.render(cam, sh=sh)
            f, fs = stylizer.features(image.clamp(0, 1)), stylizer.style_features(cam)
            totals["gram"] += gram_distance(f, fs)
            unit = lambda x: l2_normalise(x[0].flatten(1).t()).t().reshape(x.shape)  # noqa: E731
            totals["gram_normalised"] += gram_distance(unit(f), unit(fs))
    return {k: v / len(cameras) for k, v in totals.items()}
