"""A grid cell with ``method = "2d"``: the deliberately inconsistent reference for the consistency measure.

The reconstruction's renders of every view (after the pre colour transfer, as the stylizer starts) are stylized one
by one in 2D (training/evaluate/baseline_2d.py: no 3D model, no guidance between views), then measured exactly as a
stylized model is, with the reconstruction's depth for the warps. Writes the same files a stylize cell does:
``renders/NNN_<view>.png`` and ``report.json`` with "metrics".
"""

from __future__ import annotations

import json
import time
from pathlib import Path


def run_baseline_cell(model: Path, data: Path, painting: Path, out: Path, flags: list[str]) -> dict:
    from app.evaluate.remeasure import prepared_stylizer
    from training.core.atomic_write import atomic_open, make_output_dir
    from training.evaluate.baseline_2d import stylize_images_independently
    from training.evaluate.measure import METRICS_VERSION, measure_images, measure_order, render_all
    from training.scene.image_io import write_image

    t0 = time.perf_counter()
    # The stylizer only prepares the views: cameras at the stylization size, trajectory order, pre colour transfer.
    stylizer, args = prepared_stylizer(model, data, painting, flags)
    style = stylizer.style_image
    cfg = stylizer.config
    g = stylizer.gaussians.detached()
    renders = render_all(g, g.sh, stylizer.cameras, cfg.background, cfg.backend, stylizer.device, mode="RGB+ED")
    start = [img[..., :3] for img, _ in renders]
    original = [img for img, _ in render_all(g, stylizer.original_sh.detach(), stylizer.cameras, cfg.background,
                                               cfg.backend, stylizer.device, mode="RGB")]
    stylized = stylize_images_independently(start, style, loss=cfg.loss, vgg=stylizer.vgg,
                                            color_transfer=False)  # the renders already had the stylizer's one
    metrics = measure_images(stylized, [img[..., 3:] for img, _ in renders], [a for _, a in renders], original,
                             start if stylizer.pre_transform is not None else None, stylizer.cameras, measure_order(stylizer),
                             style, max_pairs=args.metric_pairs)
    make_output_dir(out)
    names = []
    for pos, (img, cam) in enumerate(zip(stylized, stylizer.cameras)):
        name = f"{pos:03d}_{Path(cam.name).stem}.png"
        write_image(out / "renders" / name, img)
        names.append(name)
    from training.core.version import version

    report = {"splatstyler_version": version(), "method": "2d", "model": str(model), "data": str(data),
              "style": str(painting), "config": stylizer.config_dict(), "num_views": len(stylizer.cameras),
              "renders": names, "metrics": metrics, "metrics_version": METRICS_VERSION,
              "time_s": {"total": time.perf_counter() - t0}}
    with atomic_open(out / "report.json", "w") as f:
        json.dump(report, f, indent=2, default=lambda v: None)
        f.write("\n")
    return report

