"""Which view a stylization step renders, and how many steps the run makes (``config.schedule``).

"interleaved", the default and the paper's, takes the next view of the trajectory at every iteration (iteration t
renders trajectory position t mod N), so the guide map each iteration uses was built by the previous iteration on
the previous view (paper, Cross-view Matching Guidance: "the viewpoint of previous iteration"); the total,
``max(iters_per_view * N, min_total)``, is spread over passes along the trajectory. "block" stays on a view for
``iters_per_view`` iterations in a row before moving on. The counts read the config at call time: the viewer may
change ``iters_per_view`` mid-run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from training.scene.scene import Camera
from training.stylize.config import StylizeConfig, iteration_schedule
from training.stylize.view_order import scene_kind, view_order
from training.stylize.virtual_views import ViewItem, trajectory


@dataclass
class ViewSchedule:
    """The trajectory (scene views in order, virtual views between them) and the place on it."""

    trajectory: list[ViewItem]
    kind: str  # "forward" or "360": picks the paper's iteration counts
    order: list[int]  # scene camera indices in trajectory order
    num_cameras: int
    position: int = 0  # index into ``trajectory`` of the view the next step renders
    iters_on_view: int = 0  # steps made on it in a row (the block schedule)

    @classmethod
    def for_scene(cls, scene_cameras: list[Camera], cameras: list[Camera], config: StylizeConfig,
                  extent: float) -> ViewSchedule:
        """``scene_cameras`` as loaded (they pick the kind and the order), ``cameras`` at the render size."""
        order = view_order(scene_cameras, config.view_order, seed=config.seed, extent=extent)
        return cls(trajectory(cameras, order, config.virtual_views), scene_kind(scene_cameras, config.scene_kind),
                   order, len(scene_cameras))

    @property
    def current(self) -> ViewItem:
        return self.trajectory[self.position]

    def iters_per_view(self, config: StylizeConfig) -> int:
        return iteration_schedule(config, self.kind, self.num_cameras)[0]

    def total_iters(self, config: StylizeConfig) -> int:
        """Iterations of the whole schedule: every trajectory view ``iters_per_view`` times, at least the minimum."""
        per_view, min_total = iteration_schedule(config, self.kind, self.num_cameras)
        return max(per_view * len(self.trajectory), min_total)

    def iters_per_pass(self, config: StylizeConfig) -> int:
        """Iterations of one pass along the trajectory: one a view (interleaved) or ``iters_per_view`` a view."""
        per_view = 1 if config.schedule == "interleaved" else self.iters_per_view(config)
        return per_view * len(self.trajectory)

    def pass_progress(self, iteration: int, config: StylizeConfig) -> tuple[int, int]:
        """(pass, passes): the pass along the trajectory iteration ``iteration`` belongs to (1-based, at most
        ``passes``) and how many the schedule makes (the last one may stop part-way: the total need not be a whole
        number of passes)."""
        per_pass = self.iters_per_pass(config)
        passes = max(1, math.ceil(self.total_iters(config) / per_pass))
        return min(iteration // per_pass + 1, passes), passes

    def advance(self, config: StylizeConfig) -> bool:
        """Count a step made on the current view; True when the schedule moves on to the next view."""
        self.iters_on_view += 1
        if config.schedule != "interleaved" and self.iters_on_view < self.iters_per_view(config):
            return False
        self.iters_on_view = 0
        self.position = (self.position + 1) % len(self.trajectory)
        return True
