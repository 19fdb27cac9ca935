"""The stylization objective's terms beside the style loss, each declared once: its name (the step's record keeps
its value as ``<name>_loss``, the history and the status carry it, the Training tab draws it as a curve), the
config field of its weight, and how it is computed from what a step has (objective.py holds the formulas). A term
whose weight is 0 is left out. The style loss itself (CCFT, NNFM, Gram) is the loss object's (style_losses.py).

A new term is its formula (objective.py), an entry here, its weight's field and default (config.py, defaults.py)
and its flag (app/settings/stylize.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from training.stylize.objective import content_loss, moment_loss, total_variation


@dataclass(frozen=True)
class StepInputs:
    """What a step has when the terms are taken: the render's features, the content's and the painting's (each
    (1, C, h, w)), the render itself (H, W, 3), and the content weight the structure budget gives this step."""

    feats: torch.Tensor
    content: torch.Tensor
    style: torch.Tensor
    image: torch.Tensor
    content_weight: float


@dataclass(frozen=True)
class Term:
    name: str
    weight: Callable  # (config, StepInputs) -> the weight this step
    value: Callable  # (config, StepInputs) -> the unweighted term
    style_side: bool  # counted with the style loss when the balance is measured (else apart, as the content is)


TERMS: tuple[Term, ...] = (
    Term("content", lambda cfg, x: x.content_weight, lambda cfg, x: content_loss(x.feats, x.content, cfg.content_norm),
         style_side=False),
    Term("tv", lambda cfg, x: cfg.lambda_tv, lambda cfg, x: total_variation(x.image), style_side=False),
    Term("moments", lambda cfg, x: cfg.lambda_moments, lambda cfg, x: moment_loss(x.feats, x.style), style_side=True),
)
# the step's record keys of the loss values: what the history, the status and the curves carry
LOSS_KEYS = ("loss", "style_loss") + tuple(f"{t.name}_loss" for t in TERMS)
