"""``splatstyler bench viewer --live``: what the open viewer costs a running trainer, and how fast it answers.

Runs of the same training, each in a fresh process so that each has one GLFW/imgui runner and a cold start. For
each stage (``reconstruct``; then ``stylize`` where ``--style`` is given):
- ``headless``: the trainer stepping alone, built by the same stage builder as the viewer's session (the reference);
- ``window_still``: the viewer window open with the stage running in its session, the camera still (the view
  redraws when the trainer's model is refreshed, every ``refresh_s``);
- ``window_moving``: the same with the camera orbiting a little every frame (continuous input).
Each reports steps/s over ``--seconds`` after the same warm-up, and the ratio to headless (``vs_headless``), with
the trainer's device and, for a window, the display path the viewer chose (and why it draws without CUDA-GL
interop, where it does).

A last one, ``latency``: the window showing a ``--latency-splats`` Gaussian model (default 100k; at the window's
``--latency-size``, default 960x540) while the reconstruction runs; a camera move is injected every half second and
the time until the view has drawn it is recorded: p50 and p95 in ms.

The scene is ``--data`` (default: the demo's generated scene at its own 256x192 size) reconstructed with
``--preset`` (default quick); the stylize stage starts from the model the headless reconstruction saved, at
``--stylize-preset`` (default: paper where CUDA trains, quick elsewhere, as ``splatstyler stylize``). The trainer's
device is "auto": CUDA where gsplat is there. The window opens on the display (``DISPLAY``) or, with none, on
GLFW's null platform (EGL).
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

WINDOW = (1280, 800)  # the window's size in the window phases (its 3D view is the docked layout's central node)
PHASES = ("headless", "window_still", "window_moving", "latency")
STAGE_PHASES = ("headless", "window_still", "window_moving")
RECON_ITERS = 100_000  # a schedule longer than any measurement: the trainer never finishes inside one


def run_live(seconds: float, warmup_steps: int = 30, *, data: str | None = None, style: str | None = None,
             preset: str = "quick", stylize_preset: str | None = None, phases: tuple[str, ...] = PHASES,
             latency_splats: int = 100_000, latency_size: str = "960x540") -> list[dict]:
    """The rows described above; ``phases`` a subset of PHASES (the stylize stage runs the stage phases among
    them, with a headless reconstruction first to start from)."""
    bad = [p for p in phases if p not in PHASES]
    if bad:
        raise ValueError(f"unknown live phase {', '.join(bad)}; expected some of {', '.join(PHASES)}")
    work = Path(tempfile.mkdtemp(prefix="splatstyler_bench_live_"))
    common = {"seconds": seconds, "warmup": warmup_steps, "data": data, "preset": preset, "work": str(work)}
    rows = []
    recon_phases = [p for p in phases if p in STAGE_PHASES]
    if style is not None and "headless" not in recon_phases:
        recon_phases.insert(0, "headless")  # the stylize stage starts from the model it saves
    for phase in recon_phases:
        rows.append(_run_phase({**common, "phase": phase, "stage": "reconstruct", "save_model": style is not None}))
    if "latency" in phases:
        rows.append(_run_phase({**common, "phase": "latency", "stage": "reconstruct", "splats": latency_splats,
                                "size": latency_size}))
    if style is not None:
        model = str(work / "reconstruct_headless.ply")
        for phase in [p for p in phases if p in STAGE_PHASES]:
            rows.append(_run_phase({**common, "phase": phase, "stage": "stylize", "style": style, "model": model,
                                    "stylize_preset": stylize_preset}))
    for stage in ("reconstruct", "stylize"):
        base = next((r for r in rows if r["stage"] == stage and r["phase"] == "headless"), None)
        for row in rows:
            if base is not None and row["stage"] == stage and row["phase"].startswith("window"):
                row["vs_headless"] = row["steps_per_s"] / base["steps_per_s"] if base["steps_per_s"] > 0 else None
    return rows


def _run_phase(spec: dict) -> dict:
    proc = subprocess.run([sys.executable, "-m", "app.bench.viewer_live", json.dumps(spec)], capture_output=True,
                          text=True, timeout=900 + 4 * spec["seconds"])
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"bench viewer --live ({spec['stage']} {spec['phase']}) failed: "
                           f"{proc.stderr.strip().splitlines()[-1:]}")
    # each row as it comes (the table waits for the last): a run stopped by a time limit keeps what it measured
    print(f"bench viewer --live: {lines[-1]}", file=sys.stderr, flush=True)
    return json.loads(lines[-1])


def _stylize_config(preset: str | None):
    from training.raster.rasterize import resolve_device
    from training.stylize.config import StylizeConfig

    if preset is None:  # as `splatstyler stylize`: the paper's preset where the trainer runs on CUDA
        preset = "paper" if resolve_device("auto").type == "cuda" else "quick"
    return StylizeConfig(preset=preset)


def _data(spec: dict) -> tuple[str, int | None]:
    """The scene and the downscale factor: the demo's generated scene at its own size, or ``data`` as the preset
    sizes it."""
    if spec.get("data"):
        return spec["data"], None
    from assets.demo.assets import demo_assets

    return str(demo_assets().scene_dir), 1


def _trainer(spec: dict):
    """The stage's trainer, built as the viewer's session builds it (app/viewer/live/stages.py)."""
    from app.viewer.live.stages import reconstruct_stage, stylize_stage

    data, downscale = _data(spec)
    out = Path(spec["work"]) / f"{spec['stage']}_{spec['phase']}"
    if spec["stage"] == "reconstruct":
        stage = reconstruct_stage(data, out, preset=spec["preset"], downscale=downscale, iterations=RECON_ITERS)
    else:
        stage = stylize_stage(data, spec["style"], out, config=_stylize_config(spec.get("stylize_preset")),
                              model=spec["model"])
    return stage.build(None)


def _steps(trainer) -> int:
    return getattr(trainer, "step_count", getattr(trainer, "iteration", 0))


def _where(trainer=None) -> dict:
    import torch

    info = {"gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None}
    if trainer is not None:
        info["device"] = str(trainer.device)
    return info


def _headless(spec: dict) -> dict:
    trainer = _trainer(spec)
    for _ in range(spec["warmup"]):
        trainer.step()
    start, t0 = _steps(trainer), time.perf_counter()
    while time.perf_counter() - t0 < spec["seconds"] and not getattr(trainer, "done", False):
        trainer.step()
    elapsed = time.perf_counter() - t0
    row = {"stage": spec["stage"], "phase": "headless", "steps_per_s": (_steps(trainer) - start) / elapsed,
           "seconds": elapsed, **_where(trainer)}
    if spec.get("save_model"):
        from training.model.ply_io import write_ply

        write_ply(Path(spec["work"]) / "reconstruct_headless.ply", trainer.export_gaussians())
    return row


def _app(spec: dict):
    from app.viewer.app import ViewerApp
    from app.viewer.state import Paths

    data, downscale = _data(spec)
    out = str(Path(spec["work"]) / f"viewer_{spec['stage']}_{spec['phase']}")
    if spec["stage"] == "reconstruct":
        return ViewerApp(Paths(data=data, out=out), start="reconstruct", preset=spec["preset"],
                         recon_iters=RECON_ITERS, downscale=downscale)
    app = ViewerApp(Paths(data=data, model=spec["model"], style=spec["style"], out=out), start="stylize")
    app.ui.training.stylize = _stylize_config(spec.get("stylize_preset"))
    return app


def _display(app) -> dict:
    """The display path the view chose, and why it draws without CUDA-GL interop where it does."""
    choice = getattr(app.ui.view, "display", None)
    if choice is None:
        return {"display_path": None}
    return {"display_path": choice.label(), "display_note": choice.interop_note(app.ui.view.cuda)}


def _trainer_device(app) -> dict:
    status = app.session.trainer_status()
    return {"device": status.device} if status is not None and status.device else {}


def _window(spec: dict) -> dict:
    from imgui_bundle import hello_imgui, immapp

    from app.viewer.platform import choose_platform, prepare_glfw

    phase, seconds, warmup = spec["phase"], spec["seconds"], spec["warmup"]
    app = _app(spec)
    state = {"start": None, "t0": None, "frames": 0, "draws0": 0, "result": None}
    inner = app.gui

    def gui():
        inner()
        status = app.session.status()
        now = time.perf_counter()
        if phase == "window_moving" and app.view.camera is not None:
            app.view.camera.orbit(4.0, 0.0)  # a drag of 4 px every frame, as continuous mouse input
            app.view.moved()
            app.note_input()  # what a real mouse event does to the frame pacing
        if state["start"] is None:
            if status.state == "running" and status.step >= warmup:
                state.update(start=status.step, t0=now, draws0=app.view.frames_drawn, frames=app.frames)
        elif now - state["t0"] >= seconds or status.state != "running":
            elapsed = now - state["t0"]
            state["result"] = {"stage": spec["stage"], "phase": phase,
                               "steps_per_s": (status.step - state["start"]) / elapsed, "seconds": elapsed,
                               "trainer_state": status.state,
                               "ui_fps": (app.frames - state["frames"]) / elapsed,
                               "view_draws_per_s": (app.view.frames_drawn - state["draws0"]) / elapsed,
                               **_where(), **_trainer_device(app), **_display(app)}
            hello_imgui.get_runner_params().app_shall_exit = True

    app.gui = gui
    prepare_glfw(choose_platform())
    immapp.run(app.runner_params(size=WINDOW), immapp.AddOnsParams(with_implot=True))
    if state["result"] is None:
        raise RuntimeError(f"the window closed before the {spec['stage']} stage ran {warmup} steps: "
                           f"{app.ui.messages.error or 'no error shown'}")
    return state["result"]


def _latency(spec: dict) -> dict:
    import numpy as np
    from imgui_bundle import hello_imgui, immapp

    from app.render_inputs import parse_size
    from app.viewer.platform import choose_platform, prepare_glfw
    from training.core.messages import ModelSnapshot

    seconds, warmup, n = spec["seconds"], spec["warmup"], int(spec["splats"])
    app = _app(spec)
    app.ui.training.refresh_s = 1e9  # the view keeps the synthetic model; the trainer runs beside it
    rng = np.random.default_rng(0)
    ro = lambda a: (a.setflags(write=False), a)[1]  # noqa: E731
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    model = ModelSnapshot(1, 1, 0, ro(rng.uniform(-3, 3, (n, 3)).astype(np.float32)),
                          ro(rng.uniform(0.01, 0.06, (n, 3)).astype(np.float32)),
                          ro(quats / np.linalg.norm(quats, axis=1, keepdims=True)),
                          ro(rng.uniform(0.2, 0.9, n).astype(np.float32)),
                          ro(rng.normal(0, 1, (n, 1, 3)).astype(np.float32)), 0)
    state = {"pending": None, "latencies": [], "t0": None, "last": 0.0}
    inner_gui = app.gui

    def gui():
        if app.view is not None and app.view.renderer.count(0) != n:
            app.view.show(model, 0)
        inner_gui()
        now = time.perf_counter()
        if state["t0"] is None:
            if app.session.status().step >= warmup:
                state["t0"] = now
        elif now - state["t0"] >= seconds:
            hello_imgui.get_runner_params().app_shall_exit = True
        elif state["pending"] is None and now - state["last"] > 0.5:
            app.view.camera.orbit(6.0, 0.0)
            app.view.moved()
            app.note_input()
            state["pending"] = (now, app.view.frames_drawn)

    def drawn():  # after every panel and the view have been drawn, before imgui renders the frame
        if state["pending"] is not None and app.view.frames_drawn > state["pending"][1]:
            state["latencies"].append(time.perf_counter() - state["pending"][0])
            state["last"] = time.perf_counter()
            state["pending"] = None

    app.gui = gui
    prepare_glfw(choose_platform())
    params = app.runner_params(size=parse_size(spec["size"]))
    params.callbacks.before_imgui_render = drawn
    immapp.run(params, immapp.AddOnsParams(with_implot=True))
    row = {"stage": spec["stage"], "phase": "latency", "splats": n, "size": spec["size"], **_where(),
           **_trainer_device(app), **_display(app)}
    lat = sorted(state["latencies"])
    if not lat:
        return {**row, "samples": 0}
    p95 = lat[min(len(lat) - 1, int(round(0.95 * (len(lat) - 1))))]
    return {**row, "samples": len(lat), "p50_ms": 1000 * statistics.median(lat), "p95_ms": 1000 * p95}


def main(spec_json: str) -> None:
    spec = json.loads(spec_json)
    spec["seconds"], spec["warmup"] = float(spec["seconds"]), int(spec["warmup"])
    if spec["phase"] == "headless":
        row = _headless(spec)
    elif spec["phase"] == "latency":
        row = _latency(spec)
    else:
        row = _window(spec)
    print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main(sys.argv[1])
