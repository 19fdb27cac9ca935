"""The whole ``splatstyler reconstruct`` job: load the scene, train, write the outputs; what the command, the demo, the
evaluation grid and the GPU benchmark all run.

Outputs (each written atomically): OUT/point_cloud.ply (standard 3DGS layout), OUT/report.json (metrics and
settings), OUT/renders/ and OUT/contact_sheet.png (training/reconstruct/results.py) and OUT/checkpoint.pt (every
``checkpoint_every`` iterations, on an interrupt and at the end). The checkpoint is kept after a finished run, on
purpose: resuming with more iterations extends the run from it, and resuming a finished run writes the report again.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

from training.core.errors import InputError
from training.core.messages import Scored
from training.reconstruct.config import ReconstructConfig
from training.reconstruct.early_stop import FlatWatch


class Stopped(KeyboardInterrupt):
    """The run was interrupted (Ctrl-C, SIGTERM) and its checkpoint saved: at ``iteration``, in ``checkpoint``. Its
    text completes "stopped by SIGTERM" (the CLI's line)."""

    def __init__(self, iteration: int, checkpoint: Path, finished: bool = False):
        what = ("after the last iteration, while writing the report; the model and checkpoint are saved (run again "
                "with --resume to write the report)" if finished else
                f"at iteration {iteration}; checkpoint saved to {checkpoint} (continue with --resume)")
        super().__init__(what)
        self.iteration, self.checkpoint = iteration, checkpoint


def reconstruct_to_folder(data: str | Path, out: str | Path, config: ReconstructConfig | None, *,
                          resume: bool = False, force: bool = False, iterations: int | None = None,
                          checkpoint_every: int = 1000, overwrite: bool = False,
                          resume_config: Callable[[ReconstructConfig], ReconstructConfig] | None = None,
                          listener=None, log: Callable[[str], None] | None = None,
                          say: Callable[[str], None] | None = None,
                          warn: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run the job and return the report (also written to OUT/report.json).

    ``config`` sets a fresh run; ``resume`` continues from OUT/checkpoint.pt with the settings it holds and
    ``iterations``, when given, as the run's new length (InputsChanged, exit 2, when it was made from other data,
    unless ``force``: then afresh with ``config``, which may be None only when there is a checkpoint to resume).
    ``resume_config``, when given, turns the checkpoint's settings into the ones the resumed run goes on with
    (InputError to refuse, e.g. a flag that contradicts them). Without ``resume`` or ``overwrite``, an OUT holding an
    interrupted run's checkpoint (or one that cannot be read) is refused: a fresh run would replace it at its first
    save. ``listener`` receives the trainer's events (training/core/messages.py); ``log`` gets the lines describing the
    run, ``say`` the time estimates (default: ``log``), ``warn`` the warnings (default: ``warnings.warn``).

    A stop (Ctrl-C, SIGTERM: training/core/stop.py) saves the checkpoint and goes on up as ``Stopped``."""
    from training.core import stop
    from training.core.atomic_write import check_output_dir, make_output_dir
    from training.core.run_estimate import RunEstimate
    from training.model.ply_io import write_ply
    from training.reconstruct.checkpoint import CHECKPOINT_NAME, load_checkpoint, save_checkpoint
    from training.reconstruct.metrics import constant_color_psnr
    from training.reconstruct.resolution import training_downscale
    from training.reconstruct.time_estimate import ReconstructSteps
    from training.reconstruct.trainer import Reconstructor
    from training.scene.fingerprint import dataset_fingerprint, make_fingerprint, state_to_resume
    from training.scene.loader import load_scene

    if warn is None:
        import warnings

        warn = warnings.warn
    log = log or (lambda line: None)
    say = say or log
    data, out = Path(data), Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(out, "the output path exists and is not a folder")
    check_output_dir(out)
    ckpt_path = out / CHECKPOINT_NAME
    # the data only: a resumed run takes its settings from the checkpoint, so they cannot differ from it
    fingerprint = make_fingerprint(dataset=dataset_fingerprint(data))
    state = None
    if not resume and not overwrite:
        _check_no_interrupted_run(ckpt_path)
    if resume:
        state = state_to_resume(load_checkpoint(ckpt_path), fingerprint, ckpt_path, force,
                                lambda line: log(f"reconstruct: {line}"), warn)
    if state is not None:
        cfg = ReconstructConfig.from_dict(state["config"])
        if resume_config is not None:
            cfg = resume_config(cfg)
        if iterations is not None:
            cfg.iterations = iterations
    elif config is None:
        raise ValueError("a fresh reconstruction needs a config")
    else:
        cfg = config
    if cfg.iterations < 1:
        raise InputError(None, f"--iters must be at least 1, got {cfg.iterations}")
    if cfg.downscale < 1:
        raise InputError(None, f"--downscale must be at least 1, got {cfg.downscale}")
    if cfg.max_side is not None and cfg.max_side < 16:
        raise InputError(None, f"--max-side must be at least 16 pixels, got {cfg.max_side}")
    if state is None:
        # resolved once; a resumed run keeps the factor its checkpoint recorded
        cfg.downscale = training_downscale(data, cfg.max_side, cfg.downscale)

    with stop.says("before the first iteration; nothing saved" if state is None else
                   "before the resumed run's first iteration; its checkpoint is as it was"):
        scene = load_scene(data, downscale=cfg.downscale)
        trainer = Reconstructor(scene, cfg)
        cam0 = scene.cameras[0]
        why = (f"long side at most {cfg.max_side} px" if cfg.max_side is not None else
               ("full size" if cfg.downscale == 1 else f"--downscale {cfg.downscale}"))
        log(f"training at {cam0.width}x{cam0.height} pixels (factor {cfg.downscale}: {why}; {cfg.preset} preset, "
            f"{cfg.iterations} iterations)")
        elapsed = 0.0
        report_extra: dict = {}
        if state is not None:
            trainer.load_state_dict(state)
            elapsed = float(state.get("elapsed", 0.0))
            report_extra = dict(state.get("report_extra", {}))
            log(f"resuming from {ckpt_path} at iteration {trainer.step_count}")
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

    # said a tenth into the run, again when densification or other jobs move it by more than 20 %
    estimate = RunEstimate(ReconstructSteps(trainer), say=say, what="training")
    trainer.add_listener(estimate)
    if listener is not None:
        trainer.add_listener(listener)
    eval_every = cfg.eval_every if cfg.eval_every is not None else max(1, cfg.iterations // 10)
    if not scene.test_indices:
        eval_every = 0
    curve = list(report_extra.get("test_curve", []))  # a resumed run's points so far
    eval_seconds = float(report_extra.get("test_curve_seconds", 0.0))
    flat = FlatWatch(cfg.stop_when_flat, cfg.densify.stop) if cfg.stop_when_flat else None
    if flat is not None and not eval_every:
        warn("--stop-when-flat needs test views scored during the run (--eval-every, and a scene with test "
             "views): it is off")
        flat = None
    t_start = time.perf_counter()
    estimate.begin(trainer.step_count)
    try:
        while not trainer.done:
            stop.check()
            trainer.step()
            if eval_every and (trainer.step_count % eval_every == 0 or trainer.done):
                t_eval = time.perf_counter()
                point = trainer.evaluate(scene.test_indices)
                curve.append({"iteration": trainer.step_count, "psnr": point["psnr"], "ssim": point["ssim"]})
                eval_seconds += time.perf_counter() - t_eval
                report_extra["test_curve"], report_extra["test_curve_seconds"] = curve, eval_seconds
                trainer.events.emit(Scored, trainer.step_count, psnr=point["psnr"], ssim=point["ssim"])
                estimate.not_a_step()
                if flat is not None and flat.see(trainer.step_count, point["psnr"], trainer):
                    break
            if checkpoint_every > 0 and trainer.step_count % checkpoint_every == 0:
                checkpoint()
    except BaseException as exc:
        if not stop.is_stop(exc):
            raise
        with stop.saving():
            checkpoint()
        raise Stopped(trainer.step_count, ckpt_path) from None
    seconds = elapsed + (time.perf_counter() - t_start)
    if flat is not None:
        report_extra["early_stop"] = flat.finish(trainer, curve, say=log)
    checkpoint()
    model = trainer.export_gaussians()
    write_ply(out / "point_cloud.ply", model)
    timing = estimate.record()
    if timing["first_estimate_s"] is not None:
        report_extra["estimated_seconds"] = timing["first_estimate_s"]  # this session's, as printed first
    report_extra["time_estimate"] = timing
    try:
        return write_reconstruction(trainer, model, out, data, seconds, report_extra, fingerprint, log)
    except BaseException as exc:
        if not stop.is_stop(exc):
            raise
        raise Stopped(trainer.step_count, ckpt_path, finished=True) from None


def write_reconstruction(trainer, model, out: Path, data: Path, seconds: float, report_extra: dict,
                         fingerprint: dict, log: Callable[[str], None]) -> dict[str, Any]:
    """What a finished reconstruction writes beside its model (``model``, the trainer's, saved): the train and test
    measures, the renders and contact sheet (``_write_results``) and OUT/report.json, which returns. ``seconds``: the
    run's time; ``report_extra``: what was measured before its first step and while it ran; ``fingerprint``: its
    data's. The console's job and the viewer's stage both end with it."""
    from training.core.atomic_write import atomic_open
    from training.core.version import version
    from training.reconstruct.regularizers import scale_stats

    scene, cfg = trainer.scene, trainer.config
    train = trainer.evaluate(scene.train_indices)
    test = trainer.evaluate(scene.test_indices)
    views = _write_results(trainer, out, scene.test_indices or scene.train_indices, log)
    stats = scale_stats(model.scales / trainer.extent)
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
            "data": str(data.resolve()),
            "depth_used": trainer.depth_mode,
            "init": trainer.init_source,
            "extent": trainer.extent,
            "image_size": [scene.cameras[0].width, scene.cameras[0].height],
            "config": cfg.to_dict(),
        },
    }
    with atomic_open(out / "report.json", "w") as f:
        json.dump(report, f, indent=2)
    return report


def _check_no_interrupted_run(ckpt_path: Path) -> None:
    """InputError when ``ckpt_path`` holds a checkpoint a fresh run would replace at its first save: an interrupted
    run's, or one that cannot be read (what it holds is not known). A finished run's is replaced with its model, as
    a new run into its folder asks."""
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


def _write_results(trainer, out: Path, indices, log: Callable[[str], None]) -> dict:
    """Renders, contact sheet and per-view metrics; LPIPS only when its weights can be had (a warning otherwise)."""
    import warnings

    from training.reconstruct.lpips import LPIPS, load_lpips_weights
    from training.reconstruct.results import write_view_results

    try:
        lpips = LPIPS(load_lpips_weights(log=lambda line: log(f"splatstyler: {line}")))
    except Exception as exc:  # no network and no cache: the other metrics and the pictures still matter
        warnings.warn(f"LPIPS skipped: its VGG weights could not be fetched ({type(exc).__name__}: {exc})"
                      .splitlines()[0])
        lpips = None
    return write_view_results(trainer, out, list(indices), lpips=lpips)


def summary_line(report: dict[str, Any], out: Path) -> str:
    """The one line that sums a finished reconstruction in OUT up."""
    from training.core.run_estimate import format_duration

    def fmt(value, spec):
        return "n/a" if value is None else format(value, spec)

    return (f"wrote {out / 'point_cloud.ply'} ({report['num_gaussians']} Gaussians) in "
            f"{format_duration(report['seconds'])}; test PSNR {fmt(report['test_psnr'], '.2f')} dB, SSIM "
            f"{fmt(report['test_ssim'], '.3f')}, LPIPS {fmt(report['test_lpips'], '.3f')}; renders in "
            f"{out / 'renders'}, contact sheet {out / 'contact_sheet.png'}")
