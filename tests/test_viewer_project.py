"""The viewer's session saved as a project and opened again (app/viewer/project_io.py), with no window: the
editor's kept rows, selection and hidden Gaussians, the camera path and the stylization settings come back; the
view's camera goes through a keyframe and back unchanged."""

from __future__ import annotations

import numpy as np
import torch

from app.camera_path import Keyframe
from app.project import save_project
from app.viewer.app import Paths, ViewerApp
from app.viewer.camera_control import ViewerCamera
from app.viewer.project_io import apply_project, keyframe_of, project_from_app, viewer_camera_of
from training.model.gaussians import Gaussians
from training.model.ply_io import write_ply


def write_model(path, n=150):
    g = torch.Generator().manual_seed(0)
    write_ply(path, Gaussians(torch.randn(n, 3, generator=g), torch.randn(n, 3, generator=g) - 3,
                              torch.randn(n, 4, generator=g), torch.randn(n, generator=g),
                              torch.randn(n, 1, 3, generator=g), torch.randn(n, 3, 3, generator=g), 1))


def test_the_viewer_session_comes_back_from_a_project(tmp_path):
    write_model(tmp_path / "m.ply")
    app = ViewerApp(Paths(out=str(tmp_path / "out")), stylize_overrides={"tau": 0.7, "loss": "gram"})
    app.open_model(str(tmp_path / "m.ply"))
    ed = app.editor
    ed.select(np.arange(150) % 7 == 0)
    ed.delete()
    ed.select(np.arange(len(ed.index)) % 5 == 0)
    ed.hide()
    ed.select(np.arange(len(ed.index)) % 3 == 0)
    m = np.eye(4)
    m[:3, 3] = [0.0, 0.0, 3.0]
    app.path.keys = [Keyframe(m, 400.0, 400.0, 320.0, 180.0, 640, 360)]
    app.path.seconds, app.path.loop = 5.0, True
    path = save_project(tmp_path / "s.splatproj", project_from_app(app, layout="[Docking]\n"))

    again = ViewerApp(Paths(out=str(tmp_path / "out2")))
    opened = apply_project(again, path)
    assert opened.problems == [] and opened.layout == "[Docking]\n"
    a, b = app.editor, again.editor
    assert np.array_equal(a.index, b.index) and np.array_equal(a.selected, b.selected)
    assert np.array_equal(a.hidden, b.hidden) and np.array_equal(a.model.sh, b.model.sh)
    assert np.array_equal(a.model.means, b.model.means) and len(b.undo_stack) == 0
    assert again.training.stylize.tau == 0.7 and again.training.stylize.loss == "gram"
    assert again.path.seconds == 5.0 and again.path.loop and len(again.path.keys) == 1
    assert np.array_equal(again.path.keys[0].world_to_camera, m)


def test_the_view_camera_round_trips_through_a_keyframe():
    cam = ViewerCamera.looking_at([1.0, -2.0, -4.0], [0.0, 0.0, 0.0], up=(0.0, -1.0, 0.0), fov_y_degrees=42.0)
    key = keyframe_of(cam, 800, 600)
    back = viewer_camera_of(key, up=cam.up, target_distance=cam.target_distance)
    assert np.allclose(back.rotation, cam.rotation) and np.allclose(back.position, cam.position)
    assert np.isclose(back.fov_y_degrees, 42.0) and np.isclose(back.target_distance, cam.target_distance)


def test_an_embedded_model_opens_in_the_viewer_without_its_file(tmp_path):
    write_model(tmp_path / "m.ply")
    app = ViewerApp(Paths(out=str(tmp_path / "out")))
    app.open_model(str(tmp_path / "m.ply"))
    app.editor.select(np.arange(150) < 20)
    app.editor.delete()
    path = save_project(tmp_path / "s.splatproj", project_from_app(app), embed=True)
    (tmp_path / "m.ply").unlink()
    again = ViewerApp(Paths(out=str(tmp_path / "out2")))
    opened = apply_project(again, path)
    assert opened.problems == [] and np.array_equal(again.editor.model.sh, app.editor.model.sh)
    assert again.paths.model.startswith(str(tmp_path / "out2" / "project_models"))


def test_models_the_viewer_does_not_show_are_saved_back_unchanged(tmp_path):
    """A project with a model whose file changed and a second model: the viewer shows the one it can, says so for
    the other, and saving the session keeps both (the changed one still flagged)."""
    from app.project import FileRef, ModelEntry, Project, open_project

    write_model(tmp_path / "a.ply")
    write_model(tmp_path / "b.ply", n=80)
    rows = np.arange(0, 150, 2)
    path = save_project(tmp_path / "s.splatproj", Project([ModelEntry(FileRef(tmp_path / "a.ply"), "a", kept=rows),
                                                           ModelEntry(FileRef(tmp_path / "b.ply"), "b")]))
    write_model(tmp_path / "a.ply", n=120)  # a changed: its kept rows no longer fit
    app = ViewerApp(Paths(out=str(tmp_path / "out")))
    opened = apply_project(app, path)
    assert len(opened.problems) == 2 and "changed since the project was saved" in opened.problems[0]
    assert "'a' is in the project but not shown" in opened.problems[1]
    assert app.paths.model == str(tmp_path / "b.ply") and len(app.editor.model) == 80
    again = save_project(tmp_path / "t.splatproj", project_from_app(app, carry=opened.not_shown))
    project, problems = open_project(again)
    assert [m.name for m in project.models] == ["b", "a"] and project.models[1].file.changed
    assert np.array_equal(project.models[1].kept, rows) and len(problems) == 1
