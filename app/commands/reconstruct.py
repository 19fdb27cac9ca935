"""``splatstyler reconstruct DATA -o OUT``: train a 3DGS model with the paper's regularizers.

Writes OUT/point_cloud.ply (standard 3DGS layout), OUT/report.json (metrics and settings), OUT/renders/ and
OUT/contact_sheet.png (each test view's photo beside its render, and the depth; training/reconstruct/results.py)
and OUT/checkpoint.pt (every --checkpoint-every iterations, on Ctrl-C and at the end; ``--resume`` continues from
it). The checkpoint is kept after a finished run, on purpose: ``--resume --iters N`` extends the run from it and the
demo's window writes the reconstruction's report from it; it costs about three times the PLY on disk, which --help
says, so a user who wants only the model deletes it. The training resolution comes from the preset's target long
side (training/reconstruct/resolution.py); a time estimate is printed a tenth into the run, when the first large
Gaussians have shrunk, and again whenever it moves by more than 20 % (training/reconstruct/time_estimate.py);
report.json keeps the first one and the actual time.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.commands import add_run_flags
from training.reconstruct.config import PRESETS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reconstruct",
        help="train a 3D Gaussian Splatting model of a scene (3DGS + depth/shape/size regularizers)",
        description="Train a 3DGS model of DATA (a COLMAP folder or a transforms.json scene) into OUT: "
                    "OUT/point_cloud.ply, OUT/report.json, OUT/checkpoint.pt. The checkpoint is kept when the run "
                    "finishes (the model with the optimiser's state, about three times point_cloud.ply's size): "
                    "--resume --iters N trains on from it, and --resume alone writes the report again; delete it "
                    "once the model is final (the viewer's reconstructions keep theirs too).",
    )
    p.add_argument("data", metavar="DATA", help="scene: COLMAP folder (images/ + sparse/), or transforms.json")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output folder")
    p.add_argument("--preset", choices=PRESETS, default="quick",
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
    p.add_argument("--depth", choices=("sfm", "mono", "none"), default=None,
                   help="depth targets: sparse SfM depth (default), Depth Anything V2 aligned to SfM, or none. "
                        "With sfm on a scene without SfM points the depth term is switched off, with a warning")
    p.add_argument("--mono-depth-model", default=None, metavar="PATH",
                   help="local folder of depth-anything/Depth-Anything-V2-Small-hf (for --depth mono)")
    p.add_argument("--no-shape", action="store_true", help="switch the shape regularizer off")
    p.add_argument("--no-size", action="store_true", help="switch the size regularizer off")
    p.add_argument("--no-depth", action="store_true", help="switch the depth term off")
    p.add_argument("--backend", choices=("auto", "cpu", "cuda", "torch"), default=None, help="rasterizer backend")
    p.add_argument("--background", choices=("black", "white", "random"), default=None,
                   help="background colour behind the Gaussians (default black)")
    p.add_argument("--force", action="store_true",
                   help="with --resume: when OUT/checkpoint.pt was made from other data, start afresh (replacing "
                        "it) instead of stopping")
    p.add_argument("--checkpoint-every", type=int, default=1000, metavar="N",
                   help="save OUT/checkpoint.pt every N iterations (0: only on Ctrl-C and at the end)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    add_run_flags(p, progress="no progress bar (the time estimates are still printed)",
                  resume="continue from OUT/checkpoint.pt (its settings, with --iters allowed to extend the run); it must have "
                         "been made from this DATA, else exit 2")
    p.set_defaults(func=run)


def _config(args):
    from training.core.errors import InputError
    from training.reconstruct.config import ReconstructConfig

    cfg = ReconstructConfig.from_preset(args.preset)
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
    cfg.mono_depth_model = args.mono_depth_model
    cfg.use_shape = not args.no_shape
    cfg.use_size = not args.no_size
    cfg.use_depth = not args.no_depth
    if args.no_depth:
        cfg.depth = "none"  # no targets to compute (--depth mono would otherwise run the depth model for nothing)
    if args.backend is not None:
        cfg.backend = args.backend
    if args.background is not None:
        cfg.background = args.background
    if args.seed is not None:
        cfg.seed = args.seed
    return cfg


def _one_line_warnings() -> None:
    """Show warnings as the CLI's other messages: one line, no source excerpt."""
    import warnings

    warnings.formatwarning = lambda message, category, filename, lineno, line=None: (
        f"splatstyler: warning: {message}\n")


def run(args) -> int:
    import json
    import time

    from training.reconstruct.checkpoint import CHECKPOINT_NAME, load_checkpoint, save_checkpoint
    from training.core.errors import InputError
    from training.model.ply_io import write_ply
    from training.reconstruct.config import ReconstructConfig
    from training.reconstruct.trainer import Reconstructor
    from training.reconstruct.regularizers import scale_stats
    from training.scene.loader import load_scene
    from training.core.atomic_write import atomic_open
    from training.reconstruct.metrics import constant_color_psnr
    from training.reconstruct.resolution import training_downscale
    from training.core.run_estimate import RunEstimate, format_duration
    from training.reconstruct.time_estimate import ReconstructSteps
    from training.core.atomic_write import check_output_dir, make_output_dir
    from training.scene.fingerprint import InputsChanged, check_same_inputs, dataset_fingerprint, make_fingerprint

    _one_line_warnings()
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise InputError(out, "the output path exists and is not a folder")
    check_output_dir(out)
    ckpt_path = out / CHECKPOINT_NAME
    # the data only: a resumed run takes its settings from the checkpoint, so they cannot differ from it
    fingerprint = make_fingerprint(dataset=dataset_fingerprint(args.data))
    state = None
    if args.resume:
        state = load_checkpoint(ckpt_path)
        try:
            warning = check_same_inputs(state.get("fingerprint"), fingerprint, ckpt_path)
        except InputsChanged as exc:
            if not args.force:
                raise
            print(f"splatstyler: {ckpt_path}: made from other inputs ({exc.difference}): starting afresh "
                  f"(--force)", file=sys.stderr)
            state, warning = None, None
        if warning:
            print(f"splatstyler: warning: {warning}", file=sys.stderr)
    if state is not None:
        cfg = ReconstructConfig.from_dict(state["config"])
        if args.iters is not None:
            cfg.iterations = args.iters
    else:
        cfg = _config(args)
    if cfg.iterations < 1:
        raise InputError(None, f"--iters must be at least 1, got {cfg.iterations}")
    if cfg.downscale < 1:
        raise InputError(None, f"--downscale must be at least 1, got {cfg.downscale}")
    if cfg.max_side is not None and cfg.max_side < 16:
        raise InputError(None, f"--max-side must be at least 16 pixels, got {cfg.max_side}")
    if state is None:
        # resolved once; a resumed run keeps the factor its checkpoint recorded
        cfg.downscale = training_downscale(args.data, cfg.max_side, cfg.downscale)

    scene = load_scene(args.data, downscale=cfg.downscale)
    trainer = Reconstructor(scene, cfg)
    cam0 = scene.cameras[0]
    why = (f"long side at most {cfg.max_side} px" if cfg.max_side is not None else
           ("full size" if cfg.downscale == 1 else f"--downscale {cfg.downscale}"))
    print(f"training at {cam0.width}x{cam0.height} pixels (factor {cfg.downscale}: {why}; {cfg.preset} preset, "
          f"{cfg.iterations} iterations)", file=sys.stderr)
    elapsed = 0.0
    report_extra: dict = {}
    if state is not None:
        trainer.load_state_dict(state)
        elapsed = float(state.get("elapsed", 0.0))
        report_extra = dict(state.get("report_extra", {}))
        print(f"resuming from {ckpt_path} at iteration {trainer.step_count}", file=sys.stderr)
    else:
        init = trainer.evaluate(scene.test_indices or scene.train_indices)
        report_extra = {"initial_psnr": init["psnr"], "initial_ssim": init["ssim"],
                        "constant_color_psnr": constant_color_psnr(scene, scene.train_indices,
                                                                   scene.test_indices or scene.train_indices)}
    make_output_dir(out)

    def checkpoint() -> None:
        s = trainer.state_dict()
        s["elapsed"] = elapsed + (time.perf_counter() - t_start)
        s["report_extra"] = report_extra
        s["fingerprint"] = fingerprint
        save_checkpoint(ckpt_path, s)

    from app.progress import ProgressBar, say_above_bars

    # said a tenth into the run, again when densification or other jobs move it by more than 20 %
    estimate = RunEstimate(ReconstructSteps(trainer), say=say_above_bars, what="training")
    trainer.add_listener(estimate)
    t_start = time.perf_counter()
    estimate.begin(trainer.step_count)
    try:
        bar = ProgressBar(initial=trainer.step_count, desc="reconstruct", disable=args.no_progress,
                          postfix={"loss": "loss", "psnr": "psnr", "num_gaussians": "n"})
        trainer.add_listener(bar)
        while not trainer.done:
            trainer.step()
            if args.checkpoint_every > 0 and trainer.step_count % args.checkpoint_every == 0:
                checkpoint()
    except KeyboardInterrupt:
        if "bar" in locals():
            bar.close()
        checkpoint()
        from app import stop_signals

        print(f"stopped by {stop_signals.signal_name()} at iteration {trainer.step_count}; checkpoint saved to "
              f"{ckpt_path} (continue with --resume)", file=sys.stderr)
        return stop_signals.exit_code()
    bar.close()
    seconds = elapsed + (time.perf_counter() - t_start)
    checkpoint()
    timing = estimate.record()
    if timing["first_estimate_s"] is not None:
        report_extra["estimated_seconds"] = timing["first_estimate_s"]  # this session's, as printed first
    report_extra["time_estimate"] = timing

    model = trainer.export_gaussians()
    write_ply(out / "point_cloud.ply", model)
    train = trainer.evaluate(scene.train_indices)
    test = trainer.evaluate(scene.test_indices)
    views = _write_results(trainer, out, scene.test_indices or scene.train_indices)
    stats = scale_stats(model.scales / trainer.extent)
    from training.core.version import version

    report = {
        "splatstyler_version": version(),
        "train_psnr": train["psnr"], "train_ssim": train["ssim"],
        "test_psnr": test["psnr"], "test_ssim": test["ssim"],
        "test_lpips": views["lpips"] if scene.test_indices else None, "test_views": test["views"],
        "views": views["views"], "views_split": "test" if scene.test_indices else "train",
        "contact_sheet": views.get("contact_sheet"),
        "num_gaussians": len(model),
        "aniso_p95": stats["aniso_p95"], "smax_p95": stats["smax_p95"],
        "seconds": seconds,
        "iterations": trainer.step_count,
        **report_extra,
        "nan_recoveries": trainer.recoveries,
        "fingerprint": fingerprint,
        "settings": {
            "data": str(Path(args.data).resolve()),
            "depth_used": trainer.depth_mode,
            "init": trainer.init_source,
            "extent": trainer.extent,
            "image_size": [scene.cameras[0].width, scene.cameras[0].height],
            "config": cfg.to_dict(),
        },
    }
    with atomic_open(out / "report.json", "w") as f:
        json.dump(report, f, indent=2)
    def fmt(value, spec):
        return "n/a" if value is None else format(value, spec)

    print(f"wrote {out / 'point_cloud.ply'} ({len(model)} Gaussians) in {format_duration(seconds)}; test PSNR "
          f"{fmt(test['psnr'], '.2f')} dB, SSIM {fmt(test['ssim'], '.3f')}, LPIPS {fmt(report['test_lpips'], '.3f')}"
          f"; renders in {out / 'renders'}, contact sheet {out / 'contact_sheet.png'}", file=sys.stderr)
    return 0


def _write_results(trainer, out: Path, indices) -> dict:
    """Renders, contact sheet and per-view metrics; LPIPS only when its weights can be had (a warning otherwise)."""
    import warnings

    from training.reconstruct.lpips import LPIPS, load_lpips_weights
    from training.reconstruct.results import write_view_results

    try:
        lpips = LPIPS(load_lpips_weights(log=lambda line: print(f"splatstyler: {line}", file=sys.stderr)))
    except Exception as exc:  # no network and no cache: the other metrics and the pictures still matter
        warnings.warn(f"LPIPS skipped: its VGG weights could not be fetched ({type(exc).__name__}: {exc})"
                      .splitlines()[0])
        lpips = None
    return write_view_results(trainer, out, list(indices), lpips=lpips)
