"""What makes a trainer drivable from another thread, shared by both trainers: the model lock, config changes
applied at the next step, versions, snapshots, the published status and events (the message types are in
``messages``, the status in ``status``).

A trainer mixes ``LiveTrainer`` in, calls ``_init_live(config_name, stage)`` in its constructor, takes
``self._model_lock`` around every write to its model's tensors (bumping ``_version``, and ``_geometry_version``
when means, scales, rotations, opacities or the count change), calls ``_take_pending_config()`` at the start of
each step and ``_publish_status()`` at its end (before its events: a listener reading the status sees the step's),
and after every change a caller makes to it, and provides ``_snapshot_geometry()``, ``_snapshot_colours()`` and
``_build_status()``.

``update_config`` is the one way live settings reach a trainer, whoever sends them (the viewer's sliders through
the live session, a test, a script).
"""

from __future__ import annotations

import threading
from typing import Any

import torch

from training.core.messages import EventSource, ModelSnapshot, checked_config_changes, frozen_array
from training.core.status import TrainerStatus
from training.core.trainer import Keep, SetRegion, UseModel


class LiveTrainer:
    FIXED_AT_START: tuple[str, ...] = ()  # config fields only construction may set

    def _init_live(self, what: str, stage: str) -> None:
        self._what = what
        self._model_lock = threading.Lock()
        self._pending_config = None
        self._version = 0
        self._geometry_version = 0
        self._structure_version = 0
        self._last_snapshot: ModelSnapshot | None = None
        self.events = EventSource(stage)
        self._published = TrainerStatus(stage)

    def add_listener(self, listener) -> None:
        self.events.add_listener(listener)

    def remove_listener(self, listener) -> None:
        self.events.remove_listener(listener)

    # ------------------------------------------------------------------ status
    def status(self) -> TrainerStatus:
        """Where the trainer is, as its last step (or the last change made to it) left it; any thread, never
        waits."""
        return self._published

    def _publish_status(self, locked: bool = False) -> None:
        """Build the status and swap it in (``locked``: the caller holds the model lock already)."""
        if locked:
            self._published = self._build_status()
            return
        with self._model_lock:
            self._published = self._build_status()

    def _build_status(self) -> TrainerStatus:
        """The status now; called with the lock held."""
        raise NotImplementedError

    # ------------------------------------------------------------------ commands (training/core/trainer.py)
    def apply(self, command):
        """Carry out ``command`` now (the caller runs it between two steps) and return its result; ValueError in
        one line when this trainer cannot."""
        if isinstance(command, Keep):
            if self.structure_version != command.structure_version:
                raise ValueError("the trainer changed its Gaussians since the selection was made: select again")
            return self.keep(command.keep)
        if isinstance(command, SetRegion):
            return self.set_region(command.mask)
        if isinstance(command, UseModel):
            return command.use(self.whole_model(), self.input_colours())
        raise TypeError(f"not a command for a trainer: {command!r}")

    def keep(self, keep) -> None:
        """Keep only the Gaussians where ``keep`` (N,) bool."""
        raise NotImplementedError

    def set_region(self, mask) -> None:
        """The Gaussians the next steps change ((N,) bool, None: all); a trainer that has no such region refuses."""
        raise ValueError(f"the {self._published.stage} stage has no region to stylize")

    def whole_model(self):
        """The model whole: Gaussians detached, on the CPU."""
        raise NotImplementedError

    def input_colours(self):
        """The colours the run started from (N, K, 3) on the CPU, where it keeps them (a stylization); else None."""
        return None

    # ------------------------------------------------------------------ config
    def update_config(self, **changes: Any):
        """Validate ``changes`` now (ValueError naming the setting, or a setting only construction may set) and
        apply them at the start of the next step; any thread. Returns the config the next step will use."""
        with self._model_lock:
            new = checked_config_changes(self._pending_config or self.config, changes, self.FIXED_AT_START,
                                         self._what)
            new.validate()
            self._pending_config = new
        return new

    def _take_pending_config(self) -> None:
        with self._model_lock:
            if self._pending_config is not None:
                self.config, self._pending_config = self._pending_config, None

    @property
    def structure_version(self) -> int:
        """Bumped whenever Gaussians are added, removed or reordered: rows of an older snapshot no longer match."""
        return self._structure_version

    def _model_changed(self, geometry: bool = False) -> None:
        """Call with the lock held after writing the model's tensors (``geometry``: means, scales, rotations or
        opacities among them): the next snapshot is a new one."""
        self._version += 1
        if geometry:
            self._geometry_version += 1

    def _structure_changed(self) -> None:
        """Call with the lock held, in the same hold as the change: a snapshot never pairs new Gaussians with an
        old structure version."""
        self._structure_version += 1
        self._version += 1  # the next snapshot is a new one, whatever the change's own bookkeeping did

    # ------------------------------------------------------------------ snapshots
    def _snapshot_step(self) -> int:
        raise NotImplementedError

    def _snapshot_geometry(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(means, scales, unit quats, opacities), activated; called with the lock held."""
        raise NotImplementedError

    def _snapshot_colours(self) -> tuple[torch.Tensor, int]:
        """(SH coefficients (N, K, 3), degree); called with the lock held."""
        raise NotImplementedError

    def snapshot(self) -> ModelSnapshot:
        """A consistent copy of the model as a renderer draws it (activated, float32, read-only); any thread.
        When only the colours changed since the last snapshot, the geometry's arrays are that snapshot's."""
        with self._model_lock:
            last = self._last_snapshot
            if last is not None and last.version == self._version:
                return last
            with torch.no_grad():
                if last is not None and last.geometry_version == self._geometry_version:
                    geometry = (last.means, last.scales, last.quats, last.opacities)
                else:
                    geometry = tuple(frozen_array(t) for t in self._snapshot_geometry())
                sh, degree = self._snapshot_colours()
                snap = ModelSnapshot(self._version, self._geometry_version, self._snapshot_step(), *geometry,
                                     frozen_array(sh), degree, self._structure_version)
            self._last_snapshot = snap
            return snap
