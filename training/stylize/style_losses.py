"""Style losses behind one interface: CCFT (ours), NNFM (ARF's nearest-neighbour feature matching), Gram (Gatys).

``loss, stats = style_loss(render_feats, style_feats, source=view)`` with render_feats (1, C, h, w) and style_feats
(1, C, h2, w2); ``source`` names the view the render came from. Parameters are plain attributes that may change
between calls (the viewer edits them live). CCFT keeps its guide map from one call to the next (built from the
previous call's render) and says whose it was: ``guide_source`` (the ``source`` of the call that built the map it
holds) and ``used_guide_source`` (of the map the last call was guided by; None when that call had no guidance);
``reset_guide()`` forgets it.
"""

from __future__ import annotations

import torch

from training.stylize import defaults
from training.stylize.ccft import DEFAULT_CHUNK_ELEMENTS, column_statistics, ccft_loss, l2_normalise


def _flatten(feats: torch.Tensor, what: str) -> torch.Tensor:
    """(1, C, h, w) -> (h*w, C)."""
    if feats.dim() != 4 or feats.shape[0] != 1:
        raise ValueError(f"{what} features must be (1, C, h, w), got {tuple(feats.shape)}")
    return feats[0].flatten(1).t()


class CCFTStyleLoss:
    """Capacity-controlled feature transport with cross-view guidance (``training.stylize.ccft``).

    stats: loss, utilisation, column_entropy, column_entropy_normalised, reachable_fraction, and the timings
    (seconds) similarity_topk_s, cost_s, sinkhorn_s, guide_s."""

    name = "ccft"

    def __init__(self, k: int = defaults.K, epsilon: float = defaults.EPSILON, tau: float = defaults.TAU,
                 lambda_guide: float = defaults.LAMBDA_GUIDE, iters: int = defaults.SINKHORN_ITERS, chunk_elements: int = DEFAULT_CHUNK_ELEMENTS):
        self.k = k
        self.epsilon = epsilon
        self.tau = tau
        self.lambda_guide = lambda_guide
        self.iters = iters
        self.chunk_elements = chunk_elements
        self.guide: torch.Tensor | None = None  # (m, C) from the previous call
        self.guide_source = None  # the ``source`` of the call that built ``guide``
        self.used_guide_source = None  # the source of the guide the last call used (None: unguided)
        self.last_result = None  # the last CCFTResult (plan, column mass) for reports

    def reset_guide(self) -> None:
        self.guide = self.guide_source = None

    def __call__(self, render_feats: torch.Tensor, style_feats: torch.Tensor,
                 source=None) -> tuple[torch.Tensor, dict]:
        X = _flatten(render_feats, "render")
        Y = _flatten(style_feats, "style").detach()
        guide = self.guide
        if guide is not None and (guide.shape != Y.shape or guide.device != Y.device):
            guide = None  # the style features changed size (another resolution): the old guide does not apply
        result = ccft_loss(X, Y, guide, k=self.k, epsilon=self.epsilon, tau=self.tau,
                           lambda_guide=self.lambda_guide, iters=self.iters, chunk_elements=self.chunk_elements)
        self.used_guide_source = self.guide_source if guide is not None and self.lambda_guide > 0 else None
        self.guide, self.guide_source = result.guide, source
        self.last_result = result
        stats = {
            "loss": float(result.loss.detach()),
            "utilisation": result.utilisation,
            "column_entropy": result.column_entropy,
            "column_entropy_normalised": result.column_entropy_normalised,
            "reachable_fraction": float(result.reachable.to(torch.float64).mean()),
        }
        stats.update({f"{k}_s": v for k, v in result.timings.items()})
        return result.loss, stats


@torch.no_grad()
def nearest_style_indices(Xn: torch.Tensor, Yn: torch.Tensor,
                          chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> torch.Tensor:
    """Index (n,) of the most cosine-similar row of Yn (m, C) for each row of Xn (n, C), chunked."""
    n, m = Xn.shape[0], Yn.shape[0]
    rows = max(1, chunk_elements // m)
    out = torch.empty(n, dtype=torch.int64, device=Xn.device)
    Yt = Yn.t().contiguous()
    for s in range(0, n, rows):
        out[s:s + rows] = torch.argmax(Xn[s:s + rows] @ Yt, dim=1)
    return out


class NNFMStyleLoss:
    """ARF's NNFM: each rendered feature is pulled toward its nearest style feature by cosine distance.

    loss = mean_i (1 - cos(x_i, y_nn(i))), nn(i) = argmin_j (1 - cos(x_i, y_j)) found without gradient.
    stats: loss, distinct_fraction (distinct nearest neighbours / style features), distinct_count, and the
    utilisation/column entropy of the hard assignment's column marginal over all style features, comparable to CCFT's.
    """

    name = "nnfm"

    def __init__(self, chunk_elements: int = DEFAULT_CHUNK_ELEMENTS):
        self.chunk_elements = chunk_elements

    def reset_guide(self) -> None:  # no state; present so callers can treat every loss alike
        pass

    def __call__(self, render_feats: torch.Tensor, style_feats: torch.Tensor,
                 source=None) -> tuple[torch.Tensor, dict]:
        Xn = l2_normalise(_flatten(render_feats, "render"))
        Yn = l2_normalise(_flatten(style_feats, "style").detach())
        nn_idx = nearest_style_indices(Xn.detach(), Yn, self.chunk_elements)
        loss = (1.0 - (Xn * Yn[nn_idx]).sum(dim=1)).mean()
        m = Yn.shape[0]
        counts = torch.bincount(nn_idx, minlength=m).to(torch.float64)
        distinct = int((counts > 0).sum())
        util, entropy, entropy_norm = column_statistics(counts / counts.sum(), torch.ones(m, dtype=torch.bool))
        stats = {
            "loss": float(loss.detach()),
            "distinct_count": distinct,
            "distinct_fraction": distinct / m,
            "utilisation": util,
            "column_entropy": entropy,
            "column_entropy_normalised": entropy_norm,
        }
        return loss, stats


def gram_matrix(feats: torch.Tensor) -> torch.Tensor:
    """(N, C) -> (C, C) = F^T F / N."""
    return feats.t() @ feats / feats.shape[0]


class GramStyleLoss:
    """Gatys et al.: squared Frobenius distance of the Gram matrices, averaged over the C x C entries.

    stats: loss (the Gram distance)."""

    name = "gram"

    def reset_guide(self) -> None:
        pass

    def __call__(self, render_feats: torch.Tensor, style_feats: torch.Tensor,
                 source=None) -> tuple[torch.Tensor, dict]:
        G_r = gram_matrix(_flatten(render_feats, "render"))
        G_s = gram_matrix(_flatten(style_feats, "style").detach())
        loss = ((G_r - G_s) ** 2).mean()
        return loss, {"loss": float(loss.detach())}


STYLE_LOSSES = {"ccft": CCFTStyleLoss, "nnfm": NNFMStyleLoss, "gram": GramStyleLoss}


def make_style_loss(name: str, **params):
    """A style loss by name ('ccft', 'nnfm', 'gram') with its parameters (e.g. tau=0.5 for ccft)."""
    try:
        cls = STYLE_LOSSES[name.lower()]
    except KeyError:
        raise ValueError(f"unknown style loss '{name}' (choose from {', '.join(STYLE_LOSSES)})") from None
    return cls(**params)
