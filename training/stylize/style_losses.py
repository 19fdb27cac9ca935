"""Style losses behind one interface: CCFT (ours), NNFM (ARF's nearest-neighbour feature matching), Gram (Gatys).

``loss, stats = style_loss(render_feats, style_feats, source=view, settings=config)`` with render_feats (1, C, h, w)
and style_feats (1, C, h2, w2); ``source`` names the view the render came from; ``settings`` is where the call reads
its parameters (the stylizer's live config: the viewer edits it between steps), the loss's own attributes when
None. CCFT keeps its guide map from one call to the next (built from the
previous call's render) and says whose it was (``guide_source``, ``used_guide_source``); ``reset_guide()`` forgets
it. CCFT's own is in ``training.stylize.ccft`` beside its formula.
"""

from __future__ import annotations

import torch

from training.stylize.ccft import DEFAULT_CHUNK_ELEMENTS, CCFTStyleLoss, column_statistics, flatten_features, \
    l2_normalise


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

    def __call__(self, render_feats: torch.Tensor, style_feats: torch.Tensor, source=None,
                 settings=None) -> tuple[torch.Tensor, dict]:
        Xn = l2_normalise(flatten_features(render_feats, "render"))
        Yn = l2_normalise(flatten_features(style_feats, "style").detach())
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

    def __call__(self, render_feats: torch.Tensor, style_feats: torch.Tensor, source=None,
                 settings=None) -> tuple[torch.Tensor, dict]:
        G_r = gram_matrix(flatten_features(render_feats, "render"))
        G_s = gram_matrix(flatten_features(style_feats, "style").detach())
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
