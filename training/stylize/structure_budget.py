"""The structure budget: the content weight steered while the run goes, so that the scene's structure drifts by a set
amount and the painting gets all the room that leaves, whatever the painting and the scene.

Why not a constant weight: one weight gives one painting a painted scene and another a tint (the balance of the two
gradients on the render can read 1 in both, docs/stylization.md "Every painting"): how far a painting pulls the
scene's structure at a given weight depends on the painting. What a user wants held is the structure, so that is
what is measured and held.

The drift is measured at every step, on features the step has anyway: the self-similarity structure distance
(STROTSS, Kolkin et al. 2019, as training/evaluate/content_metrics.py measures the result, here on the relu3_1
features of the halved render against the content features of the same view, at every position of that grid). It
is an exponential average over the last few views. The weight follows a multiplicative integral rule: each step its
logarithm moves by ``RATE`` times the relative excess of the drift over the budget, within [1/``SPAN``, ``SPAN``]
times the configured ``lambda_content``. Below the budget the weight falls (more painting), above it rises (more
scene).

Two measures (``StylizeConfig.structure_measure``, defaults.STRUCTURE_MEASURES). ``render``: the render as it is
stylized against its content (the pre colour transfer's colours). ``output``: the render as the final colour
transfer will map it (the map fitted from the renders' colour statistics, averaged over the last views like the
drift, to the painting's) against the input model's render in its own colours, which is what the report's structure
distance compares. On the grid's 18 cells at the defaults the report's figure ended 1.15-1.7 times the ``render``
drift held, and the final colour transfer made most of that difference (docs/stylization.md, "Every painting").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from training.stylize.color_transfer import ColorTransform, transfer_between

# relu3_1 is the first 256 of the 768 feature channels (vgg_features.py)
RELU3_1 = 256
AVERAGE = 0.1  # the drift's exponential average: about the last ten views under the interleaved schedule
RATE = 0.05  # per step, on the log of the weight, per unit of relative excess (a factor e in 20 steps at most)
SPAN = 64.0  # the weight stays within lambda_content / SPAN .. lambda_content * SPAN
MIN_COVERED = 16  # covered pixels a view needs to count in the colour statistics


def structure_drift(feats: torch.Tensor, content: torch.Tensor) -> float:
    """The self-similarity structure distance between the render's and the content's features (1, C, h, w): per
    image the cosine self-distance of the relu3_1 features of every position, each column divided by its mean; the
    mean absolute difference of the two matrices. 0 when the two arrangements agree."""
    a = _self_distance(feats.detach()[0, :RELU3_1].flatten(1).t().float())
    b = _self_distance(content.detach()[0, :RELU3_1].flatten(1).t().float())
    return float((a - b).abs().mean())


def _self_distance(rows: torch.Tensor) -> torch.Tensor:
    unit = rows / rows.norm(dim=1, keepdim=True).clamp_min(1e-12)
    d = (1 - unit @ unit.t()).clamp_min(0)
    return d / d.mean(dim=0, keepdim=True).clamp_min(1e-12)


@dataclass
class OutputColours:
    """The mean and second moment of the renders' covered colours (alpha >= 0.5, un-premultiplied), averaged over
    the last views as the drift is: what the final colour transfer fits its map from."""

    mean: np.ndarray | None = None
    second: np.ndarray | None = None

    def update(self, image: torch.Tensor, alpha: torch.Tensor) -> None:
        """Take one (H, W, 3) render over black and its (H, W, 1) alpha."""
        covered = alpha[..., 0] >= 0.5
        if int(covered.sum()) < MIN_COVERED:
            return
        px = (image[covered] / alpha[covered]).double().cpu().numpy()
        mean, second = px.mean(axis=0), px.T @ px / len(px)
        if self.mean is None:
            self.mean, self.second = mean, second
        else:
            self.mean = (1 - AVERAGE) * self.mean + AVERAGE * mean
            self.second = (1 - AVERAGE) * self.second + AVERAGE * second

    def transfer(self, painting: tuple[np.ndarray, np.ndarray]) -> ColorTransform | None:
        """The map to the ``painting``'s (mean, covariance); None before a view had covered pixels."""
        if self.mean is None:
            return None
        return transfer_between((self.mean, self.second - np.outer(self.mean, self.mean)), painting)


@dataclass
class StructureBudget:
    """The content weight's multiplier (``scale``) and the averaged drift, stepped by ``update``; under the
    ``output`` measure, the renders' averaged colours."""

    log_scale: float = 0.0
    drift: float | None = None  # the exponential average; None before the first step
    colours: OutputColours = field(default_factory=OutputColours)

    @property
    def scale(self) -> float:
        return math.exp(self.log_scale)

    def update(self, drift: float, budget: float) -> None:
        """Take one step's drift; ``budget`` <= 0 holds nothing (the multiplier stays)."""
        self.drift = drift if self.drift is None else (1 - AVERAGE) * self.drift + AVERAGE * drift
        if budget > 0:
            limit = math.log(SPAN)
            excess = (self.drift - budget) / budget
            self.log_scale = min(limit, max(-limit, self.log_scale + RATE * max(-1.0, min(1.0, excess))))

    def state(self) -> dict:
        c = self.colours
        return {"log_scale": self.log_scale, "drift": self.drift,
                "colour_mean": None if c.mean is None else c.mean.tolist(),
                "colour_second": None if c.second is None else c.second.tolist()}

    @classmethod
    def from_state(cls, state: dict | None) -> "StructureBudget":
        if not state:
            return cls()
        mean, second = state.get("colour_mean"), state.get("colour_second")  # absent in older checkpoints
        colours = OutputColours(None if mean is None else np.array(mean, dtype=np.float64),
                                None if second is None else np.array(second, dtype=np.float64))
        return cls(float(state["log_scale"]), None if state["drift"] is None else float(state["drift"]), colours)
