"""The viewer's session saved as a project and opened again (the document's to_project and from_project, through
File > Save and Open's functions), with no window: the editor's kept rows, selection and hidden Gaussians, the
camera path and the stylization settings come back; the view's camera goes through a keyframe and back
unchanged."""

from __future__ import annotations

import numpy as np
import torch

from app.camera_path import keyframe_from
from app.project import save_project
from app.viewer.app import ViewerApp
from app.viewer.camera import ViewerCamera
from app.viewer.files import open_model, open_project
from app.viewer.files import save_project as save_session
from app.viewer.state import Paths
from training.model.gaussians import Gaussians
from training.model.ply_io import write_ply
from training.scene.camera import Camera


def write_model(path, n=150):
    g = torch.Generator().manual_seed(0)
    write_ply(path, Gaussians(torch.randn(n, 3, generator=g), torch.randn(n, 3, generator=g) - 3,
                              torch.randn(n, 4, generator=g), torch.randn(n, generator=g),
                              torch.randn(n, 1, 3, generator=g), torch.randn(n, 3, 3, generator=g), 1))


def test_the_viewer_session_comes_back_from_a_project(tmp_path):
    write_model(tmp_path / "m.ply")
    app = ViewerApp(Paths(out=str(tmp_path / "out")), stylize_overrides={"tau": 0.7, "loss": "gram"})
    open_model(app.document, app.session, app.ui, str(tmp_path / "m.ply"))
    ed = app.document.editor
    ed.select(np.arange(150) % 7 == 0)
    ed.delete()
    ed.select(np.arange(len(ed.index)) % 5 == 0)
    ed.hide()
    ed.select(np.arange(len(ed.index)) % 3 == 0)
    m = np.eye(4)
    m[:3, 3] = [0.0, 0.0, 3.0]
    path = app.document.camera_path
    path.keyframes = [Camera("keyframe", 640, 360, 400.0, 400.0, 320.0, 180.0, m)]
    path.duration, path.loop = 5.0, True
    saved = save_session(app.document, app.session, app.ui, str(tmp_path / "s.splatproj"), layout="[Docking]\n")
    again = ViewerApp(Paths(out=str(tmp_path / "out2")))
    opened = again.document.from_project(saved, tmp_path / "out2")
    assert opened.problems == [] and opened.project.layout == "[Docking]\n"
    open_project(again.document, again.session, again.ui, str(saved))
    a, b = app.document.editor, again.document.editor
    assert np.array_equal(a.index, b.index) and np.array_equal(a.selected, b.selected)
    assert np.array_equal(a.hidden, b.hidden) and np.array_equal(a.model.sh, b.model.sh)
    assert np.array_equal(a.model.means, b.model.means) and len(b.undo_stack) == 0
    assert again.ui.training.stylize.tau == 0.7 and again.ui.training.stylize.loss == "gram"
    path = again.document.camera_path
    assert path.duration == 5.0 and path.loop and len(path.keyframes) == 1
    assert np.array_equal(path.keyframes[0].world_to_camera, m)


def test_the_stylization_schedule_round_trips_through_a_project(tmp_path):
    """The schedule (issue 28: interleaved, the default, or block) is a stylization setting like the others: File >
    Save writes it in the project's stylize settings and File > Open gives it back to the Style panel."""
    write_model(tmp_path / "m.ply")
    for schedule in ("block", "interleaved"):
        app = ViewerApp(Paths(out=str(tmp_path / "out")), stylize_overrides={"schedule": schedule})
        open_model(app.document, app.session, app.ui, str(tmp_path / "m.ply"))
        saved = save_session(app.document, app.session, app.ui, str(tmp_path / f"{schedule}.splatproj"),
                             layout="")
        again = ViewerApp(Paths(out=str(tmp_path / "out2")), stylize_overrides={"schedule": "interleaved"
                                                                               if schedule == "block" else "block"})
        open_project(again.document, again.session, again.ui, str(saved))
        assert again.document.from_project(saved, tmp_path / "out2").project.stylize["schedule"] == schedule
        assert again.ui.training.stylize.schedule == schedule and again.ui.messages.error == ""


def test_the_view_camera_round_trips_through_a_keyframe():
    cam = ViewerCamera.looking_at([1.0, -2.0, -4.0], [0.0, 0.0, 0.0], up=(0.0, -1.0, 0.0), fov_y_degrees=42.0)
    key = keyframe_from(cam.camera(800, 600))
    back = ViewerCamera.from_camera(key, up=cam.up, target_distance=cam.target_distance)
    assert np.allclose(back.rotation, cam.rotation) and np.allclose(back.position, cam.position)
    assert np.isclose(back.fov_y_degrees, 42.0) and np.isclose(back.target_distance, cam.target_distance)


def test_an_embedded_model_opens_in_the_viewer_without_its_file(tmp_path):
    write_model(tmp_path / "m.ply")
    app = ViewerApp(Paths(out=str(tmp_path / "out")))
    open_model(app.document, app.session, app.ui, str(tmp_path / "m.ply"))
    app.document.editor.select(np.arange(150) < 20)
    app.document.delete()
    path = save_project(tmp_path / "s.splatproj", app.document.to_project(), embed=True)
    (tmp_path / "m.ply").unlink()
    again = ViewerApp(Paths(out=str(tmp_path / "out2")))
    open_project(again.document, again.session, again.ui, str(path))
    assert not any("not shown" in line for line in again.ui.messages.lines), again.ui.messages.lines
    assert np.array_equal(again.document.editor.model.sh, app.document.editor.model.sh)
    assert again.ui.paths.model.startswith(str(tmp_path / "out2" / "project_models"))


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
    opened = app.document.from_project(path, tmp_path / "out")
    assert len(opened.problems) == 2 and "changed since the project was saved" in opened.problems[0]
    assert "'a' is in the project but not shown" in opened.problems[1]
    assert app.document.models.files[0].path == tmp_path / "b.ply" and len(app.document.editor.model) == 80
    again = save_project(tmp_path / "t.splatproj", app.document.to_project())
    project, problems = open_project(again)
    assert [m.name for m in project.models] == ["b", "a"] and project.models[1].file.changed
    assert np.array_equal(project.models[1].kept, rows) and len(problems) == 1
