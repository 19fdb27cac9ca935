"""What a trainer says about itself to whoever shows it: one frozen ``TrainerStatus``, built by the trainer on its own
thread after each step (and after each change a caller made: a deletion, a loaded checkpoint) and swapped in whole,
so a reader on another thread (the viewer's panels, through the live session) sees one step's figures or the next
one's, never a mix, and never waits on a step.

Each stage has its status type (``ReconstructStatus``, ``StylizeStatus``, ``SfmStatus``): a reader matches on the
type for the figures only that stage has.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np


@dataclass(frozen=True)
class TrajectoryStop:
    """One view of a stylization's trajectory, in optimisation order: the dataset camera it comes from, where it
    is, and whether it is a virtual view made between dataset cameras."""

    source_index: int
    center: np.ndarray
    is_virtual: bool


@dataclass(frozen=True)
class TrainerStatus:
    """What every trainer says of itself. stage: "reconstruct", "stylize" or "sfm" (each has a status type of its
    own below). step/total: steps taken and the schedule's length (SfM: the units of its current phase). device:
    where it trains. num_gaussians and structure_version: the model's size and the version that changes when
    Gaussians are added, removed or reordered. config: the settings the next step uses (replaced whole on a change,
    never changed in place). editable: the model takes deletions and crops (``Keep``). losses: the last step's
    scalar losses."""

    stage: str
    step: int = 0
    total: int = 0
    device: str = ""
    num_gaussians: int = 0
    structure_version: int = 0
    config: Any = None
    editable: bool = False
    losses: Mapping[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class ReconstructStatus(TrainerStatus):
    """A reconstruction's: the common figures."""


@dataclass(frozen=True)
class StylizeStatus(TrainerStatus):
    """A stylization's: trajectory (its views in optimisation order), trajectory_position (index into it of the
    view the next step optimises), pass_progress (pass the next step belongs to, 1-based; passes), capacity ((h, w)
    column mass of the last transport plan on the painting's feature grid, read-only; None before the first plan),
    utilisation (the last plan's style-feature utilisation figures), gradient_balance (the last measured
    content/style gradient ratio: above 1 the scene leads), colour_only (only the colours are optimised: the
    geometry is the input's), original_sh (the input model's colours (N, K, 3) over the current rows, a tensor
    nobody writes: what style strength blends back), structure_drift and content_weight (the structure budget's
    averaged drift and the content weight the last step used)."""

    trajectory: tuple[TrajectoryStop, ...] = ()
    trajectory_position: int | None = None
    pass_progress: tuple[int, int] | None = None
    capacity: np.ndarray | None = None
    utilisation: Mapping[str, float] = field(default_factory=dict)
    gradient_balance: float | None = None
    colour_only: bool = False
    original_sh: Any = None
    structure_drift: float | None = None
    content_weight: float | None = None


@dataclass(frozen=True)
class SfmStatus(TrainerStatus):
    """Structure from motion's: cameras (the registered photos' cameras so far) and points (the sparse points so
    far)."""

    cameras: tuple = ()
    points: int = 0


def scalars(stats: Mapping[str, Any], keys: tuple[str, ...]) -> dict[str, float]:
    """The plain numbers among ``stats[keys]`` (a step's result holds tensors and dicts too)."""
    return {k: float(stats[k]) for k in keys
            if isinstance(stats.get(k), (int, float)) and not isinstance(stats[k], bool)}
