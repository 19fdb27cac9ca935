"""The whole ``splatstyler stylize`` job: read the model, the scene and the painting, stylize, write the outputs.

Outputs (each written atomically, and only once stylization has finished, so an error leaves nothing half-made):
OUT/point_cloud.ply, OUT/renders/NNN_<view>.png for every view of the scene, OUT/report.json, and
OUT/before_after.png: a contact sheet of ``SHEET_VIEWS`` evenly spaced views, the input model's render beside the
stylized one, with the painting beside the first row.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from training.core.errors import InputError
from training.core.version import version
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
                      metrics: Callable[[Stylizer], dict[str, Any]] | None = None,
                      report_extra: Callable[[], dict[str, Any]] | None = None) -> dict[str, Any]:
    """Run the job and return the report (also written to OUT/report.json). ``listener`` receives the stylizer's
    events (training/core/messages.py); ``log`` (a str -> None callable) gets one line describing the run.
    ``mask``: (N,) bool, stylize only those Gaussians (Stylizer's ``mask``). ``metrics(stylizer)``, called once the
    stylization has finished, gives the report's "metrics" (the CLI passes training/evaluate's measures, which sit
    above this package). ``report_extra()``, called as the report is written, adds its entries (the CLI's time
    estimate)."""
    from training.core.atomic_write import atomic_open, check_output_dir, make_output_dir
    from training.scene.image_io import write_image
    from training.model.ply_io import read_ply, write_ply
    from training.scene.loader import load_scene
    from training.stylize.style_image import load_style_image

    config.validate()
    t_start = time.perf_counter()
    if out.exists() and not out.is_dir():
        raise InputError(out, "output exists and is not a folder")
    check_output_dir(out)
    style_image = load_style_image(style)  # first: a bad painting should not cost a scene load
    gaussians = read_ply(model)
    scene = load_scene(data, downscale=choose_downscale(data, config.render_max_side))
    t_loaded = time.perf_counter()

    stylizer = Stylizer(gaussians, scene, style_image, config, vgg_weights=vgg_weights, model_name=model, mask=mask)
    t0 = time.perf_counter()
    distance_start = stylizer.style_distance(sh=stylizer.original_sh)
    distance_pre = stylizer.style_distance() if stylizer.pre_transform is not None else distance_start
    stylizer.times.add("style_distance", time.perf_counter() - t0)
    if listener is not None:
        stylizer.add_listener(listener)
    if log is not None:
        log(f"stylize: {len(scene.cameras)} views ({stylizer.kind}), {len(stylizer.trajectory)} in the "
              f"trajectory, {stylizer.total_iters} iterations at "
              f"{stylizer.cameras[0].width}x{stylizer.cameras[0].height}; VGG weights: "
              f"{getattr(stylizer.vgg, 'weights_source', 'given')}")
    t0 = time.perf_counter()
    try:
        stylizer.run()
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: keep what was stylized so far
        make_output_dir(out)
        write_ply(out / "point_cloud.ply", stylizer.stylized_gaussians())
        if log is not None:
            log(f"stylize: stopped at iteration {stylizer.iteration}; the model so far is in "
                f"{out / 'point_cloud.ply'}")
        raise
    first = stylizer.history[0] if stylizer.history else None
    stylize_seconds = time.perf_counter() - t0
    utilisation = stylizer.utilisation()
    stylizer.finish()
    t0 = time.perf_counter()
    distance_end = stylizer.style_distance()
    stylizer.times.add("style_distance", time.perf_counter() - t0)

    measured = None
    if metrics is not None:
        t0 = time.perf_counter()
        measured = metrics(stylizer)
        stylizer.times.add("metrics", time.perf_counter() - t0)

    t0 = time.perf_counter()
    renders = stylizer.render_views()
    make_output_dir(out)
    write_ply(out / "point_cloud.ply", stylizer.stylized_gaussians())
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
        "model": str(model), "data": str(data), "style": str(style), "output": str(out),
        "config": stylizer.config_dict(),
        "scene_kind": stylizer.kind,
        "num_views": len(scene.cameras),
        "trajectory_length": len(stylizer.trajectory),
        "view_order": [scene.cameras[i].name for i in stylizer.order],
        "iterations": stylizer.iteration,
        "iters_per_view": stylizer.iters_per_view,
        "render_size": [stylizer.cameras[0].width, stylizer.cameras[0].height],
        "num_gaussians": len(stylizer.gaussians),
        "sh_degree": stylizer.gaussians.sh_degree,
        "vgg_weights": str(getattr(stylizer.vgg, "weights_source", "given")),
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
        "metrics": measured,
        "metrics_version": getattr(metrics, "version", None) if measured is not None else None,
        "color_transfer": {
            "pre": stylizer.pre_transform.to_dict() if stylizer.pre_transform else None,
            "post": stylizer.post_transform.to_dict() if stylizer.post_transform else None,
        },
        "iterations_per_second": stylizer.iteration / stylize_seconds if stylize_seconds > 0 else None,
        "time_s": {"load_inputs": t_loaded - t_start, **stylizer.times.totals,
                   "stylize_loop": stylize_seconds, "total": time.perf_counter() - t_start},
        "renders": render_names,
        "contact_sheet": CONTACT_SHEET,
    }
    if report_extra is not None:
        report.update(report_extra())
    with atomic_open(out / "report.json", "w") as f:
        json.dump(_jsonable(report), f, indent=2)
        f.write("\n")
    return report


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

