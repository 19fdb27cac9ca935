"""What a trainer and whoever drives it (the CLI's progress bar, the viewer's session) pass to each other.

Out of the trainer: ``TrainerEvent``s, one type for each thing that happens (``Stepped``, ``StructureChanged``,
``ViewMoved``, ``Scored``, ``Finished``, ``Warned``, ``Noted``), delivered to listeners registered with
``add_listener``; ``ModelSnapshot``s, consistent numpy copies of what a viewer draws, with version numbers; and
the ``TrainerStatus`` it publishes after each step (status.py).
Into the trainer: config changes (``update_config``), checked by ``checked_config_changes`` against the fields that
only construction may set. A long call that loops over views takes a ``cancel`` callable and raises ``Cancelled``
between views.

Threading contract: a trainer's ``step()`` runs on one thread; ``snapshot()``, ``status()``, ``update_config()``
and ``add_listener()`` may be called from any other. Listeners run on the trainer's thread and must not block.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field, fields, replace
from typing import Any, Callable

import numpy as np

from training.core import stop

@dataclass(frozen=True)
class TrainerEvent:
    """Something that happened in a trainer, matched by its type: ``stage`` names the trainer ("reconstruct",
    "stylize", or "sfm": structure from motion, whose work is no series of steps, so its ``Stepped`` events count the
    units of its current phase), ``step`` is its step count when it happened."""

    stage: str
    step: int


@dataclass(frozen=True)
class Stepped(TrainerEvent):
    """A step ended. ``metrics``: its scalar figures (timings flattened as ``times/name``; ``total_iters``, the
    schedule's length then); ``message``: SfM's phase in words."""

    metrics: dict[str, float] = field(default_factory=dict)
    message: str = ""


@dataclass(frozen=True)
class StructureChanged(TrainerEvent):
    """The number or geometry of the Gaussians changed (densification, pruning, a NaN restore, an edit; SfM: the
    sparse points grew): ``num_gaussians`` now, ``counts`` what changed (cloned, split, pruned)."""

    num_gaussians: int = 0
    counts: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class ViewMoved(TrainerEvent):
    """A stylizer moved to another view of its trajectory."""

    trajectory_position: int = 0
    view_index: int = 0
    virtual: bool = False


@dataclass(frozen=True)
class Scored(TrainerEvent):
    """The held-out views were scored during a run, by whoever drives it."""

    psnr: float | None = None
    ssim: float | None = None


@dataclass(frozen=True)
class Finished(TrainerEvent):
    """The schedule is done."""


@dataclass(frozen=True)
class Warned(TrainerEvent):
    """A warning, in one line."""

    message: str = ""


@dataclass(frozen=True)
class Noted(TrainerEvent):
    """A line for the user that is no warning (what the console prints)."""

    message: str = ""


Listener = Callable[[TrainerEvent], None]


class EventSource:
    """Listeners and the emit call, shared by both trainers."""

    def __init__(self, stage: str):
        self._stage = stage
        self._listeners: list[Listener] = []
        self._listeners_lock = threading.Lock()

    def add_listener(self, listener: Listener) -> None:
        with self._listeners_lock:
            self._listeners.append(listener)

    def remove_listener(self, listener: Listener) -> None:
        with self._listeners_lock:
            if listener in self._listeners:
                self._listeners.remove(listener)

    @property
    def stage(self) -> str:
        return self._stage

    def emit(self, kind: type[TrainerEvent], step: int, **fields_: Any) -> None:
        """Send a ``kind`` event of this source's stage at ``step`` to every listener (a Stepped's metrics reduced
        to plain numbers)."""
        if "metrics" in fields_:
            fields_["metrics"] = _scalars(fields_["metrics"] or {})
        if "counts" in fields_:
            fields_["counts"] = _scalars(fields_["counts"] or {})
        event = kind(self._stage, int(step), **fields_)
        with self._listeners_lock:
            listeners = list(self._listeners)
        for listener in listeners:
            listener(event)


def _scalars(metrics: dict[str, Any]) -> dict[str, float]:
    """The plain numbers of a metrics dict (nested timings flattened as ``times/name``)."""
    out: dict[str, float] = {}
    for key, value in metrics.items():
        if isinstance(value, dict):
            out.update({f"{key}/{k}": float(v) for k, v in value.items() if isinstance(v, (int, float))})
        elif isinstance(value, (bool, int, float)) and not isinstance(value, str):
            out[key] = float(value)
    return out


@dataclass(frozen=True)
class ModelSnapshot:
    """A consistent copy of a trainer's Gaussians, activated, as a renderer draws them (all float32, read-only).

    means (N, 3); scales (N, 3) standard deviations; quats (N, 4) unit, wxyz; opacities (N,); sh (N, K, 3) with
    K = (sh_degree + 1)^2, DC first. ``version`` changes whenever anything changed; ``geometry_version`` only when
    means, scales, quats, opacities or N changed, so a viewer whose geometry version is current re-uploads the
    colours alone. Two snapshots with equal ``version`` hold equal arrays (often the same objects)."""

    version: int
    geometry_version: int
    step: int
    means: np.ndarray
    scales: np.ndarray
    quats: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    sh_degree: int
    structure_version: int = 0  # changes when Gaussians are added, removed or reordered (a selection's rows move)

    def __len__(self) -> int:
        return int(self.means.shape[0])


def frozen_array(tensor) -> np.ndarray:
    """A float32 numpy copy of a torch tensor that nobody can write to."""
    array = np.array(tensor.detach().to("cpu", copy=False).float().numpy(), dtype=np.float32, copy=True)
    array.setflags(write=False)
    return array


class Cancelled(Exception):
    """A long call was cancelled between two of its units of work; nothing it would have changed was changed."""


def check_cancel(cancel: Callable[[], bool] | None) -> None:
    """Between two units of a long call: Cancelled when ``cancel()`` says so, StopRequested when the user asked to
    stop (training/core/stop.py)."""
    if cancel is not None and cancel():
        raise Cancelled()
    stop.check()


def checked_config_changes(config: Any, changes: dict[str, Any], fixed: tuple[str, ...], what: str) -> Any:
    """``config`` with ``changes`` applied (a new object), refusing unknown fields and those in ``fixed``
    (settable only when the trainer is built) with a ValueError that says which and why; the caller validates."""
    known = {f.name for f in fields(config)}
    unknown = sorted(set(changes) - known)
    if unknown:
        raise ValueError(f"the {what} has no setting {', '.join(unknown)}")
    frozen = sorted(name for name in changes if name in fixed and changes[name] != getattr(config, name))
    if frozen:
        raise ValueError(f"{', '.join(frozen)} can only be set before the {what} starts "
                         f"(start a new {what} to change {'it' if len(frozen) == 1 else 'them'})")
    return replace(config, **changes)
