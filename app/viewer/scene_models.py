"""Several models in one scene, and moves of any of their Gaussians, under the editor's undo.

**One model on screen.** A model added to the scene joins the opened one in the editor: its Gaussians are appended
to the editor's model, so the view draws one concatenated model (one draw, one back-to-front sort across both:
splats of two models interleave correctly where they overlap), selections and edits reach both, and Export writes
the union. Nothing here draws anything itself.

**The ledger.** The editor's rows index ``app.source_gaussians`` (raw parameters; Export takes its rows). Every
source row belongs to a *part*: a block of rows of one model file, all moved by one similarity transform (source
row = transform(file row)). Adding a model appends a part (identity); moving Gaussians (a gizmo drag, a three-point
alignment) appends, for each part the moved rows came from, a new part with the composed transform and points the
editor's rows at it. Source rows are only ever appended, so every state on the undo stack still indexes the same
rows: undo of a move restores the editor's earlier model object, bit for bit, and needs nothing from here.

**The world.** The editor's model is the source rows moved by the scene's world transform (the measure and up
tools, app/viewer/world_edit.py; identity until they are used), so a move made in the view (a gizmo drag, picked
points) is a move in the world: on the source rows it is that move seen from the file's side, W^-1 D W.

A project (File > Save project) gets one entry per part the editor still shows: the file, its rows kept, selected
and hidden, and the part's transform, which is the format's "several models with transforms"; `splatstyler export
--project` bakes and merges them (app/project_bake.py) into what the viewer shows.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from training.model.transform import split_similarity, transform_gaussians

# snapshot versions made here: never equal to an earlier model's (the view skips an upload whose version it holds)
_versions = itertools.count(3_000_000_000)
_ARRAYS = ("means", "scales", "quats", "opacities", "sh")


@dataclass
class ModelFile:
    path: Path
    name: str
    colour: object = None  # ColourEdits of a project entry, kept for saving (regions index the file's rows)
    original: str | None = None  # the unstylized model of a project entry


@dataclass
class Part:
    file: int  # index into SceneModels.files
    rows: np.ndarray  # (M,) int64 rows of the file
    transform: np.ndarray  # 4x4 similarity: the file's rows into the scene
    start: int  # its first row in app.source_gaussians


@dataclass
class SceneModels:
    files: list[ModelFile] = field(default_factory=list)
    parts: list[Part] = field(default_factory=list)

    @classmethod
    def opened(cls, path, count: int) -> "SceneModels":
        models = cls()
        models.add_part(models.add_file(path), np.arange(count), np.eye(4))
        return models

    def add_file(self, path, colour=None, original=None) -> int:
        self.files.append(ModelFile(Path(path), Path(path).stem, colour, original))
        return len(self.files) - 1

    @property
    def size(self) -> int:
        return 0 if not self.parts else self.parts[-1].start + len(self.parts[-1].rows)

    def add_part(self, file: int, rows, transform) -> Part:
        part = Part(file, np.asarray(rows, np.int64), np.asarray(transform, np.float64), self.size)
        self.parts.append(part)
        return part

    def part_of(self, source_rows: np.ndarray) -> np.ndarray:
        starts = np.array([p.start for p in self.parts], np.int64)
        return np.searchsorted(starts, np.asarray(source_rows, np.int64), side="right") - 1

    def file_of(self, source_rows: np.ndarray) -> np.ndarray:
        files = np.array([p.file for p in self.parts], np.int64)
        return files[self.part_of(source_rows)]


def _require_ledger(app):
    ed = app.editor
    if ed is None:
        raise ValueError("no model is open")
    if app.source_gaussians is None or not app.scene_models.parts:
        raise ValueError("the running trainer's model cannot be moved or joined: open a model file")
    if app.scene_models.size != len(app.source_gaussians):
        raise RuntimeError("the scene's ledger and the source model disagree")  # a bug, not a user error
    return ed


def snapshot_arrays(g) -> dict[str, np.ndarray]:
    """The render arrays of raw Gaussians (activated as app.snapshot_of does)."""
    from app.viewer.app import snapshot_of

    snap = snapshot_of(g)
    return {name: getattr(snap, name) for name in _ARRAYS}


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def _pad_sh(sh: np.ndarray, k: int) -> np.ndarray:
    if sh.shape[1] >= k:
        return sh
    return np.concatenate([sh, np.zeros((len(sh), k - sh.shape[1], 3), sh.dtype)], axis=1)


def with_rows(model, mask: np.ndarray, arrays: dict[str, np.ndarray]):
    """The ModelSnapshot with the rows at ``mask`` replaced by ``arrays`` (a new version, same structure)."""
    out = {}
    for name in _ARRAYS:
        a = np.array(getattr(model, name), copy=True)
        a[mask] = arrays[name]
        out[name] = _frozen(a)
    v = next(_versions)
    return replace(model, version=v, geometry_version=v, **out)


def world(app) -> np.ndarray:
    from app.viewer.world_edit import world_of

    return world_of(app)


def in_world(app, g):
    """Source Gaussians as the view shows them (moved by the scene's world; the identity returns ``g``)."""
    return transform_gaussians(g, world(app))


def source_move(app, matrix) -> np.ndarray:
    """The move ``matrix`` (made in the view's world) as a move of the source rows: W^-1 D W."""
    w = world(app)
    if np.array_equal(w, np.eye(4)):
        return np.asarray(matrix, np.float64)
    return np.linalg.inv(w) @ np.asarray(matrix, np.float64) @ w


def moved_arrays(app, mask: np.ndarray, matrix) -> dict[str, np.ndarray]:
    """What the editor's rows at ``mask`` become when moved by ``matrix`` in the view's world (the drag preview;
    nothing changes)."""
    rows = torch.as_tensor(app.editor.index[mask], dtype=torch.long)
    return snapshot_arrays(in_world(app, transform_gaussians(app.source_gaussians.subset(rows),
                                                             source_move(app, matrix))))


def transform_rows(app, mask, matrix) -> None:
    """Move the editor's Gaussians at ``mask`` by the similarity ``matrix`` (4x4, in the view's world): one undo
    step."""
    from app.project_bake import merge

    ed = _require_ledger(app)
    mask = np.asarray(mask, bool)
    if mask.shape != (ed.count,):
        raise ValueError(f"a move needs one flag per Gaussian ({ed.count}), got {mask.shape}")
    if not mask.any():
        raise ValueError("nothing to move: select Gaussians first")
    matrix = np.asarray(matrix, np.float64)
    split_similarity(matrix)  # a similarity or a one-line refusal, before anything changes
    matrix = source_move(app, matrix)
    models = app.scene_models
    source_rows = ed.index[mask]
    part_ids = models.part_of(source_rows)
    new_rows = np.empty_like(source_rows)
    pieces = []
    for pid in np.unique(part_ids):
        at = part_ids == pid
        part = models.parts[pid]
        rows = source_rows[at]
        pieces.append(transform_gaussians(app.source_gaussians.subset(torch.as_tensor(rows, dtype=torch.long)),
                                          matrix))
        new_part = models.add_part(part.file, part.rows[rows - part.start], matrix @ part.transform)
        new_rows[at] = new_part.start + np.arange(len(rows))
    app.source_gaussians = merge([app.source_gaussians] + pieces)
    arrays = snapshot_arrays(in_world(app, app.source_gaussians.subset(torch.as_tensor(new_rows, dtype=torch.long))))
    ed._push()
    ed.model = with_rows(ed.model, mask, arrays)
    index = ed.index.copy()
    index[mask] = new_rows
    ed.index = index
    ed.version += 1


def add_model(app, path: str, select: bool = True):
    """Join the model file at ``path`` to the scene (one undo step); opens it when no model is open. Its Gaussians
    are selected, so the gizmo moves it at once. Returns the file's index in the scene."""
    from training.model.model_io import read_model
    from app.project_bake import merge

    if app.editor is None:
        app.open_model(path)
        return 0
    ed = _require_ledger(app)
    g = read_model(Path(path))
    if len(g) == 0:
        raise ValueError(f"{path}: the model has no Gaussians")
    models = app.scene_models
    fid = models.add_file(path)
    start = models.add_part(fid, np.arange(len(g)), np.eye(4)).start
    app.source_gaussians = merge([app.source_gaussians, g])
    n = len(g)
    ed._push()
    if select:
        ed.selected = np.zeros_like(ed.selected)
    add_model_rows(ed, snapshot_arrays(in_world(app, g)), g.sh_degree, np.full(n, select), np.zeros(n, bool),
                   start + np.arange(n))
    ed.version += 1
    return fid


def rows_of_file(app, fid: int) -> np.ndarray:
    """Which of the editor's rows come from the scene's model ``fid``."""
    ed = _require_ledger(app)
    return app.scene_models.file_of(ed.index) == fid


def file_rows(app, source_rows=None) -> tuple[np.ndarray, np.ndarray]:
    """For source rows (default: the editor's rows), the scene model each comes from and its row in that file:
    what per-file data (colour regions, an original model's SH) is indexed by once models were added or moved."""
    models = app.scene_models
    rows = np.asarray(app.editor.index if source_rows is None else source_rows, np.int64)
    by_source_row = np.concatenate([p.rows for p in models.parts])  # the parts tile the source rows in order
    return models.file_of(rows), by_source_row[rows]


def files_shown(app) -> list[int]:
    """The scene's models that have Gaussians in the editor now (undo may have taken one out)."""
    if app.editor is None or not app.scene_models.parts or app.source_gaussians is None:
        return []
    return sorted(set(app.scene_models.file_of(app.editor.index).tolist()))


# ------------------------------------------------------------------ projects
def project_entries(app, colour=None, original: str | None = None) -> list:
    """The editor's models as project entries: one per run of rows from one part, in the order of the editor's rows,
    with the part's transform; the first file gets ``colour``/``original`` (those of the entry it was opened
    from), the others what their own entries had."""
    from app.project import FileRef, ModelEntry
    from training.model.colour_edit import ColourEdits

    ed = app.editor
    models = app.scene_models
    part_ids = models.part_of(ed.index)
    # one entry per run of rows from the same part, so the project opens with the editor's order (a selection moved
    # out of the middle of a model is a run of its own between two runs of the rest)
    bounds = np.flatnonzero(np.diff(part_ids)) + 1
    entries = []
    for at in np.split(np.arange(len(part_ids)), bounds):
        if len(at) == 0:
            continue
        pid = part_ids[at[0]]
        part = models.parts[pid]
        f = models.files[part.file]
        edits = colour if part.file == 0 and colour is not None else f.colour
        orig = original if part.file == 0 and original else f.original
        entries.append(ModelEntry(FileRef(f.path), f.name, FileRef(Path(orig)) if orig else None,
                                  part.rows[ed.index[at] - part.start].astype(np.int64), ed.selected[at].copy(),
                                  ed.hidden[at].copy(), part.transform.copy(),
                                  edits if edits is not None else ColourEdits()))
    return entries


def open_project_models(app, opened) -> None:
    """After a project's first model was opened (project_io.apply_project): its transform applied, and every
    other model of the project whose file is there joined to the scene with its rows, selection, hidden flags
    and transform, so the view shows what `export --project` writes. The history starts after them."""
    from training.model.model_io import read_model
    from app.project_bake import merge

    ed = app.editor
    entry = opened.entry
    models = app.scene_models
    first = models.files[0]
    first.colour, first.original = entry.colour, str(entry.original.path) if entry.original else None
    if not np.array_equal(entry.transform, np.eye(4)):
        w = world(app)  # the world is already on the editor's model: the entry's move goes under it
        transform_rows(app, np.ones(ed.count, bool), w @ entry.transform @ np.linalg.inv(w))
    for other in [m for m in opened.not_shown if m.usable and m.file.embedded is None]:
        g = read_model(other.file.path)
        rows = np.arange(len(g)) if other.kept is None else other.kept
        if len(rows) and int(rows.max()) >= len(g):
            opened.problems.append(f"{other.file.path}: the project keeps rows the model does not have: not shown")
            continue
        fid = next((i for i, f in enumerate(models.files) if f.path.resolve() == other.file.path.resolve()),
                   None)
        if fid is None:
            fid = models.add_file(other.file.path, other.colour,
                                  str(other.original.path) if other.original else None)
            models.files[fid].name = other.name or models.files[fid].name
        g = transform_gaussians(g.subset(torch.as_tensor(rows, dtype=torch.long)), other.transform)
        start = models.add_part(fid, rows, other.transform).start
        app.source_gaussians = merge([app.source_gaussians, g])
        n = len(rows)
        add_model_rows(ed, snapshot_arrays(in_world(app, g)), g.sh_degree,
                       other.selected if other.selected is not None and len(other.selected) == n else np.zeros(n, bool),
                       other.hidden if other.hidden is not None and len(other.hidden) == n else np.zeros(n, bool),
                       start + np.arange(n))
        opened.not_shown.remove(other)
        opened.problems = [line for line in opened.problems if f"model '{other.name}' is in the project but not"
                           not in line]
    ed.undo_stack.clear()
    ed.redo_stack.clear()
    ed.version += 1


def add_model_rows(ed, arrays: dict, sh_degree: int, selected, hidden, index) -> None:
    """Append Gaussians to the editor's model without an undo step (a project being opened)."""
    old = ed.model
    k = max(old.sh.shape[1], arrays["sh"].shape[1])
    out = {name: np.concatenate([getattr(old, name), arrays[name]]) for name in _ARRAYS[:-1]}
    out["sh"] = np.concatenate([_pad_sh(old.sh, k), _pad_sh(arrays["sh"], k)])
    v = next(_versions)
    ed.model = replace(old, version=v, geometry_version=v, sh_degree=max(old.sh_degree, sh_degree),
                       structure_version=old.structure_version + 1, **{n: _frozen(a) for n, a in out.items()})
    ed.selected = np.concatenate([ed.selected, np.asarray(selected, bool)])
    ed.hidden = np.concatenate([ed.hidden, np.asarray(hidden, bool)])
    ed.index = np.concatenate([ed.index, np.asarray(index, np.int64)])
