"""A stylization's checkpoint, OUT/stylize_checkpoint.pt: the Stylizer's ``state_dict()``, what the pipeline had
measured before the loop, and the fingerprint of the inputs (training/scene/fingerprint.py), in the
trainers' checkpoint file (training/core/checkpoint.py: atomic, ``weights_only`` loading).

The fingerprint holds the dataset, the model file's and the painting's sha256, the selection, and the settings the
Stylizer fixes when it is built (``FIXED_AT_START``: which views, their order, the render size, the colour
transfer, which parameters move) less the device: the same run may go on on another device. The live settings
(the loss and its parameters, the weights, the learning rate, iterations per view) are not in it: the viewer's
sliders change them mid-run, and a resumed run may go on with others just as legitimately.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from training.core.checkpoint import load_checkpoint, save_checkpoint
from training.core.errors import InputError
from training.scene.fingerprint import dataset_fingerprint, file_sha256, make_fingerprint
from training.stylize.trainer import FIXED_AT_START, StylizeConfig, Stylizer

CHECKPOINT_NAME = "stylize_checkpoint.pt"
KIND = "stylize"
NOT_FINGERPRINTED = ("device",)


def fingerprint_settings(config: StylizeConfig) -> dict[str, Any]:
    return {k: getattr(config, k) for k in FIXED_AT_START if k not in NOT_FINGERPRINTED}


def stylize_fingerprint(model: str | Path, data: str | Path, style: str | Path, config: StylizeConfig,
                        mask=None) -> dict[str, Any]:
    """The fingerprint of a stylization of ``model`` (a PLY) after ``style`` on the scene ``data``."""
    selection = "all" if mask is None else hashlib.sha256(np.packbits(np.asarray(mask, dtype=bool))).hexdigest()[:16]
    return make_fingerprint(dataset=dataset_fingerprint(data), model=file_sha256(model),
                            painting=file_sha256(style), selection=selection,
                            settings=fingerprint_settings(config))


def save_stylize_checkpoint(path: str | Path, stylizer: Stylizer, fingerprint: dict[str, Any],
                            pipeline: dict[str, Any] | None = None) -> None:
    """Write the stylizer's state, ``fingerprint`` and the ``pipeline``'s own values (plain) atomically."""
    save_checkpoint(path, {"kind": KIND, "trainer": stylizer.state_dict(), "fingerprint": fingerprint,
                           "pipeline": dict(pipeline or {})})


def load_stylize_checkpoint(path: str | Path) -> dict[str, Any]:
    """{"trainer", "fingerprint", "pipeline"}; InputError when missing, unreadable or not a stylization's."""
    state = load_checkpoint(path)
    if state.get("kind") != KIND:
        raise InputError(path, "not a stylization's checkpoint")
    return state
