"""One stylization iteration up to the optimiser's step: render the current view, VGG features of the render, the
content and the painting (feature_cache.py), the objective (objective.py: the style loss reading the live config,
the content term, total variation), what the plan shows (plan_readouts.py), and the objective's gradient pushed
through the rasterizer into the model's leaves. The Stylizer takes the optimiser's step under its model lock and
keeps the books (trainer.py).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from training.stylize.objective import render_gradients
from training.stylize.optimizer import colour_learning_rate
from training.stylize.plan_readouts import capacity_map
from training.stylize.terms import TERMS, StepInputs

if TYPE_CHECKING:
    from training.stylize.trainer import Stylizer


@dataclass
class StageTimes:
    """Seconds spent per stage of a run, accumulated."""

    totals: dict[str, float] = field(default_factory=dict)

    def add(self, name: str, seconds: float) -> None:
        self.totals[name] = self.totals.get(name, 0.0) + seconds


class StepTimer:
    """Seconds per stage of a step (``timings``), the GPU synchronised before each reading."""

    def __init__(self, device: torch.device):
        self.timings: dict[str, float] = {}
        self._sync = torch.cuda.synchronize if device.type == "cuda" else None
        self._t = time.perf_counter()

    def start(self) -> None:
        self._t = time.perf_counter()

    def stop(self, name: str, sync: bool = True) -> None:
        if sync and self._sync is not None:
            self._sync()
        self.timings[name] = time.perf_counter() - self._t


def gradient_step(st: Stylizer, timer: StepTimer) -> tuple[dict[str, Any], np.ndarray | None]:
    """The gradients of one iteration on ``st``'s current view, in its optimiser's leaves; returns the step's record
    (losses, the view, the settings it used, the loss's statistics; ``timer.timings`` as "timings") and the plan's
    capacity map (None for a loss without one)."""
    cfg, view, position = st.config, st.views.current, st.views.position
    timer.start()
    rendered, alpha = st.render(view.camera, render_mode="RGB+ED")  # the depth: for the step's agreement
    rendered, depth = rendered[..., :3], rendered[..., 3:].detach()
    # the objective's gradient on the render is taken first (its terms apart, for the balance), then pushed
    # through the rasterizer: two timed backward stages
    image = rendered.detach().requires_grad_(True)
    timer.stop("rasterize")

    timer.start()
    feats, content, style = st.features(image), st.content_features(), st.style_features(view.camera)
    timer.stop("vgg_forward")

    timer.start()
    style_loss, stats = st.style_loss(feats, style, source=position, settings=cfg)
    last = getattr(st.style_loss, "last_result", None)
    capacity = capacity_map(last, style.shape[2:])
    # the content weight the structure budget gives this step (structure_budget.py)
    inputs = StepInputs(feats, content, style, image, cfg.lambda_content * st.budget.scale)
    terms, values = {"style": cfg.style_weight * style_loss}, {}
    for term in TERMS:
        weight = term.weight(cfg, inputs)
        if weight > 0 or term.name == "content":  # the content's value is reported at any weight
            values[term.name] = term.value(cfg, inputs)
            terms[term.name] = weight * values[term.name]
    loss = sum(terms.values())
    timer.stop("loss")
    timer.start()
    agreement = st.agreement.update(last, feats.shape[2:], position, view.camera, depth, alpha.detach())
    timer.stop("agreement", sync=False)
    for key, value in stats.items():  # the loss's own breakdown: similarity_topk_s, sinkhorn_s, guide_s
        if key.endswith("_s"):
            timer.timings[key[:-2]] = float(value)

    timer.start()
    drift = st.measured_drift(image.detach(), alpha.detach(), feats, content)
    st.budget.update(drift, cfg.structure_budget)
    timer.stop("structure", sync=False)
    timer.start()
    grads = render_gradients(image, terms, cfg.measure_balance and st.iteration % cfg.balance_every == 0,
                             apart=tuple(t.name for t in TERMS if not t.style_side))
    timer.stop("vgg_backward")
    timer.start()
    st.optimizer.zero_grad(set_to_none=True)
    rendered.backward(grads.total)
    timer.stop("raster_backward")

    record = {
        "iteration": st.iteration, "loss": float(loss.detach()), "style_loss": float(style_loss.detach()),
        **{f"{t.name}_loss": float(values[t.name].detach()) if t.name in values else None for t in TERMS},
        # the structure drift of this view's render from its content, and the content weight the step used
        "structure_drift": drift, "content_weight": inputs.content_weight,
        # the norms of the style and content terms' gradients on the render (None: not measured)
        "grad_style": grads.style_norm, "grad_content": grads.content_norm,
        "content_to_style": grads.content_to_style,
        "view": view.camera.name, "view_index": view.source_index, "trajectory_position": position,
        "virtual": view.is_virtual,
        # the trajectory position whose features built the guide map this step used (None: no guidance)
        "guide_view": getattr(st.style_loss, "used_guide_source", None),
        # share of the cells this view and the previous step's (another view) both see that the two steps'
        # plans gave the same style feature (None: same view, no CCFT plan, or too few shared cells)
        "match_agreement": agreement,
        "pass": st.pass_progress()[0], "coverage": float(alpha.detach().mean()), "timings": timer.timings,
        # the settings this step used: a live change shows in the first step that applied it
        "tau": cfg.tau, "k": cfg.k, "epsilon": cfg.epsilon, "lambda_guide": cfg.lambda_guide,
        "lambda_style": cfg.style_weight, "lambda_content": cfg.lambda_content,
        "lr": colour_learning_rate(cfg, st.iteration, st.total_iters), "style_scale": cfg.style_scale,
    }
    record.update({k: _plain(v) for k, v in stats.items()
                   if k not in ("loss",) and not k.endswith("_s") and _is_scalar(v)})
    return record, capacity


def _is_scalar(value: Any) -> bool:
    return isinstance(value, (int, float, bool, str)) or (isinstance(value, torch.Tensor) and value.numel() == 1)


def _plain(value: Any) -> Any:
    return value.item() if isinstance(value, torch.Tensor) else value
