"""``splatstyler bench viewer --live``: what the open viewer costs a running trainer, and how fast it answers.

Three runs of the same reconstruction (the demo scene, quick preset, at its own 256x192 size), each in a fresh
process so that each has one GLFW/imgui runner and a cold start:
- ``headless``: the Reconstructor stepping alone (the reference);
- ``window_still``: the viewer window open with the reconstruction running in its session, the camera still (the
  view redraws when the trainer's model is refreshed, every ``refresh_s``);
- ``window_moving``: the same with the camera orbiting a little every frame (continuous input).
Each reports steps/s over ``--seconds`` after the same warm-up, and the ratio to headless.

A fourth, ``latency``: the window at 960x540 showing a 100k-Gaussian model while the reconstruction runs; a camera
move is injected every half second and the time until the view has drawn it is recorded: p50 and p95 in ms.
The window opens on GLFW's null platform (EGL) when there is no display.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time


WINDOW = (1280, 800)  # the window's size in the window phases (its 3D view is the docked layout's central node)


def run_live(seconds: float, warmup_steps: int = 30) -> list[dict]:
    rows = []
    for phase in ("headless", "window_still", "window_moving", "latency"):
        spec = json.dumps({"phase": phase, "seconds": seconds, "warmup": warmup_steps})
        proc = subprocess.run([sys.executable, "-m", "app.bench.viewer_live", spec], capture_output=True, text=True,
                              timeout=600 + 4 * seconds)
        lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
        if proc.returncode != 0 or not lines:
            raise RuntimeError(f"bench viewer --live ({phase}) failed: {proc.stderr.strip().splitlines()[-1:]}")
        rows.append(json.loads(lines[-1]))
    base = rows[0]["steps_per_s"]
    for row in rows[1:3]:
        row["vs_headless"] = row["steps_per_s"] / base if base > 0 else float("nan")
    return rows


def _trainer_config():
    from training.reconstruct.trainer import ReconstructConfig

    return ReconstructConfig.from_preset("quick", downscale=1, iterations=100_000)


def _headless(seconds: float, warmup: int) -> dict:
    from assets.demo.assets import demo_assets
    from training.reconstruct.trainer import Reconstructor
    from training.scene.loader import load_scene

    trainer = Reconstructor(load_scene(demo_assets().scene_dir, downscale=1), _trainer_config())
    for _ in range(warmup):
        trainer.step()
    start, t0 = trainer.step_count, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        trainer.step()
    elapsed = time.perf_counter() - t0
    return {"phase": "headless", "steps_per_s": (trainer.step_count - start) / elapsed, "seconds": elapsed}


def _window(phase: str, seconds: float, warmup: int) -> dict:
    from imgui_bundle import hello_imgui, immapp

    from app.viewer.app import ViewerApp
    from app.viewer.platform import choose_platform, prepare_glfw
    from app.viewer.state import Paths
    from assets.demo.assets import demo_assets

    app = ViewerApp(Paths(data=str(demo_assets().scene_dir), out="/tmp/splatstyler_bench_viewer"),
                    start="reconstruct", recon_iters=100_000, downscale=1)
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
        elif now - state["t0"] >= seconds:
            elapsed = now - state["t0"]
            state["result"] = {"phase": phase, "steps_per_s": (status.step - state["start"]) / elapsed,
                               "seconds": elapsed, "ui_fps": (app.frames - state["frames"]) / elapsed,
                               "view_draws_per_s": (app.view.frames_drawn - state["draws0"]) / elapsed}
            hello_imgui.get_runner_params().app_shall_exit = True

    app.gui = gui
    prepare_glfw(choose_platform())
    immapp.run(app.runner_params(size=WINDOW), immapp.AddOnsParams(with_implot=True))
    return state["result"]


def _latency(seconds: float, warmup: int, n: int = 100_000) -> dict:
    import numpy as np
    from imgui_bundle import hello_imgui, immapp

    from app.viewer.app import ViewerApp
    from app.viewer.platform import choose_platform, prepare_glfw
    from app.viewer.state import Paths
    from assets.demo.assets import demo_assets
    from training.core.messages import ModelSnapshot

    app = ViewerApp(Paths(data=str(demo_assets().scene_dir), out="/tmp/splatstyler_bench_viewer"),
                    start="reconstruct", recon_iters=100_000, downscale=1)
    app.ui.training.refresh_s = 1e9  # the view keeps the 100k model; the trainer runs beside it
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
    params = app.runner_params(size=(960, 540))
    params.callbacks.before_imgui_render = drawn
    immapp.run(params, immapp.AddOnsParams(with_implot=True))
    lat = sorted(state["latencies"])
    if not lat:
        return {"phase": "latency", "samples": 0}
    p95 = lat[min(len(lat) - 1, int(round(0.95 * (len(lat) - 1))))]
    return {"phase": "latency", "splats": n, "size": "960x540", "samples": len(lat),
            "p50_ms": 1000 * statistics.median(lat), "p95_ms": 1000 * p95}


def main(spec_json: str) -> None:
    spec = json.loads(spec_json)
    phase, seconds, warmup = spec["phase"], float(spec["seconds"]), int(spec["warmup"])
    if phase == "headless":
        row = _headless(seconds, warmup)
    elif phase == "latency":
        row = _latency(seconds, warmup)
    else:
        row = _window(phase, seconds, warmup)
    print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main(sys.argv[1])
