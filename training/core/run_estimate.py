"""How long a trainer's run will take: said early, said again when it moves, and kept for the report.

``RunEstimate`` is a listener on a trainer's events (training/core/messages.py). It times each step (the wall time
between two "step" events, so what the loop does besides the step, a checkpoint or a progress bar, counts too)
and asks a cost model what the remaining steps will cost:

- ``ready(step)``: whether the model has measured enough to say anything;
- ``observe(step, seconds, metrics)``: one finished step, with the event's metrics;
- ``seconds_left(step, total)``: the remaining steps' cost;
- ``basis()``: a few words on what the figure rests on, for the printed line;
- ``review(step)``: whether now is a moment to compare the estimate with the last one said (the model's own
  rhythm: after a densification, every few percent of the run).

The first estimate is said as soon as the model is ready; a later one only when it differs from the last one said
by more than ``REVISE_BY`` (20 %) of it, so a user sees the figure move when it matters and not at every step.
``record(actual)`` gives the report's entry: the first estimate, each revision, the actual time, and the machine's
load average (/proc/loadavg) at the start, at the first estimate and at the end, since other jobs on a shared
machine change step times by 2x or more.

``UniformSteps`` is the model for a run whose steps cost about the same throughout (a stylization: fixed Gaussians,
fixed render size): the mean of the latest steps times the steps left. The reconstruction's model, whose steps grow
with the Gaussians densification adds, is training/reconstruct/time_estimate.py.
"""

from __future__ import annotations

import os
import time
from collections import deque
from typing import Any, Callable, Protocol

from training.core.messages import Stepped

REVISE_BY = 0.2


class CostModel(Protocol):
    def ready(self, step: int) -> bool: ...

    def observe(self, step: int, seconds: float, metrics: dict[str, float]) -> None: ...

    def seconds_left(self, step: int, total: int) -> float: ...

    def basis(self) -> str: ...

    def review(self, step: int) -> bool: ...


def load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (None where the system has none)."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def format_duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 600:  # to the second: a 20 % revision of a short run must not read "2 min, was 2 min"
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


class RunEstimate:
    """A listener (``trainer.add_listener(estimate)``) that says the run's estimated time through ``say`` (one line
    each); ``what`` names the work in those lines. Call ``begin()`` just before the loop's first step."""

    def __init__(self, model: CostModel, say: Callable[[str], None], what: str = "training",
                 revise_by: float = REVISE_BY, clock: Callable[[], float] = time.perf_counter):
        self.model, self.say, self.what, self.revise_by, self.clock = model, say, what, revise_by, clock
        self.t_begin: float | None = None
        self.step_begin = 0
        self._t_last: float | None = None
        self.first: dict[str, Any] | None = None
        self.revisions: list[dict[str, Any]] = []
        self.looks: list[dict[str, Any]] = []  # every estimate made, said or not
        self.said_total: float | None = None
        self.load_at_begin: list[float] | None = None

    def begin(self, step: int = 0) -> None:
        """The loop starts now, at ``step`` steps done (a resumed run's count)."""
        self.t_begin = self._t_last = self.clock()
        self.step_begin = int(step)
        self.load_at_begin = load_average()

    def __call__(self, event) -> None:
        if not isinstance(event, Stepped) or event.metrics.get("recovered"):
            return
        now = self.clock()
        if self.t_begin is None:
            self.begin(event.step - 1)
        seconds = now - self._t_last
        step, total = event.step, int(event.metrics.get("total_iters", 0)) or event.step
        try:
            self._estimate(step, total, seconds, event.metrics)
        finally:
            # what the model did here (a probe of later steps' cost) is time the run spent, but no step's
            self._t_last = self.clock()

    def _estimate(self, step: int, total: int, seconds: float, metrics: dict[str, float]) -> None:
        self.model.observe(step, seconds, metrics)
        if step >= total or not self.model.ready(step):
            return
        now = self.clock()
        if self.first is not None and not self.model.review(step):
            return
        elapsed = now - self.t_begin
        left = self.model.seconds_left(step, total)
        estimate = {"step": step, "total_s": elapsed + left, "left_s": left, "elapsed_s": elapsed,
                    "basis": self.model.basis()}
        load = load_average()
        self.looks.append({"iteration": step, "elapsed_s": round(elapsed, 2), "estimate_s": round(elapsed + left, 2),
                           "load_1min": load[0] if load else None, "basis": estimate["basis"]})
        if self.first is None:
            self.first = {**estimate, "load_average": load_average()}
            self.said_total = estimate["total_s"]
            self.say(f"estimated {self.what} time: about {format_duration(estimate['total_s'])} on this machine for "
                     f"{total - self.step_begin} iterations ({estimate['basis']}; other jobs on the machine make "
                     f"it longer)")
        elif abs(estimate["total_s"] - self.said_total) > self.revise_by * self.said_total:
            self.revisions.append(estimate)
            self.say(f"revised estimate at iteration {step}: about {format_duration(estimate['total_s'])} in all, "
                     f"{format_duration(left)} left ({estimate['basis']}; was "
                     f"{format_duration(self.said_total)})")
            self.said_total = estimate["total_s"]

    def not_a_step(self) -> None:
        """What the loop did since the last step (scoring test views) is not a step's time: the next step is timed
        from now."""
        if self._t_last is not None:
            self._t_last = self.clock()

    def record(self, actual_s: float | None = None) -> dict[str, Any]:
        """The report's entry: first estimate, revisions, actual seconds of the loop (from its start to the last
        step seen, unless given) and load averages."""
        if actual_s is None and self.t_begin is not None:
            actual_s = self._t_last - self.t_begin
        first = self.first or {}
        out: dict[str, Any] = {
            "from_iteration": self.step_begin,
            "first_estimate_s": first.get("total_s"),
            "first_estimate_at_iteration": first.get("step"),
            "first_estimate_basis": first.get("basis"),
            "revisions": [{"iteration": r["step"], "estimate_s": r["total_s"], "basis": r["basis"]}
                          for r in self.revisions],
            "looks": self.looks,
            "actual_s": actual_s,
            "actual_over_first_estimate": (actual_s / first["total_s"]
                                           if actual_s and first.get("total_s") else None),
            "load_average_1_5_15": {"at_start": self.load_at_begin, "at_first_estimate": first.get("load_average"),
                                    "at_end": load_average()},
        }
        return out


class UniformSteps:
    """Every step costs about the same: ``warmup`` steps are not timed (the first one fills caches and compiles),
    then the estimate is the mean of the latest ``window`` steps (at least ``timed`` of them) times the steps left,
    reviewed every ``review_every`` steps."""

    def __init__(self, warmup: int = 2, timed: int = 8, window: int = 50, review_every: int = 25):
        self.warmup, self.timed, self.review_every = warmup, timed, review_every
        self.times: deque[float] = deque(maxlen=max(window, timed))
        self.seen = 0

    def observe(self, step: int, seconds: float, metrics: dict[str, float]) -> None:
        self.seen += 1
        if self.seen > self.warmup:
            self.times.append(seconds)

    def ready(self, step: int) -> bool:
        return len(self.times) >= self.timed

    def per_step(self) -> float:
        return sum(self.times) / len(self.times)

    def seconds_left(self, step: int, total: int) -> float:
        return self.per_step() * max(0, total - step)

    def basis(self) -> str:
        return f"{len(self.times)} timed steps at {1000 * self.per_step():.0f} ms each"

    def review(self, step: int) -> bool:
        return self.seen % self.review_every == 0
