"""The ledger of a scene of several models: which model file, and which row of it, each source row comes from, and
the similarity that moved it (the document, document.py, keeps it in step with the editor and the source model).

**One model on screen.** A model added to the scene joins the opened one in the editor: its Gaussians are appended
to the editor's model, so the view draws one concatenated model (one draw, one back-to-front sort across both:
splats of two models interleave correctly where they overlap), selections and edits reach both, and Export writes
the union.

**The ledger.** The editor's rows index the document's source model (raw parameters; Export takes its rows).
Every source row belongs to a *part*: a block of rows of one model file, all moved by one similarity transform
(source row = transform(file row)). Adding a model appends a part (identity); moving Gaussians (a gizmo drag, a
three-point alignment) appends, for each part the moved rows came from, a new part with the composed transform and
points the editor's rows at it. Source rows are only ever appended, so every state on the undo stack still indexes
the same rows: undo of a move restores the editor's earlier model object, bit for bit, and needs nothing from here.

A project (File > Save project) gets one entry per part the editor still shows: the file, its rows kept, selected
and hidden, and the part's transform, which is the format's "several models with transforms"; `splatstyler export
--project` bakes and merges them (app/project_bake.py) into what the viewer shows.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from app.project import FileRef
from training.core.messages import ModelSnapshot, frozen_array

# snapshot versions made here: never equal to an earlier model's (the view skips an upload whose version it holds)
versions = itertools.count(3_000_000_000)
ARRAYS = ("means", "scales", "quats", "opacities", "sh")


@dataclass
class ModelFile:
    path: Path  # where the viewer reads it (an embedded model: its copy in the output folder)
    name: str
    ref: FileRef  # what a project records: the file as opened (its hash then), or the project's own reference
    colour: object = None  # ColourEdits of a project entry, kept for saving (regions index the file's rows)
    original: FileRef | None = None  # the unstylized model of a project entry


@dataclass
class Part:
    file: int  # index into SceneModels.files
    rows: np.ndarray  # (M,) int64 rows of the file
    transform: np.ndarray  # 4x4 similarity: the file's rows into the scene
    start: int  # its first row in the source model


@dataclass
class SceneModels:
    files: list[ModelFile] = field(default_factory=list)
    parts: list[Part] = field(default_factory=list)

    @classmethod
    def opened(cls, path, count: int, ref: FileRef | None = None) -> "SceneModels":
        models = cls()
        models.add_part(models.add_file(path, ref), np.arange(count), np.eye(4))
        return models

    def add_file(self, path, ref: FileRef | None = None, colour=None, original=None, name: str = "") -> int:
        ref = ref if ref is not None else FileRef(Path(path))
        self.files.append(ModelFile(Path(path), name or Path(path).stem, ref, colour, original))
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

    def file_rows(self, source_rows) -> tuple[np.ndarray, np.ndarray]:
        """For source rows, the scene model each comes from and its row in that file: what per-file data (colour
        regions, an original model's SH) is indexed by once models were added or moved."""
        rows = np.asarray(source_rows, np.int64)
        by_source_row = np.concatenate([p.rows for p in self.parts])  # the parts tile the source rows in order
        return self.file_of(rows), by_source_row[rows]


def snapshot_of(gaussians, version: int = 0) -> ModelSnapshot:
    """A ModelSnapshot of a Gaussians model (a file the user opened)."""
    g = gaussians
    return ModelSnapshot(version, version, 0, frozen_array(g.means), frozen_array(g.scales),
                         frozen_array(g.rotations), frozen_array(g.opacities), frozen_array(g.sh), g.sh_degree)


def snapshot_arrays(g) -> dict[str, np.ndarray]:
    """The render arrays of raw Gaussians (activated as snapshot_of does)."""
    snap = snapshot_of(g)
    return {name: getattr(snap, name) for name in ARRAYS}


def frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def pad_sh(sh: np.ndarray, k: int) -> np.ndarray:
    if sh.shape[1] >= k:
        return sh
    return np.concatenate([sh, np.zeros((len(sh), k - sh.shape[1], 3), sh.dtype)], axis=1)


def with_rows(model, mask: np.ndarray, arrays: dict[str, np.ndarray]):
    """The ModelSnapshot with the rows at ``mask`` replaced by ``arrays`` (a new version, same structure)."""
    out = {}
    for name in ARRAYS:
        a = np.array(getattr(model, name), copy=True)
        a[mask] = arrays[name]
        out[name] = frozen(a)
    v = next(versions)
    return replace(model, version=v, geometry_version=v, **out)


def appended(model, arrays: dict, sh_degree: int):
    """The ModelSnapshot with ``arrays`` appended (SH bands padded to the larger degree), a new structure."""
    k = max(model.sh.shape[1], arrays["sh"].shape[1])
    out = {name: np.concatenate([getattr(model, name), arrays[name]]) for name in ARRAYS[:-1]}
    out["sh"] = np.concatenate([pad_sh(model.sh, k), pad_sh(arrays["sh"], k)])
    v = next(versions)
    return replace(model, version=v, geometry_version=v, sh_degree=max(model.sh_degree, sh_degree),
                   structure_version=model.structure_version + 1, **{n: frozen(a) for n, a in out.items()})
