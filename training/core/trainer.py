"""The one shape of everything a live session drives (``Trainer``: the reconstruction, the stylization and structure
from motion), and the commands a trainer takes between two of its steps (``Keep``, ``SetRegion``, ``UseModel``).

A trainer answers each command itself (``apply``), and refuses one it cannot carry out with a ValueError in one line
(a reconstruction has no region to stylize; structure from motion has no model to edit): whoever drives it asks
nothing about what it is.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

from training.core.messages import ModelSnapshot
from training.core.status import TrainerStatus


@dataclass(frozen=True)
class Keep:
    """Keep only the Gaussians where ``keep`` (N,) bool (a deletion or crop), if the trainer's Gaussians are still
    those of ``structure_version`` (the version the selection was made on; densification in between would shift the
    rows)."""

    keep: np.ndarray
    structure_version: int


@dataclass(frozen=True)
class SetRegion:
    """The Gaussians a running stylization changes from its next step on, (N,) bool over its rows (None: all)."""

    mask: np.ndarray | None


@dataclass(frozen=True)
class UseModel:
    """``use(gaussians, original_sh)`` with the trainer's model whole (detached, on the CPU) and, for a stylization,
    its input colours (N, K, 3) (else None); what ``use`` returns is the command's result."""

    use: Callable[[Any, Any], Any]


Command = Keep | SetRegion | UseModel


@runtime_checkable
class Trainer(Protocol):
    """What a live session drives. ``step()`` runs on one thread; ``status()``, ``snapshot()``, ``update_config()``
    and ``add_listener()`` may be called from any other; ``apply()`` runs on the stepping thread, between steps."""

    @property
    def total_iters(self) -> int: ...

    @property
    def done(self) -> bool: ...

    def step(self) -> Any: ...

    def status(self) -> TrainerStatus: ...

    def snapshot(self) -> ModelSnapshot | None: ...

    def update_config(self, **changes: Any) -> Any:
        """Take live settings from the next step on; ValueError (one line) for one it does not take."""

    def apply(self, command: Command) -> Any:
        """Carry out ``command`` now and return its result; ValueError (one line) when this trainer cannot."""

    def add_listener(self, listener: Callable) -> None: ...
