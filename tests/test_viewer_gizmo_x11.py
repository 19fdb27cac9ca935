"""The gizmo and two models in one scene as a display shows them: the real application on GLFW's X11 platform under
Xvfb, driven by imgui's Test Engine, checked on the pixels the X server shows (python-xlib), never on a GL read."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from tests.gizmo_scenes import moved_copy, similarity
from tests.test_viewer_x11 import LOOK, demo_scene, headless_render, psnr, x11_env, x_server  # noqa: F401  (fixtures)
from tests.viewer_harness import PRELUDE, check_frame, run_gui, xvfb_missing

pytestmark = [pytest.mark.slow, pytest.mark.skipif(bool(xvfb_missing()), reason=xvfb_missing() or "ok")]


def test_x11_two_models_on_screen_and_the_gizmo_on_selection_box_and_model(demo_scene, x_server, tmp_path):
    """Two models drawn as one: the view on the X screen is the merged export's render, with both models in it.
    Then the gizmo, held mid-drag, on the selection, on the crop box (which Crop then uses) and on the second
    model; each drag is the pointer's and leaves the camera where it was. Screenshots: gizmo_*.png.
    Slow: a viewer process of its own on X11 under Xvfb with software GL (llvmpipe): its start, the second model
    dropped in and the merged export, a still screen recorded, three drags each held a second mid-drag for a shot
    of the X screen, undo and redo, a pick, then a headless reference render of the merged model (32 s in a
    clean-clone CI run on 2 cores)."""
    _, _, model = demo_scene
    second = moved_copy(model, similarity(25.0, (0, 1, 0), 0.7, (15.0, 0.0, 1.0)), tmp_path / "second.ply")
    found = run_gui(PRELUDE + LOOK + f"""
import pickle
from imgui_bundle import imgui
from app.viewer.display import gestures
from app.viewer.camera import ViewerCamera
from app.viewer.edit.editor import in_box
from training.scene.image_io import write_image
app = ViewerApp(Paths(model={str(model)!r}, out=str(OUT / "out")))

def on_screen(points):
    return gestures.on_screen(app.ui, np.asarray(points, float).reshape(-1, 3))[0]

def drag_and_shoot(ctx, start, offset, name):
    ctx.mouse_move_to_pos(imgui.ImVec2(float(start[0]), float(start[1])))
    settle(ctx, 0.3)
    ctx.mouse_down(0)
    for t in np.linspace(0, 1, 6):
        ctx.mouse_move_to_pos(imgui.ImVec2(float(start[0] + offset[0] * t), float(start[1] + offset[1] * t)))
    settle(ctx, 1.0)  # held mid-drag: the preview on screen
    write_image(OUT / f"gizmo_{{name}}.png", x_screen() / 255.0)
    ctx.mouse_up(0)
    settle(ctx, 0.5)

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    n1 = app.document.editor.count
    app.on_drop(None, [{str(second)!r}])
    ctx.yield_(3)
    app.document.editor.select_none()
    means = app.document.editor.model.means.astype(float)
    mid = means.mean(axis=0)
    app.view.camera = ViewerCamera.looking_at(mid + np.array([0.0, -8.0, -36.0]), mid, up=(0.0, -1.0, 0.0))
    app.ui.export.path = str(OUT / "merged.ply")
    open_window(ctx, "Edit")
    ctx.item_click("Export")
    record("merged", ctx)
    found["centres"] = [on_screen(means[:n1].mean(axis=0))[0].tolist(), on_screen(means[n1:].mean(axis=0))[0].tolist()]
    found["origin"] = list(window_origin())
    rotation = app.view.camera.rotation.copy()
    # the selection: the first model's right half, moved
    app.document.editor.select(np.arange(app.document.editor.count) < n1)
    app.document.editor.select(means[:, 0] > np.median(means[:n1, 0]), "remove")
    app.ui.gizmo.target = "selection"  # adding the model made it the gizmo's target
    ctx.set_ref("")
    ctx.key_press(imgui.Key.g)
    sel = app.document.editor.selected.copy()
    before = app.document.editor.model.means.copy()
    drag_and_shoot(ctx, on_screen(before[sel].mean(axis=0))[0], (30, -60), "selection")
    found["selection_moved"] = float(np.abs(app.document.editor.model.means[sel] - before[sel]).max())
    found["others_still"] = bool(np.array_equal(app.document.editor.model.means[~sel], before[~sel]))
    app.document.editor.select_none()
    # the crop box around the second model, moved onto part of it, then Crop uses it
    box = np.array([means[n1:].min(axis=0), means[n1:].max(axis=0)])
    app.ui.edit.box = [list(box[0]), list(box[1])]
    app.ui.gizmo.target = "box"
    settle(ctx, 0.3)
    drag_and_shoot(ctx, on_screen(box.mean(axis=0))[0], (-90, 0), "crop_box")
    found["box_shift"] = (np.array(app.ui.edit.box) - box).tolist()
    count = app.document.editor.count
    inside = int(in_box(app.document.editor.model.means, *np.array(app.ui.edit.box)).sum())
    open_window(ctx, "Edit")
    ctx.item_click("Crop to box")
    found["after_crop"], found["expected_crop"], found["before_crop"] = app.document.editor.count, inside, count
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.z)
    settle(ctx, 0.3)
    found["count_after_undo"] = app.document.editor.count
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.z)  # the box drag is a step of its own
    settle(ctx, 0.3)
    found["box_after_second_undo"] = np.array(app.ui.edit.box).tolist()
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.y)
    settle(ctx, 0.3)
    found["box_after_redo"] = np.array(app.ui.edit.box).tolist()
    # the second model, turned about its centre... shown on screen, and moved by a drag
    ctx.set_ref("")
    app.ui.gizmo.target = "model:1"
    ctx.key_press(imgui.Key.t)
    settle(ctx, 0.8)
    write_image(OUT / "gizmo_model_turn.png", x_screen() / 255.0)
    ctx.key_press(imgui.Key.g)
    before = app.document.editor.model.means.copy()
    rows = np.arange(app.document.editor.count) >= n1
    drag_and_shoot(ctx, on_screen(before[rows].mean(axis=0))[0], (0, 70), "second_model")
    found["model_moved"] = float(np.abs(app.document.editor.model.means[rows] - before[rows]).max())
    found["model_others_still"] = bool(np.array_equal(app.document.editor.model.means[~rows], before[~rows]))
    found["camera_turned"] = float(np.abs(app.view.camera.rotation - rotation).max())
    # a pick for the alignment runs a depth pass inside imgui's frame: the window must still show everything
    open_window(ctx, "Edit")
    ctx.item_click("Align second by 3 point pairs")
    ctx.set_ref("")
    xy = on_screen(app.document.editor.model.means[rows].astype(float).mean(axis=0))[0]
    ctx.mouse_move_to_pos(imgui.ImVec2(float(xy[0]), float(xy[1])))
    ctx.mouse_click(0)
    settle(ctx, 1.0)
    np.save(OUT / "after_pick.npy", x_screen())
    found["picked"] = len(app.ui.gizmo.align.moving)

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env=x11_env(x_server))
    assert found["error"] == "", found["error"]
    region = np.load(tmp_path / "merged_region.npy")
    with open(tmp_path / "merged_camera.pkl", "rb") as f:
        camera = pickle.load(f)
    reference = headless_render(tmp_path / "merged.ply", camera)
    value = psnr(region, reference)
    assert value >= 25.0, f"the view on the X screen is not the merged model's render (PSNR {value:.1f} dB)"
    x, y = found["merged"]["rect"][:2]
    for cx, cy in found["centres"]:  # each model's centre on screen is covered by splats, not background
        px, py = int(cx) - x, int(cy) - y
        patch = region[py - 10: py + 10, px - 10: px + 10]
        assert patch.size and float(patch.mean()) > 20, (cx, cy, float(patch.mean()))
    assert found["selection_moved"] > 0.1 and found["others_still"]
    shift = np.array(found["box_shift"])
    assert np.abs(shift[0] - shift[1]).max() < 1e-4 and np.linalg.norm(shift[0]) > 0.1  # moved, not resized
    assert found["before_crop"] > found["after_crop"] == found["expected_crop"] > 0
    assert found["count_after_undo"] == found["before_crop"]
    box = np.array(found["box_after_redo"]) - shift  # the box as it was before the drag
    assert np.allclose(found["box_after_second_undo"], box, atol=1e-5)  # Ctrl+Z undid the drag
    assert not np.allclose(found["box_after_redo"], box)  # and Ctrl+Y did it again
    assert found["model_moved"] > 0.1 and found["model_others_still"]
    assert found["camera_turned"] == 0.0
    assert found["picked"] == 1
    check_frame(np.load(tmp_path / "after_pick.npy"))  # panels and view still on screen after a pick
    for name in ("selection", "crop_box", "second_model", "model_turn"):
        assert (tmp_path / f"gizmo_{name}.png").is_file()
