"""Time per stage of a stylization step, on any checkout of splatstyler (the before/after tables of
docs/performance.md).

    PYTHONPATH=CHECKOUT python scripts/profile_stylize_step.py MODEL DATA PAINTING [--iters N] [--warmup N]
        [--settings-before-issue-37] [--set NAME=VALUE ...]

Builds the Stylizer as ``splatstyler stylize MODEL --data DATA --style PAINTING --preset quick`` does (CCFT, the
quick preset's render size), runs ``--warmup`` untimed steps, then ``--iters`` timed ones, and prints one JSON line:
the mean wall milliseconds of each stage the step reports (rasterize, vgg_forward, loss and inside it
similarity_topk, sinkhorn, guide; agreement; the backward, as one stage or as vgg_backward and raster_backward;
optimizer), the rasterizer's backward timed by wrapping it (``raster_backward_wrapped``, the same measurement on
every checkout), the step's wall and CPU time, iterations per second and the load average.

``--settings-before-issue-37`` pins the stylization settings that changed in issue 37 to their values before it
(those of ``scripts/gpu_check.sh``'s ``_old`` runs), where the checkout has them, so that an older checkout and a
newer one run the same objective; ``--set`` sets any other StylizeConfig field (a number, true/false or text).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import time
import warnings
from pathlib import Path

import training  # noqa: F401  (sets OMP_WAIT_POLICY before torch loads, as the CLI does)

# the pre-issue-37 values of the settings it changed (an older checkout lacks some of these fields: skipped)
BEFORE_ISSUE_37 = {"content_norm": "mse", "lambda_content": 0.005, "content_source": "photo", "style_scale": 1.0,
                   "dc_only": False, "lr": 0.02, "lr_final": 1.0, "lambda_tv": 0.0, "k": 16,
                   "measure_balance": False}


def _value(text: str):
    if text in ("true", "false"):
        return text == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("model")
    p.add_argument("data")
    p.add_argument("painting")
    p.add_argument("--iters", type=int, default=20)
    p.add_argument("--warmup", type=int, default=4)
    p.add_argument("--settings-before-issue-37", action="store_true")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    args = p.parse_args()
    warnings.simplefilter("ignore")

    import torch

    import training.raster.cpu as cpu
    from training.model.model_io import read_model
    from training.scene.loader import load_scene
    from training.stylize.pipeline import choose_downscale
    from training.stylize.style_image import load_style_image
    from training.stylize.trainer import StylizeConfig, Stylizer

    known = {f.name for f in dataclasses.fields(StylizeConfig)}
    settings = dict(BEFORE_ISSUE_37) if args.settings_before_issue_37 else {}
    settings.update({k: _value(v) for k, v in (item.split("=", 1) for item in args.set)})
    cfg = StylizeConfig(preset="quick", loss="ccft", **{k: v for k, v in settings.items() if k in known})

    wrapped: list[float] = []
    backward = cpu._RasterizeCPU.backward

    def timed_backward(*a, **k):
        t = time.perf_counter()
        try:
            return backward(*a, **k)
        finally:
            wrapped.append(time.perf_counter() - t)

    cpu._RasterizeCPU.backward = staticmethod(timed_backward)

    data = Path(args.data)
    scene = load_scene(data, downscale=choose_downscale(data, cfg.render_max_side))
    st = Stylizer(read_model(Path(args.model)), scene, load_style_image(args.painting), cfg)
    for _ in range(args.warmup):
        st.step()
    wrapped.clear()
    samples: dict[str, list[float]] = {}
    walls, cpus = [], []
    for _ in range(args.iters):
        c0, t0 = time.process_time(), time.perf_counter()
        result = st.step()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
        for key, value in result["timings"].items():
            samples.setdefault(key, []).append(value)
    out = {k: round(1000 * statistics.mean(v), 1) for k, v in samples.items()}
    out.update(raster_backward_wrapped=round(1000 * sum(wrapped) / args.iters, 1),
               step_ms=round(1000 * statistics.mean(walls), 1), step_cpu_ms=round(1000 * statistics.mean(cpus), 1),
               it_per_s=round(args.iters / sum(walls), 3), render=f"{st.current_view.camera.width}x"
               f"{st.current_view.camera.height}", gaussians=len(st.gaussians),
               settings={k: v for k, v in settings.items() if k in known},
               skipped=sorted(k for k in settings if k not in known), load_1min=os.getloadavg()[0],
               threads=torch.get_num_threads())
    print(json.dumps(out))


if __name__ == "__main__":
    main()
