"""The training resolution: presets name a target long side, the 3DGS tools' cache wants a whole factor.

A fixed factor suits one capture size only (factor 8 trained a 1000 px capture at 125x82 pixels and the 1920 px
fox at 135x240), so presets give ``max_side`` instead and the factor is the smallest whole N that brings the
longest image side to at most ``max_side``: the images still come from the ``images_N`` cache the 3DGS tools share.
``max_side=None`` (the paper preset, or ``--downscale N``) uses ``downscale`` as given.
"""

from __future__ import annotations

import math
from pathlib import Path


def downscale_for_long_side(long_side: int, max_side: int | None, downscale: int) -> int:
    """The whole factor N with ceil(long_side / N) <= max_side, smallest such; ``downscale`` when max_side is None."""
    if max_side is None:
        return int(downscale)
    return max(1, math.ceil(long_side / max(1, int(max_side))))


def full_long_side(data: str | Path) -> int:
    """The longest side of the scene's full-resolution images, read from headers only (nothing is decoded)."""
    from training.core.errors import InputError
    from training.scene.loader import load_scene

    cams = load_scene(data, downscale=1, load_images=False).cameras
    if not cams:
        raise InputError(data, "the scene has no cameras")
    return max(max(c.width, c.height) for c in cams)


def training_downscale(data: str | Path, max_side: int | None, downscale: int) -> int:
    """The factor to load ``data`` with for a run whose config holds ``max_side`` and ``downscale``."""
    if max_side is None:
        return int(downscale)
    return downscale_for_long_side(full_long_side(data), max_side, downscale)
