"""The measure and up tools in the real viewer (GLFW's null platform, driven by imgui's Test Engine): two clicks
on the model pick the points the rendered depth puts under them, a typed length rescales the model and the dataset
cameras by exactly that ratio, Ctrl+Z gives back the very model and cameras, "Up from the cameras" makes their
mean up the viewer's, and ``splatstyler export --project`` of the saved session is the file moved by that scale
and turn."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from tests.viewer_harness import PRELUDE, ROOT, make_demo_scene, run_gui

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    return make_demo_scene(tmp_path_factory)


PICKING = """
from imgui_bundle import imgui
from app.viewer.display.gestures import view_camera

def still(ctx):
    app.view.moved()
    settle(ctx, 0.4)
    wait(ctx, lambda: not app.view.needs_draw(False), 60, "the still view")

def rendered(ctx):
    # the camera and the depth the renderer draws for it, on the window's thread (GL is current only there)
    def read():
        cam = view_camera(app.ui)
        return cam, app.view.renderer.render_arrays(cam, ("alpha", "depth"))
    return on_gl_thread(ctx, read)

def two_solid_pixels(alpha):
    ys, xs = np.nonzero(alpha > 0.98)
    row = int(np.median(ys))
    cols = np.sort(xs[ys == row])
    return [(int(np.percentile(cols, 15)), row), (int(np.percentile(cols, 85)), row)]

def click_pixel(ctx, ix, iy):
    scale = imgui.get_io().display_framebuffer_scale
    left, top = app.ui.window.view_rect[:2]
    ctx.mouse_move_to_pos(imgui.ImVec2(left + (ix + 0.5) / scale.x, top + (iy + 0.5) / scale.y))
    ctx.mouse_click(0)
    ctx.yield_(2)
"""


def test_measure_rescale_undo_up_and_export_of_the_project(demo_scene, tmp_path):
    scene_dir, _, model = demo_scene
    found = run_gui(PRELUDE + PICKING + f"""
from app.viewer.edit.world_edit import distance
app = ViewerApp(Paths(model={str(model)!r}, data={str(scene_dir)!r}, out=str(OUT / "out")))

def centres():
    return [c.center.tolist() for c in app.document.cameras]

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    open_window(ctx, "Scale and up")
    ctx.item_click("Measure")
    still(ctx)
    cam, out = rendered(ctx)
    pixels = two_solid_pixels(out["alpha"])
    for ix, iy in pixels:
        click_pixel(ctx, ix, iy)
    found["pixels"] = pixels
    found["depths"] = [float(out["depth"][iy, ix]) for ix, iy in pixels]
    found["K"] = [cam.fx, cam.fy, cam.cx, cam.cy]
    found["w2c"] = cam.world_to_camera.tolist()
    found["picked"] = [p.tolist() for p in app.ui.world.points]
    found["distance"] = distance(app.ui.world)
    before, cameras_before = app.document.editor.model, list(app.document.cameras)
    found["centres_before"] = centres()
    open_window(ctx, "Scale and up")
    ctx.item_input_value("known length", 0.75)
    ctx.item_click("Rescale to this length")
    ctx.yield_(2)
    found["means_ratio"] = (app.document.editor.model.means.astype(np.float64) / before.means).tolist()
    found["scales_ratio"] = (app.document.editor.model.scales.astype(np.float64) / before.scales).tolist()
    found["centres_scaled"] = centres()
    found["distance_scaled"] = distance(app.ui.world)
    ctx.set_ref("")
    ctx.key_press(imgui.Key.mod_ctrl.value | imgui.Key.z.value)  # undo, as a user does
    ctx.yield_(2)
    found["undo_same_model"] = app.document.editor.model is before
    found["undo_same_cameras"] = all(a is b for a, b in zip(app.document.cameras, cameras_before))
    found["undo_world"] = app.document.world.tolist()
    found["distance_undone"] = distance(app.ui.world)
    open_window(ctx, "Scale and up")
    ctx.item_click("Up from the cameras")
    ctx.yield_(2)
    found["ups"] = [(-c.camera_to_world[:3, 1]).tolist() for c in app.document.cameras]
    found["view_up"] = app.view.camera.up.tolist()
    ctx.item_input_value("known length", 2.0)
    ctx.item_click("Rescale to this length")
    ctx.yield_(2)
    found["world"] = app.document.world.tolist()
    found["shown_means"] = app.document.editor.model.means.tolist()
    ctx.set_ref("##MainMenuBar")
    ctx.menu_click("File/Save project")
    ctx.yield_(2)

run(app, test)
found["project"] = app.ui.project.path
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert found["error"] == "", found["error"]
    # the picked points are the rendered depths under the clicked pixels, unprojected by the view's camera
    fx, fy, cx, cy = found["K"]
    w2c = np.array(found["w2c"])
    for (ix, iy), z, picked in zip(found["pixels"], found["depths"], found["picked"]):
        in_camera = np.array([(ix + 0.5 - cx) / fx * z, (iy + 0.5 - cy) / fy * z, z])
        assert z > 0 and np.allclose(picked, w2c[:3, :3].T @ (in_camera - w2c[:3, 3]), rtol=1e-6, atol=1e-6)
    d = float(np.linalg.norm(np.subtract(*found["picked"])))
    assert d > 0.05 and found["distance"] == pytest.approx(d, rel=1e-12)
    # the known length rescales the model and the cameras by exactly length / distance
    ratio = 0.75 / d
    means_ratio = np.array(found["means_ratio"])
    assert np.allclose(means_ratio[np.isfinite(means_ratio) & (np.abs(means_ratio) < 1e3)], ratio, rtol=1e-4)
    assert np.allclose(found["scales_ratio"], ratio, rtol=1e-5)
    assert np.allclose(np.array(found["centres_scaled"]), np.array(found["centres_before"]) * ratio, rtol=1e-9,
                       atol=1e-12)
    assert found["distance_scaled"] == pytest.approx(0.75, rel=1e-9)
    # Ctrl+Z: the very model and cameras from before, the distance as measured
    assert found["undo_same_model"] and found["undo_same_cameras"]
    assert np.array_equal(found["undo_world"], np.eye(4)) and found["distance_undone"] == pytest.approx(d)
    # up from the cameras: their mean up is the viewer's (-y), and the view orbits about it
    mean_up = np.mean(found["ups"], axis=0)
    assert np.allclose(mean_up / np.linalg.norm(mean_up), [0.0, -1.0, 0.0], atol=1e-9)
    assert np.allclose(found["view_up"], [0.0, -1.0, 0.0], atol=1e-12)
    # export --project: the file moved by the world the session shows (scale 2 / d after the turn)
    world = np.array(found["world"])
    assert np.cbrt(np.linalg.det(world[:3, :3])) == pytest.approx(2.0 / d, rel=1e-9)
    out = tmp_path / "baked.ply"
    proc = subprocess.run([sys.executable, "-m", "app", "export", "--project", found["project"], "-o", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    from training.model.ply_io import read_ply
    from training.model.transform import transform_gaussians

    baked = read_ply(out)
    expected = transform_gaussians(read_ply(model), world)
    for name, value in expected.parameters().items():
        assert torch.allclose(baked.parameters()[name], value, atol=1e-5), name
    assert np.allclose(baked.means.numpy(), found["shown_means"], atol=1e-5)  # what the view showed
