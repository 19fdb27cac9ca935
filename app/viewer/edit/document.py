"""The edited scene as one object, with no UI: what File > Open and Save project open and save, what the panels
edit and the 3D view shows.

It holds the editor and its history (editor.py: the model shown, selected and hidden Gaussians, the undo and
redo stacks), the models of the scene (the source model's raw parameters and the ledger of which file, row and
transform each source row comes from, scene_models.py), the world transform the measure and up tools set, the
colour edits and style strength with the original model they blend with, the dataset's cameras and the painting,
and the camera path. Every change that touches more than one of them is a method here, one undo step each; the
undo stack is the editor's, inside the document.

The world transform and the colour edits are extras of the editor's history (``"world"``, ``"colour"``), so undo
restores them with the model they were applied to. The editor's model is the source rows moved by the world, so a
move made in the view (a gizmo drag, picked points) is a move in the world: on the source rows it is that move seen
from the file's side, W^-1 D W.

A project (app/project.py) is ``to_project()`` and ``from_project()``: one entry per run of editor rows from one
part, with the file as opened (its hash then, or the project's own reference with its embedded member), its rows
kept, selected and hidden, the part's transform and the colour edits; models of an opened project that the viewer
cannot show are carried and written back unchanged. Editing a running trainer's model (``edit_live``) sets the
opened scene aside, not away: a save meanwhile writes that scene, since the run's model is the run's to save.

Unsaved edits (``unsaved()``): the scene changed since it was opened or saved (``mark_saved``): an edit step of its
editor, its original, or its camera path. Editing a running trainer's model is not one: those deletions are the
run's. The window asks before anything replaces unsaved edits, and keeps a recovery project of them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.camera_path import CameraPath
from app.project import FileRef, ModelEntry, Project, extract_member, file_sha256, open_project
from app.viewer.edit.editor import Editor, subset
from app.viewer.edit.scene_models import SceneModels, appended, snapshot_arrays, snapshot_of, with_rows
from training.core.errors import InputError
from training.model.colour_edit import ColourEdits
from training.model.model_io import read_model

COLOUR = "colour"  # the editor's extra holding the colour edits (ColourEdits)
WORLD = "world"  # the editor's extra holding the world transform (4x4 similarity)


@dataclass
class Dataset:
    """The dataset the model was reconstructed from: its cameras as loaded, and its photos (loaded on first use)."""

    path: str
    cameras: list
    photos: dict[int, np.ndarray] = field(default_factory=dict)
    images_scene: Any = None

    def photo(self, index: int) -> np.ndarray:
        """The photo of camera ``index`` at the loader's size (a long side of about 1024 at most)."""
        if index not in self.photos:
            if self.images_scene is None:
                from training.scene.loader import load_scene

                long_side = max(max(c.width, c.height) for c in self.cameras)
                self.images_scene = load_scene(self.path, downscale=max(1, long_side // 1024))
            self.photos[index] = self.images_scene.images[index]
        return self.photos[index]


@dataclass
class Painting:
    path: str
    image: np.ndarray  # (H, W, 3) float32 in [0, 1]


@dataclass
class Original:
    """The unstylized model paired with the opened one for style strength: its SH over the first file's rows."""

    ref: FileRef  # the file as paired (its hash then), or a project's reference
    sh: np.ndarray  # (N, K, 3) float32, read-only
    paired_with: Path  # the first model file it was checked against


@dataclass
class Opened:
    """What opening a project brought besides the models: the lines for the user, and the project (its camera,
    settings and layout, for the window)."""

    project: Project
    problems: list[str] = field(default_factory=list)


@dataclass
class CamerasMoved:
    """The dataset cameras were put in a new world (``Document.show_world``): ``delta`` moves what was placed in
    the old one (the view's camera, picked points); None when the document changed (its picks no longer apply)."""

    delta: np.ndarray | None


def colour_problem(entry: ModelEntry, rows: int) -> str | None:
    """Why a project entry's colour regions do not fit a model of ``rows`` rows (one line), or None."""
    for region, _ in entry.colour.adjustments + entry.colour.strength_regions:
        if region is not None and len(region) != rows:
            return f"a colour region of model '{entry.name}' has {len(region)} rows; the model has {rows}"
    return None


class Document:
    def __init__(self):
        self.editor: Editor | None = None
        self.source = None  # the scene's Gaussians, raw parameters as read (what the editor's rows index)
        self.models = SceneModels()
        self.live = False  # the editor edits a running trainer's model (no source, no ledger)
        self.original: Original | None = None
        self.stylized_from = ""  # the model the last stylization in this session started from (offered as original)
        self.dataset: Dataset | None = None
        self.cameras: list = []  # the dataset's cameras as the view shows them (in the shown world)
        self.painting: Painting | None = None
        self.camera_path = CameraPath()
        self.carried: list[ModelEntry] = []  # models of an opened project not shown: saved back unchanged
        self.project_source: Path | None = None  # the project file embedded models are copied from on saving
        # the viewer's own copies of the opened project's embedded models, by member name: a save reads them when
        # the project file has moved or gone
        self.member_copies: dict[str, Path] = {}
        # (editor, source, models) of the opened scene while the editor edits a running trainer's model
        self._set_aside: tuple | None = None
        self._shown: tuple = (None, None, None)  # (dataset, editor, world) the shown cameras were made for
        self._saved: tuple = ()  # the scene as last opened or saved (``mark_saved``)
        self.mark_saved()

    # ------------------------------------------------------------------ what is shown
    @property
    def model(self):
        """The edited model (ModelSnapshot) as the view shows it, or None."""
        return None if self.editor is None else self.editor.model

    @property
    def has_ledger(self) -> bool:
        """An opened model with its ledger (not a running trainer's model)."""
        return self.source is not None and bool(self.models.parts)

    def edited(self) -> bool:
        """The model shown is not the opened file as read: Gaussians deleted, cropped, hidden or moved, or other
        models joined to the scene (a stylization starts from what is shown, not from the first file)."""
        return self.editor is not None and self.source is not None and (
            len(self.models.parts) > 1 or len(self.editor.index) != len(self.source)
            or bool(self.editor.hidden.any()))

    # ------------------------------------------------------------------ unsaved edits
    def _scene(self) -> tuple:
        """(editor, source, models) of the scene the user opened: the editor's, or the ones set aside while the
        editor edits a running trainer's model."""
        return self._set_aside if self._set_aside is not None else (self.editor, self.source, self.models)

    def _state(self) -> tuple:
        editor = self._scene()[0]
        return editor, None if editor is None else editor.version, self.original, self.camera_path.to_dict()

    def mark_saved(self) -> None:
        """The scene as it is now is saved (or was just opened, or its edits were discarded)."""
        self._saved = self._state()

    def mark_unsaved(self) -> None:
        """The scene as it is now is in no project of the user's (edits recovered after a crash)."""
        self._saved = (object(), None, None, None)

    def unsaved(self) -> bool:
        """The scene has edits no project holds: an edit step, an original paired, the camera path changed."""
        (editor, version, original, path), saved = self._state(), self._saved
        return not (editor is saved[0] and version == saved[1] and original is saved[2] and path == saved[3])

    # ------------------------------------------------------------------ opening
    def open(self, path) -> None:
        """The model file at ``path`` as the scene's only model (the history starts afresh). The scene is no
        longer an opened project's: its models not shown and its embedded files are not carried into it."""
        p = Path(path)
        g = read_model(p)
        self._open_read(p, g, FileRef(p, file_sha256(p)))
        self.carried, self.project_source, self.member_copies = [], None, {}
        self.mark_saved()

    def _open_read(self, path: Path, g, ref: FileRef) -> None:
        self.source = g
        self.models = SceneModels.opened(path, len(g), ref)
        self.editor = Editor(snapshot_of(g, version=-int(time.time() * 1000) % 1_000_000_000))
        self.live = False
        self._set_aside = None

    def new_scene(self) -> None:
        """An empty scene (what photos are made into): no model, dataset, camera path or project; the painting
        stays, as a project that names none keeps it."""
        fresh = Document()
        fresh.painting = self.painting
        for name, value in vars(fresh).items():
            setattr(self, name, value)

    def open_dataset(self, path: str) -> None:
        from training.scene.loader import load_scene

        scene = load_scene(path, load_images=False)
        if not scene.cameras:
            raise ValueError(f"{path}: the scene has no cameras")
        self.dataset = Dataset(str(path), list(scene.cameras))
        self.cameras = list(scene.cameras)

    def open_painting(self, path: str) -> None:
        from training.stylize.style_image import load_style_image

        self.painting = Painting(str(path), load_style_image(path))

    def edit_live(self, snapshot, on_keep) -> None:
        """Select and delete in the model a running trainer trains (``snapshot``, its model now):
        ``on_keep(keep, structure_version)`` hands each deletion to it (it cannot be undone). The opened scene is
        set aside, and is what a project saved meanwhile holds."""
        if self._set_aside is None and self.has_ledger:
            self._set_aside = (self.editor, self.source, self.models)
        self.editor = Editor(snapshot, on_keep=on_keep)
        self.source = None
        self.models = SceneModels()
        self.live = True

    # ------------------------------------------------------------------ edits (each one undo step)
    def _ledger_editor(self) -> Editor:
        if self.editor is None:
            raise ValueError("no model is open")
        if not self.has_ledger:
            raise ValueError("the running trainer's model cannot be moved or joined: open a model file")
        if self.models.size != len(self.source):
            raise RuntimeError("the scene's ledger and the source model disagree")  # a bug, not a user error
        return self.editor

    def delete(self) -> np.ndarray:
        return self._editor().delete()

    def hide(self) -> None:
        self._editor().hide()

    def show_all(self) -> None:
        self._editor().show_all()

    def crop(self, lo, hi, inside: bool = True) -> np.ndarray:
        return self._editor().crop(lo, hi, inside)

    def undo(self) -> bool:
        return self.editor is not None and self.editor.undo()

    def redo(self) -> bool:
        return self.editor is not None and self.editor.redo()

    def _editor(self) -> Editor:
        if self.editor is None:
            raise ValueError("no model is open")
        return self.editor

    def add(self, path, select: bool = True) -> int:
        """Join the model file at ``path`` to the scene (one undo step); opens it when no model is open. Its
        Gaussians are selected, so the gizmo moves it at once. Returns the file's index in the scene."""
        from app.project_bake import merge

        if self.editor is None:
            self.open(path)
            return 0
        ed = self._ledger_editor()
        p = Path(path)
        g = read_model(p)
        if len(g) == 0:
            raise ValueError(f"{path}: the model has no Gaussians")
        fid = self.models.add_file(p, FileRef(p, file_sha256(p)))
        start = self.models.add_part(fid, np.arange(len(g)), np.eye(4)).start
        self.source = merge([self.source, g])
        n = len(g)
        selected = np.zeros_like(ed.selected) if select else ed.selected
        ed.step(model=appended(ed.model, snapshot_arrays(self.in_world(g)), g.sh_degree),
                selected=np.concatenate([selected, np.full(n, select)]),
                hidden=np.concatenate([ed.hidden, np.zeros(n, bool)]),
                index=np.concatenate([ed.index, start + np.arange(n)]))
        return fid

    def transform(self, mask, matrix) -> None:
        """Move the editor's Gaussians at ``mask`` by the similarity ``matrix`` (4x4, in the view's world): one
        undo step."""
        import torch

        from app.project_bake import merge
        from training.model.transform import split_similarity, transform_gaussians

        ed = self._ledger_editor()
        mask = np.asarray(mask, bool)
        if mask.shape != (ed.count,):
            raise ValueError(f"a move needs one flag per Gaussian ({ed.count}), got {mask.shape}")
        if not mask.any():
            raise ValueError("nothing to move: select Gaussians first")
        matrix = np.asarray(matrix, np.float64)
        split_similarity(matrix)  # a similarity or a one-line refusal, before anything changes
        matrix = self.source_move(matrix)
        models = self.models
        source_rows = ed.index[mask]
        part_ids = models.part_of(source_rows)
        new_rows = np.empty_like(source_rows)
        pieces = []
        for pid in np.unique(part_ids):
            at = part_ids == pid
            part = models.parts[pid]
            rows = source_rows[at]
            pieces.append(transform_gaussians(self.source.subset(torch.as_tensor(rows, dtype=torch.long)), matrix))
            new_part = models.add_part(part.file, part.rows[rows - part.start], matrix @ part.transform)
            new_rows[at] = new_part.start + np.arange(len(rows))
        self.source = merge([self.source] + pieces)
        arrays = snapshot_arrays(self.in_world(self.source.subset(torch.as_tensor(new_rows, dtype=torch.long))))
        index = ed.index.copy()
        index[mask] = new_rows
        ed.step(model=with_rows(ed.model, mask, arrays), index=index)

    def moved_arrays(self, mask: np.ndarray, matrix) -> dict[str, np.ndarray]:
        """What the editor's rows at ``mask`` become when moved by ``matrix`` in the view's world (a drag's
        preview; nothing changes)."""
        import torch

        from training.model.transform import transform_gaussians

        rows = torch.as_tensor(self.editor.index[mask], dtype=torch.long)
        return snapshot_arrays(self.in_world(transform_gaussians(self.source.subset(rows), self.source_move(matrix))))

    def edited_gaussians(self, selection_only: bool = False):
        """The opened model after the edits (raw parameters, as read), or only its selected Gaussians."""
        import torch

        if self.editor is None:
            raise ValueError("no model is open")
        rows = self.editor.index[self.editor.selected] if selection_only else self.editor.index
        if selection_only and len(rows) == 0:
            raise ValueError("nothing is selected")
        if self.source is None:
            raise ValueError("the edited model belongs to the run: export it from the running trainer")
        return self.source.subset(torch.as_tensor(rows, dtype=torch.long))

    # ------------------------------------------------------------------ the scene's models
    def rows_of_file(self, fid: int) -> np.ndarray:
        """Which of the editor's rows come from the scene's model ``fid``."""
        ed = self._ledger_editor()
        return self.models.file_of(ed.index) == fid

    def files_shown(self) -> list[int]:
        """The scene's models that have Gaussians in the editor now (undo may have taken one out)."""
        if self.editor is None or not self.has_ledger:
            return []
        return sorted(set(self.models.file_of(self.editor.index).tolist()))

    def first_model_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """For the editor's rows: whether each is the first (opened) model's, and its row in that file."""
        if not self.has_ledger:
            return np.ones(self.editor.count, bool), self.editor.index
        files, rows = self.models.file_rows(self.editor.index)
        return files == 0, rows

    def file_row_count(self) -> int:
        """How many rows the opened model file has (the length of a colour region)."""
        if self.has_ledger:
            return len(self.models.parts[0].rows)  # part 0: the opened file as read, in its own frame
        index = self.editor.index
        return int(index.max()) + 1 if len(index) else 0

    # ------------------------------------------------------------------ the world
    @property
    def world(self) -> np.ndarray:
        """The scene's world transform (4x4 similarity; the identity until a tool changes it)."""
        return np.eye(4) if self.editor is None else self.editor.extras.get(WORLD, np.eye(4))

    def world_problem(self, trainer_shown: bool) -> str:
        """'' when the world can be changed now, else why not (one line)."""
        if self.editor is None:
            return "open a model first"
        if trainer_shown or self.live:
            return "the view shows a trainer's model: scale and up apply to a model opened in the viewer"
        return ""

    def set_world(self, world: np.ndarray, trainer_shown: bool = False) -> None:
        """Give the scene the world transform ``world`` (one undo step); the dataset cameras follow at the next
        ``show_world``."""
        from app.world_transform import compose, transform_snapshot

        why = self.world_problem(trainer_shown)
        if why:
            raise ValueError(why)
        ed = self.editor
        delta = compose(world, np.linalg.inv(self.world))
        model = transform_snapshot(ed.model, delta, version=ed.model.version + 1_000_000)
        ed.change(model, **{WORLD: np.asarray(world, np.float64).copy()})

    def _open_with_world(self, world) -> None:
        """A project's world given to the model it just opened (not a step to undo: the history starts here)."""
        from app.world_transform import transform_snapshot

        world = np.asarray(world, np.float64)
        ed = self.editor
        if ed is None or np.array_equal(world, np.eye(4)):
            return
        ed.model = transform_snapshot(ed.model, world, version=ed.model.version + 1_000_000)
        ed.extras = {**ed.extras, WORLD: world.copy()}
        ed.version += 1

    def in_world(self, g):
        """Source Gaussians as the view shows them (moved by the scene's world; the identity returns ``g``)."""
        from training.model.transform import transform_gaussians

        return transform_gaussians(g, self.world)

    def source_move(self, matrix) -> np.ndarray:
        """The move ``matrix`` (made in the view's world) as a move of the source rows: W^-1 D W."""
        w = self.world
        if np.array_equal(w, np.eye(4)):
            return np.asarray(matrix, np.float64)
        return np.linalg.inv(w) @ np.asarray(matrix, np.float64) @ w

    def in_file_frame(self, snap):
        """A snapshot of the editor's model moved back to the file's frame (where a trainer works)."""
        from app.world_transform import transform_snapshot

        world = self.world
        if snap is None or np.array_equal(world, np.eye(4)):
            return snap
        return transform_snapshot(snap, np.linalg.inv(world), version=snap.version + 1_000_000)

    def shown_world(self, trainer_shown: bool) -> np.ndarray:
        """The world the view shows: the editor's, or the identity while it shows a trainer's model (which lives in
        the dataset's frame)."""
        return np.eye(4) if trainer_shown or self.live else self.world

    def show_world(self, trainer_shown: bool) -> CamerasMoved | None:
        """Put the dataset's cameras in the world the view shows (``cameras``); None when nothing changed."""
        from app.world_transform import transform_camera

        world = self.shown_world(trainer_shown)
        dataset, editor, applied = self._shown
        if dataset is self.dataset and editor is self.editor and applied is not None \
                and np.array_equal(world, applied):
            return None
        loaded = [] if self.dataset is None else self.dataset.cameras
        identity = np.array_equal(world, np.eye(4))
        self.cameras = list(loaded) if identity else [transform_camera(c, world) for c in loaded]
        same = editor is self.editor and applied is not None
        self._shown = (self.dataset, self.editor, world.copy())
        return CamerasMoved(world @ np.linalg.inv(applied) if same else None)

    # ------------------------------------------------------------------ colour edits and their original
    @property
    def colour(self) -> ColourEdits:
        return self.editor.extras.get(COLOUR, ColourEdits()) if self.editor is not None else ColourEdits()

    def set_colour(self, edits: ColourEdits, merge=None) -> None:
        """The new colour edits as an undo step (a slider drag's changes merged into one)."""
        self._editor().set_extra(COLOUR, edits, merge=merge)

    def paired(self) -> bool:
        """An original is paired with the first model file, row for row."""
        return self.has_ledger and self._paired_with(self.models)

    def _paired_with(self, models: SceneModels) -> bool:
        o = self.original
        return (o is not None and bool(models.parts) and o.paired_with == models.files[0].path
                and len(o.sh) == len(models.parts[0].rows))

    def pair_original(self, path, ref: FileRef | None = None) -> None:
        """Read ``path`` as the opened model's original: same rows (count) and SH degree, else one line.
        ``ref``: what a project recorded for it (default: the file as read now)."""
        p = Path(path)
        if self.source is None:
            raise ValueError("open the stylized model first")
        if not p.is_file():
            raise InputError(p, "file does not exist")
        g = read_model(p)
        n = self.file_row_count()
        if len(g) != n or g.sh_degree != self.source.sh_degree:
            raise InputError(p, f"does not pair with the opened model row for row ({len(g)} Gaussians of SH degree "
                                f"{g.sh_degree}; the opened model has {n} of degree {self.source.sh_degree})")
        sh = g.sh.detach().cpu().numpy().astype(np.float32)
        sh.setflags(write=False)
        self.original = Original(ref if ref is not None else FileRef(p, file_sha256(p)), sh,
                                 self.models.files[0].path)

    # ------------------------------------------------------------------ projects
    def to_project(self, stylize: dict | None = None, camera=None, camera_distance: float = 1.0,
                   up=(0.0, -1.0, 0.0), layout: str = "") -> Project:
        """The document as a Project, with the window's own parts given: the stylization settings (StylizeConfig
        fields), the view's camera (a pinhole camera, or None), the orbit distance and up, the dock layout. While
        the editor edits a running trainer's model, the project is the opened scene set aside."""
        editor, source, scene = self._scene()
        models = []
        if editor is not None and source is not None and scene.parts:
            models += self._entries(editor, scene)
        models += list(self.carried)
        world = np.eye(4) if editor is None else editor.extras.get(WORLD, np.eye(4))
        dataset = FileRef(Path(self.dataset.path)) if self.dataset is not None else None
        painting = FileRef(Path(self.painting.path)) if self.painting is not None else None
        return Project(models=models, dataset=dataset, painting=painting, stylize=dict(stylize or {}),
                       camera=camera, camera_distance=camera_distance, camera_path=self.camera_path.copy(),
                       layout=layout, up=np.asarray(up, float), world=world, source=self.project_source,
                       copies=dict(self.member_copies))

    def _entries(self, ed: Editor, models: SceneModels) -> list[ModelEntry]:
        """One entry per run of the editor's rows from one part, in the editor's order (a selection moved out of
        the middle of a model is a run of its own between two runs of the rest), with the part's transform; the
        first file has the editor's colour edits and the paired original, the others what their entries had."""
        part_ids = models.part_of(ed.index)
        bounds = np.flatnonzero(np.diff(part_ids)) + 1
        entries = []
        for at in np.split(np.arange(len(part_ids)), bounds):
            if len(at) == 0:
                continue
            part = models.parts[part_ids[at[0]]]
            f = models.files[part.file]
            if part.file == 0:
                edits = ed.extras.get(COLOUR, ColourEdits())
                original = self.original.ref if self._paired_with(models) else f.original
            else:
                edits, original = f.colour, f.original
            entries.append(ModelEntry(_copy(f.ref), f.name, _copy(original),
                                      part.rows[ed.index[at] - part.start].astype(np.int64), ed.selected[at].copy(),
                                      ed.hidden[at].copy(), part.transform.copy(),
                                      edits if edits is not None else ColourEdits()))
        return entries

    def from_project(self, path, models_folder: Path) -> Opened:
        """Open the project at ``path``: every model whose files are there, unchanged and fitting its edits, joined
        into one scene with its rows, selection, hidden flags, transform and colour edits (embedded ones copied to
        ``models_folder`` first); the dataset, painting and camera path. The others are carried, one line each.
        InputError (one line) when the file is not a project.

        The project is opened into a document of its own, which this one becomes only once it has opened: a
        project that fails part-way (any error) leaves this document as it was, so nothing the user had is lost,
        and the next save does not write a half-opened scene over the project it came from."""
        fresh = Document()
        # what the project does not name stays as it is (a project without a painting keeps the one open)
        fresh.dataset, fresh.cameras, fresh.painting = self.dataset, self.cameras, self.painting
        opened = fresh._read_project(path, models_folder)
        for name in ("editor", "source", "models", "live", "original", "dataset", "cameras", "painting",
                     "camera_path", "carried", "project_source", "member_copies", "_set_aside"):
            setattr(self, name, getattr(fresh, name))
        self.mark_saved()
        return opened

    def _read_project(self, path, models_folder: Path) -> Opened:
        project, problems = open_project(path)
        opened = Opened(project, list(problems))
        self.carried, self.project_source, self.member_copies = [], project.source, {}
        for entry in project.models:
            try:
                read = self._entry_model(entry, project, models_folder)
            except InputError as exc:  # its file cannot be read (a damaged member, not a model): the rest opens
                read = exc.problem
            except ValueError as exc:  # a file the reader refused in other words
                read = _first_line(exc)
            if isinstance(read, str):
                self.carried.append(entry)
                opened.problems.append(f"{entry.file.path}: model '{entry.name}' is in the project but not shown "
                                       f"({read})")
                self._keep_copies(entry, project, models_folder)
            else:
                self._join(entry, project, models_folder, opened.problems, *read)
        if self.editor is not None:
            self.editor.forget_history()
        for ref, fn, what in ((project.dataset, self.open_dataset, "dataset"),
                              (project.painting, self.open_painting, "painting")):
            if ref is not None and not ref.missing:
                try:
                    fn(str(ref.path))
                except Exception as exc:  # noqa: BLE001  (one line, and the rest of the project still opens)
                    opened.problems.append(f"cannot open the {what}: {_first_line(exc)}")
        self.camera_path = project.camera_path.copy()
        return opened

    def _entry_model(self, entry: ModelEntry, project: Project, models_folder: Path):
        """(path, Gaussians, scene file index or None) of a project's model whose edits fit it, or why it cannot
        be shown (one line). Nothing in the scene changes here, so a model refused leaves it whole."""
        if not entry.usable:
            return "its file is missing or changed"
        fid = next((i for i, f in enumerate(self.models.files) if f.ref.path.resolve() == entry.file.path.resolve()
                    and f.ref.embedded == entry.file.embedded), None)
        path = entry.file.path if fid is None else self.models.files[fid].path
        if fid is None and entry.file.embedded is not None:  # the viewer opens files: embedded ones are copied out
            path = self._copy_member(project, entry.file.embedded, models_folder)
        g = read_model(path)
        why = colour_problem(entry, len(g))
        if why is None and entry.kept is not None and len(entry.kept) and int(entry.kept.max()) >= len(g):
            why = "the project keeps rows the model does not have"
        if why is None and entry.kept is not None and len(entry.kept) == 0:
            why = "the project keeps none of its rows"
        return why if why is not None else (path, g, fid)

    def _join(self, entry: ModelEntry, project: Project, models_folder: Path, problems: list[str], path: Path, g,
              fid: int | None) -> None:
        """One model of an opened project (read and checked by ``_entry_model``) into the scene; the first opens
        it."""
        import torch

        from app.project_bake import merge
        from training.model.transform import transform_gaussians

        rows = np.arange(len(g)) if entry.kept is None else entry.kept
        n = len(rows)
        selected = entry.selected if entry.selected is not None and len(entry.selected) == n else np.zeros(n, bool)
        hidden = entry.hidden if entry.hidden is not None and len(entry.hidden) == n else np.zeros(n, bool)
        first = self.editor is None
        if first:
            self._open_read(path, g, _copy(entry.file))
            self.models.files[0].name = entry.name or self.models.files[0].name
            self.models.files[0].original = _copy(entry.original)
            ed = self.editor
            if entry.kept is not None:
                ed.model, ed.index = subset(ed.model, rows), rows.copy()
            ed.selected, ed.hidden = selected.copy(), hidden.copy()
            self._open_with_world(project.world)  # the scale and up axis the measure tools set
            if not entry.colour.is_identity:
                ed.extras = {**ed.extras, COLOUR: entry.colour}
            if entry.original is not None and not entry.original.missing:
                try:
                    self._pair_project_original(entry.original, models_folder, project)
                except Exception as exc:  # noqa: BLE001  (one line; the rest of the project still opens)
                    problems.append(f"cannot pair the original model: {str(exc).splitlines()[0] if str(exc) else exc}")
            if not np.array_equal(entry.transform, np.eye(4)):
                w = self.world  # the world is already on the editor's model: the entry's move goes under it
                self.transform(np.ones(ed.count, bool), w @ entry.transform @ np.linalg.inv(w))
            return
        moved = transform_gaussians(g.subset(torch.as_tensor(rows, dtype=torch.long)), entry.transform)
        source = merge([self.source, moved])
        if fid is None:
            fid = self.models.add_file(path, _copy(entry.file), entry.colour, _copy(entry.original), entry.name)
        start = self.models.add_part(fid, rows, entry.transform).start
        self.source = source
        ed = self.editor
        ed.model = appended(ed.model, snapshot_arrays(self.in_world(moved)), moved.sh_degree)
        ed.selected = np.concatenate([ed.selected, selected])
        ed.hidden = np.concatenate([ed.hidden, hidden])
        ed.index = np.concatenate([ed.index, start + np.arange(n)])

    def _pair_project_original(self, ref: FileRef, models_folder: Path, project: Project) -> None:
        path = ref.path
        if ref.embedded is not None:
            path = self._copy_member(project, ref.embedded, models_folder)
        self.pair_original(path, ref=_copy(ref))

    def _copy_member(self, project: Project, member: str, models_folder: Path) -> Path:
        """The viewer's copy of an embedded model (made now), noted for saving when the project file is gone."""
        path = extract_member(project.source, member, embedded_copy(models_folder, project.source, member))
        self.member_copies[member] = path
        return path

    def _keep_copies(self, entry: ModelEntry, project: Project, models_folder: Path) -> None:
        """A carried model's embedded files copied out too, so that it is still saved once the project file has
        moved; a member that cannot be copied is read from the project file at the save, as before."""
        for ref in (entry.file, entry.original):
            if ref is not None and ref.embedded is not None and ref.embedded not in self.member_copies:
                try:
                    self._copy_member(project, ref.embedded, models_folder)
                except InputError:
                    pass


def embedded_copy(models_folder: Path, source: Path, member: str) -> Path:
    """Where the viewer keeps its copy of a project's embedded model: in a folder named after the project and the
    member's content (its CRC-32 and size, from the zip's directory). Every project names its first model
    ``models/0-<file name>``: copies by member name alone overwrote another project's, which the runs, the
    stylizations' originals and the Colour panel still pointed at. The same content lands on the same path."""
    import zipfile

    try:
        with zipfile.ZipFile(source) as z:
            info = z.getinfo(member)
    except KeyError:
        raise InputError(source, f"embedded model {member} is not in the project") from None
    except (zipfile.BadZipFile, OSError) as exc:
        raise InputError(source, f"embedded model {member} cannot be read ({_first_line(exc)})") from None
    return models_folder / f"{Path(source).stem}-{info.CRC:08x}-{info.file_size}" / Path(member).name


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _copy(ref: FileRef | None) -> FileRef | None:
    return None if ref is None else FileRef(Path(ref.path), ref.sha256, ref.embedded, ref.missing, ref.changed)
