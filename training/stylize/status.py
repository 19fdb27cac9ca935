"""What a stylization publishes about itself after each step (training/core/status.py): its trajectory and where
on it the next step is, the pass, the last plan's capacity map and utilisation, the losses and the balance of the
content and style gradients."""

from __future__ import annotations

from training.core.status import StylizeStatus, TrajectoryStop, scalars
from training.stylize.terms import LOSS_KEYS

LOSSES = LOSS_KEYS + ("grad_style", "grad_content")
UTILISATION = ("utilisation", "column_entropy", "column_entropy_normalised", "reachable_fraction",
               "distinct_fraction", "distinct_count")


def stylize_status(stylizer) -> StylizeStatus:
    """The status of ``stylizer`` now (a ``Stylizer``; called with its model lock held)."""
    stats = stylizer.last_stats
    # the trajectory is fixed when the run starts: the stops are made once
    last = stylizer.status()
    stops = (last.trajectory if isinstance(last, StylizeStatus) and last.trajectory else
             tuple(TrajectoryStop(item.source_index, item.camera.center, item.is_virtual)
                   for item in stylizer.trajectory))
    # the last measured balance (measured every balance_every steps)
    measured = (h for h in reversed(stylizer.history) if h["grad_style"] and h["grad_content"] is not None)
    balance = next(measured, None) if stylizer.config.measure_balance else None
    return StylizeStatus(
        "stylize", stylizer.iteration, stylizer.total_iters, str(stylizer.device), len(stylizer.gaussians),
        stylizer.structure_version, stylizer.config, editable=True, losses=scalars(stats, LOSSES),
        trajectory=stops, trajectory_position=stylizer.trajectory_position,
        pass_progress=stylizer.pass_progress(), capacity=stylizer.capacity,
        utilisation=scalars(stats, UTILISATION),
        gradient_balance=None if balance is None else balance["grad_content"] / balance["grad_style"],
        colour_only=stylizer.config.params == "colour", original_sh=stylizer.original_sh,
        structure_drift=stylizer.budget.drift, content_weight=stats.get("content_weight"))
