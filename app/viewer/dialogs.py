"""The system's file dialogs (portable_file_dialogs, through zenity or kdialog) and what the File menu does with
their answers: open a model, a dataset, a painting or a project (files.py opens it), save the project under a name
(asking again before replacing a file the name reaches only once ``.splatproj`` is added), choose the folder of
photos for a new scene (live/photos.py takes it from there).
"""

from __future__ import annotations

import shutil
from pathlib import Path

from app.project import with_suffix
from app.viewer.files import (add_to_scene, free_project_path, open_data, open_model, open_project, open_style,
                              save_project)
from app.viewer.live.photos import ask_for_photos
from app.viewer.state import Question
from training.model.formats import FILE_DIALOG_PATTERN

DIALOG_FILTERS = {"model": ["Gaussians", FILE_DIALOG_PATTERN],
                  "data": ["Scenes", "transforms.json cameras.bin images.bin"],
                  "style": ["Images", "*.jpg *.jpeg *.png *.exr *.tif"],
                  "project": ["Projects", "*.splatproj"]}


def dialogs_available() -> bool:
    return any(shutil.which(t) for t in ("zenity", "kdialog", "qarma", "matedialog"))


def choose_file(title: str, filters: list[str], save: bool = False, start: str = "") -> str:
    """A path from the system's file dialog, to open (or with ``save``, to write; the dialog asks before
    replacing a file), '' when cancelled; an error when no dialog program exists."""
    if not dialogs_available():
        raise ValueError("no file dialog program on this system (zenity or kdialog): type the path in the Scene "
                         "panel, or drop the file on the window" if not save else
                         "no file dialog program on this system (zenity or kdialog): Ctrl+S saves to a free name "
                         "in the output folder")
    from imgui_bundle import portable_file_dialogs as pfd

    if save:
        return pfd.save_file(title, start, filters).result()
    chosen = pfd.open_file(title, start, filters).result()
    return chosen[0] if chosen else ""


def choose_folder(title: str, start: str = "") -> str:
    """A folder from the system's folder dialog, '' when cancelled; an error when no dialog program exists."""
    if not dialogs_available():
        raise ValueError("no file dialog program on this system (zenity or kdialog): drop the folder on the window, "
                         "or give it on the command line (splatstyler view FOLDER)")
    from imgui_bundle import portable_file_dialogs as pfd

    return pfd.select_folder(title, str(Path(start).absolute()) if start else "").result()


def save_project_as(doc, session, ui) -> Path | None:
    """File > Save project as: a path from the system's save dialog (which asks before replacing the file it was
    given), then saved there; None when the dialog was cancelled. A name typed without ``.splatproj`` gets it, and
    when that names a file already there, the window asks before replacing it (the dialog asked about another)."""
    start = ui.project.path or str(free_project_path(ui.out_dir()))
    path = choose_file("Save project as", DIALOG_FILTERS["project"], save=True, start=str(Path(start).absolute()))
    if not path:
        return None
    target = with_suffix(path)
    if target != Path(path) and target.exists():
        ui.questions.append(Question("Replace project", f"{target} exists. Replace it?",
                                     [("Replace", lambda: save_project(doc, session, ui, str(target))),
                                      ("Cancel", None)]))
        return None
    return save_project(doc, session, ui, str(target))


def choose_photos_folder(ui) -> None:
    """File > New from photos...: the photos folder from the system's folder dialog, then the settings dialog."""
    folder = choose_folder("New from photos: the folder of photos", ui.photos.folder)
    if folder:
        ask_for_photos(ui, folder)


OPENERS = {"model": open_model, "data": open_data, "style": open_style, "project": open_project,
           "add": add_to_scene}


def open_from_dialog(doc, session, ui, what: str) -> None:
    """File menu: a file dialog (where a dialog program exists) for the model, dataset, painting or project, or
    a model to add to the scene."""
    filters = DIALOG_FILTERS["model" if what == "add" else what]
    title = "Add model to scene" if what == "add" else f"Open {what}"
    path = choose_file(title, filters)
    if path:
        OPENERS[what](doc, session, ui, path)
