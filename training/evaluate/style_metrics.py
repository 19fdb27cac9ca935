"""Style distances between VGG-16 features of renders and of the painting, per layer relu1_1 .. relu4_1.

For features F (N, C) of a render (every position of the layer's map) and S (M, C) of the painting, resized so its
long side equals the render's (``training.stylize.style_image.style_for_render``, as the stylizer prepares it; no
halving here: the metric looks at the full render):

- Gram distance (Gatys et al.): G(F) = F^T F / N, d = mean over the C x C entries of (G(F) - G(S))^2, the value
  ``training.stylize.style_losses.GramStyleLoss`` computes (the stylizer's ``style_distance`` takes it on relu3_1..3
  of halved images; here it is per layer on relu1_1 .. relu4_1).
- Sliced Wasserstein distance: P = ``SWD_PROJECTIONS`` random unit directions w_p in R^C (Gaussian draws normalised,
  torch generator seeded with ``SWD_SEED``: the same directions for every call, so values compare across renders);
  at most ``SWD_MAX_POSITIONS`` = 8192 rows of each set (a fixed-seed random subset: relu1_1 at 256 x 192 has
  49,152 positions and sorting them all would be most of the cost); the projections F w_p and S w_p sorted; both
  brought to Q = min(N', M') samples by linear interpolation of the sorted values at the quantiles (k + 0.5) / Q
  (exact when the sizes agree); d = sqrt(mean_p mean_k (a_pk - b_pk)^2), the root of the sliced 2-Wasserstein
  distance squared (STROTSS / Heitz et al. use its square as a loss). Products in float32, the sort numpy's.

Both are in feature units and only comparable within a layer: the report divides them by the same distance for the
unstylized renders (measure.py's ratios).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from training.evaluate.vgg_taps import LAYERS

SWD_PROJECTIONS = 128
SWD_SEED = 0
SWD_MAX_POSITIONS = 8192  # sorting is the cost: larger maps (relu1, relu2 at 256 px) are subsampled to this many


def _rows(feats: torch.Tensor) -> torch.Tensor:
    """(1, C, h, w) or (C, h, w) or (N, C) -> (N, C)."""
    if feats.dim() == 4:
        if feats.shape[0] != 1:
            raise ValueError(f"one feature map at a time, got a batch of {feats.shape[0]}")
        feats = feats[0]
    if feats.dim() == 3:
        feats = feats.flatten(1).t()
    return feats


_directions: dict[int, torch.Tensor] = {}


def projections(channels: int) -> torch.Tensor:
    """(C, P) unit directions, the same on every call for a given C."""
    if channels not in _directions:
        g = torch.Generator().manual_seed(SWD_SEED + channels)
        w = torch.randn(channels, SWD_PROJECTIONS, generator=g, dtype=torch.float64)
        _directions[channels] = w / w.norm(dim=0, keepdim=True)
    return _directions[channels]


def quantiles(sorted_values: np.ndarray, q: int) -> np.ndarray:
    """(P, N) row-sorted values -> (P, q) float64 at the quantiles (k + 0.5) / q, linearly interpolated (the sorted
    values sitting at (i + 0.5) / N)."""
    n = sorted_values.shape[1]
    if n == q:
        return sorted_values.astype(np.float64)
    pos = np.clip((np.arange(q, dtype=np.float64) + 0.5) / q * n - 0.5, 0, n - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, n - 1)
    frac = pos - lo
    v = sorted_values.astype(np.float64)
    return v[:, lo] * (1 - frac) + v[:, hi] * frac


def subsample(rows: torch.Tensor, limit: int = SWD_MAX_POSITIONS) -> torch.Tensor:
    """At most ``limit`` of the (N, C) rows: a random subset drawn with a generator seeded by ``SWD_SEED`` and N
    (the same rows for the same N), all of them when N <= limit."""
    n = rows.shape[0]
    if n <= limit:
        return rows
    g = torch.Generator().manual_seed(SWD_SEED * 1_000_003 + n)
    return rows[torch.randperm(n, generator=g)[:limit].to(rows.device)]


@dataclass
class FeatureStats:
    """What the distances need of one feature set: its Gram matrix (C, C) float64 and its sorted projections
    (P, N') float32, each row sorted."""

    gram: torch.Tensor
    sorted_projections: np.ndarray


def feature_stats(feats: torch.Tensor) -> FeatureStats:
    """Gram matrix and sorted projections of (1, C, h, w) / (C, h, w) / (N, C) features. The products are float32
    (a relative error of about 1e-6), the sort is numpy's (several times faster than torch's on a CPU)."""
    f = _rows(feats).float()
    gram = (f.t() @ f).double() / f.shape[0]
    w = projections(f.shape[1]).to(f.device, torch.float32)
    proj = (w.t() @ subsample(f).t()).cpu().numpy()  # (P, N')
    return FeatureStats(gram, np.sort(proj, axis=1))


def _check(a: FeatureStats, b: FeatureStats) -> None:
    if a.gram.shape != b.gram.shape:
        raise ValueError(f"channel counts differ: {a.gram.shape[0]} and {b.gram.shape[0]}")


def stats_gram_distance(a: FeatureStats, b: FeatureStats) -> float:
    _check(a, b)
    return float(((a.gram - b.gram) ** 2).mean())


def stats_sliced_wasserstein(a: FeatureStats, b: FeatureStats) -> float:
    _check(a, b)
    q = min(a.sorted_projections.shape[1], b.sorted_projections.shape[1])
    return float(np.sqrt(((quantiles(a.sorted_projections, q) - quantiles(b.sorted_projections, q)) ** 2).mean()))


def gram_distance(feats: torch.Tensor, style_feats: torch.Tensor) -> float:
    """Mean squared difference of the Gram matrices F^T F / N (module docstring)."""
    return stats_gram_distance(feature_stats(feats), feature_stats(style_feats))


def sliced_wasserstein(feats: torch.Tensor, style_feats: torch.Tensor) -> float:
    """Sliced 2-Wasserstein distance between the two feature sets (module docstring)."""
    return stats_sliced_wasserstein(feature_stats(feats), feature_stats(style_feats))


def painting_for(painting: np.ndarray, width: int, height: int, style_scale: float = 1.0) -> torch.Tensor:
    """(1, 3, h, w) painting as the stylization saw it: its long side ``style_scale`` times the render's."""
    from training.stylize.style_image import check_style_array, painting_side, style_for_render

    return style_for_render(check_style_array(painting), painting_side(max(width, height), style_scale))


def taps_stats(taps: dict[str, torch.Tensor], layers=LAYERS) -> dict[str, FeatureStats]:
    """``feature_stats`` of each layer of a ``VGGTaps`` output (for the painting: computed once, compared often)."""
    return {layer: feature_stats(taps[layer]) for layer in layers}


def style_distances(render_taps: dict[str, torch.Tensor], painting: dict[str, torch.Tensor | FeatureStats],
                    layers=LAYERS) -> dict[str, float]:
    """{"gram_relu1": .., "swd_relu1": .., ...} for one render's taps against the painting's (taps, or their
    ``taps_stats``)."""
    out = {}
    for layer in layers:
        mine = feature_stats(render_taps[layer])
        theirs = painting[layer] if isinstance(painting[layer], FeatureStats) else feature_stats(painting[layer])
        out[f"gram_{layer}"] = stats_gram_distance(mine, theirs)
        out[f"swd_{layer}"] = stats_sliced_wasserstein(mine, theirs)
    return out


def mean_style_distances(per_view: list[dict[str, float]]) -> dict[str, float]:
    """Mean of ``style_distances`` over views."""
    return {k: float(np.mean([d[k] for d in per_view])) for k in per_view[0]} if per_view else {}


