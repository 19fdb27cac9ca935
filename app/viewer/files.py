"""What File > Open, File > Save project (Save project as) and a file dropped on the window do: open a model, a
dataset, a painting or a project into the document, join a model to the scene, save the session as a project.
Each takes the document, the session and the UI state; the 3D view follows at its next frame (a new model is shown
and framed, a new dataset places the camera at its first view).

A save never writes over a project the session did not open or save: Save project writes where the session's
project was opened or last saved, and without one (nothing opened, or a model opened since, which starts a new
scene) to a free name in the output folder (project.splatproj, project_2.splatproj, ...). The system's file dialogs
(Open..., Save project as) are dialogs.py's: this module has no UI.

Nothing replaces unsaved edits without asking (``unless_unsaved``): opening a model or a project, starting from
photos and quitting first ask Save / Discard / Cancel while the document has edits no project holds.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from app.project import save_project as write_project
from app.viewer.state import Question
from training.core.errors import InputError
from training.model.formats import SUFFIX_LIST, has_model_suffix

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".exr", ".tif", ".tiff", ".webp", ".bmp")


def _no_run(session, what: str) -> None:
    if session.running:
        # the view shows the run's model at every refresh: an opened file would be drawn over at once
        raise ValueError(f"a run is going: stop it (Training panel) before opening {what}")


def _model_opened(session, ui, path: str) -> None:
    """The view shows (and the editor edits) the opened model from here on, not an ended run's."""
    session.release()
    ui.training.before = None
    ui.training.shown_step = None
    ui.training.base_model = str(path)
    ui.edit.shown_version = None
    ui.paths.model = str(path)


UNSAVED = "Unsaved edits"  # the question's title (the modal's name)


def unless_unsaved(doc, session, ui, what: str, action) -> None:
    """``action()`` now, or, while the document has unsaved edits, once the user has answered the question this
    asks: Save (the project is saved first, as Ctrl+S saves it), Discard (the edits go), or Cancel (nothing
    happens). ``what``: the action in words ("quitting", "opening fox.ply")."""
    if not doc.unsaved():
        action()
        return

    def save_first() -> None:
        save_project(doc, session, ui)
        action()

    def discard_first() -> None:
        doc.mark_saved()
        action()

    if any(q.title == UNSAVED for q in ui.questions):  # asked already (a second click on the close button)
        return
    where = f" to {Path(ui.project.path).name}" if ui.project.path else " as a project"
    ui.questions.append(Question(UNSAVED, f"The scene has edits that are not saved. Save them{where} before "
                                          f"{what}?", [("Save", save_first), ("Discard", discard_first),
                                                       ("Cancel", None)]))


def open_model(doc, session, ui, path: str, ask: bool = True) -> None:
    """The model file at ``path`` as a new scene (after asking, with ``ask``, when the scene has unsaved edits)."""
    _no_run(session, "another model")
    if ask:
        unless_unsaved(doc, session, ui, f"opening {Path(path).name}", lambda: _open_model(doc, session, ui, path))
    else:
        _open_model(doc, session, ui, path)


def _open_model(doc, session, ui, path: str) -> None:
    doc.open(path)
    _model_opened(session, ui, path)
    ui.project.path = ""  # a new scene: the next save must not replace the project opened before it
    ui.messages.say(f"opened {path} ({doc.editor.count} Gaussians)")


def open_data(doc, session, ui, path: str) -> None:
    doc.open_dataset(path)
    ui.paths.data = str(path)
    ui.training.order_preview = None
    ui.requests.reset = ui.requests.overlays = True  # the view at the first camera, with the frustums
    ui.messages.say(f"opened {path} ({len(doc.dataset.cameras)} cameras)")


def open_style(doc, session, ui, path: str) -> None:
    doc.open_painting(path)
    ui.paths.style = str(path)
    image = doc.painting.image
    ui.messages.say(f"opened painting {path} ({image.shape[1]}x{image.shape[0]})")


def add_to_scene(doc, session, ui, path: str) -> None:
    """Join a model file to the scene (one undo step), selected and the gizmo's target; opens it when no model
    is open."""
    if doc.editor is None:
        return open_model(doc, session, ui, path)
    fid = doc.add(path)
    ui.gizmo.target = f"model:{fid}"
    ui.messages.say(f"added {path} to the scene ({doc.editor.count:,} Gaussians in all); it is selected: move it "
                    "with the gizmo (G), or align it by three point pairs; Ctrl+Z takes it out")


def open_dropped(doc, session, ui, path: str) -> None:
    """A file or folder dropped on the window: a model file opens as the model (or joins
    the open one), an image as the painting, a folder or transforms.json as the dataset, a .splatproj as the
    project."""
    p = Path(path)
    suffix = p.suffix.lower()
    if has_model_suffix(p):
        # joined, not replacing: a drop beside an open model is most often a part of the same scene, and Ctrl+Z
        # takes it out again, while a replaced model's edits would be gone (File > Open model replaces)
        add_to_scene(doc, session, ui, path)
    elif suffix == ".splatproj":
        open_project(doc, session, ui, path)
    elif suffix in IMAGE_SUFFIXES:
        open_style(doc, session, ui, path)
    elif p.is_dir() or p.name == "transforms.json":
        open_data(doc, session, ui, path)
    else:
        raise InputError(path, f"not a model ({SUFFIX_LIST}), a painting (an image), a dataset (a folder or "
                               "transforms.json) or a project (.splatproj)")


def open_project(doc, session, ui, path: str) -> None:
    """A .splatproj: its models with their edits, the dataset, the painting, the camera path, and for the window
    the stylization settings, the view's camera and the dock layout; one line for each thing it could not use."""
    _no_run(session, "a project")
    unless_unsaved(doc, session, ui, f"opening {Path(path).name}", lambda: _open_project(doc, session, ui, path))


def _open_project(doc, session, ui, path: str) -> None:
    opened = doc.from_project(path, ui.out_dir() / "project_models")
    project = opened.project
    for line in opened.problems:
        ui.messages.say(line)
    # the project's first model is what the view shows and what Stylize starts from; with none shown, nothing is (the
    # model open before is not the project's)
    _model_opened(session, ui, str(doc.models.files[0].path) if doc.editor is not None else "")
    if doc.editor is None:
        ui.window.model_info = {}
        if ui.view is not None:
            ui.view.clear(0)
            ui.view.clear(1)
    ui.paths.data = doc.dataset.path if doc.dataset is not None else ui.paths.data
    ui.paths.style = doc.painting.path if doc.painting is not None else ui.paths.style
    if project.stylize:
        ui.training.stylize = project.stylize_config()
    ui.training.order_preview = None
    ui.project.path, ui.project.layout_to_load = str(path), project.layout
    ui.requests.reset = ui.requests.overlays = True
    if project.camera is not None:
        ui.requests.camera_to = (project.camera, project.up, project.camera_distance)
    ui.messages.say(f"opened project {path}")


def open_recovered(doc, session, ui, path: str, scene: str, adopt) -> None:
    """A recovery project (recovery.py) of a window that closed with unsaved edits: opened as a project, then the
    scene's own project is where the next save goes (``scene``: its path; a model or nothing: a free name), and its
    edits are unsaved until then. ``adopt(path)``: this window's recovery takes it over."""
    _no_run(session, "the recovered edits")

    def recovered() -> None:
        _open_project(doc, session, ui, path)
        ui.project.path = scene if scene.endswith(".splatproj") else ""
        doc.mark_unsaved()
        adopt(Path(path))
        ui.messages.say("opened the unsaved edits kept when splatstyler last closed: save them (Ctrl+S) to keep them"
                        + (f" in {scene}" if ui.project.path else ""))

    unless_unsaved(doc, session, ui, "opening the recovered edits", recovered)


def free_project_path(out: Path) -> Path:
    """``out/project.splatproj``, or ``project_2``, ``project_3``...: the first name no file has (a second viewer
    session writing to the same folder keeps the first one's project)."""
    candidate, n = out / "project.splatproj", 1
    while candidate.exists():
        n += 1
        candidate = out / f"project_{n}.splatproj"
    return candidate


def project_now(doc, ui, layout: str | None = None):
    """The session as a Project: the document with the window's parts (the stylization settings, the view's camera,
    the dock layout: the window's as it is now (``ui.window.layout_now``) unless ``layout`` is given)."""
    from app.camera_path import keyframe_from

    if layout is None:
        layout = ui.window.layout_now() if ui.window.layout_now is not None else ""
    view = ui.view
    camera, distance, up = None, 1.0, np.array([0.0, -1.0, 0.0])
    if view is not None and view.camera is not None:
        w, h = max(ui.window.view_rect[2], 1), max(ui.window.view_rect[3], 1)
        camera, distance, up = keyframe_from(view.camera.camera(w, h)), view.camera.target_distance, view.camera.up
    stylize = dataclasses.asdict(ui.training.stylize) if ui.training.stylize is not None else {}
    return doc.to_project(stylize=stylize, camera=camera, camera_distance=distance, up=up, layout=layout)


def save_project(doc, session, ui, path: str | None = None, layout: str | None = None) -> Path:
    """The session as a project file (atomically): to ``path``, or where it was opened or saved, or a free name
    in the output folder (``free_project_path``). ``layout``: the dock layout (default: the window's, as it is now)."""
    named = bool(path or ui.project.path)
    target = Path(path or ui.project.path or free_project_path(ui.out_dir()))
    written = write_project(target, project_now(doc, ui, layout))
    # embedded models keep their member names: the file written holds them from now on
    doc.project_source = written
    doc.mark_saved()
    ui.project.path = str(written)
    ui.messages.say(f"saved project {written}" + ("" if named else " (File > Save project as... chooses the name)"))
    return written
