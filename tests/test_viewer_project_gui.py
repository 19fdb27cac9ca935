"""Projects saved and opened through the real window (File > Save project, Ctrl+S, a project dropped on the window
or named on the command line) on GLFW's null platform: what a project holds survives a save, and a project the
viewer cannot apply is one line in the window while the session goes on. `splatstyler export --project` bakes what
was saved."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from tests.viewer_harness import PRELUDE, run_gui

pytestmark = pytest.mark.slow


@pytest.fixture(autouse=True)
def null_platform(monkeypatch):
    monkeypatch.setenv("SPLATSTYLER_VIEWER_PLATFORM", "null")


def test_a_camera_path_over_the_frame_limit_is_one_line_and_the_window_goes_on(tmp_path):
    """A hand-edited project asking for a 4000 s path at 30 fps (120,000 frames; a path file may hold 100,000):
    refused in one line naming the file, the window keeps drawing frames and holds no path."""
    import json

    key = {"world_to_camera": np.eye(4).tolist(), "fx": 100.0, "fy": 100.0, "cx": 32.0, "cy": 24.0,
           "width": 64, "height": 48}
    far = dict(key, world_to_camera=[[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    path = tmp_path / "long.splatproj"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("project.json", json.dumps({"version": 1, "models": [], "camera_path": {
            "duration": 4000.0, "fps": 30, "keyframes": [key, far]}}))
    found = run_gui(PRELUDE + f"""
app = ViewerApp(Paths(out=str(OUT / "out")))

def test(ctx):
    app.on_drop(None, [{str(path)!r}])
    ctx.yield_(3)
    frames = app.frames
    t0 = time.time()
    settle(ctx, 1.0)
    found["frames_in_a_second"] = app.frames - frames
    found["seconds"] = time.time() - t0
    found["keys"] = len(app.path.keys)

run(app, test)
found["error"] = app.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert found["error"].startswith(f"{path}: ") and "\n" not in found["error"], found["error"]
    assert "100000" in found["error"] and found["keys"] == 0
    assert found["frames_in_a_second"] >= 3 and found["seconds"] < 5
