"""What the viewer's GUI tests share: the demo scene and a model of it, a runner that starts the real application in
its own process (one GLFW/imgui runner per process, as a user's session has) driven by imgui's Test Engine, and the
X server under which the X11 tests look at what a display shows.
"""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def make_demo_scene(tmp_path_factory):
    """The generated demo scene (32 views at 256x192, cached between runs), its painting, and a model of it:
    Gaussians at its surface points (what a reconstruction starts from), opaque enough to cover the views."""
    import torch

    from assets.demo.assets import demo_assets
    from training.model.gaussian_init import gaussians_from_points
    from training.model.ply_io import write_ply
    from training.scene.loader import load_scene

    assets = demo_assets()
    scene = load_scene(assets.scene_dir, load_images=False)
    g = gaussians_from_points(scene.points, scene.point_colors, sh_degree=1)
    g.opacity_logits = torch.full_like(g.opacity_logits, 2.0)
    model = tmp_path_factory.mktemp("model") / "model.ply"
    write_ply(model, g)
    return assets.scene_dir, assets.style_image, model


def run_gui(script: str, tmp_path: Path, timeout: int = 420, env: dict | None = None) -> dict:
    """Run a viewer test script in its own process; it writes its findings as JSON, which this returns."""
    result_file = tmp_path / "result.json"
    full_env = dict(os.environ, RESULT=str(result_file), OUT=str(tmp_path),
                    XDG_CONFIG_HOME=str(tmp_path / "config"))  # the layout file goes here, not to the user's
    full_env.update(env or {})
    code = textwrap.dedent(script)
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=full_env, capture_output=True, text=True,
                          timeout=timeout)
    assert proc.returncode == 0, (f"viewer process failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n"
                                  f"{proc.stderr[-5000:]}")
    return json.loads(result_file.read_text())


def file_dialog_answering(folder: Path, answer: Path) -> dict:
    """The environment for a viewer process whose file dialog answers ``answer``, as a user picking that file would:
    the dialog program imgui-bundle's portable_file_dialogs runs (zenity, found on PATH) is a script in ``folder``
    that prints the path, and appends how it was asked (its arguments, one a line) to ``folder/dialog_calls.txt``. A
    test cannot click in another program's window; everything of ours, from the File menu to the path coming back,
    runs as it does for a user."""
    folder.mkdir(parents=True, exist_ok=True)
    script = folder / "zenity"
    calls = folder / "dialog_calls.txt"
    script.write_text(f"#!/bin/sh\nprintf '%s\\n' \"$@\" >> '{calls}'\necho '{answer}'\n")
    script.chmod(0o755)
    return {"PATH": f"{folder}{os.pathsep}{os.environ.get('PATH', '')}"}


def check_screenshot(path: Path) -> None:
    """A real frame: not blank, not uniform, many colours (panels, text, splats)."""
    from training.scene.image_io import read_image

    img = read_image(path)
    check_frame(img)


def check_frame(img: np.ndarray) -> None:
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    assert img.shape[0] >= 400 and img.shape[1] >= 600
    assert float(img.std()) > 0.05, "uniform screenshot"
    colours = len(np.unique((img * 255).astype(np.uint8).reshape(-1, 3), axis=0))
    assert colours > 200, f"only {colours} colours in the screenshot"


class Xvfb:
    """A private X server for one test module: what the X11 tests read back is what a display shows."""

    def __init__(self, size=(1400, 900)):
        self.size = size
        self.proc = None
        self.display = ""

    def start(self) -> "Xvfb":
        # -displayfd: the server takes the first free display number itself and writes it to the pipe once it
        # listens, so two test processes starting servers at once (pytest-xdist) cannot both pick one number.
        # -noreset: by default the server resets when its last client leaves, and a client connecting during the
        # reset fails ("Failed to open display"): a viewer launched just after another one exited, as the stop
        # tests do (xdotool connecting 600 times in a row, each the only client: 4-5 of 600 refused without it, 0
        # with it)
        read, write = os.pipe()
        proc = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0",
                                 f"{self.size[0]}x{self.size[1]}x24", "-nolisten", "tcp", "-noreset"],
                                pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(write)
        with os.fdopen(read) as pipe:
            ready = select.select([pipe], [], [], 60)[0]
            number = pipe.readline().strip() if ready else ""  # "" also when the server exited
        if not number.isdigit():
            proc.kill()
            proc.wait()
            raise RuntimeError("Xvfb did not start (no display number within 60 s)")
        self.proc, self.display = proc, f":{number}"
        return self

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def xvfb_missing() -> str:
    """Why the X11 tests cannot run here ('' when they can)."""
    from tests.system_deps import missing_program

    if missing_program("Xvfb", "xvfb"):
        return missing_program("Xvfb", "xvfb")
    try:
        import Xlib  # noqa: F401
    except ImportError:
        return "python-xlib not installed (pip install -e '.[test]')"
    return ""


PRELUDE = """
import json, os, time
import numpy as np
from pathlib import Path
from imgui_bundle.immapp import testing
from app.viewer.app import ViewerApp
from app.viewer.state import Paths
from app.viewer.platform import choose_platform, prepare_glfw

OUT = Path(os.environ["OUT"])
found = {}

def runner_params(app):
    from imgui_bundle import hello_imgui, imgui

    params = app.runner_params()

    def register_tests():  # a training step takes seconds here: the engine's 60 s watchdog would abort the test
        io = imgui.test_engine.get_io(hello_imgui.get_imgui_test_engine())
        io.config_watchdog_warning, io.config_watchdog_kill_test, io.config_watchdog_kill_app = 300, 600, 900

    params.callbacks.register_tests = register_tests
    frame_start = params.callbacks.post_new_frame

    def post_new_frame():
        if gl_calls:
            import moderngl

            # the frame's framebuffer: a call that binds another (an offscreen render) must not leave it bound, or
            # the window would be drawn into that one from then on
            bound = moderngl.get_context().detect_framebuffer()
            while gl_calls:
                fn, box = gl_calls.pop(0)
                try:
                    box["value"] = fn()
                except BaseException as exc:  # noqa: BLE001  (raised again in the test's thread)
                    box["error"] = exc
            bound.use()
        frame_start()

    params.callbacks.post_new_frame = post_new_frame
    return params


# The test function runs on the test engine's coroutine thread, where no GL context is current: a GL call made
# there does nothing (glReadPixels leaves moderngl's buffer uninitialised: what once looked like a band of stray
# rows in the view's picture). GL work goes to the window's thread through this queue, run at its next frame.
gl_calls = []


def on_gl_thread(ctx, fn):
    box = {}
    gl_calls.append((fn, box))
    while "value" not in box and "error" not in box:
        ctx.yield_(1)
    if "error" in box:
        raise box["error"]
    return box["value"]


def run(app, test):
    from imgui_bundle import immapp

    prepare_glfw(choose_platform())
    testing.run(test_function=test, runner_params=runner_params(app),
                add_ons_params=immapp.AddOnsParams(with_implot=True))


def open_window(ctx, name):
    # panels share docks as tabs: focusing one brings its tab to the front, as a click on the tab does
    ctx.window_focus("//" + name)
    ctx.set_ref(name)
    ctx.yield_(3)  # let the opened window's layout settle before items are aimed at


def progress():
    \"\"\"What moves while the application works: the run's stage, state and step, and the step the view shows (None
    before the script has made its app).\"\"\"
    a = globals().get("app")
    if a is None or not hasattr(a, "session"):
        return None
    s = a.session.status()
    return (s.stage, s.state, s.step, a.ui.training.shown_step)


def wait(ctx, condition, seconds, what):
    \"\"\"Frames until ``condition()`` holds. ``seconds`` is how long nothing may move (``progress``: the run's
    stage, state and step, the step on screen), not how long the wait may take: on a busy machine every step is
    slower, and a wait timed from its start failed while the run was still going. So a slow run is waited for, a
    run that hangs or ended without the condition fails after ``seconds`` of standing still, saying where it
    stood.\"\"\"
    last, moved_at = progress(), time.time()
    while not condition():
        now = progress()
        if now != last:
            last, moved_at = now, time.time()
        elif time.time() - moved_at > seconds:
            where = "" if now is None else f" (the run: {now[0] or '-'} {now[1]} at step {now[2]}, view at {now[3]})"
            raise AssertionError(f"nothing moved for {seconds} s waiting for {what}{where}")
        ctx.yield_(2)
        time.sleep(0.02)


def settle(ctx, seconds=1.0):
    t0 = time.time()
    while time.time() - t0 < seconds:
        ctx.yield_(1)
        time.sleep(0.05)


def x_screen():
    \"\"\"What the X server shows now (the root window), (H, W, 3) uint8: read from the display, not from GL.\"\"\"
    from Xlib import X, display

    d = display.Display()
    try:
        root = d.screen().root
        geo = root.get_geometry()
        raw = root.get_image(0, 0, geo.width, geo.height, X.ZPixmap, 0xFFFFFFFF)
        img = np.frombuffer(raw.data, np.uint8).reshape(geo.height, geo.width, 4)[..., 2::-1].copy()
    finally:
        d.close()
    return img


def window_origin():
    \"\"\"The window's top-left corner on the X screen.\"\"\"
    import glfw
    from imgui_bundle import glfw_utils

    return glfw.get_window_pos(glfw_utils.glfw_window_hello_imgui())
"""
