"""Colour adjustments and style strength in the viewer: what the Colour panel edits, what the 3D view shows, what
the Edit panel's export and a saved project hold. No imgui here (colour_panel.py draws the controls).

The edits are one ``ColourEdits`` (training/model/colour_edit.py), the document's (document.py: an extra of the
editor's history, so undo and redo cover them with every other edit). Their regions are masks over the rows of the
model file as opened (the editor's rows map to them through the scene's ledger, app/viewer/edit/scene_models.py), as a
project stores them, so ``splatstyler export --project`` bakes the same SH the view shows. They act on the first
(opened) model's Gaussians: a model added to the scene keeps its colours (its project entry keeps its own edits). A
row moved by the gizmo is still its file row: the edits are applied in the file's frame and the row is then turned
as its part and the scene's world turn it, the order ``export --project`` bakes in.

Style strength blends each Gaussian's stylized SH with its original's, row for row. The original comes from:

* a running or finished stylization in this session: its input model's colours (``LiveSession.original_colours``,
  rows following its deletions), when it stylizes colours only (under ``--params all`` the geometry moved too, and
  the original's colours on the new geometry are not the photo model: strength is off, said in one line);
* for an opened model: a paired original file (the panel's "original model", or the project's) with the same rows
  (count and SH degree; a file that differs is refused in one line), the document's ``original``.

Every function takes the document and the session (whose stylizer, running or finished, may be what is shown).
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np

from training.core.status import StylizeStatus
from training.model.colour_edit import ColourAdjustment, ColourEdits

_versions = itertools.count(1 << 40)  # derived snapshots' versions: never a trainer's or an opened model's
_shown: dict = {}  # the last snapshot ``displayed`` made, by its inputs: a frame that shows it again costs nothing


def region_mask(doc, region: str) -> np.ndarray | None:
    """The region a slider acts on, over the file's rows (None: everything). ValueError when it is empty."""
    if region == "all":
        return None
    ed = doc.editor
    first, frows = doc.first_model_rows()
    rows = frows[ed.selected & first]
    if len(rows) == 0 and ed.selected.any():
        raise ValueError("colour edits act on the opened model's Gaussians: the selection holds only added models'")
    if len(rows) == 0:
        raise ValueError("nothing is selected: select Gaussians (Edit panel) or apply to all")
    mask = np.zeros(doc.file_row_count(), bool)
    mask[rows] = True
    return mask


def same_region(a, b) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def current_adjustment(edits: ColourEdits, region) -> ColourAdjustment:
    """The values the sliders show: the last layer's when it has this region, else no change."""
    if edits.adjustments and same_region(edits.adjustments[-1][0], region):
        return edits.adjustments[-1][1]
    return ColourAdjustment()


def current_strength(edits: ColourEdits, region) -> float:
    """The value the slider shows: the region's own (the last strength region when it is this one), else the
    strength everywhere."""
    if region is not None and edits.strength_regions and same_region(edits.strength_regions[-1][0], region):
        return float(edits.strength_regions[-1][1])
    return edits.strength


def with_adjustment(edits: ColourEdits, region, adjustment: ColourAdjustment) -> ColourEdits:
    """The edits with the slider's layer set: the last layer when it has this region, else a new one on top."""
    adjustment.validate()
    layers = list(edits.adjustments)
    if layers and same_region(layers[-1][0], region):
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
    if regions and same_region(regions[-1][0], region):
        regions[-1] = (region, float(value))
    else:
        regions.append((region, float(value)))
    return replace(edits, adjustments=list(edits.adjustments), strength_regions=regions)


# --------------------------------------------------------------------------------------------- the original
def strength_problem(doc, session) -> str | None:
    """Why style strength cannot apply to the model shown (one line), or None."""
    run = session.trainer_status(StylizeStatus)
    if run is not None:
        if not run.colour_only:
            return "style strength needs a colour-only stylization: this one moved the geometry too (params all)"
        if doc.editor is None or run.num_gaussians != doc.editor.count:
            return "the run's Gaussians are no longer the opened model's rows (edited since it started)"
        return None
    if session.has_trainer:
        return "style strength applies to a stylized model: this run is a reconstruction"
    if doc.editor is None:
        return "open a model"
    if doc.live:
        return "style strength applies to a stylization, not to a live edit"
    if not doc.paired():
        return "pair the stylized model with its original (the model before stylization) below"
    return None


# --------------------------------------------------------------------------------------------- what the view shows
def _original_rows(doc, session, snap) -> np.ndarray | None:
    """The run's original SH for ``snap``'s rows, or None when it has none that pair."""
    if session.trainer_status(StylizeStatus) is not None:
        if strength_problem(doc, session) is not None:
            return None
        sh = session.original_colours()
        return sh if sh is not None and len(sh) == len(snap) else None
    return None  # an opened model: _opened_model_sh takes the paired original over the file's rows


def displayed(doc, session, snap):
    """``snap`` as the view shows it: the colour edits and style strength applied to its SH (the same object when
    there are none, or when the edits' rows are not ``snap``'s)."""
    ed = doc.editor
    if snap is None or ed is None or ed.count != len(snap):
        return snap
    edits = doc.colour
    if edits.is_identity:
        return snap
    run = session.trainer_status(StylizeStatus)
    original_key = id(session.original_colours()) if run is not None else id(doc.original)
    key = (id(doc), snap.version, snap.geometry_version, id(edits), id(ed.index), original_key, id(doc.source),
           id(ed.extras.get("world")))
    if _shown.get("key") == key:
        return _shown["snap"]
    if not session.has_trainer and doc.has_ledger:
        sh = _opened_model_sh(doc, edits)
    else:
        original = _original_rows(doc, session, snap) if edits.uses_original else None
        if edits.uses_original and original is None:
            edits = replace(edits, strength=1.0, strength_regions=[])  # no original: the strength cannot show
        sh = edits.apply(snap.sh, original_sh=original, rows=ed.index)
    if sh is not snap.sh:
        sh = np.ascontiguousarray(sh, np.float32)
        sh.setflags(write=False)
    out = replace(snap, version=next(_versions), sh=sh)
    _shown.update(key=key, snap=out)
    return out


def _opened_model_sh(doc, edits) -> np.ndarray:
    """The SH of the editor's rows as the view shows them: the edits applied to the opened file's rows in its own
    frame, each row then turned as its part and the scene's world turn it (the order ``export --project`` bakes
    in); the rows of added models keep their colours."""
    import torch

    from training.model.transform import transform_gaussians

    source, models, index = doc.source, doc.models, doc.editor.index
    if edits.uses_original and not doc.paired():
        edits = replace(edits, strength=1.0, strength_regions=[])  # no original: the strength cannot show
    n0 = doc.file_row_count()
    original = None if not edits.uses_original else torch.from_numpy(np.array(doc.original.sh))
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
    return doc.in_world(_with_sh(shown, sh)).sh.detach().cpu().numpy()


# --------------------------------------------------------------------------------------------- export
def export_baker(doc, session):
    """A function ``(gaussians, run=False, original_sh=None) -> gaussians`` with the edits as they are now baked in
    (``run``: the gaussians are the session's trainer's, ``original_sh`` its input colours, as session.UseModel
    gives them): what the Edit panel's export writes is what the view shows. For the opened model the edits go on
    the whole file and the kept rows are taken after (the order ``export --project`` bakes in, so both write the
    same SH)."""
    import torch

    edits = doc.colour
    if edits.is_identity or doc.editor is None:
        return lambda g, run=False, original_sh=None: g
    index = doc.editor.index.copy()
    problem = strength_problem(doc, session) if edits.uses_original else None
    if problem is not None:
        raise ValueError(problem)
    opened_sh = _opened_model_sh(doc, edits) if doc.has_ledger and not session.has_trainer else None

    def bake(g, run=False, original_sh=None):
        if run:
            if len(g) != len(index):
                raise ValueError("the colour edits belong to another set of Gaussians than the run's: export the "
                                 "opened model, or select again")
            original = original_sh if edits.uses_original else None
            sh = edits.apply(g.sh, original_sh=original, rows=index)
            return _with_sh(g, sh)
        # the opened model as shown (the editor's rows in the scene's world)
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
