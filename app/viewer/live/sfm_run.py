"""Structure from motion as the live session runs a trainer: `splatstyler sfm`'s ``run_sfm``, with its settings
(app/settings/sfm.py), in
one long step on the session's thread (COLMAP releases the GIL, so the window stays live), reporting as it goes.

Out of it, as out of the other stages' trainers: "step" events whose step counts the current phase's units (photos
prepared, photos whose features are extracted, pairs matched, photos registered) of ``metrics["total_iters"]``,
the phase in words in ``message``, and ``metrics["seconds_left"]``, the phase's time left at its rate so far (-1
before it has one); "structure" events when the mapper's model grew; "info" events with the lines the console
prints. ``snapshot()`` is the sparse points as small round Gaussians (what the view draws) and ``status()``
(training/core/status.py) holds the phase's progress and the registered photos' cameras (the view's frustums), both
as the mapper held them at its last registration.

The session's Stop (window close, Ctrl+Q, SIGTERM) reaches ``run_sfm`` through the stop the session's thread
watches (training/core/stop.py): within a fraction of a second during feature extraction and matching and at the
next registration while mapping; ``run_sfm`` then leaves no folder behind and the step ends with StopRequested.
It takes no settings and no commands while it runs (``update_config`` and ``apply`` refuse them in one line).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from training.core.messages import EventSource, Finished, ModelSnapshot, Noted, Stepped, StructureChanged
from training.core.status import SfmStatus
from training.model.sh_constants import SH_C0
from training.scene.sfm import SfmProgress

# A sparse point is drawn as a Gaussian this many times the points' spread (their median distance to their median):
# a dot of a few pixels at the distances the view starts from
POINT_SIZE = 0.004


class SfmRun(EventSource):
    """``run_sfm(photos, out, **options)`` as a session's trainer (see the module docstring); ``options``: run_sfm's
    settings as app/settings/sfm.py gives them."""

    def __init__(self, photos: Path, out: Path, options: dict):
        super().__init__("sfm")
        self.photos, self.out, self.config = Path(photos), Path(out), dict(options)
        self.total_iters = 1
        self.step_count = 0
        self.done = False
        self.result = None  # training.scene.sfm.SfmResult once done
        self._lock = threading.Lock()
        self._cameras: tuple = ()
        self._points = np.zeros((0, 3), np.float32)
        self._colors = np.zeros((0, 3), np.uint8)
        self._version = 0
        # the view keeps a model by its version: ours must not meet one another model in its slot had
        self._version_base = int(time.time() * 1000) % 1_000_000_000
        self._registered = 0
        self._snapshot: ModelSnapshot | None = None
        self._phase: tuple[str, str] = ("", "")  # (phase, attempt) the timing below is of
        self._phase_began = (0.0, 0)  # (time, units done) when it began
        self._published = SfmStatus("sfm", 0, 1, "cpu")

    # ------------------------------------------------------------------ the session's side
    def step(self) -> None:
        """The whole run. A stop (the session's, which run_sfm sees through training/core/stop.py) ends it with
        StopRequested and nothing written."""
        from training.scene.sfm import run_sfm

        self.result = run_sfm(self.photos, self.out, log=self._log, progress=False, progress_to=self._progress,
                              partial_hint="`splatstyler sfm --allow-partial` keeps such a model", **self.config)
        self.step_count = 1
        self.done = True
        self.emit(Finished, 1)

    def update_config(self, **changes) -> None:
        raise ValueError("the sfm stage takes no settings while it runs")

    def apply(self, command) -> None:
        raise ValueError("structure from motion has no model to edit or use yet: wait for the reconstruction")

    def snapshot(self) -> ModelSnapshot | None:
        """The sparse points at the last registration read, as Gaussians (None before the first)."""
        with self._lock:
            if self._version == 0:
                return None
            if self._snapshot is None or self._snapshot.version != self._version_base + self._version:
                self._snapshot = points_snapshot(self._points, self._colors, self._version_base + self._version,
                                                 self._registered)
            return self._snapshot

    def status(self) -> SfmStatus:
        """The current phase's progress, the points so far and the registered cameras; any thread."""
        return self._published

    # ------------------------------------------------------------------ run_sfm's side (its thread or COLMAP's)
    def _log(self, line: str) -> None:
        if line.strip():
            self.emit(Noted, self.step_count, message=line.strip())

    def _progress(self, p: SfmProgress) -> None:
        now = time.perf_counter()
        if (p.phase, p.attempt) != self._phase:
            self._phase, self._phase_began = (p.phase, p.attempt), (now, p.done)
        began, done_then = self._phase_began
        left = -1.0
        if p.done > done_then:
            left = (now - began) / (p.done - done_then) * (p.total - p.done)
        grew = p.cameras is not None or p.points is not None
        with self._lock:
            if p.cameras is not None:
                self._cameras = tuple(p.cameras)
                self._registered = p.done
            if p.points is not None:
                self._points, self._colors = p.points, p.colors
            if grew:
                self._version += 1
            points = len(self._points)
            self._published = SfmStatus("sfm", p.done, p.total, "cpu", points, self._version, self.config,
                                        cameras=self._cameras, points=points)
        metrics = {"total_iters": p.total, "seconds_left": left}
        if p.phase == "mapping":
            metrics.update(registered=p.done, points=points)
        line = p.line() + (f", {points:,} points ({p.attempt})" if p.phase == "mapping" else "")
        self.emit(Stepped, p.done, metrics=metrics, message=line)
        if grew:
            self.emit(StructureChanged, p.done, num_gaussians=points)


def phase_time_left(seconds: float) -> str:
    """The status line's words for an SfM phase's time left."""
    from training.core.run_estimate import format_duration

    return f"about {format_duration(seconds)} left in this phase"


def points_snapshot(points: np.ndarray, colors: np.ndarray, version: int, step: int) -> ModelSnapshot:
    """SfM points (P, 3) with their colours (P, 3) uint8 as opaque round Gaussians, POINT_SIZE of their spread."""
    means = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
    n = len(means)
    spread = float(np.median(np.linalg.norm(means - np.median(means, axis=0), axis=1))) if n else 1.0
    size = POINT_SIZE * (spread if spread > 0 else 1.0)
    quats = np.zeros((n, 4), np.float32)
    quats[:, 0] = 1.0
    sh = ((np.asarray(colors, np.float32).reshape(-1, 3) / 255.0 - 0.5) / SH_C0)[:, None, :]
    arrays = [means, np.full((n, 3), size, np.float32), quats, np.ones(n, np.float32), sh.astype(np.float32)]
    for a in arrays:
        a.setflags(write=False)
    return ModelSnapshot(version, version, step, *arrays, sh_degree=0, structure_version=version)
