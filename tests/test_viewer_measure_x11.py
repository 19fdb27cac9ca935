"""The measure and up tools as a person at a desktop sees them (GLFW's X11 platform under Xvfb, checks on the X
server's pixels): the measured line and its length are drawn over the 3D view, the floor's three picks as a
triangle, and levelling to that floor turns what the view shows."""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_viewer_measure import PICKING
from tests.test_viewer_x11 import LOOK, demo_scene, x11_env, x_server  # noqa: F401  (fixtures)
from tests.viewer_harness import PRELUDE, run_gui, xvfb_missing

pytestmark = [pytest.mark.slow, pytest.mark.skipif(bool(xvfb_missing()), reason=xvfb_missing() or "ok")]

LINE = (120, 255, 60)  # gestures.PICK_LINE


def test_x11_measure_line_and_floor_levelling_on_screen(demo_scene, x_server, tmp_path):
    scene_dir, _, model = demo_scene
    found = run_gui(PRELUDE + LOOK + PICKING + f"""
from app.viewer.edit.world_edit import distance
app = ViewerApp(Paths(model={str(model)!r}, data={str(scene_dir)!r}, out=str(OUT / "out")))

def on_screen(points):
    # window coordinates of world points in the view, and the screen offset of the window
    uv, _ = view_camera(app.ui).project(np.array(points))
    ox, oy = window_origin()
    left, top = app.ui.window.view_rect[:2]
    return [[ox + left + u, oy + top + v] for u, v in uv]

def shot(name):
    settle(ctx_ref[0], 0.5)
    screen = x_screen()
    np.save(OUT / f"{{name}}.npy", screen)

ctx_ref = []

def test(ctx):
    ctx_ref.append(ctx)
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    open_window(ctx, "Scale and up")
    ctx.item_click("Measure")
    still(ctx)
    cam, out = rendered(ctx)
    for ix, iy in two_solid_pixels(out["alpha"]):
        click_pixel(ctx, ix, iy)
    found["measure_ends"] = on_screen(app.ui.world.points)
    found["distance"] = distance(app.ui.world)
    shot("measure")
    ctx.item_click("Pick the floor")
    ys, xs = np.nonzero(out["alpha"] > 0.98)
    row_lo, row_hi = np.percentile(ys, [30, 80]).astype(int)
    picks = []
    for row, q in ((row_hi, 20), (row_hi, 80), (row_lo, 50)):
        cols = np.sort(xs[ys == row])
        picks.append((int(np.percentile(cols, q)), int(row)))
    for ix, iy in picks:
        click_pixel(ctx, ix, iy)
    found["floor_points"] = len(app.ui.world.points)
    found["floor_corners"] = on_screen(app.ui.world.points)
    shot("floor_picked")
    still(ctx)
    before = view_region(x_screen())
    ctx.item_click("Level to the floor")
    still(ctx)
    settle(ctx, 0.5)
    after = view_region(x_screen())
    found["levelled_change"] = float(np.abs(after.astype(float) - before.astype(float)).mean())
    found["view_up"] = app.view.camera.up.tolist()
    shot("floor_levelled")

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env=x11_env(x_server))
    assert found["error"] == "", found["error"]
    screen = np.load(tmp_path / "measure.npy").astype(int)
    is_line = np.all(np.abs(screen - LINE) <= 40, axis=-1)
    (x0, y0), (x1, y1) = found["measure_ends"]
    on_line = [bool(is_line[int(round(y)) - 2: int(round(y)) + 3, int(round(x)) - 2: int(round(x)) + 3].any())
               for x, y in zip(np.linspace(x0, x1, 40)[4:-4], np.linspace(y0, y1, 40)[4:-4])]
    assert sum(on_line) >= 0.9 * len(on_line), "the measured line is not on the X screen"
    # the length's label: light text on a dark box beside the line's middle
    mx, my = int((x0 + x1) / 2), int((y0 + y1) / 2)
    label = is_line[my - 30: my, mx + 4: mx + 90]
    assert label.sum() > 20, "no length label beside the line"
    assert found["floor_points"] == 3
    floor = np.all(np.abs(np.load(tmp_path / "floor_picked.npy").astype(int) - LINE) <= 40, axis=-1)
    for x, y in found["floor_corners"]:
        assert floor[int(y) - 3: int(y) + 4, int(x) - 3: int(x) + 4].sum() >= 10, "a floor pick is not drawn"
    assert found["levelled_change"] > 1.0, "levelling did not turn what the view shows"
    assert np.allclose(found["view_up"], [0.0, -1.0, 0.0])
