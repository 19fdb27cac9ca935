"""The viewer as a person at a desktop sees it: the real application on GLFW's X11 platform under an X server
(Xvfb), driven by imgui's Test Engine, with every check made on the pixels the X server shows (python-xlib's
``get_image`` of the root window), never on a GL framebuffer read. The null-platform tests
(tests/test_viewer_gui.py) read the bound framebuffer instead, which is how a black window once passed them.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

from tests.system_deps import requires_program
from tests.viewer_harness import PRELUDE, Xvfb, check_frame, make_demo_scene, run_gui, xvfb_missing

pytestmark = [pytest.mark.slow, pytest.mark.skipif(bool(xvfb_missing()), reason=xvfb_missing() or "ok")]

SCREEN = (1400, 900)


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    return make_demo_scene(tmp_path_factory)


@pytest.fixture(scope="module")
def x_server():
    server = Xvfb(SCREEN).start()
    yield server
    server.stop()


def x11_env(server) -> dict:
    return {"DISPLAY": server.display, "SPLATSTYLER_VIEWER_PLATFORM": "x11"}


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 99.0 if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def headless_render(model, camera) -> np.ndarray:
    """The same camera through renderer_gl on a standalone (EGL/OSMesa) context: what the view must show."""
    from app.render_inputs import load_model_arrays
    from renderer_gl import Offscreen, SplatRenderer, create_context

    ctx = create_context()
    try:
        renderer = SplatRenderer(ctx, sort_tolerance_deg=0.0)
        renderer.set_splats(*load_model_arrays(model))
        off = Offscreen(ctx, camera.width, camera.height)
        renderer.render(camera, off.fbo, mode="color", background=(0.0, 0.0, 0.0), max_sh_degree=3)
        img = off.read()
        renderer.release()
        return img
    finally:
        ctx.release()


LOOK = """
def view_region(screen):
    ox, oy = window_origin()
    x, y, w, h = app.ui.window.view_rect
    return screen[oy + y: oy + y + h, ox + x: ox + x + w]

def still_frame(ctx):
    # the full-resolution picture, drawn and presented: camera settled, nothing pending, a few frames swapped
    app.view.moved()
    settle(ctx, 0.6)
    wait(ctx, lambda: not app.view.needs_draw(False), 60, "the still view")
    settle(ctx, 0.5)

def record(name, ctx):
    still_frame(ctx)
    screen = x_screen()
    region = view_region(screen)
    np.save(OUT / f"{name}_screen.npy", screen)
    np.save(OUT / f"{name}_region.npy", region)
    with open(OUT / f"{name}_camera.pkl", "wb") as f:
        pickle.dump(app.view.camera.camera(region.shape[1], region.shape[0]), f)
    found[name] = {"rect": list(app.ui.window.view_rect), "origin": list(window_origin())}
"""


def test_x11_view_shows_the_model_after_resize_help_and_selection(demo_scene, x_server, tmp_path):
    scene_dir, _, model = demo_scene
    found = run_gui(PRELUDE + LOOK + f"""
import pickle
import glfw
from imgui_bundle import glfw_utils, imgui
app = ViewerApp(Paths(model={str(model)!r}, data={str(scene_dir)!r}, out=str(OUT / "out")))

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    open_window(ctx, "Scene")
    ctx.item_click("frustums")          # the headless reference has no camera frustums
    ctx.item_click("stylization path")
    record("opened", ctx)
    # a smaller window: the view follows the framebuffer, panels follow the window's edges
    glfw.set_window_size(glfw_utils.glfw_window_hello_imgui(), 1100, 700)
    settle(ctx, 1.0)
    record("resized", ctx)
    # the help overlay, opened and closed with its key: nothing of it may stay on screen
    ctx.set_ref("")
    ctx.key_press(imgui.Key.h)
    settle(ctx, 0.5)
    found["help_shown"] = app.ui.window.show_help
    ctx.key_press(imgui.Key.h)
    record("help_closed", ctx)
    # a rectangle selection dragged across the view and cleared: no trail of rectangles
    x, y, w, h = app.ui.window.view_rect
    app.ui.edit.tool = "rect"
    ctx.mouse_move_to_pos(imgui.ImVec2(x + w * 0.3, y + h * 0.3))
    ctx.mouse_down(0)
    for t in np.linspace(0.3, 0.7, 8):
        ctx.mouse_move_to_pos(imgui.ImVec2(x + w * t, y + h * t))
    ctx.mouse_up(0)
    found["selected_by_drag"] = int(app.document.editor.selected.sum())
    app.ui.edit.tool = "orbit"
    app.document.editor.select_none()
    record("after_drag", ctx)

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env=x11_env(x_server))
    assert found["error"] == "", found["error"]
    assert found["help_shown"] is True
    for name in ("opened", "resized", "help_closed", "after_drag"):
        region = np.load(tmp_path / f"{name}_region.npy")
        with open(tmp_path / f"{name}_camera.pkl", "rb") as f:
            camera = pickle.load(f)
        reference = headless_render(model, camera)
        assert region.shape == reference.shape
        assert float(reference.std()) > 5, "the reference render is empty: the camera does not see the model"
        value = psnr(region, reference)
        assert value >= 25.0, f"{name}: the view on the X screen is not the model's render (PSNR {value:.1f} dB)"
        screen = np.load(tmp_path / f"{name}_screen.npy")
        ox, oy = found[name]["origin"]
        x, y, w, h = found[name]["rect"]
        outside = screen.copy()
        outside[oy + y: oy + y + h, ox + x: ox + x + w] = 0
        check_frame(outside)  # the panels are drawn beside the view
    opened, resized = found["opened"]["rect"], found["resized"]["rect"]
    assert resized[2] < opened[2] and resized[3] < opened[3]  # the view follows the window down in size
    assert found["selected_by_drag"] > 0


def test_x11_live_stylization_shows_the_painting_takes_the_slider_and_refreshes(demo_scene, x_server, tmp_path):
    scene_dir, style, model = demo_scene
    found = run_gui(PRELUDE + LOOK + f"""
app = ViewerApp(Paths(model={str(model)!r}, data={str(scene_dir)!r}, style={str(style)!r}, out=str(OUT / "out")),
                start="stylize", stylize_overrides={{"max_side": 64, "iters_per_view": 30}})

def region(screen, rect):
    ox, oy = window_origin()
    x, y, w, h = rect
    return screen[oy + y: oy + y + h, ox + x: ox + x + w]

def test(ctx):
    wait(ctx, lambda: app.session.status().state == "running" and app.session.status().step >= 2, 180,
         "the stylizer to run")
    app.ui.training.refresh_s = 0.5
    wait(ctx, lambda: app.ui.training.shown_step is not None, 60, "the first live model on screen")
    settle(ctx, 0.5)
    first_step, first = app.ui.training.shown_step, view_region(x_screen())
    open_window(ctx, "Style")
    ctx.item_input_value("tau", 0.05)          # the slider, through the UI
    new_tau = lambda h: abs(h.get("tau", 0.0) - 0.05) < 1e-6
    wait(ctx, lambda: any(new_tau(h) for h in list(app.session.history)), 90, "a step that used the new tau")
    found["tau_after"] = app.session.trainer_status().config.tau
    wait(ctx, lambda: app.ui.training.shown_step >= first_step + 40, 180, "the view to show 40 steps later")
    settle(ctx, 0.5)
    later = view_region(x_screen())
    found["view_change"] = float(np.abs(later.astype(float) - first.astype(float)).mean())
    found["view_std"] = float(later.std())
    ctx.item_click("capacity map")             # off: the painting alone
    settle(ctx, 0.5)
    np.save(OUT / "painting_plain.npy", region(x_screen(), app.ui.window.painting_rect))
    ctx.item_click("capacity map")             # on again: the map over it
    settle(ctx, 0.5)
    np.save(OUT / "painting_map.npy", region(x_screen(), app.ui.window.painting_rect))
    found["capacity_shape"] = list(app.session.trainer_status().capacity.shape)

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env=x11_env(x_server))
    from training.stylize.style_image import load_style_image

    assert found["error"] == "", found["error"]
    assert found["tau_after"] == pytest.approx(0.05, abs=1e-6)
    assert found["view_std"] > 5, "the 3D view on screen is empty while stylizing"
    assert found["view_change"] > 0.5, "the 3D view on screen did not change while the stylizer ran"
    plain = np.load(tmp_path / "painting_plain.npy")
    with_map = np.load(tmp_path / "painting_map.npy")
    painting = load_style_image(style)
    h, w = plain.shape[:2]
    # the panel shows the painting smaller than it is, mipmapped: an area average of it
    import torch

    expected = torch.nn.functional.interpolate(torch.from_numpy(painting).permute(2, 0, 1)[None], size=(h, w),
                                               mode="area")[0].permute(1, 2, 0).numpy()
    expected = (expected * 255).round()
    assert psnr(plain, expected) >= 20.0, "the Style panel does not show the painting"
    assert float(np.abs(with_map.astype(float) - plain.astype(float)).mean()) > 3.0, "no capacity map drawn"


KEYS_APP = """
import json, os, sys
from pathlib import Path
import numpy as np
from imgui_bundle import hello_imgui
from app.viewer.app import Paths, ViewerApp, run

OUT = Path(os.environ["OUT"])
app = ViewerApp(Paths(model=sys.argv[1], out=str(OUT / "out")))
gui, post_init = app.gui, app.post_init

def post():
    post_init()
    for _ in range(3):  # three deletions to undo (each one undo step)
        app.document.editor.keep(np.arange(app.document.editor.count) >= 100)

def frame():
    gui()
    state = {"count": app.document.editor.count, "rotation": app.view.camera.rotation.tolist(), "rect": list(app.ui.window.view_rect)}
    (OUT / "state.tmp").write_text(json.dumps(state))
    (OUT / "state.tmp").replace(OUT / "state.json")
    if (OUT / "quit").exists():
        hello_imgui.get_runner_params().app_shall_exit = True

app.gui, app.post_init = frame, post
run(app)
"""


@requires_program("xdotool", "xdotool")
def test_x11_real_key_events_quick_ctrl_z_undoes_once_and_never_rolls(demo_scene, x_server, tmp_path):
    """Keys typed through the X server (xdotool's XTEST events), as a keyboard types them, into the application's
    own loop (the test engine would swallow real input): a quick Ctrl+Z undoes one deletion, a held one does not
    repeat, and neither rolls the camera (Z alone is a roll key)."""
    import json
    import os
    import subprocess
    import sys
    import time

    from tests.viewer_harness import ROOT

    _, _, model = demo_scene
    env = dict(os.environ, OUT=str(tmp_path), XDG_CONFIG_HOME=str(tmp_path / "config"), **x11_env(x_server))
    state_file = tmp_path / "state.json"

    def state(after: float = 0.0) -> dict:
        time.sleep(after)
        return json.loads(state_file.read_text())

    def xdotool(*args: str) -> None:
        subprocess.run(["xdotool", *args], env=env, check=True, timeout=30)

    proc = subprocess.Popen([sys.executable, "-c", KEYS_APP, str(model)], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        t0 = time.time()
        while not state_file.exists():
            assert proc.poll() is None and time.time() - t0 < 120, proc.stdout.read() if proc.poll() else "no start"
            time.sleep(0.2)
        first = state(0.5)
        x, y, w, h = first["rect"]
        xdotool("mousemove", str(x + w // 2), str(y + h // 2))  # the window sits at the screen's corner
        time.sleep(0.3)
        xdotool("key", "--delay", "0", "ctrl+z")  # pressed and released within a millisecond
        after_quick = state(1.0)
        xdotool("keydown", "ctrl", "keydown", "z")  # held for a second: no repeat
        time.sleep(1.0)
        xdotool("keyup", "z", "keyup", "ctrl")
        after_held = state(1.0)
    finally:
        (tmp_path / "quit").touch()
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
    n = first["count"]
    assert after_quick["count"] == n + 100  # one undo for one quick Ctrl+Z
    assert after_held["count"] == n + 200  # one more for one held Ctrl+Z, not a repeat
    assert np.abs(np.array(after_held["rotation"]) - np.array(first["rotation"])).max() < 1e-9  # no roll


def test_x11_a_saved_project_opens_to_the_same_picture(demo_scene, x_server, tmp_path):
    """Issue 21's acceptance on the X screen: a session with a deletion, a gizmo move, a colour adjustment and a
    keyframe is saved (File > Save project) and closed; a new session opens the project and the X server shows the
    same 3D view, pixel for pixel."""
    scene_dir, style, model = demo_scene
    first = run_gui(PRELUDE + LOOK + f"""
import pickle
from app.viewer.edit import colour_view as cv
from app.viewer.edit.editor import in_sphere
from training.model.colour_edit import ColourAdjustment
app = ViewerApp(Paths(model={str(model)!r}, data={str(scene_dir)!r}, style={str(style)!r}, out=str(OUT / "a")))

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    ed = app.document.editor
    ed.select(in_sphere(ed.model.means, ed.model.means[0], 1.0), "set")
    ed.delete()
    ed.select(in_sphere(ed.model.means, ed.model.means[30], 1.0), "set")
    turn = np.eye(4)  # a gizmo drag's similarity in the view's world
    turn[:3, :3] = [[0.8, -0.6, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]]
    turn[:3, 3] = [0.3, -0.2, 0.1]
    app.document.transform(ed.selected.copy(), turn)
    ed.select(in_sphere(ed.model.means, ed.model.means[5], 1.5), "set")
    app.document.set_colour(cv.with_adjustment(app.document.colour, cv.region_mask(app.document, "selection"),
                                         ColourAdjustment(brightness=0.25, hue=60.0)))
    ed.select_none()
    app.view.camera.orbit(30.0, 8.0)
    open_window(ctx, "Camera path")
    ctx.item_click("Add keyframe")
    ctx.set_ref("##MainMenuBar")
    ctx.menu_click("File/Save project")
    record("saved", ctx)

run(app, test)
found["project"] = app.ui.project.path
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env=x11_env(x_server))
    assert first["error"] == "", first["error"]
    second = run_gui(PRELUDE + LOOK + f"""
import pickle
app = ViewerApp(Paths(out=str(OUT / "b")), project={first["project"]!r})

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the project's model")
    record("opened", ctx)
    found["keys"] = len(app.document.camera_path.keyframes)

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env=x11_env(x_server))
    assert second["error"] == "", second["error"]
    assert second["keys"] == 1
    a, b = np.load(tmp_path / "saved_region.npy"), np.load(tmp_path / "opened_region.npy")
    assert first["saved"]["rect"] == second["opened"]["rect"]
    assert float(a.std()) > 5
    differ = np.any(a != b, axis=-1)
    assert not differ.any(), f"{int(differ.sum())} pixels differ on the X screen (PSNR {psnr(a, b):.1f} dB)"


def test_x11_a_model_opened_after_a_run_replaces_the_runs_model_on_screen(demo_scene, x_server, tmp_path):
    """A run ends (here a short reconstruction); the user then opens another model from the Scene panel: the X
    screen must show that model, and keep showing it, not the finished run's model."""
    scene_dir, _, model = demo_scene
    found = run_gui(PRELUDE + LOOK + f"""
import pickle
app = ViewerApp(Paths(data={str(scene_dir)!r}, out=str(OUT / "out")), start="reconstruct", recon_iters=20,
                downscale=4)

def test(ctx):
    app.session.pause()                 # before its first step (the Pause button, at once)
    wait(ctx, lambda: app.session.status().state == "paused", 180, "the paused reconstruction")
    open_window(ctx, "Scene")
    ctx.item_click("frustums")          # the headless reference has no camera frustums
    ctx.item_click("stylization path")
    ctx.item_input_value("##model", {str(model)!r})
    ctx.item_click("Open model")        # refused while the run goes on: one line, the run keeps its model
    found["while_running"] = app.ui.messages.error
    app.ui.messages.error = ""
    open_window(ctx, "Training")
    ctx.item_click("Resume")
    wait(ctx, lambda: app.session.status().state == "finished", 180, "the reconstruction to finish")
    found["run_model"] = str(app.session.saved[-1])
    open_window(ctx, "Scene")
    ctx.item_input_value("##model", {str(model)!r})   # the run put its saved model's path there
    ctx.item_click("Open model")
    record("opened", ctx)
    settle(ctx, 2.0)                    # the viewer's refreshes after the run: the picture must stay
    record("later", ctx)

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env=x11_env(x_server))
    assert found["error"] == "", found["error"]
    assert found["while_running"] == "open model: ValueError: a run is going: stop it (Training panel) before " \
                                     "opening another model"
    for name in ("opened", "later"):
        region = np.load(tmp_path / f"{name}_region.npy")
        with open(tmp_path / f"{name}_camera.pkl", "rb") as f:
            camera = pickle.load(f)
        wanted, run_model = headless_render(model, camera), headless_render(Path(found["run_model"]), camera)
        assert float(wanted.std()) > 5 and psnr(wanted, run_model) < 20  # the two models look different here
        value = psnr(region, wanted)
        assert value >= 25.0, (f"{name}: the X screen does not show the opened model (PSNR {value:.1f} dB; against "
                               f"the finished run's model {psnr(region, run_model):.1f} dB)")


def test_x11_ctrl_s_after_file_open_model_writes_a_new_project_not_the_opened_one(demo_scene, x_server, tmp_path):
    """A project is open; File > Open model (the system's dialog picks another model) replaces the scene, and the X
    screen shows that model; Ctrl+S then writes a new project holding it, read back from the file, and the project
    opened first is left byte for byte as it was (it was rewritten with the other model)."""
    import torch

    from app.project import FileRef, ModelEntry, Project, open_project, save_project
    from tests.viewer_harness import file_dialog_answering
    from training.model.ply_io import read_ply, write_ply

    _, _, model = demo_scene
    g = read_ply(model)
    other = tmp_path / "other.ply"
    write_ply(other, g.subset(torch.arange(0, len(g), 2)))
    project = save_project(tmp_path / "first.splatproj", Project([ModelEntry(FileRef(model), "scene")]))
    before = project.read_bytes()
    found = run_gui(PRELUDE + LOOK + f"""
import pickle
from imgui_bundle import imgui
app = ViewerApp(Paths(out=str(OUT / "out")), project={str(project)!r})

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the project's model")
    open_window(ctx, "Scene")
    ctx.item_click("frustums")          # the headless reference has no camera frustums
    ctx.item_click("stylization path")
    ctx.set_ref("##MainMenuBar")
    ctx.menu_click("File/Open model...")
    wait(ctx, lambda: app.ui.paths.model == {str(other)!r}, 60, "the other model")
    record("opened", ctx)
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.s)
    ctx.yield_(3)
    found["count"] = app.document.editor.count

run(app, test)
found["project"] = app.ui.project.path
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env={**x11_env(x_server), **file_dialog_answering(tmp_path / "dialog", other)})
    assert found["error"] == "", found["error"]
    assert project.read_bytes() == before, "Ctrl+S wrote the other model over the project opened first"
    assert found["project"] and Path(found["project"]) != project
    saved, problems = open_project(found["project"])
    assert problems == [] and [m.file.path for m in saved.models] == [other]
    assert found["count"] == len(read_ply(other)) and np.array_equal(saved.models[0].kept, np.arange(found["count"]))
    region = np.load(tmp_path / "opened_region.npy")
    with open(tmp_path / "opened_camera.pkl", "rb") as f:
        camera = pickle.load(f)
    value = psnr(region, headless_render(other, camera))
    assert value >= 25.0, f"the X screen does not show the model opened (PSNR {value:.1f} dB)"


def test_x11_the_window_title_says_when_edits_are_unsaved(demo_scene, x_server, tmp_path):
    """The title the X11 window carries (GLFW's, as a window manager shows it) ends in "*" after a deletion and
    loses it when Ctrl+S saves the project."""
    _, _, model = demo_scene
    found = run_gui(PRELUDE + f"""
import glfw
from imgui_bundle import glfw_utils, imgui
app = ViewerApp(Paths(model={str(model)!r}, out=str(OUT / "out")))

def title(ctx):
    ctx.yield_(2)
    return on_gl_thread(ctx, lambda: glfw.get_window_title(glfw_utils.glfw_window_hello_imgui()))

def test(ctx):
    wait(ctx, lambda: app.document.editor is not None, 60, "the model")
    found["opened"] = title(ctx)
    ed = app.document.editor
    ed.select(np.arange(ed.count) < 10)
    app.document.delete()
    found["edited"] = title(ctx)
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.s)
    found["saved"] = title(ctx)

run(app, test)
found["project"] = app.ui.project.path
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env=x11_env(x_server))
    assert found["opened"] == "splatstyler - model.ply"
    assert found["edited"] == "splatstyler - model.ply *"
    assert found["saved"] == f"splatstyler - {Path(found['project']).name}"
