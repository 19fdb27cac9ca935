"""Match agreement: whether views that see the same surface match it to the same style feature (issue 28).

What cross-view matching guidance claims (paper, Cross-view Matching Guidance: "This guidance encourages similar
rendered features across different viewpoints to match the same corresponding style feature"), measured on a
model. For each view, the render's VGG features (as the stylizer prepares them) are matched to the painting's by the
CCFT plan of Algorithm 1 with the run's K, epsilon and tau and **no guidance** (lambda_guide 0, so that a guided and
an unguided run are judged by the same rule), and each rendered feature is assigned the style feature of its largest
plan entry. For a pair of neighbouring views (target t, source s), every feature cell of the target whose centre is
covered is carried to the source with the target's rendered expected depth and the known cameras, as the
depth-warp consistency metric does (consistency.py: in front of the source camera, inside its image, covered there,
at the depth the source renders there, within 3 %); it lands in one source feature cell. The pair's agreement is the
fraction of those corresponding cells whose two assignments are the same style feature; the metric is the mean over
the pairs with at least ``MIN_VALID_CELLS`` corresponding cells.

Feature cells: the stylizer's features are relu3 of the render halved, 1/8 of the render's size; cell (i, j) covers
render pixels [8j, 8j + 8) x [8i, 8i + 8) and its centre is where the depth is read. A cell straddling a depth edge
reads a mixed depth and mostly fails the source's depth test, as silhouettes do in the consistency metric.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from training.evaluate.consistency import (DEPTH_TOLERANCE, MIN_ALPHA, pairs_at_gap, sample_bilinear, seen_by_source,
                                           warp_points)

MIN_VALID_CELLS = 8


def _plane(x) -> torch.Tensor:
    """(H, W) or (H, W, 1) array -> (H, W) float64 tensor."""
    x = torch.as_tensor(np.asarray(x), dtype=torch.float64)
    return x[..., 0] if x.dim() == 3 else x


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


def pair_agreement(target_assign: np.ndarray, target_depth, target_alpha, target_camera, source_assign: np.ndarray,
                   source_depth, source_alpha, source_camera, min_alpha: float = MIN_ALPHA,
                   depth_tolerance: float = DEPTH_TOLERANCE) -> tuple[int, int]:
    """(agreeing cells, corresponding cells) of one pair; assignments (h, w) on the feature grids of the renders
    whose expected depths and alphas (H, W[, 1]) are given."""
    zt, at = _plane(target_depth), _plane(target_alpha)
    H, W = zt.shape
    h, w = target_assign.shape
    ys, xs = torch.meshgrid((torch.arange(h, dtype=torch.float64) + 0.5) * H / h,
                            (torch.arange(w, dtype=torch.float64) + 0.5) * W / w, indexing="ij")
    target = torch.stack([zt, at], dim=-1)
    z_c, a_c = sample_bilinear(target, xs, ys).unbind(-1)
    u, v, z = warp_points(xs, ys, z_c, target_camera, source_camera)
    source = torch.stack([_plane(source_alpha), _plane(source_depth)], dim=-1)
    Hs, Ws = source.shape[:2]
    s_alpha, s_depth = sample_bilinear(source, u, v).unbind(-1)
    valid = seen_by_source(u, v, z, s_alpha, s_depth, Ws, Hs, min_alpha, depth_tolerance)
    valid &= (a_c >= min_alpha) & (z_c > 0)
    hs, ws = source_assign.shape
    ci = (v * hs / Hs).floor().long().clamp(0, hs - 1)
    cj = (u * ws / Ws).floor().long().clamp(0, ws - 1)
    landed = torch.from_numpy(np.ascontiguousarray(source_assign))[ci, cj]
    same = (landed == torch.from_numpy(np.ascontiguousarray(target_assign))) & valid
    return int(same.sum()), int(valid.sum())


def match_agreement(images: Sequence[np.ndarray], depths: Sequence[np.ndarray], alphas: Sequence[np.ndarray],
                    cameras, order: Sequence[int], features: Callable[[torch.Tensor], torch.Tensor],
                    style_features: Callable[[object], torch.Tensor], k: int, epsilon: float, tau: float,
                    iters: int, max_pairs: int | None = None, cancel=None) -> dict[str, float | None]:
    """{"match_agreement", "match_agreement_cells"} over the pairs of neighbours (gap 1) along ``order`` (at most
    ``max_pairs``, evenly spaced). ``features(image (H, W, 3) tensor)`` -> (1, C, h, w) and ``style_features(camera)``
    -> (1, C, h2, w2) are the stylizer's (``Stylizer.features``/``style_features``); lists indexed like ``cameras``.
    The agreement is None when no pair has ``MIN_VALID_CELLS`` corresponding cells."""
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
        if valid >= MIN_VALID_CELLS:
            shares.append(same / valid)
    return {"match_agreement": float(np.mean(shares)) if shares else None, "match_agreement_cells": float(cells)}
