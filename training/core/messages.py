"""What a trainer and whoever drives it (the CLI's progress bar, the viewer's session) pass to each other.

Out of the trainer: ``TrainerEvent``s, one small typed form for both trainers, delivered to listeners registered
with ``add_listener``; ``ModelSnapshot``s, consistent numpy copies of what a viewer draws, with version numbers; and
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
from typing import Any, Callable, Literal

import numpy as np

EventKind = Literal["step", "structure", "view", "test", "finished", "warning", "info"]
EVENT_KINDS: tuple[str, ...] = ("step", "structure", "view", "test", "finished", "warning", "info")


@dataclass(frozen=True)
class TrainerEvent:
    """One thing that happened in a trainer.

    kind: "step" (``metrics`` holds the step's scalar metrics), "structure" (the number or geometry of the Gaussians
    changed: densification, pruning, a NaN restore, an edit; ``metrics["num_gaussians"]``), "view" (a stylizer moved
    to another view of its trajectory; ``metrics["trajectory_position"]``), "test" (the held-out views were scored
    during a run, by whoever drives it; ``metrics["test_psnr"]``, ``metrics["test_ssim"]``), "finished" (the
    schedule is done), "warning" (``message`` says what, in one line), "info" (a line for the user that is no
    warning: what the console prints). ``step`` is the trainer's step count when it happened; ``stage`` names the
    trainer ("reconstruct", "stylize", or "sfm": structure from motion, whose work is no series of steps, so its
    "step" events count the units of its current phase, ``metrics["total_iters"]`` of them, and say the phase in
    ``message``)."""

    kind: EventKind
    stage: str
    step: int
    metrics: dict[str, float] = field(default_factory=dict)
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

    def emit(self, kind: EventKind, step: int, metrics: dict[str, Any] | None = None, message: str = "") -> None:
        event = TrainerEvent(kind, self._stage, int(step), _scalars(metrics or {}), message)
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
    if cancel is not None and cancel():
        raise Cancelled()


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
