"""What is read off each step's CCFT plan as the run goes: the capacity map (where on the painting the plan put
its mass, drawn by the viewer) and the step-to-step match agreement (what cross-view guidance acts on, averaged
for the report).
"""

from __future__ import annotations

import numpy as np
import torch

from training.scene.correspondence import MIN_CELLS, cell_correspondence, label_agreement
from training.scene.scene import Camera


def capacity_map(result, grid: tuple[int, int]) -> np.ndarray | None:
    """(h, w) float32: the column mass of a CCFT ``result``'s plan at each style feature's place on the painting's
    feature grid ``grid`` (sums to about 1); None for a loss without one."""
    if result is None or getattr(result, "column_mass", None) is None:
        return None
    return result.column_mass.detach().to("cpu", torch.float32).numpy().reshape(grid)


class StepAgreement:
    """Match agreement of each step's plan with the previous step's, where the previous step rendered another
    view: the share of this view's feature cells that see what a cell of the previous view saw (depth warp,
    training/scene/correspondence.py) and whose largest plan entry is the same style feature there."""

    def __init__(self, values: list[float] | None = None):
        self.values = list(values or [])  # one a step that changed view and had enough shared cells
        self._previous = None  # (position, camera, labels, depth, alpha) of the last step

    def update(self, result, cells: tuple[int, int], position: int, camera: Camera, depth: torch.Tensor,
               alpha: torch.Tensor) -> float | None:
        """This step's agreement (None: no CCFT plan, the same view as before, or too few shared cells)."""
        if result is None or getattr(result, "plan", None) is None:
            self._previous = None
            return None
        plan = result.plan
        labels = plan.indices.gather(1, plan.values.argmax(dim=1, keepdim=True))[:, 0].reshape(cells).cpu()
        previous, self._previous = self._previous, (position, camera, labels, depth, alpha)
        if previous is None or previous[0] == position:
            return None
        _, p_camera, p_labels, p_depth, p_alpha = previous
        landing, valid = cell_correspondence(depth, alpha, camera, cells, p_depth, p_alpha, p_camera,
                                             tuple(p_labels.shape))
        same, n = label_agreement(labels, p_labels, landing, valid)
        if n < MIN_CELLS:
            return None
        self.values.append(same / n)
        return same / n

    def mean(self) -> float | None:
        """Mean over the steps so far (those that measured one); None before any."""
        return float(np.mean(self.values)) if self.values else None
