"""Stylization settings (``StylizeConfig``, validated, the paper's defaults from ``defaults``) and the schedule they
imply: iterations per view and in all, and the render resolution."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from training.scene.scene import Camera
from training.stylize import defaults as D
from training.stylize.defaults import (CONTENT_NORMS, CONTENT_SOURCES, MAX_STYLE_SCALE, FORWARD_ITERS_PER_VIEW,
                                       FORWARD_MIN_TOTAL, LOSSES, ORBIT_ITERS_PER_VIEW, VGG_PRECISIONS,
                                       ORBIT_ITERS_PER_VIEW_MANY, ORBIT_MANY_VIEWS, PAPER_MAX_SIDE, PARAMS, PRESETS,
                                       QUICK_ITER_FRACTION, QUICK_MAX_SIDE, SCENE_KINDS, SCHEDULES,
                                       STANDARD_MAX_SIDE, VIEW_ORDERS)

DEFAULT_LAMBDA_STYLE = D.LAMBDA_STYLE
DEFAULT_LR = D.LR

# Settings that shape the run when the Stylizer is built (the cameras, the trajectory, the colour transfer, the
# device, which parameters the optimiser holds): update_config refuses them rather than ignore them, and a
# checkpoint's fingerprint holds them (checkpoint.py).
FIXED_AT_START = ("view_order", "virtual_views", "preset", "device", "color_transfer", "background", "scene_kind",
                  "max_side", "seed", "params", "schedule", "content_source", "vgg_precision", "recipe")


# The useful span of each numeric setting (low, high, logarithmic): what a live control offers. ``validate`` is
# the rule a value must meet; a value outside the span but within the rule (from the CLI) is kept, not clamped.
RANGES: dict[str, tuple[float, float, bool]] = {
    "tau": (0.01, 10.0, True), "epsilon": (0.005, 0.5, True), "lambda_guide": (0.0, 10.0, False),
    "lambda_content": (0.05, 50.0, True), "style_scale": (0.5, 8.0, True), "lambda_tv": (0.0, 100.0, False),
    "lr_final": (0.01, 1.0, True), "lambda_style": (0.0, 100.0, False), "lr": (0.001, 1.0, True),
    "k": (1, 64, False), "iters_per_view": (0, 100, False), "virtual_views": (0, 4, False),
    "structure_budget": (0.0, 0.5, False)}


# the fields by kind, each checked by ``validate`` (a None in OPTIONAL means "from the preset / the paper")
WHOLE_NUMBERS = ("k", "balance_every", "sinkhorn_iters", "iters_per_view", "min_total_iters", "seed", "virtual_views",
                 "max_side")
NUMBERS = ("tau", "epsilon", "lambda_guide", "lambda_style", "lambda_content", "lr", "style_scale", "lambda_tv",
           "lr_final", "structure_budget", "lambda_moments")
FLAGS = ("dc_only", "color_transfer", "measure_balance")
OPTIONAL = ("iters_per_view", "min_total_iters", "max_side", "lambda_style", "lr")


@dataclass
class StylizeConfig:
    """Stylization settings; ``None`` means "from the preset / the paper's schedule". The defaults are the
    "balanced" recipe's; ``recipe_config`` gives either recipe's (defaults.RECIPE_SETTINGS)."""

    recipe: str = D.DEFAULT_RECIPE  # the recipe the settings started from (recipe_departures: where they differ)
    loss: str = "ccft"  # ccft | nnfm | gram
    tau: float = D.TAU
    k: int = D.K
    epsilon: float = D.EPSILON
    lambda_guide: float = D.LAMBDA_GUIDE
    sinkhorn_iters: int = D.SINKHORN_ITERS
    lambda_style: float | None = None  # None: DEFAULT_LAMBDA_STYLE[loss] (30 for CCFT)
    lambda_content: float = D.LAMBDA_CONTENT  # the content weight (where the structure budget starts it)
    structure_budget: float = D.STRUCTURE_BUDGET  # the structure drift the content weight holds; 0: a constant weight
    structure_measure: str = D.STRUCTURE_MEASURE  # render | output: what that drift compares (structure_budget.py)
    lambda_moments: float = D.LAMBDA_MOMENTS  # the painting's per-channel feature statistics (objective.moment_loss)
    content_norm: str = "relative"  # relative: ||X - X^||^2 / ||X^||^2 | mse: ARF's mean (objective.py)
    content_source: str = D.CONTENT_SOURCE  # photo: the photos (ARF) | render: the input model's renders
    style_scale: float = D.STYLE_SCALE  # the painting's long side / the render's (stroke size)
    lambda_tv: float = D.LAMBDA_TV  # total variation of the render
    lr: float | None = D.LR  # Adam learning rate of sh0 (shN: lr / 20); None: DEFAULT_LR
    lr_final: float = D.LR_FINAL  # the rate decays exponentially to lr * lr_final at the last iteration
    measure_balance: bool = True  # the style and content gradients' norms on the render (the balance) ...
    vgg_precision: str = D.VGG_PRECISION  # float32 | bfloat16 | auto (bfloat16 on a CPU that has it natively)
    balance_every: int = D.BALANCE_EVERY  # ... measured every this many steps (each costs a VGG backward pass)
    iters_per_view: int | None = None
    min_total_iters: int | None = None
    scene_kind: str = "auto"  # auto | forward | 360
    view_order: str = "nearest"  # dataset | nearest | random
    schedule: str = "interleaved"  # interleaved: a new view every iteration (the paper) | block: iters_per_view in a row
    seed: int = 0
    virtual_views: int = 0
    dc_only: bool = D.DC_ONLY  # keep shN at its initial values (frozen): the stylization is view-independent
    params: str = "colour"  # colour: SH colours only (the paper) | all: geometry too (the paper's ablation)
    preset: str = "paper"  # paper | standard (the paper's iterations at 512 px) | quick
    max_side: int | None = None  # long side of the renders; None: the preset's
    color_transfer: bool = True  # ARF's linear colour transfer before and after
    backend: str = "auto"  # rasterizer backend
    device: str = "auto"  # auto | cpu | cuda
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def validate(self) -> None:
        for name in WHOLE_NUMBERS:  # a project's JSON may hold 4.0 or 1e400 where a command line's int could not
            v = getattr(self, name)
            if not (v is None and name in OPTIONAL) and (isinstance(v, bool) or not isinstance(v, numbers.Integral)):
                raise ValueError(f"{name} must be a whole number, got {v!r}")
        for name in NUMBERS:
            v = getattr(self, name)
            if not (v is None and name in OPTIONAL) and (isinstance(v, bool) or not isinstance(v, numbers.Real)
                                                        or not math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
        for name in FLAGS:
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        bg = self.background
        if (not isinstance(bg, (tuple, list)) or len(bg) != 3
                or not all(isinstance(c, numbers.Real) and not isinstance(c, bool) and 0 <= c <= 1 for c in bg)):
            raise ValueError(f"background must be 3 numbers in [0, 1], got {bg!r}")
        if self.recipe not in D.RECIPES:
            raise ValueError(f"recipe must be one of {', '.join(D.RECIPES)}, got {self.recipe!r}")
        if self.loss not in LOSSES:
            raise ValueError(f"unknown loss {self.loss!r}; expected one of {', '.join(LOSSES)}")
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}; expected one of {', '.join(PRESETS)}")
        if self.view_order not in VIEW_ORDERS:
            raise ValueError(f"unknown view order {self.view_order!r}; expected one of {', '.join(VIEW_ORDERS)}")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"schedule must be one of {', '.join(SCHEDULES)}, got {self.schedule!r}")
        if self.scene_kind not in SCENE_KINDS:
            raise ValueError(f"unknown scene kind {self.scene_kind!r}; expected auto, forward or 360")
        if self.content_source not in CONTENT_SOURCES:
            raise ValueError(f"content_source must be one of {', '.join(CONTENT_SOURCES)}, got "
                             f"{self.content_source!r}")
        if self.vgg_precision not in VGG_PRECISIONS:
            raise ValueError(f"vgg_precision must be one of {', '.join(VGG_PRECISIONS)}, got {self.vgg_precision!r}")
        if self.structure_measure not in D.STRUCTURE_MEASURES:
            raise ValueError(f"structure_measure must be one of {', '.join(D.STRUCTURE_MEASURES)}, got "
                             f"{self.structure_measure!r}")
        if self.content_norm not in CONTENT_NORMS:
            raise ValueError(f"content_norm must be one of {', '.join(CONTENT_NORMS)}, got {self.content_norm!r}")
        if self.params not in PARAMS:  # worded "<field> ..." so the CLI can name the flag
            raise ValueError(f"params must be one of {', '.join(PARAMS)}, got {self.params!r}")
        checks = [("k", self.k >= 1, "at least 1"), ("epsilon", self.epsilon > 0, "positive"),
                  ("tau", self.tau > 0, "positive"), ("sinkhorn_iters", self.sinkhorn_iters >= 1, "at least 1"),
                  ("balance_every", self.balance_every >= 1, "at least 1"),
                  ("lambda_content", self.lambda_content >= 0, "at least 0"),
                  ("structure_budget", self.structure_budget >= 0, "at least 0"),
                  ("lambda_moments", self.lambda_moments >= 0, "at least 0"),
                  ("style_scale", 0 < self.style_scale <= MAX_STYLE_SCALE, f"in (0, {MAX_STYLE_SCALE:g}]"),
                  ("lambda_tv", self.lambda_tv >= 0, "at least 0"),
                  ("lr_final", 0 < self.lr_final <= 1, "in (0, 1]"),
                  ("lr", self.lr is None or self.lr > 0, "positive"),
                  ("virtual_views", self.virtual_views >= 0, "at least 0"),
                  ("lambda_guide", self.lambda_guide >= 0, "at least 0"),
                  ("lambda_style", self.lambda_style is None or self.lambda_style >= 0, "at least 0"),
                  ("iters_per_view", self.iters_per_view is None or self.iters_per_view >= 1, "at least 1"),
                  ("min_total_iters", self.min_total_iters is None or self.min_total_iters >= 0, "at least 0"),
                  ("max_side", self.max_side is None or self.max_side >= 16, "at least 16")]
        for name, ok, rule in checks:
            if not ok:
                raise ValueError(f"{name} must be {rule}, got {getattr(self, name)!r}")

    @property
    def style_weight(self) -> float:
        return DEFAULT_LAMBDA_STYLE[self.loss] if self.lambda_style is None else float(self.lambda_style)

    @property
    def learning_rate(self) -> float:
        if self.lr is not None:
            return float(self.lr)
        return DEFAULT_LR

    @property
    def render_max_side(self) -> int:
        if self.max_side is not None:
            return int(self.max_side)
        return {"quick": QUICK_MAX_SIDE, "standard": STANDARD_MAX_SIDE}.get(self.preset, PAPER_MAX_SIDE)


def recipe_config(recipe: str = D.DEFAULT_RECIPE, **changes) -> StylizeConfig:
    """The settings of ``recipe`` (defaults.RECIPES), with ``changes`` on top; not yet validated."""
    if recipe not in D.RECIPES:
        raise ValueError(f"recipe must be one of {', '.join(D.RECIPES)}, got {recipe!r}")
    return StylizeConfig(**{"recipe": recipe, **D.RECIPE_SETTINGS[recipe], **changes})


def recipe_settings(config: StylizeConfig) -> dict[str, dict]:
    """Every setting the recipes set: {name: {"value": config's, <each recipe>: that recipe's}}, for the report, the
    help and the Style tab."""
    out = {}
    for name in D.RECIPE_SETTINGS[config.recipe]:
        out[name] = {"value": getattr(config, name), **{r: D.RECIPE_SETTINGS[r][name] for r in D.RECIPES}}
    return out


def recipe_departures(config: StylizeConfig) -> dict[str, tuple]:
    """The recipe-set settings where ``config`` differs from its own recipe: {name: (recipe's value, config's)}."""
    own = D.RECIPE_SETTINGS[config.recipe]
    return {name: (value, getattr(config, name)) for name, value in own.items() if getattr(config, name) != value}


def recipe_line(config: StylizeConfig) -> str:
    """The recipe a run uses, in words, with every recipe-set setting the run changed."""
    changed = ", ".join(f"{k} {b}" for k, (a, b) in recipe_departures(config).items())
    return f"the {config.recipe} recipe" + (f", changed: {changed}" if changed else "")


def paper_schedule(kind: str, num_views: int) -> tuple[int, int]:
    """(iterations per view, minimum total iterations) of the paper for a scene kind and number of views."""
    if kind == "forward":
        return FORWARD_ITERS_PER_VIEW, FORWARD_MIN_TOTAL
    return (ORBIT_ITERS_PER_VIEW if num_views <= ORBIT_MANY_VIEWS else ORBIT_ITERS_PER_VIEW_MANY), 0


def iteration_schedule(config: StylizeConfig, kind: str, num_views: int) -> tuple[int, int]:
    """(iterations per view, minimum total) after the preset and the config's overrides."""
    per_view, min_total = paper_schedule(kind, num_views)
    if config.preset == "quick":
        per_view = max(1, int(round(per_view * QUICK_ITER_FRACTION)))
        min_total = int(round(min_total * QUICK_ITER_FRACTION))
    if config.iters_per_view is not None:
        per_view = int(config.iters_per_view)
    if config.min_total_iters is not None:
        min_total = int(config.min_total_iters)
    return per_view, min_total



def render_camera(camera: Camera, max_side: int) -> Camera:
    """The camera at the stylization resolution (never upscaled)."""
    factor = min(1.0, max_side / max(camera.width, camera.height))
    return camera if factor >= 1.0 else camera.scaled(factor)
