"""The settings of a reconstruction (``splatstyler reconstruct``, a grid's ``[reconstruct]``): their flags, and the
``ReconstructConfig`` they give (training/reconstruct/config.py), checked (a bad value is one line naming the flag)."""

from __future__ import annotations

import argparse

from training.reconstruct.config import BACKGROUNDS, DEPTH_SOURCES, PRESETS
from training.raster.constants import BACKENDS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    p = parser
    p.add_argument("--preset", choices=PRESETS, default=None,
                   help="quick: minutes on a CPU (long side at most 400 px, 5000 iterations); standard: 7000 "
                        "iterations, long side at most 1000 px; paper: 3DGS's 30k iterations at full resolution, "
                        "for a GPU (default: quick)")
    p.add_argument("--iters", type=int, default=None, metavar="N", help="number of iterations (overrides preset)")
    p.add_argument("--downscale", type=int, default=None, metavar="N",
                   help="divide image sizes by the whole number N (images_N cache; overrides the preset's size)")
    p.add_argument("--max-side", type=int, default=None, metavar="PX",
                   help="train with the long side at most PX pixels, by the smallest whole factor that gets there "
                        "(overrides the preset's: quick 400, standard 1000, paper full size)")
    p.add_argument("--max-gaussians", type=int, default=None, metavar="N",
                   help="cap on the number of Gaussians densification may reach (overrides the preset's: quick "
                        "60000, standard 300000, paper none)")
    p.add_argument("--densify-grad", type=float, default=None, metavar="G",
                   help="densify Gaussians whose mean screen-space gradient (NDC units) is at least G (default "
                        "0.0002, as 3DGS; lower grows more Gaussians)")
    p.add_argument("--prune-screen", type=float, default=None, metavar="F",
                   help="after the first opacity reset, prune Gaussians whose screen radius exceeded F x the "
                        "image's long side (default 0.15; 0 = off)")
    p.add_argument("--depth", choices=DEPTH_SOURCES, default=None,
                   help="depth targets: sparse SfM depth (default), Depth Anything V2 aligned to SfM, or none. "
                        "With sfm on a scene without SfM points the depth term is switched off, with a warning")
    p.add_argument("--mono-depth-model", default=None, metavar="PATH",
                   help="local folder of depth-anything/Depth-Anything-V2-Small-hf (for --depth mono)")
    p.add_argument("--no-shape", action="store_true", help="switch the shape regularizer off")
    p.add_argument("--no-size", action="store_true", help="switch the size regularizer off")
    p.add_argument("--no-depth", action="store_true", help="switch the depth term off")
    p.add_argument("--backend", choices=BACKENDS, default=None, help="rasterizer backend")
    p.add_argument("--background", choices=BACKGROUNDS, default=None,
                   help="background colour behind the Gaussians (default black)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--eval-every", type=int, default=None, metavar="N",
                   help="score the test views every N iterations: the progress line shows their PSNR and "
                        "report.json keeps the curve (test_curve); default: a tenth of the run, 0: never")
    p.add_argument("--stop-when-flat", type=int, default=None, metavar="N",
                   help="once densification has stopped, end the run when the test views' PSNR (scored every "
                        "--eval-every iterations) has not risen by 0.05 dB for N iterations, and keep the model "
                        "that scored best; chosen on the test views themselves, so the report's test figures are "
                        "then optimistic (default 0: off)")


# the flags that set ReconstructConfig fields (their dests); a resumed run takes its settings from the checkpoint,
# and of these only RESUME_MAY_CHANGE may differ from them there
CONFIG_FLAGS = ("preset", "iters", "downscale", "max_side", "max_gaussians", "densify_grad", "prune_screen", "depth",
                "mono_depth_model", "no_shape", "no_size", "no_depth", "backend", "background", "seed", "eval_every",
                "stop_when_flat")
# a longer run; another rasterizer (the run may go on elsewhere); the test views scored more or less often, and
# another stopping rule (neither changes what a step does)
RESUME_MAY_CHANGE = ("iters", "backend", "eval_every", "stop_when_flat")


def config_from_args(args: argparse.Namespace, base=None):
    """The ReconstructConfig the flags describe: on the preset's (a fresh run), or on ``base``'s (the flags not
    given leaving those settings as they are)."""
    import copy

    from training.core.errors import InputError
    from training.reconstruct.config import ReconstructConfig

    cfg = ReconstructConfig.from_preset(args.preset or "quick") if base is None else copy.deepcopy(base)
    if args.iters is not None:
        cfg = cfg.with_iterations(args.iters)
    if args.downscale is not None and args.max_side is not None:
        raise InputError(None, "give --downscale or --max-side, not both")
    if args.downscale is not None:
        cfg.downscale, cfg.max_side = args.downscale, None
    if args.max_side is not None:
        cfg.max_side = args.max_side
    if args.max_gaussians is not None:
        if args.max_gaussians < 1:
            raise InputError(None, f"--max-gaussians must be at least 1, got {args.max_gaussians}")
        cfg.densify.max_gaussians = args.max_gaussians
    if args.densify_grad is not None:
        if not args.densify_grad > 0:
            raise InputError(None, f"--densify-grad must be positive, got {args.densify_grad}")
        cfg.densify.grad_threshold = args.densify_grad
    if args.prune_screen is not None:
        if not args.prune_screen >= 0:
            raise InputError(None, f"--prune-screen must be at least 0 (0: off), got {args.prune_screen}")
        cfg.densify.prune_screen = args.prune_screen
    if args.depth is not None:
        cfg.depth = args.depth
    if args.mono_depth_model is not None:
        cfg.mono_depth_model = args.mono_depth_model
    if args.no_shape:
        cfg.use_shape = False
    if args.no_size:
        cfg.use_size = False
    if args.no_depth:
        cfg.use_depth = False
        cfg.depth = "none"  # no targets to compute (--depth mono would otherwise run the depth model for nothing)
    if args.backend is not None:
        cfg.backend = args.backend
    if args.background is not None:
        cfg.background = args.background
    if args.seed is not None:
        cfg.seed = args.seed
    _set_scoring(args, cfg)
    return cfg


def _set_scoring(args: argparse.Namespace, cfg) -> None:
    """--eval-every and --stop-when-flat, checked, into ``cfg``."""
    from training.core.errors import InputError

    if args.eval_every is not None:
        if args.eval_every < 0:
            raise InputError(None, f"--eval-every must be at least 0 (0: never), got {args.eval_every}")
        cfg.eval_every = args.eval_every
    if args.stop_when_flat is not None:
        if args.stop_when_flat < 0:
            raise InputError(None, f"--stop-when-flat must be at least 0 (0: off), got {args.stop_when_flat}")
        cfg.stop_when_flat = args.stop_when_flat


def resumed_config(args: argparse.Namespace, saved):
    """The checkpoint's settings ``saved`` with --iters, --backend, --eval-every and --stop-when-flat applied;
    InputError naming each other flag given whose value is not the checkpoint's (dropping it silently would train
    with settings nobody asked for)."""
    from pathlib import Path

    from training.core.errors import InputError

    differ = []
    for dest in CONFIG_FLAGS:
        value = getattr(args, dest)
        if dest in RESUME_MAY_CHANGE or value is None or value is False:
            continue
        flag = "--" + dest.replace("_", "-") + ("" if value is True else f" {value}")
        if dest == "preset":
            if value != saved.preset:
                differ.append(f"{flag} (it has {saved.preset})")
            continue
        alone = argparse.Namespace(**{d: (False if d.startswith("no_") else None) for d in CONFIG_FLAGS})
        setattr(alone, dest, value)
        changed = _changes(saved.to_dict(), config_from_args(alone, saved).to_dict())
        if changed:
            differ.append(f"{flag} (it has {', '.join(changed)})")
    if differ:
        raise InputError(Path(args.output) / "checkpoint.pt",
                         f"--resume continues with the checkpoint's settings, and {'; '.join(differ)}: drop "
                         f"{'that flag' if len(differ) == 1 else 'those flags'}, or start afresh with --overwrite")
    # set, not stretched as a fresh run's --iters is: the densification schedule the run has followed stays
    if args.iters is not None:
        saved.iterations = args.iters
    if args.backend is not None:
        saved.backend = args.backend
    _set_scoring(args, saved)
    return saved


def _changes(before: dict, after: dict, prefix: str = "") -> list[str]:
    """``name value`` of each setting (nested ones dotted) whose value in ``after`` differs, as ``before`` has it."""
    out = []
    for key, old in before.items():
        new = after.get(key)
        if isinstance(old, dict) and isinstance(new, dict):
            out += _changes(old, new, f"{prefix}{key}.")
        elif new != old:
            out.append(f"{prefix}{key} {old}")
    return out
