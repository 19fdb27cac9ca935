"""The stylization settings a `splatstyler stylize` command line describes: what the stylize command runs with, and
what the evaluation reads back from a cell's recorded flags (app/evaluate)."""

from __future__ import annotations

import argparse


def config_from_args(args: argparse.Namespace):
    """The StylizeConfig the flags describe, validated (a bad value is one line naming the flag)."""
    from training.core.errors import InputError
    from training.stylize.trainer import StylizeConfig

    config = StylizeConfig(
        loss=args.loss, tau=args.tau, k=args.k, epsilon=args.epsilon, lambda_guide=args.lambda_guide,
        sinkhorn_iters=args.sinkhorn_iters, lambda_style=args.lambda_style, lambda_content=args.lambda_content,
        content_norm=args.content_norm, content_source=args.content_source, style_scale=args.style_scale, lambda_tv=args.lambda_tv,
        lr=args.lr, lr_final=args.lr_final, iters_per_view=args.iters_per_view, min_total_iters=args.min_total_iters,
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
