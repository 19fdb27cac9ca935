"""The viewer's session as a project file and back (app/project.py holds the format): what File > Save project
and File > Open project call. No imgui here: the panels call these and show the returned lines.

A project may hold several models (export merges them). Opening one shows every model whose files are there and
unchanged, joined into one scene with their transforms (scene_models.py), and says in one line each which others
are not shown (missing, changed, or embedded in the project).

What the viewer does not hold yet (a model transform from a gizmo, colour edits, the original model for style
strength) comes back in ``Opened`` for the panels that will hold it, and goes in through ``project_from_app``'s
arguments, so nothing is lost between opening and saving.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.project import FileRef, ModelEntry, Project, extract_member, open_project
from app.viewer.world_edit import open_with_world, world_of
from training.model.colour_edit import ColourEdits


@dataclass
class Opened:
    problems: list[str] = field(default_factory=list)  # one line each, for the Messages panel
    entry: ModelEntry | None = None  # the model shown: its transform, colour edits, original
    layout: str = ""  # imgui ini text: imgui.load_ini_settings_from_memory(layout) applies it
    project: Project | None = None
    not_shown: list[ModelEntry] = field(default_factory=list)  # give back to project_from_app(carry=...)


def keyframe_of(viewer_camera, width: int, height: int):
    """The project's camera (a Keyframe) for the view's camera at the view's size."""
    from app.camera_path import keyframe_from

    return keyframe_from(viewer_camera.camera(width, height))


def viewer_camera_of(keyframe, up=None, target_distance: float = 1.0):
    """The view's camera (ViewerCamera) from a project's Keyframe."""
    from app.viewer.camera_control import ViewerCamera
    from training.scene.scene import Camera

    camera = Camera("project", keyframe.width, keyframe.height, keyframe.fx, keyframe.fy, keyframe.cx, keyframe.cy,
                    np.asarray(keyframe.world_to_camera, np.float64))
    return ViewerCamera.from_camera(camera, up=up, target_distance=target_distance)


def project_from_app(app, layout: str = "", transform=None, colour: ColourEdits | None = None,
                     original: str | None = None, view_size: tuple[int, int] | None = None,
                     carry: list[ModelEntry] = ()) -> Project:
    """The viewer's session as a Project: the opened model with the editor's kept rows, selection and hidden
    Gaussians, the dataset and painting, the stylization settings, the camera and its keyframes, and the layout
    (``imgui.save_ini_settings_to_memory()``). ``carry``: the models of an opened project the viewer did not show
    (``Opened.not_shown``), written back unchanged so saving loses none of them."""
    models = []
    if app.editor is not None and app.paths.model and not app.edit.live and app.scene_models.parts:
        from app.viewer.scene_models import project_entries

        models += project_entries(app, colour, original)  # each model of the scene with its rows and transform
    elif app.editor is not None and app.paths.model and not app.edit.live:
        ed = app.editor
        models.append(ModelEntry(FileRef(Path(app.paths.model)), Path(app.paths.model).stem,
                                 FileRef(Path(original)) if original else None,
                                 np.asarray(ed.index, np.int64).copy(), ed.selected.copy(), ed.hidden.copy(),
                                 np.eye(4) if transform is None else np.asarray(transform, float),
                                 colour if colour is not None else ColourEdits()))
    camera, distance, up = None, 1.0, np.array([0.0, -1.0, 0.0])
    view = getattr(app, "view", None)
    if view is not None and view.camera is not None:
        w, h = view_size or (max(app.window.view_rect[2], 1), max(app.window.view_rect[3], 1))
        camera, distance, up = keyframe_of(view.camera, w, h), view.camera.target_distance, view.camera.up
    models += list(carry)
    stylize = dataclasses.asdict(app.training.stylize) if app.training.stylize is not None else {}
    return Project(models=models, dataset=FileRef(Path(app.paths.data)) if app.paths.data else None,
                   painting=FileRef(Path(app.paths.style)) if app.paths.style else None, stylize=stylize,
                   camera=camera, camera_distance=distance, path_keys=list(app.path.keys),
                   path_duration=app.path.seconds, path_fps=app.path.fps, path_loop=app.path.loop, layout=layout,
                   up=np.asarray(up, float), world=world_of(app))


def apply_project(app, path: str | Path) -> Opened:
    """Open the project at ``path`` into the viewer: its first usable model with its edits, dataset, painting,
    stylization settings, camera and keyframes. InputError (one line) when it is not a project; problems it
    survived come back as lines."""
    from app.viewer.selection import subset

    project, problems = open_project(path)
    opened = Opened(list(problems), None, project.layout, project)
    entry = next((m for m in project.models if m.usable), None)
    for m in project.models:
        if m is not entry:
            opened.not_shown.append(m)
            opened.problems.append(f"{m.file.path}: model '{m.name}' is in the project but not shown (the viewer "
                                   f"shows one model{'' if m.usable else '; its file is missing or changed'})")
    if entry is not None:
        model_path = entry.file.path
        if entry.file.embedded is not None:  # the viewer opens files: the embedded model goes to the output folder
            model_path = extract_member(project.source, entry.file.embedded,
                                        Path(app.paths.out) / "project_models" / Path(entry.file.embedded).name)
        app.open_model(str(model_path))
        ed = app.editor
        if entry.kept is not None:
            if len(entry.kept) and int(entry.kept.max()) >= len(ed.model):
                opened.problems.append(f"{model_path}: the project keeps rows the model does not have: shown whole")
            else:
                ed.model = subset(ed.model, entry.kept)
                ed.index = entry.kept.copy()
        n = len(ed.index)
        ed.selected = entry.selected.copy() if entry.selected is not None and len(entry.selected) == n \
            else np.zeros(n, bool)
        ed.hidden = entry.hidden.copy() if entry.hidden is not None and len(entry.hidden) == n else np.zeros(n, bool)
        ed.undo_stack.clear()
        ed.redo_stack.clear()
        ed.version += 1
        open_with_world(app, project.world)  # the scale and up axis the measure tools set
        opened.entry = entry
        from app.viewer.scene_models import open_project_models

        open_project_models(app, opened)  # its transform, and the project's other models joined to the scene
    for ref, fn, what in ((project.dataset, app.open_data, "dataset"), (project.painting, app.open_style,
                                                                        "painting")):
        if ref is not None and not ref.missing:
            try:
                fn(str(ref.path))
            except Exception as exc:  # noqa: BLE001  (one line, and the rest of the project still opens)
                why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                opened.problems.append(f"cannot open the {what}: {why}")
    if project.stylize:
        app.training.stylize = project.stylize_config()
    app.path.keys = list(project.path_keys)
    app.path.seconds, app.path.fps, app.path.loop = project.path_duration, int(project.path_fps), project.path_loop
    view = getattr(app, "view", None)
    if view is not None and project.camera is not None:
        view.camera = viewer_camera_of(project.camera, project.up, project.camera_distance)
        view.moved()
    return opened
