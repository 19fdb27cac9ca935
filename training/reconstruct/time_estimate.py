"""How long a run will take on this machine, said before it starts: from a few timed steps of the run itself.

The first steps' mean time is scaled by ``GROWTH``, the ratio of a whole quick-preset run's mean step time to its
first steps'. We expected densification (3k-9k Gaussians growing to the 60k cap) to make it well above 1, but at
the quick preset's ~400 px the per-pixel work dominates and the first steps, whose initial Gaussians are large and
cover many pixels, are as slow as the later ones: measured 0.96 (fern, SfM init), 0.70 (flower), 0.68 (fox, random
init) on the shared 2-core machine (docs/reconstruction.md). The estimate and the true time both go into
report.json so the ratio can be checked on other machines and presets.
"""

from __future__ import annotations

import time

WARMUP_STEPS = 2  # the first step compiles numba kernels and fills caches
TIMED_STEPS = 8
GROWTH = 0.8


def time_first_steps(trainer, timed: int = TIMED_STEPS, warmup: int = WARMUP_STEPS) -> float:
    """Run ``warmup + timed`` real training steps (they count toward the run) and return the mean seconds of the
    timed ones; 0.0 when the run is shorter than that."""
    if trainer.total_iters - trainer.step_count <= warmup + timed:
        return 0.0
    for _ in range(warmup):
        trainer.step()
    t = time.perf_counter()
    for _ in range(timed):
        trainer.step()
    return (time.perf_counter() - t) / timed


def estimate_seconds(seconds_per_step: float, remaining_steps: int, growth: float = GROWTH) -> float:
    return seconds_per_step * growth * max(0, remaining_steps)


def format_duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
