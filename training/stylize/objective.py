"""The stylization objective on one render: the style term, the content term and a total-variation term, and the
balance of their gradients on the render.

Content term. The paper writes L_content = (1/N) sum_i ||x_i - x^_i||^2 over the N feature positions and sets
lambda_content = 0.005 beside lambda_CCFT = 30; the 0.005 is ARF's, whose code takes the mean over channels *and*
positions (``torch.nn.functional.mse_loss``) with a style weight of 1. Neither unit is comparable to CCFT's, a mean
of cosine distances (scale-free): the MSE's gradient on a render grows with the square of VGG's activation scale and,
as a mean over channels, shrinks with their number. ``content_norm`` picks the unit:

- ``relative`` (the default): ||X - X^||^2 / ||X^||^2 over every channel and position, the squared error relative to
  the content features' own energy. Dimensionless: independent of the channel count, the image size and the
  activation scale, so one weight means the same balance at every preset and resolution.
- ``mse``: the mean over channels and positions (ARF's code, the paper's 0.005 as printed): for the paper's grid.

One ``relative`` unit equals (mean square of the content features) ``mse`` units: on the fox and the fern at 256 px
that is 1/700 to 1/900 (docs/stylization.md, "The content balance").

The total-variation term is the mean squared difference of neighbouring pixels of the render, the smoothness prior
ARF's grids carry; 0 leaves it out.

Gradient balance: with ``measure_balance`` the style and content terms' gradients on the render are taken apart
every ``balance_every`` steps (one more VGG backward pass on those steps) and their norms reported, so that a user
sees which term steers the colours.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch



def content_loss(feats: torch.Tensor, content: torch.Tensor, norm: str) -> torch.Tensor:
    """The content term between rendered and content features (1, C, h, w), in ``norm``'s unit (module doc)."""
    diff = (feats - content).pow(2)
    if norm == "mse":
        return diff.mean()
    return diff.sum() / content.pow(2).sum().clamp_min(1e-12)


def moment_loss(feats: torch.Tensor, style: torch.Tensor) -> torch.Tensor:
    """How far the render's features' per-channel means and standard deviations are from the painting's (1, C, h, w)
    each, relative to the painting's: ||mu_r - mu_p||^2 / ||mu_p||^2 + ||sd_r - sd_p||^2 / ||sd_p||^2. CCFT compares
    directions (cosine), so it says which painting feature a render feature becomes but not how strongly it fires;
    this term carries the painting's contrast and texture energy."""
    f, s = feats.flatten(2)[0], style.flatten(2)[0]
    mf, sf, ms, ss = f.mean(1), f.std(1), s.mean(1), s.std(1)
    return (mf - ms).pow(2).sum() / ms.pow(2).sum().clamp_min(1e-12) + \
        (sf - ss).pow(2).sum() / ss.pow(2).sum().clamp_min(1e-12)


def total_variation(image: torch.Tensor) -> torch.Tensor:
    """Mean squared difference between horizontally and vertically neighbouring pixels of an (H, W, 3) image."""
    dy = (image[1:] - image[:-1]).pow(2).mean()
    dx = (image[:, 1:] - image[:, :-1]).pow(2).mean()
    return dx + dy


@dataclass
class Gradients:
    """The gradient of the whole objective on the render, and, where measured, the norms of its terms' parts."""

    total: torch.Tensor  # (H, W, 3), d loss / d render
    style_norm: float | None = None
    content_norm: float | None = None
    tv_norm: float | None = None

    @property
    def content_to_style(self) -> float | None:
        """||content gradient|| / ||style gradient|| on the render (None where not measured)."""
        if self.style_norm is None or self.content_norm is None or self.style_norm <= 0:
            return None
        return self.content_norm / self.style_norm


def render_gradients(render: torch.Tensor, terms: dict[str, torch.Tensor], measure_balance: bool,
                     apart: tuple[str, ...] = ("content", "tv")) -> Gradients:
    """d(sum of ``terms``)/d ``render`` (a leaf the terms were computed from), with the terms' norms taken apart
    when ``measure_balance``. ``terms``: "style" and the others (terms.py), each already weighted; ``apart``: those
    whose gradients are not the style side's (the content, the total variation).

    The total is the gradient of the sum whether or not the balance is measured, so measuring it (or how often)
    cannot change a run: the gradients of the terms ``apart`` are taken on their own and the style's is what
    remains of the total (one more VGG backward pass, not two)."""
    loss = sum(terms.values())
    if not measure_balance:
        (total,) = torch.autograd.grad(loss, render)
        return Gradients(total)
    parts: dict[str, torch.Tensor] = {}
    for name in apart:
        if name in terms and terms[name].requires_grad:
            (parts[name],) = torch.autograd.grad(terms[name], render, retain_graph=True)
    (total,) = torch.autograd.grad(loss, render)
    norm = {name: float(g.norm()) for name, g in parts.items()}
    return Gradients(total, float((total - sum(parts.values())).norm()), norm.get("content", 0.0),
                     norm.get("tv", 0.0) if "tv" in terms else None)
