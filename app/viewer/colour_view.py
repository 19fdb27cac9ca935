"""Colour adjustments and style strength in the viewer: what the Colour panel edits, what the 3D view shows, what
the Edit panel's export and a saved project hold. No imgui here (colour_panel.py draws the controls).

The edits are one ``ColourEdits`` (training/model/colour_edit.py) kept in the editor's ``extra`` under
``"colour"``, so undo and redo cover them with every other edit. Their regions are masks over the rows of the model
file as opened (the editor's rows map to them through the scene's ledger, app/viewer/scene_models.py), as a project
stores them, so ``splatstyler export --project`` bakes the same SH the view shows. They act on the first (opened)
model's Gaussians: a model added to the scene keeps its colours (its project entry keeps its own edits). A row moved
by the gizmo is still its file row: the edits are applied in the file's frame and the row is then turned as its
part and the scene's world turn it, the order ``export --project`` bakes in.

Style strength blends each Gaussian's stylized SH with its original's, row for row. The original comes from:

* a running or finished stylization in this session: the stylizer's ``original_sh`` (its input model's colours,
  rows following its deletions), when it stylizes colours only (under ``--params all`` the geometry moved too, and
  the original's colours on the new geometry are not the photo model: strength is off, said in one line);
* for an opened model: a paired original file (the panel's "original model", or the project's) with the same rows
  (count and SH degree; a file that differs is refused in one line).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from training.model.colour_edit import ColourAdjustment, ColourEdits

KEY = "colour"  # the editor's extra entry
_versions = itertools.count(1 << 40)  # derived snapshots' versions: never a trainer's or an opened model's


@dataclass
class ColourState:
    """What the panel holds besides the edits: the paired original model, and the shown snapshot's cache."""

    original_path: str = ""  # the paired original (unstylized) model file
    original_input: str = ""  # what the panel's field holds (paired by its button)
    original_sh: np.ndarray | None = None  # (N, K, 3) float32 over the opened file's rows
    paired_with: object = None  # the first model file (its path) the original was checked against
    stylized_from: str = ""  # the model the last stylization in this session started from (offered as original)
    region: str = "selection"  # what a slider applies to: selection | all
    drag: int = 0  # counts slider drags: changes within one drag are one undo step
    _cache_key: tuple | None = None
    _cache: object = None


def edits_of(app) -> ColourEdits:
    ed = app.editor
    return ed.extras.get(KEY, ColourEdits()) if ed is not None else ColourEdits()


def _ledger(app) -> bool:
    """The viewer holds an opened model with the scene's ledger (not a running trainer's model)."""
    return app.source_gaussians is not None and bool(app.scene_models.parts)


def first_model_rows(app) -> tuple[np.ndarray, np.ndarray]:
    """For the editor's rows: whether each is the first (opened) model's, and its row in that file."""
    if not _ledger(app):
        return np.ones(app.editor.count, bool), app.editor.index
    from app.viewer.scene_models import file_rows as ledger_rows

    files, rows = ledger_rows(app)
    return files == 0, rows


def file_rows(app) -> int:
    """How many rows the opened model file has (the length of a colour region)."""
    if _ledger(app):
        return len(app.scene_models.parts[0].rows)  # part 0: the opened file as read, in its own frame
    index = app.editor.index
    return int(index.max()) + 1 if len(index) else 0


def _paired(app) -> bool:
    st = app.colour
    if st.original_sh is None:
        return False
    if _ledger(app):
        return st.paired_with == str(app.scene_models.files[0].path) and len(st.original_sh) == file_rows(app)
    return False


def region_mask(app, region: str) -> np.ndarray | None:
    """The region a slider acts on, over the file's rows (None: everything). ValueError when it is empty."""
    if region == "all":
        return None
    ed = app.editor
    first, frows = first_model_rows(app)
    rows = frows[ed.selected & first]
    if len(rows) == 0 and ed.selected.any():
        raise ValueError("colour edits act on the opened model's Gaussians: the selection holds only added models'")
    if len(rows) == 0:
        raise ValueError("nothing is selected: select Gaussians (Edit panel) or apply to all")
    mask = np.zeros(file_rows(app), bool)
    mask[rows] = True
    return mask


def _same_region(a, b) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def current_adjustment(edits: ColourEdits, region) -> ColourAdjustment:
    """The values the sliders show: the last layer's when it has this region, else no change."""
    if edits.adjustments and _same_region(edits.adjustments[-1][0], region):
        return edits.adjustments[-1][1]
    return ColourAdjustment()


def current_strength(edits: ColourEdits, region) -> float:
    """The value the slider shows: the region's own (the last strength region when it is this one), else the
    strength everywhere."""
    if region is not None and edits.strength_regions and _same_region(edits.strength_regions[-1][0], region):
        return float(edits.strength_regions[-1][1])
    return edits.strength


def with_adjustment(edits: ColourEdits, region, adjustment: ColourAdjustment) -> ColourEdits:
    """The edits with the slider's layer set: the last layer when it has this region, else a new one on top."""
    adjustment.validate()
    layers = list(edits.adjustments)
    if layers and _same_region(layers[-1][0], region):
        layers[-1] = (region, adjustment)
    else:
        layers.append((region, adjustment))
    return replace(edits, adjustments=layers, strength_regions=list(edits.strength_regions))


def with_strength(edits: ColourEdits, region, value: float) -> ColourEdits:
    """Strength ``value`` over ``region`` (None: everywhere, which drops the regions set before)."""
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"style strength must be in [0, 1], got {value:g}")
    if region is None:
        return replace(edits, adjustments=list(edits.adjustments), strength=float(value), strength_regions=[])
    regions = list(edits.strength_regions)
    if regions and _same_region(regions[-1][0], region):
        regions[-1] = (region, float(value))
    else:
        regions.append((region, float(value)))
    return replace(edits, adjustments=list(edits.adjustments), strength_regions=regions)


def set_edits(app, edits: ColourEdits, merge=None) -> None:
    """The new edits as an undo step (a drag's changes merged into one)."""
    app.editor.set_extra(KEY, edits, merge=merge)


# --------------------------------------------------------------------------------------------- the original
def stylizer(app):
    """The session's stylizer (running or finished), or None."""
    trainer = app.session.trainer
    return trainer if trainer is not None and hasattr(trainer, "original_sh") else None


def strength_problem(app) -> str | None:
    """Why style strength cannot apply to the model shown (one line), or None."""
    trainer = stylizer(app)
    if trainer is not None:
        if getattr(trainer.config, "params", "colour") != "colour":
            return "style strength needs a colour-only stylization: this one moved the geometry too (params all)"
        if app.editor is None or len(trainer.original_sh) != app.editor.count:
            return "the run's Gaussians are no longer the opened model's rows (edited since it started)"
        return None
    if app.session.trainer is not None:
        return "style strength applies to a stylized model: this run is a reconstruction"
    if app.editor is None:
        return "open a model"
    if app.edit.live:
        return "style strength applies to a stylization, not to a live edit"
    if not _paired(app):
        return "pair the stylized model with its original (the model before stylization) below"
    return None


def pair_original(app, path: str) -> None:
    """Read ``path`` as the opened model's original: same rows (count) and SH degree, else one line."""
    from training.core.errors import InputError
    from training.model.model_io import read_model

    if app.source_gaussians is None:
        raise ValueError("open the stylized model first")
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "file does not exist")
    g = read_model(p)
    src = app.source_gaussians
    n = file_rows(app)
    if len(g) != n or g.sh_degree != src.sh_degree:
        raise InputError(p, f"does not pair with the opened model row for row ({len(g)} Gaussians of SH degree "
                            f"{g.sh_degree}; the opened model has {n} of degree {src.sh_degree})")
    st = app.colour
    st.original_sh = g.sh.detach().cpu().numpy().astype(np.float32)
    st.original_sh.setflags(write=False)
    st.original_path, st.paired_with = str(p), str(app.scene_models.files[0].path) if app.scene_models.files else ""
    st._cache_key = None
    app.say(f"paired {p} as the original of {app.paths.model} ({len(g):,} rows)")


# --------------------------------------------------------------------------------------------- what the view shows
def _original_rows(app, snap) -> np.ndarray | None:
    """The original's SH for ``snap``'s rows, or None when it has none that pair."""
    trainer = stylizer(app)
    if trainer is not None:
        if strength_problem(app) is not None:
            return None
        sh = trainer.original_sh
        return sh.detach().cpu().numpy() if len(sh) == len(snap) else None
    return None  # an opened model: _opened_model_sh takes the paired original over the file's rows


def displayed(app, snap):
    """``snap`` as the view shows it: the colour edits and style strength applied to its SH (the same object when
    there are none, or when the edits' rows are not ``snap``'s)."""
    ed = app.editor
    if snap is None or ed is None or ed.count != len(snap):
        return snap
    edits = edits_of(app)
    if edits.is_identity:
        return snap
    st = app.colour
    trainer = stylizer(app)
    original_key = id(trainer.original_sh) if trainer is not None else id(st.original_sh)
    key = (snap.version, snap.geometry_version, id(edits), id(ed.index), original_key, id(app.source_gaussians),
           id(ed.extras.get("world")))
    if st._cache_key == key:
        return st._cache
    if trainer is None and _ledger(app) and app.session.trainer is None:
        sh = _opened_model_sh(app, edits)
    else:
        original = _original_rows(app, snap) if edits.uses_original else None
        if edits.uses_original and original is None:
            edits = replace(edits, strength=1.0, strength_regions=[])  # no original: the strength cannot show
        sh = edits.apply(snap.sh, original_sh=original, rows=ed.index)
    if sh is not snap.sh:
        sh = np.ascontiguousarray(sh, np.float32)
        sh.setflags(write=False)
    out = replace(snap, version=next(_versions), sh=sh)
    st._cache_key, st._cache = key, out
    return out


def _opened_model_sh(app, edits) -> np.ndarray:
    """The SH of the editor's rows as the view shows them: the edits applied to the opened file's rows in its own
    frame, each row then turned as its part and the scene's world turn it (the order ``export --project`` bakes
    in); the rows of added models keep their colours."""
    import torch

    from app.viewer.scene_models import in_world
    from training.model.transform import transform_gaussians

    source, models, index = app.source_gaussians, app.scene_models, app.editor.index
    if edits.uses_original and not _paired(app):
        edits = replace(edits, strength=1.0, strength_regions=[])  # no original: the strength cannot show
    n0 = file_rows(app)
    original = None if not edits.uses_original else torch.from_numpy(np.array(app.colour.original_sh))
    adjusted = edits.apply(source.sh[:n0].detach().cpu(), original_sh=original)
    adjusted = torch.as_tensor(adjusted)
    rows = torch.as_tensor(index, dtype=torch.long)
    shown = source.subset(rows)
    sh = shown.sh.detach().cpu().clone()
    parts = models.part_of(index)
    for pid in np.unique(parts):
        part = models.parts[pid]
        if part.file != 0:
            continue
        at = np.flatnonzero(parts == pid)
        frows = torch.as_tensor(part.rows[index[at] - part.start], dtype=torch.long)
        g = _with_sh(source.subset(frows), adjusted[frows])  # part 0's rows are the file's, in its frame
        sh[torch.as_tensor(at, dtype=torch.long)] = transform_gaussians(g, part.transform).sh.detach().cpu()
    return in_world(app, _with_sh(shown, sh)).sh.detach().cpu().numpy()


# --------------------------------------------------------------------------------------------- export and project
def export_baker(app):
    """A function ``(gaussians, trainer or None) -> gaussians`` with the edits as they are now baked in: what the
    Edit panel's export writes is what the view shows. For the opened model the edits go on the whole file and the
    kept rows are taken after (the order ``export --project`` bakes in, so both write the same SH)."""
    import torch

    edits = edits_of(app)
    if edits.is_identity or app.editor is None:
        return lambda g, trainer=None: g
    index = app.editor.index.copy()
    problem = strength_problem(app) if edits.uses_original else None
    if problem is not None:
        raise ValueError(problem)
    opened_sh = _opened_model_sh(app, edits) if _ledger(app) and app.session.trainer is None else None

    def bake(g, trainer=None):
        if trainer is not None:
            if len(g) != len(index):
                raise ValueError("the colour edits belong to another set of Gaussians than the run's: export the "
                                 "opened model, or select again")
            original = trainer.original_sh.detach().cpu() if edits.uses_original else None
            sh = edits.apply(g.sh, original_sh=original, rows=index)
            return _with_sh(g, sh)
        # the opened model as shown (model_to_export: the editor's rows in the scene's world)
        if opened_sh is None or len(g) != len(opened_sh):
            raise ValueError("the colour edits belong to another set of Gaussians: select again")
        return _with_sh(g, torch.from_numpy(np.array(opened_sh)))

    return bake


def _with_sh(g, sh):
    import torch

    from training.model.gaussians import Gaussians

    if sh is g.sh:
        return g
    sh = torch.as_tensor(np.asarray(sh)) if not isinstance(sh, torch.Tensor) else sh
    params = g.parameters()
    params["sh0"], params["shN"] = sh[:, :1].contiguous(), sh[:, 1:].contiguous()
    return Gaussians(**params, sh_degree=g.sh_degree)


def for_project(app) -> tuple[ColourEdits | None, str | None]:
    """(colour edits, original model path) for project_from_app: the panel's, or the opened project's when the
    viewer holds no edits of its own."""
    opened = app.project.opened
    entry = opened.entry if opened is not None else None
    if app.editor is None:
        return (None if entry is None else entry.colour,
                None if entry is None or entry.original is None else str(entry.original.path))
    edits = edits_of(app)
    st = app.colour
    original = st.original_path if _paired(app) and st.original_path else None
    if original is None and entry is not None and entry.original is not None:
        original = str(entry.original.path)
    return edits, original


def load_from_project(app, opened) -> None:
    """An opened project's colour edits and original model into the viewer (not an undo step: where it starts)."""
    entry = opened.entry
    if entry is None or app.editor is None:
        return
    if entry.original is not None and not entry.original.missing:
        try:
            pair_original(app, str(entry.original.path))
        except Exception as exc:  # noqa: BLE001  (one line; the rest of the project still opens)
            app.say(f"cannot pair the original model: {str(exc).splitlines()[0] if str(exc) else exc}")
    if not entry.colour.is_identity:
        app.editor.extras = {**app.editor.extras, KEY: entry.colour}
        app.editor.version += 1


def show_run_colours(app) -> None:
    """The editor changed while a run's model is shown: show that model again with the colour edits as they are
    now (nothing is uploaded when its colours did not change)."""
    snap = app.session.snapshot()
    if snap is not None and app.view.show(displayed(app, snap), 0):
        app.view.dirty = True
    app.edit.shown_version = app.editor.version
