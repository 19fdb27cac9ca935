"""The Colour panel and the Edit panel's more selections, driven through the real viewer (tests/viewer_harness.py:
the application in its own process, imgui's Test Engine, GLFW's null platform; tests/test_viewer_x11.py's X server
for what a display shows):

* a brightness change on a selection changes the view's pixels where the selection is drawn and no others, and
  undo gives the picture back;
* style strength 0 exports the stylizer's input model's SH bit for bit and 1 the stylized model's (a real run);
* colour pick, surface brush, opacity and size ranges, grow and shrink select what they should on the demo scene;
* the Edit panel's export of an opened stylized model paired with its original, with colour layers and a partial
  strength, is bit for bit what ``splatstyler export --project`` bakes from the saved project.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.viewer_harness import PRELUDE, ROOT, make_demo_scene, run_gui

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    return make_demo_scene(tmp_path_factory)


@pytest.fixture(autouse=True)
def null_platform(monkeypatch):
    monkeypatch.setenv("SPLATSTYLER_VIEWER_PLATFORM", "null")


STILL = """
# the test function runs in the engine's coroutine thread, where the GL context is not current: the view's picture
# is read on the main thread, after a frame (the runner's after_swap callback, which is app.pace)
_reads = []

def install_reader(app):
    import functools

    # a small window: software GL pays per pixel
    app.runner_params = functools.partial(type(app).runner_params, app, size=(1100, 720))
    paced = app.pace

    def pace():
        if _reads and _reads[0] is None:
            _reads[0] = app.view.read()
        paced()

    app.pace = pace

def still(ctx):
    app.view.moved()
    settle(ctx, 0.4)
    wait(ctx, lambda: not app.view.needs_draw(False), 60, "the still view")
    settle(ctx, 0.3)
    _reads[:] = [None]
    wait(ctx, lambda: _reads[0] is not None, 30, "the view's picture")
    return _reads[0]
"""


def indicator_render(model, camera, rows) -> np.ndarray:
    """(H, W) how much of each pixel's colour comes from ``rows`` (white SH there, black elsewhere, black
    background), rendered headless at ``camera``."""
    from app.render_inputs import load_model_arrays
    from renderer_gl import SplatRenderer, create_context
    from training.model.sh_constants import SH_C0

    means, scales, quats, opacities, sh, degree = load_model_arrays(model)
    sh = np.zeros_like(sh)
    sh[:, 0, :] = -0.5 / SH_C0
    sh[rows, 0, :] = 0.5 / SH_C0
    ctx = create_context()
    try:
        renderer = SplatRenderer(ctx, sort_tolerance_deg=0.0)
        renderer.set_splats(means, scales, quats, opacities, sh, degree)
        return renderer.render_arrays(camera, ("rgb",))["rgb"].mean(axis=2)
    finally:
        ctx.release()


def test_brightness_on_a_selection_changes_its_pixels_only_and_undo_restores(demo_scene, tmp_path):
    scene_dir, _, model = demo_scene
    found = run_gui(PRELUDE + STILL + f"""
import pickle
from app.viewer.edit.editor import in_sphere
app = ViewerApp(Paths(model={str(model)!r}, data={str(scene_dir)!r}, out=str(OUT / "out")))
install_reader(app)

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    open_window(ctx, "Scene")
    ctx.item_click("frustums")
    ctx.item_click("stylization path")
    ed = app.document.editor
    before = still(ctx)
    means = ed.model.means
    picked = in_sphere(means, np.median(means, axis=0), 0.1 * np.ptp(means, axis=0).max())
    ed.select(picked, "set")
    open_window(ctx, "Colour")
    ctx.item_input_value("brightness", 0.3)
    found["brightness_steps"] = len(ed.undo_stack)
    open_window(ctx, "Edit")
    ctx.item_click("None")               # untinted, to compare with the picture before
    after = still(ctx)
    testing.capture(ctx, str(OUT / "colour_brightness.png"))
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.z)   # the None
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.z)   # the brightness
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.z)   # the selection
    undone = still(ctx)
    np.save(OUT / "before.npy", before)
    np.save(OUT / "after.npy", after)
    np.save(OUT / "undone.npy", undone)
    found["rows"] = np.nonzero(picked)[0].tolist()
    found["edits_after_undo"] = len(app.document.editor.extras.get("colour").adjustments) if "colour" in app.document.editor.extras else 0
    with open(OUT / "camera.pkl", "wb") as f:
        pickle.dump(app.view.camera.camera(before.shape[1], before.shape[0]), f)

from imgui_bundle import imgui
run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert found["error"] == "", found["error"]
    before, after, undone = (np.load(tmp_path / f"{n}.npy").astype(np.int16) for n in ("before", "after", "undone"))
    with open(tmp_path / "camera.pkl", "rb") as f:
        camera = pickle.load(f)
    share = indicator_render(Path(model), camera, np.array(found["rows"]))
    mine, others = share > 0.5, share < 1.0 / 255
    assert mine.sum() > 500 and others.sum() > 500, "the selection must cover part of the view, not all of it"
    change = np.abs(after - before).max(axis=2)
    assert change[others].max() <= 1, "pixels the selection does not reach changed"
    assert change[mine].mean() > 20, f"the selection's pixels hardly changed ({change[mine].mean():.1f})"
    assert np.array_equal(undone, before), "undo did not give the picture back"
    assert found["edits_after_undo"] == 0


def test_selection_tools_pick_what_they_should(demo_scene, tmp_path):
    """On the demo model in the viewer: a colour pick at the view's middle picks the colour of the splat drawn most
    at that pixel and selects exactly the Gaussians within 0.12 of it; the surface brush takes some, not all, of the
    centres the plain brush would, the nearer ones; Select by size takes exactly those in the typed range; Select by
    opacity takes all of them in [0.8, 0.95] and none in [0, 0.5]; Grow adds each selected Gaussian's 6 nearest
    neighbours, Shrink takes off the border, and undo gives the grown selection back.
    Slow: a viewer process of its own (torch, imgui and an EGL context on llvmpipe: software GL) whose still
    full-resolution view is drawn and read back, then the tools driven through the test engine frame by frame, each
    frame drawn on the CPU (34 s in a clean-clone CI run on 2 cores)."""
    scene_dir, _, model = demo_scene
    found = run_gui(PRELUDE + STILL + f"""
import pickle
from imgui_bundle import imgui
from app.viewer.display.gestures import view_camera
from app.viewer.edit import select_tools as st
from app.viewer.edit.editor import in_brush
app = ViewerApp(Paths(model={str(model)!r}, data={str(scene_dir)!r}, out=str(OUT / "out")))
install_reader(app)

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    ed = app.document.editor
    still(ctx)
    x, y, w, h = app.ui.window.view_rect
    cam = view_camera(app.ui)
    open_window(ctx, "Edit")
    # colour pick: a click on the middle of the view
    ctx.combo_click("tool/colour pick")
    ctx.mouse_move_to_pos(imgui.ImVec2(x + w * 0.5, y + h * 0.55))
    ctx.mouse_click(0)
    settle(ctx, 0.2)
    found["picked"] = list(app.ui.select_tools.picked) if app.ui.select_tools.picked else None
    found["pick_selected"] = np.nonzero(ed.selected)[0].tolist()
    found["pick_cursor"] = [w * 0.5, h * 0.55]
    with open(OUT / "camera.pkl", "wb") as f:
        pickle.dump(cam, f)
    testing.capture(ctx, str(OUT / "colour_pick.png"))
    # surface brush: a stroke across the middle
    ctx.combo_click("tool/surface brush")
    ctx.combo_click("selection mode/set")
    stroke = [(x + w * t, y + h * 0.55) for t in np.linspace(0.4, 0.6, 6)]
    ctx.mouse_move_to_pos(imgui.ImVec2(*stroke[0]))
    ctx.mouse_down(0)
    for p in stroke[1:]:
        ctx.mouse_move_to_pos(imgui.ImVec2(*p))
    ctx.mouse_up(0)
    settle(ctx, 0.2)
    found["brush_selected"] = np.nonzero(ed.selected)[0].tolist()
    radius = app.ui.edit.brush_radius
    plain = np.zeros(ed.count, bool)
    for px, py in stroke:
        plain |= in_brush(ed.model.means, cam, px - x, py - y, radius)
    found["plain_brush"] = np.nonzero(plain)[0].tolist()
    found["depths"] = st.camera_depths(ed.model.means, cam).tolist()
    testing.capture(ctx, str(OUT / "surface_brush.png"))
    ctx.combo_click("tool/orbit")
    # sizes: the middle third of the model's sizes
    sizes = st.sizes(ed.model.scales)
    lo, hi = np.percentile(sizes, [33, 66])
    ctx.item_input_value("size min", float(lo))
    ctx.item_input_value("size max", float(hi))
    ctx.item_click("Select by size")
    found["size_range"] = [app.ui.select_tools.size[0], app.ui.select_tools.size[1]]
    found["size_selected"] = np.nonzero(ed.selected)[0].tolist()
    # opacity: all of them lie in [0.8, 0.95] (the model's opacity is sigmoid(2) = 0.881), none in [0, 0.5]
    app.ui.select_tools.opacity = [0.8, 0.95]
    ctx.item_click("Select by opacity")
    found["opacity_high"] = int(ed.selected.sum())
    app.ui.select_tools.opacity = [0.0, 0.5]
    ctx.item_click("Select by opacity")
    found["opacity_low"] = int(ed.selected.sum())
    # grow and shrink one Gaussian's neighbourhood
    ed.select(np.arange(ed.count) == 100, "set")
    ctx.item_input_value("neighbours", 6)
    ctx.item_click("Grow")
    found["grown"] = np.nonzero(ed.selected)[0].tolist()
    ctx.item_click("Grow")
    found["grown2"] = np.nonzero(ed.selected)[0].tolist()
    ctx.item_click("Shrink")
    found["shrunk"] = np.nonzero(ed.selected)[0].tolist()
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.z)
    found["undo_shrink"] = np.nonzero(ed.selected)[0].tolist()

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    from types import SimpleNamespace

    from scipy.spatial import cKDTree

    from app.render_inputs import load_model_arrays
    from app.viewer.edit.select_tools import weights_at

    from training.model.ply_io import read_ply
    from training.model.sh_constants import SH_C0

    assert found["error"] == "", found["error"]
    g = read_ply(model)
    means = g.means.numpy().astype(np.float64)
    colours = np.clip(SH_C0 * g.sh[:, 0].numpy().astype(np.float64) + 0.5, 0, 1)
    # colour pick: a Gaussian's colour was picked and exactly those within the tolerance (0.12) are selected
    assert found["picked"] is not None
    picked = np.array(found["picked"])
    with open(tmp_path / "camera.pkl", "rb") as f:
        camera = pickle.load(f)
    arrays = load_model_arrays(Path(model))
    shown = SimpleNamespace(means=arrays[0], scales=arrays[1], quats=arrays[2], opacities=arrays[3])
    under = np.argmax(weights_at(shown, camera, *found["pick_cursor"]))  # the splat the pixel shows most of
    assert np.abs(colours[under] - picked).max() < 1e-6, "the picked colour is not the splat under the cursor's"
    expected = np.nonzero(np.linalg.norm(colours - picked, axis=1) <= 0.12)[0]
    assert found["pick_selected"] == expected.tolist() and 0 < len(expected) < len(g)
    # surface brush: part of what the plain brush takes, the nearest ones
    brush, plain = set(found["brush_selected"]), set(found["plain_brush"])
    assert brush and brush < plain, "the surface brush must take some, not all, of the centres under it"
    depths = np.array(found["depths"])
    left_out = np.array(sorted(plain - brush))
    taken = np.array(sorted(brush))
    assert np.median(depths[taken]) < np.median(depths[left_out]), "the brush took the far Gaussians"
    # size range
    sizes = g.scales.numpy().astype(np.float64).max(axis=1)
    lo, hi = found["size_range"]
    assert found["size_selected"] == np.nonzero((sizes >= lo) & (sizes <= hi))[0].tolist()
    assert 0.2 * len(g) < len(found["size_selected"]) < 0.5 * len(g)
    assert found["opacity_high"] == len(g) and found["opacity_low"] == 0
    # grow: the seed and its 6 nearest; again: those and their 6 nearest; shrink: minus the border
    tree = cKDTree(means)
    near = lambda rows: set(tree.query(means[rows], k=7)[1][:, 1:].ravel().tolist())  # noqa: E731
    assert set(found["grown"]) == {100} | near([100])
    grown2 = set(found["grown"]) | near(found["grown"])
    assert set(found["grown2"]) == grown2
    inner = {r for r in grown2 if near([r]) <= grown2}
    assert set(found["shrunk"]) == inner and len(inner) < len(grown2)
    assert found["undo_shrink"] == found["grown2"]


@pytest.fixture(scope="module")
def stylized_pair(demo_scene, tmp_path_factory):
    """A real stylization (a few steps of the quick preset at 64 px) of the demo model: (original, stylized)."""
    import torch  # noqa: F401

    from training.model.ply_io import read_ply, write_ply
    from training.scene.loader import load_scene
    from training.stylize.style_image import load_style_image
    from training.stylize.trainer import StylizeConfig, Stylizer

    scene_dir, style, model = demo_scene
    scene = load_scene(scene_dir)
    trainer = Stylizer(read_ply(model), scene, load_style_image(style),
                       StylizeConfig(preset="quick", max_side=64, iters_per_view=2))
    for _ in range(3):
        trainer.step()
    out = tmp_path_factory.mktemp("stylized") / "stylized.ply"
    write_ply(out, trainer.stylized_gaussians())
    return model, out


def test_export_of_an_opened_stylized_model_is_what_export_project_bakes(stylized_pair, tmp_path):
    """The Colour panel's logic on an opened stylized model paired with its original (the calls its widgets
    make): strength 0 and 1 export the two models' SH bit for bit; colour layers and a partial strength on a
    selection, after a deletion, export what ``splatstyler export --project`` bakes from the saved session, bit for
    bit; undo takes the last drag back."""
    import torch

    from app.viewer.app import ViewerApp
    from app.viewer.edit import colour_view as cv
    from app.viewer.files import open_model, open_project, save_project
    from app.viewer.panels.export_panel import write
    from app.viewer.state import Paths
    from training.model.colour_edit import ColourAdjustment
    from training.model.ply_io import read_ply

    original, stylized = stylized_pair
    app = ViewerApp(Paths(out=str(tmp_path / "out")))
    doc, session, ui = app.document, app.session, app.ui
    open_model(doc, session, ui, str(stylized))
    doc.pair_original(str(original))
    ed = app.document.editor
    ed.select(np.arange(ed.count) % 5 == 0)
    ed.delete()
    rows = torch.as_tensor(ed.index)
    a, b = read_ply(original), read_ply(stylized)
    assert not torch.equal(a.sh, b.sh)
    for value, reference in ((0.0, a), (1.0, b)):
        doc.set_colour(cv.with_strength(doc.colour, None, value))
        app.ui.export.path = str(tmp_path / f"strength_{value:g}.ply")
        write(doc, session, ui)
        assert torch.equal(read_ply(app.ui.export.path).sh, reference.sh[rows]), f"strength {value:g}"
    ed.select(np.arange(ed.count) % 3 == 0)
    region = cv.region_mask(doc, "selection")
    edits = cv.with_adjustment(doc.colour, None, ColourAdjustment(saturation=0.4, temperature=0.3))
    edits = cv.with_adjustment(edits, region, ColourAdjustment(brightness=0.1, hue=40.0))
    doc.set_colour(cv.with_strength(edits, region, 0.35), merge=("drag", 1))
    doc.set_colour(cv.with_strength(edits, region, 0.4), merge=("drag", 1))  # the same drag: one step
    app.ui.export.path = str(tmp_path / "edited.ply")
    write(doc, session, ui)
    project = save_project(doc, session, ui, str(tmp_path / "session.splatproj"), layout="")
    baked = tmp_path / "baked.ply"
    proc = subprocess.run([sys.executable, "-m", "app", "export", "--project", str(project), "-o", str(baked)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    mine, theirs = read_ply(tmp_path / "edited.ply"), read_ply(baked)
    assert torch.equal(mine.sh, theirs.sh) and torch.equal(mine.means, theirs.means)
    shown = cv.displayed(doc, session, ed.model).sh
    assert np.allclose(shown, mine.sh.numpy(), atol=1e-5)  # the view shows what was exported
    again = ViewerApp(Paths(out=str(tmp_path / "out2")))
    # as File > Open project does: the edits and the paired original come back
    open_project(again.document, again.session, again.ui, str(project))
    assert np.array_equal(cv.displayed(again.document, again.session, again.document.editor.model).sh, shown)
    assert not np.allclose(shown, b.sh[rows].numpy(), atol=1e-3)
    ed.undo()
    undone = doc.colour  # the drag's two changes went back in one step
    assert undone.adjustments == [] and undone.strength == 1.0 and undone.strength_regions == []


def test_style_strength_while_and_after_stylizing_exports_the_original_and_the_stylized(demo_scene, tmp_path):
    """A real stylization started from the Training panel and paused: style strength 0 (every Gaussian) shows the
    model as it was before, 1 the stylized one again; after Stop, the Edit panel's export at 0 is the input model's
    SH bit for bit and at 1 the saved stylized model's.
    Slow: a viewer process of its own (torch, imgui and an EGL context on llvmpipe: software GL) in which a real
    stylization of the demo model at 64 px loads (VGG-16, the views' content) and steps until paused, five still
    full-resolution views drawn and read back, the save of the stopped run, the exports, and the run's model
    opened again (62 s in a clean-clone CI run on 2 cores)."""
    scene_dir, style, model = demo_scene
    found = run_gui(PRELUDE + STILL + f"""
from imgui_bundle import imgui
# a run far longer than the test (it is stopped after the pause): with a short one (2 per view, about 70 steps) a
# busy machine drew the window so slowly that the run reached its end, where a pause is never taken, before Pause
# was clicked; the steps up to the pause are the same whatever the length (no schedule depends on it)
app = ViewerApp(Paths(model={str(model)!r}, data={str(scene_dir)!r}, style={str(style)!r}, out=str(OUT / "out")),
                stylize_overrides={{"max_side": 64, "iters_per_view": 30}})
install_reader(app)

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    open_window(ctx, "Scene")
    ctx.item_click("frustums")          # the current view's frustum turns red while stylizing
    ctx.item_click("stylization path")
    photo = still(ctx)
    open_window(ctx, "Training")
    ctx.item_click("Stylize")
    wait(ctx, lambda: app.session.status().step >= 3, 240, "three stylization steps")
    open_window(ctx, "Training")  # the Style tab came in front when the stylization started
    ctx.item_click("Pause")
    wait(ctx, lambda: app.session.status().state == "paused", 60, "the pause")
    app.ui.training.refresh_s = 0.05
    wait(ctx, lambda: app.ui.training.shown_step == app.session.status().step, 60, "the paused model on screen")
    stylized = still(ctx)
    open_window(ctx, "Colour")
    ctx.combo_click("apply to/every Gaussian")
    ctx.item_input_value("style strength", 0.0)
    zero = still(ctx)
    ctx.item_input_value("style strength", 1.0)
    one = still(ctx)
    for name, img in (("photo", photo), ("stylized", stylized), ("zero", zero), ("one", one)):
        np.save(OUT / f"{{name}}.npy", img)
    open_window(ctx, "Training")
    ctx.item_click("Stop")
    wait(ctx, lambda: not app.session.running, 120, "the run to stop and save")
    ctx.yield_(3)
    found["runs"] = [str(p) for p in app.ui.training.runs]
    open_window(ctx, "Colour")
    for value in (0.0, 1.0):
        ctx.item_input_value("style strength", value)
        app.ui.export.path = str(OUT / f"strength_{{value:g}}.ply")
        open_window(ctx, "Edit")
        ctx.item_click("Export")
        open_window(ctx, "Colour")
    found["undo_steps"] = len(app.document.editor.undo_stack)
    # the run's result opened from the Training panel's list: shown as it was when stopped, its original offered
    open_window(ctx, "Training")
    ctx.item_click("Open##run0")
    # the strengths typed in are unsaved edits: opening another model asks first (Discard: open it without them)
    ctx.yield_(2)
    found["asked"] = ctx.item_exists("//Unsaved edits/Discard")
    ctx.item_click("//Unsaved edits/Discard")
    ctx.yield_(2)
    found["opened"] = app.ui.paths.model
    found["running_trainer"] = app.session.has_trainer
    np.save(OUT / "opened_run.npy", still(ctx))
    open_window(ctx, "Colour")
    ctx.yield_(2)
    found["original_offered"] = app.ui.colour.original_input

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    import torch

    from training.model.ply_io import read_ply

    assert found["error"] == "", found["error"]
    photo, stylized, zero, one = (np.load(tmp_path / f"{n}.npy").astype(np.int16)
                                  for n in ("photo", "stylized", "zero", "one"))
    assert np.abs(stylized - photo).mean() > 2, "the stylization did not change the picture"
    assert np.abs(zero - photo).max() <= 1, "strength 0 does not show the model as it was before stylizing"
    assert np.array_equal(one, stylized), "strength 1 does not show the stylized model"
    original, saved = read_ply(model), read_ply(found["runs"][-1])
    assert torch.equal(read_ply(tmp_path / "strength_0.ply").sh, original.sh)
    assert torch.equal(read_ply(tmp_path / "strength_1.ply").sh, saved.sh)
    assert not torch.equal(original.sh, saved.sh)
    assert found["undo_steps"] == 4  # each strength typed in is one undo step
    assert found["asked"], "opening a run over unsaved edits did not ask"
    assert found["opened"] == found["runs"][-1] and not found["running_trainer"]
    assert np.array_equal(np.load(tmp_path / "opened_run.npy").astype(np.int16), stylized)
    assert found["original_offered"] == str(model)
