"""Selections and edits of the model the viewer holds, with undo and redo.

A selection is a boolean mask over the Gaussians, made in screen space (rectangle, brush, lasso: the Gaussians
whose centres the camera, a training/scene/camera.py Camera, projects inside, in front of it) or in world space (box, sphere), and combined with the current
one by a mode: set, add, remove. Edits change what the model is: hide and show (kept, not drawn), delete, crop to a
box (keep inside or outside). Every edit is a step on the undo stack; undo restores the model exactly.

The model here is a ``ModelSnapshot``-like set of arrays; an edit produces a new one (the arrays it keeps, copied)
with a new version, so the view re-uploads it like any other model change and a trainer can take the same keep-mask.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

MODES = ("set", "add", "remove")


def combine(current: np.ndarray, picked: np.ndarray, mode: str) -> np.ndarray:
    if mode == "set":
        return picked.copy()
    if mode == "add":
        return current | picked
    if mode == "remove":
        return current & ~picked
    raise ValueError(f"unknown selection mode {mode!r}; expected one of {', '.join(MODES)}")


def in_rect(means, camera, x0, y0, x1, y1) -> np.ndarray:
    uv, front = camera.project(means)
    lo_x, hi_x = sorted((x0, x1))
    lo_y, hi_y = sorted((y0, y1))
    return front & (uv[:, 0] >= lo_x) & (uv[:, 0] <= hi_x) & (uv[:, 1] >= lo_y) & (uv[:, 1] <= hi_y)


def in_brush(means, camera, x, y, radius) -> np.ndarray:
    uv, front = camera.project(means)
    return front & ((uv[:, 0] - x) ** 2 + (uv[:, 1] - y) ** 2 <= radius ** 2)


def in_lasso(means, camera, polygon) -> np.ndarray:
    """Centres inside the closed polygon (K, 2) of pixel points (even-odd rule)."""
    poly = np.asarray(polygon, dtype=np.float64).reshape(-1, 2)
    uv, front = camera.project(means)
    if len(poly) < 3:
        return np.zeros(len(means), dtype=bool)
    x, y = uv[:, 0], uv[:, 1]
    inside = np.zeros(len(means), dtype=bool)
    for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0)):
        crosses = (ay > y) != (by > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = ax + (y - ay) * (bx - ax) / (by - ay)
        inside ^= crosses & (x < x_cross)
    return front & inside


def in_box(means, lo, hi) -> np.ndarray:
    lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
    return np.all((means >= lo) & (means <= hi), axis=1)


def in_sphere(means, center, radius) -> np.ndarray:
    return np.sum((means - np.asarray(center)) ** 2, axis=1) <= float(radius) ** 2


@dataclass
class UndoEntry:
    """What undo restores: the model and which of its Gaussians are selected and hidden."""

    model: object  # ModelSnapshot
    selected: np.ndarray
    hidden: np.ndarray
    index: np.ndarray
    extras: dict = field(default_factory=dict)  # other panels' edits by name (world, colour), each value immutable


@dataclass
class Editor:
    """Selection and edits over one model; ``model`` is always the current one (a ModelSnapshot)."""

    model: object
    selected: np.ndarray = None
    hidden: np.ndarray = None
    index: np.ndarray = None  # for each current Gaussian, its row in the model the editor started from
    undo_stack: list[UndoEntry] = field(default_factory=list)
    redo_stack: list[UndoEntry] = field(default_factory=list)
    version: int = 0  # bumped by every change the view must show
    on_keep: object = None  # called with each keep-mask (and the structure it was made on): a running trainer
    structure_version: int = 0  # the trainer's structure the rows refer to, counting the keeps handed to it
    # what else an edit step carries, restored by undo with the model ("world": the scene's transform that the
    # measure and up tools set; "colour": colour_view's layers); values are never changed in place, only replaced
    extras: dict = field(default_factory=dict)
    _merge: object = None  # the gesture whose first change made the top undo step (set_extra's merge)


    def __post_init__(self) -> None:
        n = len(self.model)
        self.selected = np.zeros(n, bool) if self.selected is None else self.selected
        self.hidden = np.zeros(n, bool) if self.hidden is None else self.hidden
        self.index = np.arange(n) if self.index is None else self.index
        self.structure_version = getattr(self.model, "structure_version", 0)

    # ------------------------------------------------------------------ selection (undoable too)
    def select(self, picked: np.ndarray, mode: str = "set") -> None:
        self._push()
        self.selected = combine(self.selected, picked & ~self.hidden, mode)
        self.version += 1

    def select_all(self) -> None:
        self.select(~self.hidden, "set")

    def select_none(self) -> None:
        self.select(np.zeros_like(self.selected), "set")

    def invert(self) -> None:
        self.select(~self.selected & ~self.hidden, "set")

    # ------------------------------------------------------------------ edits
    def hide(self) -> None:
        self._push()
        self.hidden = self.hidden | self.selected
        self.selected = np.zeros_like(self.selected)
        self.version += 1

    def show_all(self) -> None:
        self._push()
        self.hidden = np.zeros_like(self.hidden)
        self.version += 1

    def delete(self) -> np.ndarray:
        """Remove the selected Gaussians; returns the keep-mask over the model before the edit."""
        return self.keep(~self.selected)

    def crop(self, lo, hi, inside: bool = True) -> np.ndarray:
        """Keep the Gaussians inside the box (or outside it); returns the keep-mask."""
        box = in_box(self.model.means, np.asarray(lo, float), np.asarray(hi, float))
        return self.keep(box if inside else ~box)

    def keep(self, keep: np.ndarray) -> np.ndarray:
        if self.on_keep is not None:
            # a running trainer cannot take Gaussians back: its edits are final, and the history starts here
            self.on_keep(keep, self.structure_version)
            self.structure_version += 1  # the trainer's keep changes its structure once
            self.undo_stack.clear()
            self.redo_stack.clear()
        else:
            self._push()
        self.model = subset(self.model, keep)
        self.selected = self.selected[keep]
        self.hidden = self.hidden[keep]
        self.index = self.index[keep]
        self.version += 1
        return keep

    def change(self, model, **extras) -> None:
        """Replace the model by one with the same Gaussians in the same order (moved, rescaled) and set
        ``extras``: one undoable step."""
        if len(model) != len(self.model):
            raise ValueError(f"a change must keep the {len(self.model)} Gaussians, got {len(model)}")
        self._push()
        self._merge = None
        self.model = model
        self.extras = {**self.extras, **extras}
        self.version += 1

    def set_extra(self, key: str, value, merge=None, was=None) -> None:
        """Another panel's edit (an immutable value) as an undo step. Changes carrying the same ``merge`` token one
        after another (a slider's drag) make one step: undo goes back to before the drag. ``was``: the value the
        step undoes to, when the editor did not hold it yet (a crop box dragged before it was ever recorded)."""
        if was is not None:
            self.extras = {**self.extras, key: was}
        if merge is None or merge != self._merge or not self.undo_stack:
            self._push()
            self._merge = merge
        self.extras = {**self.extras, key: value}
        self.version += 1

    def step(self, **changes) -> None:
        """One undo step that sets several of model, selected, hidden, index and extras at once (a move of rows
        from other files, a model joined to the scene)."""
        self._push()
        for name, value in changes.items():
            setattr(self, name, value)
        self.version += 1

    def forget_history(self) -> None:
        """The history starts here (a project was opened: its state is where undo stops)."""
        self.undo_stack.clear()
        self.redo_stack.clear()
        self._merge = None
        self.version += 1

    # ------------------------------------------------------------------ history
    def _state(self) -> UndoEntry:
        return UndoEntry(self.model, self.selected.copy(), self.hidden.copy(), self.index, dict(self.extras))

    def _restore(self, state: UndoEntry) -> None:
        self.model, self.selected, self.hidden, self.index = state.model, state.selected, state.hidden, state.index
        self.extras = dict(state.extras)
        self._merge = None
        self.version += 1

    def _push(self) -> None:
        self.undo_stack.append(self._state())
        self.redo_stack.clear()
        self._merge = None

    def undo(self) -> bool:
        if not self.undo_stack:
            return False
        self.redo_stack.append(self._state())
        self._restore(self.undo_stack.pop())
        return True

    def redo(self) -> bool:
        if not self.redo_stack:
            return False
        self.undo_stack.append(self._state())
        self._restore(self.redo_stack.pop())
        return True

    def flags(self) -> np.ndarray:
        """uint8 per Gaussian for the renderer: bit 0 selected (tinted), bit 1 hidden."""
        return (self.selected.astype(np.uint8) | (self.hidden.astype(np.uint8) << 1))

    @property
    def count(self) -> int:
        return len(self.model)


def subset(model, keep: np.ndarray):
    """The ModelSnapshot with only the Gaussians where ``keep``, as a new version of the geometry."""
    def take(a):
        out = np.ascontiguousarray(a[keep])
        out.setflags(write=False)
        return out

    return replace(model, version=model.version + 1_000_000, geometry_version=model.geometry_version + 1_000_000,
                   means=take(model.means), scales=take(model.scales), quats=take(model.quats),
                   opacities=take(model.opacities), sh=take(model.sh))
