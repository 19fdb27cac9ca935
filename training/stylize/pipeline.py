"""The whole ``splatstyler stylize`` job: read the model, the scene and the painting, stylize, write the outputs.

Outputs (each written atomically): OUT/point_cloud.ply, OUT/renders/NNN_<view>.png for every view of the scene,
OUT/report.json, and OUT/before_after.png: a contact sheet of ``SHEET_VIEWS`` evenly spaced views, the input
model's render beside the stylized one, with the painting beside the first row. The model and
OUT/stylize_checkpoint.pt are written as soon as the stylization has finished (or is interrupted after its first
step), before the metrics and the renders; the checkpoint goes once the report is written.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from training.core.errors import InputError
from training.core.version import version
from training.stylize.config import recipe_departures, recipe_line, recipe_settings
from training.stylize.trainer import StylizeConfig, Stylizer

SHEET_VIEWS = 4
SHEET_CELL = 360
CONTACT_SHEET = "before_after.png"


def choose_downscale(data: Path, max_side: int) -> int:
    """The largest whole downscale whose images are still at least ``max_side`` on their long side."""
    from training.scene.loader import load_scene

    cams = load_scene(data, load_images=False).cameras
    if not cams:
        raise InputError(data, "the scene has no cameras")
    long_side = max(max(c.width, c.height) for c in cams)
    return max(1, long_side // max(1, max_side))


def stylize_to_folder(model: Path, data: Path, style: Path, out: Path, config: StylizeConfig,
                      vgg_weights: str | None = None, listener=None, log=None, mask=None,
                      metrics: Callable[[Stylizer], dict[str, Any]] | None = None, resume: bool = False,
                      force: bool = False, overwrite: bool = False, warn: Callable[[str], None] | None = None,
                      report_extra: Callable[[], dict[str, Any]] | None = None) -> dict[str, Any]:
    """Run the job and return the report (also written to OUT/report.json). ``listener`` receives the stylizer's
    events (training/core/messages.py); ``log`` (a str -> None callable) gets one line describing the run, and
    ``warn`` the warnings (default: ``warnings.warn``). ``mask``: (N,) bool, stylize only those Gaussians (Stylizer's
    ``mask``). ``metrics(stylizer)``, called once the stylization has finished, gives the report's "metrics" (the
    CLI passes training/evaluate's measures, which sit above this package); ``report_extra()``, called as the report
    is written, adds its entries (the CLI's time estimate).

    The work is kept as it is made: an interrupt (KeyboardInterrupt: Ctrl-C, SIGTERM) after the first step saves
    OUT/point_cloud.ply and OUT/stylize_checkpoint.pt before it goes on up; once the iterations and the post
    colour transfer are done, both are saved before the metrics and renders. ``resume`` continues from that
    checkpoint (InputsChanged, exit 2, when it was made from other inputs, unless ``force``: then afresh); the
    checkpoint is removed once the report is written, so one found without ``resume`` is an interrupted run's:
    InputError unless ``overwrite`` (a fresh run would replace it at its first save)."""
    from training.core import stop
    from training.core.atomic_write import check_output_dir, make_output_dir
    from training.scene.fingerprint import state_to_resume
    from training.model.model_io import read_model
    from training.model.ply_io import write_ply
    from training.scene.loader import load_scene
    from training.stylize.checkpoint import (CHECKPOINT_NAME, load_stylize_checkpoint, save_stylize_checkpoint,
                                             stylize_fingerprint)
    from training.stylize.style_image import load_style_image

    if warn is None:
        import warnings

        warn = warnings.warn
    say = log or (lambda line: None)
    config.validate()
    t_start = time.perf_counter()
    if out.exists() and not out.is_dir():
        raise InputError(out, "output exists and is not a folder")
    check_output_dir(out)
    ckpt_path = out / CHECKPOINT_NAME
    if not resume and not overwrite and ckpt_path.is_file():
        raise InputError(ckpt_path, "holds an interrupted stylization's checkpoint: continue it with --resume, or "
                                    "start afresh with --overwrite (which replaces it)")
    style_image = load_style_image(style)  # first: a bad painting should not cost a scene load
    gaussians = read_model(model)
    fingerprint = stylize_fingerprint(model, data, style, config, mask)
    state = None
    if resume:
        state = state_to_resume(load_stylize_checkpoint(ckpt_path), fingerprint, ckpt_path, force,
                                lambda line: say(f"stylize: {line}"), warn)
    with stop.says("before the first iteration; nothing saved" if state is None else
                   "before the resumed run's first iteration; its checkpoint is as it was"):
        scene = load_scene(data, downscale=choose_downscale(data, config.render_max_side))
        t_loaded = time.perf_counter()

        stylizer = Stylizer(gaussians, scene, style_image, config, vgg_weights=vgg_weights, model_name=model,
                            mask=mask)
        saved = state["pipeline"] if state is not None else {}
        if "distance_start" in saved:
            distance_start, distance_pre = saved["distance_start"], saved["distance_pre"]
        else:  # before the first step
            distance_start, distance_pre = start_distances(stylizer)
    if state is not None:
        stylizer.load_state(state["trainer"])
    earlier = {"stylize_loop": saved.get("stylize_seconds", 0.0), "total": saved.get("total_seconds", 0.0)}
    if listener is not None:
        stylizer.add_listener(listener)
    if log is not None:
        passes = stylizer.pass_progress()[1]
        where = "" if state is None else (f"; resuming from {ckpt_path} at iteration {stylizer.iteration}"
                                          + (", stylization finished" if stylizer.finished else ""))
        log(f"stylize: {recipe_line(config)}")
        log(f"stylize: {len(scene.cameras)} views ({stylizer.kind}), {len(stylizer.trajectory)} in the "
              f"trajectory, {stylizer.total_iters} iterations ({config.schedule}: {passes} "
              f"pass{'es' if passes != 1 else ''} along the trajectory) at "
              f"{stylizer.cameras[0].width}x{stylizer.cameras[0].height}; VGG weights: "
              f"{getattr(stylizer.vgg, 'weights_source', 'given')} in "
              f"{'bfloat16' if stylizer.feature_cache.bfloat16 else 'float32'}{where}")
    t0 = time.perf_counter()

    def loop_seconds() -> float:
        return earlier["stylize_loop"] + (time.perf_counter() - t0)

    def keep() -> None:
        """The model and the state to resume from, as they are now."""
        make_output_dir(out)
        write_ply(out / "point_cloud.ply", stylizer.stylized_gaussians())
        save_stylize_checkpoint(ckpt_path, stylizer, fingerprint, {
            "distance_start": distance_start, "distance_pre": distance_pre,
            "stylize_seconds": loop_seconds() if stylize_seconds is None else stylize_seconds,
            "total_seconds": earlier["total"] + (time.perf_counter() - t_start)})

    start_iteration = stylizer.iteration
    stylize_seconds = None
    try:
        if stylizer.finished and not stylizer.done:  # more iterations asked for than the finished run had
            stylizer.finished = False
        if not stylizer.finished:
            stylizer.run()
            stylize_seconds = loop_seconds()
            stylizer.finish()
            keep()  # before the metrics and the renders, which an interrupt may cut short
    except BaseException as exc:  # Ctrl-C or SIGTERM: keep what was stylized so far
        if not stop.is_stop(exc):
            raise
        if stylizer.iteration > start_iteration or state is not None:
            with stop.saving():
                keep()
            raise stop.StopRequested(f"at iteration {stylizer.iteration}; the model so far is in "
                                     f"{out / 'point_cloud.ply'} (continue with --resume)") from None
        raise stop.StopRequested("before the first iteration; nothing saved") from None
    if stylize_seconds is None:  # resumed after the stylization had finished
        stylize_seconds = earlier["stylize_loop"]
    record = StylizationRecord(model, data, style, fingerprint, distance_start, distance_pre,
                               load_seconds=t_loaded - t_start, loop_seconds=stylize_seconds,
                               earlier_seconds=earlier["total"], started=t_start,
                               resumed_at=None if state is None else start_iteration)
    try:
        return write_stylization(stylizer, out, record, metrics, report_extra)
    except BaseException as exc:
        if not stop.is_stop(exc):
            raise
        raise stop.StopRequested(f"after the stylization finished, while measuring and rendering; the model is in "
                                 f"{out / 'point_cloud.ply'} (run again with --resume to write the report and "
                                 "renders)") from None


@dataclass
class StylizationRecord:
    """What a stylization's report holds beyond the finished stylizer: its inputs, the fingerprint of them, the
    style distances measured before its first step (``start_distances``), and its times: loading the inputs, the
    loop (this session's and earlier ones'), a resumed session's earlier total, when this session ``started``
    (``time.perf_counter``) and the iteration it resumed at."""

    model: Path
    data: Path
    style: Path
    fingerprint: dict[str, Any]
    distance_start: dict[str, float]
    distance_pre: dict[str, float]
    load_seconds: float = 0.0
    loop_seconds: float = 0.0
    earlier_seconds: float = 0.0
    started: float = field(default_factory=time.perf_counter)
    resumed_at: int | None = None


def start_distances(stylizer: Stylizer) -> tuple[dict[str, float], dict[str, float]]:
    """The style distances of the input model's renders and of the renders after the pre colour transfer, taken
    before the first step (the report's style_distance starts from them)."""
    from training.stylize.style_distance import style_distance

    t0 = time.perf_counter()
    start = style_distance(stylizer, sh=stylizer.original_sh)
    pre = style_distance(stylizer) if stylizer.pre_transform is not None else start
    stylizer.times.add("style_distance", time.perf_counter() - t0)
    return start, pre


def write_stylization(stylizer: Stylizer, out: Path, record: StylizationRecord, metrics=None,
                      report_extra: Callable[[], dict[str, Any]] | None = None) -> dict[str, Any]:
    """What a finished stylization writes beside its model (saved): the measures (``metrics(stylizer)``, when
    given), the renders of every view, the before/after sheet and OUT/report.json, which returns; the checkpoint
    goes once the report is written. The console's job and the viewer's stage both end with it."""
    from training.core.atomic_write import atomic_open, make_output_dir
    from training.scene.image_io import write_image
    from training.stylize.checkpoint import CHECKPOINT_NAME
    from training.stylize.style_distance import style_distance

    scene, style_image, stylize_seconds = stylizer.scene, stylizer.style_image, record.loop_seconds
    distance_start, distance_pre = record.distance_start, record.distance_pre
    ckpt_path = out / CHECKPOINT_NAME
    first = stylizer.history[0] if stylizer.history else None
    utilisation = stylizer.utilisation()
    t0 = time.perf_counter()
    distance_end = style_distance(stylizer)
    stylizer.times.add("style_distance", time.perf_counter() - t0)

    measured = None
    if metrics is not None:
        t0 = time.perf_counter()
        measured = metrics(stylizer)
        stylizer.times.add("metrics", time.perf_counter() - t0)

    t0 = time.perf_counter()
    renders = stylizer.render_views()
    make_output_dir(out)
    render_names = []
    for pos, ((img, _), cam) in enumerate(zip(renders, stylizer.cameras)):
        name = f"{pos:03d}_{Path(cam.name).stem}.png"
        write_image(out / "renders" / name, img)
        render_names.append(name)
    # renders of an earlier run into the same folder (with more views) would otherwise pass for this run's
    for stale in (out / "renders").glob("[0-9][0-9][0-9]_*.png"):
        if stale.name not in render_names:
            stale.unlink()
    write_image(out / CONTACT_SHEET, before_after_sheet(stylizer, renders, style_image))
    stylizer.times.add("write_outputs", time.perf_counter() - t0)

    last = stylizer.history[-1] if stylizer.history else None
    report: dict[str, Any] = {
        "splatstyler_version": version(),
        "model": str(record.model), "data": str(record.data), "style": str(record.style), "output": str(out),
        "config": stylizer.config_dict(),
        # which recipe ran, every setting the two recipes set differently, and where this run left its recipe
        "recipe": {"name": stylizer.config.recipe, "settings": recipe_settings(stylizer.config),
                   "changed": {k: {"recipe": a, "used": b}
                               for k, (a, b) in recipe_departures(stylizer.config).items()}},
        "structure_budget": structure_budget_summary(stylizer),
        "scene_kind": stylizer.kind,
        "num_views": len(scene.cameras),
        "trajectory_length": len(stylizer.trajectory),
        "view_order": [scene.cameras[i].name for i in stylizer.order],
        "iterations": stylizer.iteration,
        "iters_per_view": stylizer.iters_per_view,
        "schedule": stylizer.config.schedule,
        "passes": stylizer.pass_progress()[1],
        "render_size": [stylizer.cameras[0].width, stylizer.cameras[0].height],
        "num_gaussians": len(stylizer.gaussians),
        "sh_degree": stylizer.gaussians.sh_degree,
        "vgg_weights": str(getattr(stylizer.vgg, "weights_source", "given")),
        "vgg_arithmetic": "bfloat16" if stylizer.feature_cache.bfloat16 else "float32",  # vgg_precision resolved
        "losses": {"first": first, "last": last, "history": stylizer.history},
        "style_distance": {
            "metric": "Gram distance of VGG relu3 features to the painting, mean over up to 8 evenly spaced views "
                      "(gram: raw features; gram_normalised: features of unit length per position)",
            **{f"{k}_start": v for k, v in distance_start.items()},
            **{f"{k}_after_pre_color_transfer": v for k, v in distance_pre.items()},
            **{f"{k}_end": v for k, v in distance_end.items()},
            **{f"{k}_ratio_end_to_start": distance_end[k] / v if v > 0 else None for k, v in distance_start.items()},
        },
        "utilisation": utilisation,
        # ||content gradient|| / ||style gradient|| on the render over the run (objective.py)
        "gradient_balance": gradient_balance(stylizer.history),
        # each step's plan against the previous step's, where it saw another view (plan_readouts.StepAgreement)
        "step_match_agreement": stylizer.agreement.mean(),
        "metrics": measured,
        "metrics_version": getattr(metrics, "version", None) if measured is not None else None,
        "color_transfer": {
            "pre": stylizer.pre_transform.to_dict() if stylizer.pre_transform else None,
            "post": stylizer.post_transform.to_dict() if stylizer.post_transform else None,
        },
        "iterations_per_second": stylizer.iteration / stylize_seconds if stylize_seconds > 0 else None,
        "time_s": {"load_inputs": record.load_seconds, **stylizer.times.totals, "stylize_loop": stylize_seconds,
                   "total": record.earlier_seconds + time.perf_counter() - record.started},
        "renders": render_names,
        "contact_sheet": CONTACT_SHEET,
        "fingerprint": record.fingerprint,
        "resumed_at_iteration": record.resumed_at,
    }
    if report_extra is not None:
        report.update(report_extra())
    with atomic_open(out / "report.json", "w") as f:
        json.dump(_jsonable(report), f, indent=2)
        f.write("\n")
    ckpt_path.unlink(missing_ok=True)  # the run is whole: nothing left to resume, and checkpoints are large
    return report


def structure_budget_summary(stylizer: Stylizer) -> dict[str, Any] | None:
    """What the structure budget did (structure_budget.py): the budget, the drift averaged over the last views and
    the content weight at the end, the range of the weight over the run; None when no step ran."""
    rows = [h for h in stylizer.history if h.get("content_weight") is not None]
    if not rows:
        return None
    weights = [h["content_weight"] for h in rows]
    return {"budget": stylizer.config.structure_budget, "measure": stylizer.config.structure_measure,
            "drift_end": stylizer.budget.drift,
            "content_weight_end": weights[-1], "content_weight_min": min(weights),
            "content_weight_max": max(weights)}


def gradient_balance(history: list[dict]) -> dict[str, Any] | None:
    """The content-to-style gradient ratio on the render (training/stylize/objective.py) over the steps that measured
    it: first, last, median, and the mean of each norm; None where no step did."""
    rows = [h for h in history if h.get("grad_style") and h.get("grad_content") is not None]
    if not rows:
        return None
    ratios = [h["grad_content"] / h["grad_style"] for h in rows]
    return {"content_to_style_first": ratios[0], "content_to_style_last": ratios[-1],
            "content_to_style_median": float(np.median(ratios)),
            "grad_style_mean": float(np.mean([h["grad_style"] for h in rows])),
            "grad_content_mean": float(np.mean([h["grad_content"] for h in rows])), "steps": len(rows)}


def before_after_sheet(stylizer: Stylizer, renders: list, style_image: np.ndarray) -> np.ndarray:
    """Evenly spaced views, one row each: the input model's render | the stylized render; the painting ends the
    first row, so the sheet alone shows what the stylization aimed at."""
    from training.scene.image_grid import grid, shrink_to

    n = len(stylizer.cameras)
    picks = sorted({round(k * (n - 1) / max(1, SHEET_VIEWS - 1)) for k in range(min(SHEET_VIEWS, n))})
    before = stylizer.render_views([stylizer.cameras[i] for i in picks], sh=stylizer.original_sh,
                                   input_geometry=True)  # the input model, also under --params all
    rows = [[shrink_to(b, SHEET_CELL), shrink_to(renders[i][0], SHEET_CELL)] for (b, _), i in zip(before, picks)]
    rows[0].append(shrink_to(style_image, SHEET_CELL))
    return grid(rows)


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value

