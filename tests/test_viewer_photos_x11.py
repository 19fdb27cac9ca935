"""Photos to a scene in the window, as a person at a desktop sees it: File > New from photos... (the system's
folder dialog answers a folder of real fern photos, shrunk, with no cameras), the New from photos dialog, Start;
then, read from the X server, the registered cameras' frustums and the sparse points in the 3D view while structure
from motion runs, and the reconstruction starting from its scene."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

from tests.viewer_harness import PRELUDE, Xvfb, file_dialog_answering, run_gui, xvfb_missing
from training.scene.image_io import read_image, resize_image, write_image

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
FERN = SHARED / "data" / "scenes" / "llff_fern" / "images"

pytestmark = [pytest.mark.slow, pytest.mark.skipif(bool(xvfb_missing()), reason=xvfb_missing() or "ok"),
              pytest.mark.skipif(not FERN.is_dir(), reason="shared llff_fern photos not available (../shared)")]


@pytest.fixture(scope="module")
def x_server():
    server = Xvfb((1400, 900)).start()
    yield server
    server.stop()


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fern10")
    for p in sorted(FERN.iterdir())[::2]:  # 10 of the 20 views, over the whole capture
        img = read_image(p)
        h, w = img.shape[:2]
        write_image(folder / p.name, resize_image(img, 320, round(h * 320 / w)))
    return folder


def project(camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) pixel positions of world ``points`` in ``camera``'s picture, and whether each is in front of it."""
    w2c = np.asarray(camera.world_to_camera, np.float64)
    p = points @ w2c[:3, :3].T + w2c[:3, 3]
    z = p[:, 2]
    uv = np.stack([camera.fx * p[:, 0] / z + camera.cx, camera.fy * p[:, 1] / z + camera.cy], axis=1)
    return uv, z > 1e-6


def frustum_pixels(region: np.ndarray) -> np.ndarray:
    """Where the view shows a frustum's colour: yellow (the cameras) or red (the newest), over the black background
    and the points' greens and greys."""
    r, g, b = (region[..., i].astype(int) for i in range(3))
    return (r > 110) & (r > b + 70) & ((g > 0.6 * r) | (g < 0.45 * r))


def test_x11_new_from_photos_shows_cameras_and_points_as_they_register_then_reconstructs(photos, x_server, tmp_path):
    env = {"DISPLAY": x_server.display, "SPLATSTYLER_VIEWER_PLATFORM": "x11",
           **file_dialog_answering(tmp_path / "dialog", photos)}
    found = run_gui(PRELUDE + """
import pickle, threading
from training.core.messages import StructureChanged
app = ViewerApp(Paths(out=str(OUT / "out")))
start = app.session.start
captured = threading.Event()

def held(event):
    # a person's photos take a second or more per registration; these 10 small ones a tenth of that, which the
    # view's refreshes would miss: each registration is held on the mapper's thread, so they are seen one by one,
    # and from the fourth on until the screen is captured (beside a trainer on software GL the window draws twice
    # a second, slower than the held registrations come)
    if isinstance(event, StructureChanged):
        time.sleep(0.5)
        if event.step >= 4:
            captured.wait(300)

def paced_start(stages, paused=False):
    build = stages[0].build

    def built(previous):
        trainer = build(previous)
        trainer.add_listener(held)
        return trainer

    stages[0].build = built
    start(stages, paused)

app.session.start = paced_start

def view_region(screen):
    ox, oy = window_origin()
    x, y, w, h = app.ui.window.view_rect
    return screen[oy + y: oy + y + h, ox + x: ox + x + w]

def test(ctx):
    wait(ctx, lambda: app.view is not None, 60, "the window")
    app.ui.training.refresh_s = 0.2            # the SfM previews of 10 small photos come and go in a second or two
    ctx.set_ref("##MainMenuBar")
    ctx.menu_click("File/New from photos...")
    wait(ctx, lambda: app.ui.photos.dialog, 30, "the New from photos dialog")
    found["folder"] = app.ui.photos.folder
    ctx.set_ref("New from photos")
    ctx.item_input_value("reconstruction iterations (0: preset's)", 40)
    ctx.item_input_value("photos' long side at most (px)", 320)
    ctx.item_click("Start")
    found["dialog_after_start"] = app.ui.photos.dialog
    # a preview with at least three registered cameras on screen: captured with what the view was given for it
    for attempt in range(400):
        wait(ctx, lambda: len(app.sfm_shown[0]) >= 3 or app.session.status().stage != "sfm", 240,
             "three registered cameras")
        assert app.session.status().stage == "sfm", "the SfM stage ended before a preview of three cameras"
        shown = app.sfm_shown
        ctx.yield_(2)
        if app.view.dirty or app.sfm_shown is not shown:
            continue
        screen, status = x_screen(), app.session.status()
        registrations = sorted({int(h["registered"]) for h in list(app.session.history) if "registered" in h})
        if app.sfm_shown is shown and not app.view.dirty and status.stage == "sfm":
            break
    region = view_region(screen)
    cams, snap = shown
    np.save(OUT / "region.npy", region)
    np.save(OUT / "centres.npy", np.array([c.center for c in cams]))
    np.save(OUT / "points.npy", np.asarray(snap.means))
    with open(OUT / "camera.pkl", "wb") as f:
        pickle.dump(app.view.camera.camera(region.shape[1], region.shape[0]), f)
    found["hidden"] = sorted(app._frustums_hidden)
    found["status_line"] = status.detail
    found["registrations"] = registrations
    captured.set()
    wait(ctx, lambda: app.session.status().stage == "reconstruct" and app.session.status().step >= 1, 300,
         "the reconstruction's first steps")
    found["scene"] = str(app.document.dataset.path)
    found["cameras"] = len(app.document.cameras)

try:
    run(app, test)
finally:
    captured.set()
found["error"] = app.ui.messages.error
found["messages"] = app.ui.messages.lines
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env=env, timeout=900)
    assert found["error"] == "", found["error"]
    assert found["folder"] == str(photos) and found["dialog_after_start"] is False
    assert found["status_line"].startswith("registering:"), found["status_line"]
    region = np.load(tmp_path / "region.npy")
    centres, points = np.load(tmp_path / "centres.npy"), np.load(tmp_path / "points.npy")
    with open(tmp_path / "camera.pkl", "rb") as f:
        camera = pickle.load(f)
    h, w = region.shape[:2]
    # every registered camera's frustum is on the X screen where the camera is (its apex, the camera centre)
    frustum = frustum_pixels(region)
    uv, ahead = project(camera, centres)
    checked = 0
    for i, ((u, v), front) in enumerate(zip(uv, ahead)):
        if i in found["hidden"] or not front or not (8 <= u < w - 8 and 8 <= v < h - 8):
            continue
        checked += 1
        window = frustum[int(v) - 6: int(v) + 7, int(u) - 6: int(u) + 7]
        assert window.sum() >= 3, f"no frustum on the X screen at camera {i} ({u:.0f}, {v:.0f})"
    assert checked >= 3, f"only {checked} cameras in view"
    # the sparse points are drawn where they are: lit pixels at most of the points in view, and dark between
    uv, ahead = project(camera, points)
    inside = ahead & (uv[:, 0] >= 2) & (uv[:, 0] < w - 2) & (uv[:, 1] >= 2) & (uv[:, 1] < h - 2)
    assert inside.sum() >= 50, f"only {int(inside.sum())} points in view"
    bright = region.max(axis=-1)
    lit = [bright[int(v) - 1: int(v) + 2, int(u) - 1: int(u) + 2].max() > 40 for u, v in uv[inside]]
    assert np.mean(lit) > 0.8, f"only {np.mean(lit):.0%} of the points in view are drawn on the X screen"
    assert (bright > 40).mean() < 0.5, "the view is lit everywhere, not at the points"
    # the cameras came one registration at a time, and the reconstruction started from the scene made
    # (the session's history runs ahead of the preview on screen, which the view takes at its refresh)
    assert found["registrations"][:3] == [0, 2, 3] and 3 <= len(centres) <= found["registrations"][-1]
    assert len(centres) < 10, "the capture came after the last registration"
    assert Path(found["scene"]) == tmp_path / "out" / "scene" and found["cameras"] == 10
    assert (tmp_path / "out" / "scene" / "sfm_report.json").is_file()
    assert any(line.startswith("registered 10/10 photos") for line in found["messages"])
