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

PRESETS = ("quick", "standard", "paper")


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
    p.add_argument("--overwrite", action="store_true",
                   help="start afresh in an OUT that holds an interrupted run's checkpoint.pt, replacing it (without "
                        "--resume or --overwrite such an OUT is refused, exit 2: nothing is lost by mistake)")
    p.add_argument("--checkpoint-every", type=int, default=1000, metavar="N",
                   help="save OUT/checkpoint.pt every N iterations (0: only on Ctrl-C and at the end)")
    p.add_argument("--eval-every", type=int, default=None, metavar="N",
                   help="score the test views every N iterations: the progress line shows their PSNR and "
                        "report.json keeps the curve (test_curve); default: a tenth of the run, 0: never")
    p.add_argument("--stop-when-flat", type=int, default=0, metavar="N",
                   help="once densification has stopped, end the run when the test views' PSNR (scored every "
                        "--eval-every iterations) has not risen by 0.05 dB for N iterations, and keep the model "
                        "that scored best; chosen on the test views themselves, so the report's test figures are "
                        "then optimistic (default 0: off)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    add_run_flags(p, progress="no progress bar (the time estimates are still printed)",
                  resume="continue from OUT/checkpoint.pt with its settings: --iters may extend the run and "
                         "--backend change the rasterizer; any other setting given must be the checkpoint's, and "
                         "the checkpoint must have been made from this DATA, else exit 2")
    p.set_defaults(func=run)


# the flags that set ReconstructConfig fields (their dests); a resumed run takes its settings from the checkpoint,
# and of these only RESUME_MAY_CHANGE may differ from them there
CONFIG_FLAGS = ("preset", "iters", "downscale", "max_side", "max_gaussians", "densify_grad", "prune_screen", "depth",
                "mono_depth_model", "no_shape", "no_size", "no_depth", "backend", "background", "seed")
RESUME_MAY_CHANGE = ("iters", "backend")  # a longer run; another rasterizer (the run may go on elsewhere)


def _config(args, base=None):
    """The settings the flags give: on the preset's (``base``: on those, the flags not given leaving them)."""
    import copy

    from training.core.errors import InputError
    from training.reconstruct.trainer import ReconstructConfig

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
    return cfg


def _resumed_config(args, saved):
    """The checkpoint's settings ``saved`` with --iters and --backend applied; InputError naming each other flag
    given whose value is not the checkpoint's (dropping it silently would train with settings nobody asked for)."""
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
        changed = _changes(saved.to_dict(), _config(alone, saved).to_dict())
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


def _check_no_interrupted_run(ckpt_path: Path) -> None:
    """InputError when ``ckpt_path`` holds a checkpoint a fresh run would replace at its first save: an interrupted
    run's, or one that cannot be read (what it holds is not known). A finished run's is replaced with its model, as
    a new run into its folder asks."""
    from training.core.errors import InputError
    from training.reconstruct.checkpoint import load_checkpoint

    if not ckpt_path.is_file():
        return
    try:
        state = load_checkpoint(ckpt_path, mmap=True)  # its step and settings only: the tensors stay on disk
        step, total = int(state["step"]), int(state["config"]["iterations"])
    except (InputError, KeyError, TypeError, ValueError):
        raise InputError(ckpt_path, "holds a checkpoint that cannot be read: start afresh with --overwrite (which "
                                    "replaces it), or move it away") from None
    if step < total:
        raise InputError(ckpt_path, f"holds an interrupted run's checkpoint (iteration {step} of {total}): continue "
                                    "it with --resume, or start afresh with --overwrite (which replaces it)")


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
    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
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
    if args.eval_every is not None and args.eval_every < 0:
        raise InputError(None, f"--eval-every must be at least 0 (0: never), got {args.eval_every}")
    if args.stop_when_flat < 0:
        raise InputError(None, f"--stop-when-flat must be at least 0 (0: off), got {args.stop_when_flat}")
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise InputError(out, "the output path exists and is not a folder")
    check_output_dir(out)
    ckpt_path = out / CHECKPOINT_NAME
    # the data only: a resumed run takes its settings from the checkpoint, so they cannot differ from it
    fingerprint = make_fingerprint(dataset=dataset_fingerprint(args.data))
    state = None
    if not args.resume and not args.overwrite:
        _check_no_interrupted_run(ckpt_path)
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
        cfg = _resumed_config(args, ReconstructConfig.from_dict(state["config"]))
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

    eval_every = args.eval_every if args.eval_every is not None else max(1, cfg.iterations // 10)
    if not scene.test_indices:
        eval_every = 0
    curve = list(report_extra.get("test_curve", []))  # a resumed run's points so far
    eval_seconds = float(report_extra.get("test_curve_seconds", 0.0))
    flat = _FlatWatch(args.stop_when_flat, cfg.densify.stop) if args.stop_when_flat else None
    if flat is not None and not eval_every:
        print("splatstyler: warning: --stop-when-flat needs test views scored during the run (--eval-every, and a "
              "scene with test views): it is off", file=sys.stderr)
        flat = None

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
            if eval_every and (trainer.step_count % eval_every == 0 or trainer.done):
                t_eval = time.perf_counter()
                point = trainer.evaluate(scene.test_indices)
                curve.append({"iteration": trainer.step_count, "psnr": point["psnr"], "ssim": point["ssim"]})
                eval_seconds += time.perf_counter() - t_eval
                report_extra["test_curve"], report_extra["test_curve_seconds"] = curve, eval_seconds
                bar.show("test", f"{point['psnr']:.2f} dB")
                estimate.not_a_step()
                if flat is not None and flat.see(trainer.step_count, point["psnr"], trainer):
                    bar.show("stopped", f"flat since {flat.best_iteration}")
                    break
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
    if flat is not None:
        report_extra["early_stop"] = flat.finish(trainer, curve, say=lambda line: print(line, file=sys.stderr))
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


class _FlatWatch:
    """--stop-when-flat: after densification stops (before it the model grows and the opacity reset dips the
    curve), the iteration of the last rise by MIN_GAIN of the test views' PSNR and a copy of the best-scoring model;
    ``see`` says when ``patience`` iterations have passed without such a rise."""

    MIN_GAIN = 0.05  # dB

    def __init__(self, patience: int, after: int):
        self.patience, self.after = int(patience), int(after)
        self.best_psnr = self.rise_psnr = None
        self.best_iteration = self.rise_iteration = None
        self.best_params = None
        self.stopped_at = None

    def see(self, iteration: int, psnr: float, trainer) -> bool:
        if iteration <= self.after or psnr is None:
            return False
        if self.best_psnr is None or psnr > self.best_psnr:
            self.best_psnr, self.best_iteration = psnr, iteration
            self.best_params = {k: v.detach().clone() for k, v in trainer.gaussians.parameters().items()}
        if self.rise_psnr is None or psnr >= self.rise_psnr + self.MIN_GAIN:
            self.rise_psnr, self.rise_iteration = psnr, iteration
        if iteration - self.rise_iteration >= self.patience and not trainer.done:
            self.stopped_at = iteration
            return True
        return False

    def finish(self, trainer, curve: list, say) -> dict:
        """Keep the best-scoring model when the last one scored lower; the report's entry."""
        last = curve[-1] if curve else None
        kept = "last"
        if self.best_params is not None and last is not None and self.best_psnr > last["psnr"]:
            trainer.load_parameters(self.best_params)
            kept = "best"
        if self.stopped_at is not None:
            say(f"stopped at iteration {self.stopped_at} of {trainer.total_iters}: the test views' PSNR has not "
                f"risen by {self.MIN_GAIN} dB since iteration {self.rise_iteration} (--stop-when-flat "
                f"{self.patience})")
        if kept == "best":
            say(f"kept the model of iteration {self.best_iteration} (test PSNR {self.best_psnr:.2f} dB; iteration "
                f"{last['iteration']}: {last['psnr']:.2f} dB)")
        return {"patience": self.patience, "min_gain_db": self.MIN_GAIN, "stopped_at": self.stopped_at,
                "best_iteration": self.best_iteration, "best_test_psnr": self.best_psnr, "kept": kept,
                "chosen_on": "the test views"}


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
