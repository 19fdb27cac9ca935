"""Match agreement: whether views that see the same surface match it to the same style feature (issue 28).

What cross-view matching guidance claims (paper, Cross-view Matching Guidance: "This guidance encourages similar
rendered features across different viewpoints to match the same corresponding style feature"), measured on a
model. For each view, the render's VGG features (as the stylizer prepares them) are matched to the painting's by the
CCFT plan of Algorithm 1 with the run's K, epsilon and tau and **no guidance** (lambda_guide 0, so that a guided and
an unguided run are judged by the same rule), and each rendered feature is assigned the style feature of its largest
plan entry. For a pair of neighbouring views (target t, source s), every feature cell of the target whose centre is
covered is carried to the source with the target's rendered expected depth and the known cameras, by the depth warp
of the consistency metric (training/scene/correspondence.py: in front of the source camera, inside its image,
covered there, at the depth the source renders there, within 3 %); it lands in one source feature cell. The pair's agreement is the
fraction of those corresponding cells whose two assignments are the same style feature; the metric is the mean over
the pairs with at least ``MIN_CELLS`` corresponding cells.

Feature cells: the stylizer's features are relu3 of the render halved, 1/8 of the render's size; cell (i, j) covers
render pixels [8j, 8j + 8) x [8i, 8i + 8) and its centre is where the depth is read. A cell straddling a depth edge
reads a mixed depth and mostly fails the source's depth test, as silhouettes do in the consistency metric.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from training.evaluate.consistency import pairs_at_gap
from training.scene.correspondence import MIN_CELLS, cell_correspondence, label_agreement


def plan_assignments(features: torch.Tensor, style_features: torch.Tensor, k: int, epsilon: float, tau: float,
                     iters: int) -> np.ndarray:
    """(h, w) int64: for each rendered feature of ``features`` (1, C, h, w), the style feature (index into the
    flattened (1, C, h2, w2) ``style_features``) of its largest entry in the unguided CCFT plan."""
    from training.stylize.ccft import ccft_loss

    h, w = features.shape[2:]
    X = features[0].flatten(1).t().detach()
    Y = style_features[0].flatten(1).t().detach()
    plan = ccft_loss(X, Y, None, k=k, epsilon=epsilon, tau=tau, lambda_guide=0.0, iters=iters).plan
    best = plan.values.argmax(dim=1, keepdim=True)
    return plan.indices.gather(1, best)[:, 0].reshape(h, w).cpu().numpy()


def pair_agreement(target_assign, target_depth, target_alpha, target_camera, source_assign, source_depth,
                   source_alpha, source_camera) -> tuple[int, int]:
    """(agreeing cells, corresponding cells) of one pair; assignments (h, w) on the feature grids of the renders
    whose expected depths and alphas (H, W[, 1]) are given."""
    landing, valid = cell_correspondence(target_depth, target_alpha, target_camera, tuple(target_assign.shape),
                                         source_depth, source_alpha, source_camera, tuple(source_assign.shape))
    return label_agreement(target_assign, source_assign, landing, valid)


def match_agreement(images: Sequence[np.ndarray], depths: Sequence[np.ndarray], alphas: Sequence[np.ndarray],
                    cameras, order: Sequence[int], features: Callable[[torch.Tensor], torch.Tensor],
                    style_features: Callable[[object], torch.Tensor], k: int, epsilon: float, tau: float,
                    iters: int, max_pairs: int | None = None, cancel=None) -> dict[str, float | None]:
    """{"match_agreement", "match_agreement_cells"} over the pairs of neighbours (gap 1) along ``order`` (at most
    ``max_pairs``, evenly spaced). ``features(image (H, W, 3) tensor)`` -> (1, C, h, w) and ``style_features(camera)``
    -> (1, C, h2, w2) are the stylizer's (``Stylizer.features``/``style_features``); lists indexed like ``cameras``.
    The agreement is None when no pair has ``MIN_CELLS`` corresponding cells."""
    from training.core.messages import check_cancel

    pairs = pairs_at_gap(order, 1, max_pairs)
    assigned: dict[int, np.ndarray] = {}

    def assignment(i: int) -> np.ndarray:
        if i not in assigned:
            check_cancel(cancel)
            with torch.no_grad():
                f = features(torch.as_tensor(np.asarray(images[i], dtype=np.float32)[..., :3]))
                assigned[i] = plan_assignments(f, style_features(cameras[i]), k, epsilon, tau, iters)
        return assigned[i]

    shares, cells = [], 0
    for t, s in pairs:
        same, valid = pair_agreement(assignment(t), depths[t], alphas[t], cameras[t], assignment(s), depths[s],
                                     alphas[s], cameras[s])
        cells += valid
        if valid >= MIN_CELLS:
            shares.append(same / valid)
    return {"match_agreement": float(np.mean(shares)) if shares else None, "match_agreement_cells": float(cells)}
