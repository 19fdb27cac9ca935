"""A stylization's checkpoint, OUT/stylize_checkpoint.pt: the Stylizer's state (``trainer_state``, read back by
``restore_trainer``: what ``Stylizer.state_dict``/``load_state`` give and take), what the pipeline had measured before
the loop, and the fingerprint of the inputs (training/scene/fingerprint.py), in the
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

from typing import TYPE_CHECKING

from training.core.checkpoint import load_checkpoint, save_checkpoint
from training.core.errors import InputError
from training.scene.fingerprint import dataset_fingerprint, file_sha256, make_fingerprint
from training.stylize.color_transfer import ColorTransform
from training.stylize.config import FIXED_AT_START, StylizeConfig
from training.stylize.optimizer import GEOMETRY
from training.stylize.plan_readouts import StepAgreement
from training.stylize.structure_budget import StructureBudget

if TYPE_CHECKING:
    from training.stylize.trainer import Stylizer

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


def trainer_state(stylizer: Stylizer) -> dict[str, Any]:
    """What a resumed run needs beyond its inputs: the place in the schedule, the colours (and under "all" the
    geometry), the optimiser's moments, the CCFT guide carried from step to step, the losses so far, and whether the
    post colour transfer was applied. Tensors on the CPU; plain values otherwise. The caller holds the model lock."""
    g = stylizer.gaussians.detached().to("cpu")
    loss, post = stylizer.style_loss, stylizer.post_transform
    guide = getattr(loss, "guide", None)
    names = ("sh0", "shN") + (GEOMETRY if stylizer.model.trains_geometry else ())
    return {
        "iteration": stylizer.iteration, "position": stylizer.views.position,
        "iters_on_view": stylizer.views.iters_on_view, "num_gaussians": len(g),
        "model": {k: getattr(g, k) for k in names},
        "optimizer": None if stylizer.optimizer is None else stylizer.optimizer.state_dict(),
        "dc_only": stylizer.optimizer_dc_only, "loss": None if loss is None else loss.name,
        "guide": None if guide is None else guide.detach().to("cpu"),
        "guide_source": getattr(loss, "guide_source", None),
        "agreements": list(stylizer.agreement.values),
        "budget": stylizer.budget.state(),
        "history": [dict(h) for h in stylizer.history],
        "last_stats": {k: v for k, v in stylizer.last_stats.items() if isinstance(v, (bool, int, float, str))},
        "finished": stylizer.finished,
        "post_transform": None if post is None else post.to_dict(),
        "times": dict(stylizer.times.totals),
    }


def restore_trainer(stylizer: Stylizer, state: dict[str, Any]) -> None:
    """Put ``trainer_state``'s ``state`` back into a Stylizer built on the same inputs; its live settings (loss,
    weights, learning rate) stay its config's. InputError when the model differs. The caller holds the model lock."""
    g = stylizer.gaussians
    if int(state["num_gaussians"]) != len(g):
        raise InputError(stylizer.model_name, f"the checkpoint holds {state['num_gaussians']} Gaussians, this "
                                              f"model {len(g)}")
    for name, value in state["model"].items():
        setattr(g, name, value.to(stylizer.device, getattr(g, name).dtype))
    stylizer.iteration = int(state["iteration"])
    stylizer.views.position, stylizer.views.iters_on_view = int(state["position"]), int(state["iters_on_view"])
    stylizer.finished = bool(state["finished"])
    if state["post_transform"] is not None:
        t = state["post_transform"]
        stylizer.post_transform = ColorTransform(np.asarray(t["A"], dtype=np.float64),
                                                 np.asarray(t["b"], dtype=np.float64))
    stylizer.optimizer = None
    stylizer.history = [dict(h) for h in state["history"]]
    stylizer.last_stats = dict(state["last_stats"])
    for name, seconds in state["times"].items():
        stylizer.times.add(name, float(seconds))
    if state["loss"] is not None:
        from training.stylize.style_losses import make_style_loss

        stylizer.style_loss = make_style_loss(state["loss"])
        if state["guide"] is not None and hasattr(stylizer.style_loss, "guide"):
            stylizer.style_loss.guide = state["guide"].to(stylizer.device)
            stylizer.style_loss.guide_source = state.get("guide_source")
    stylizer.agreement = StepAgreement([float(a) for a in state.get("agreements", [])])
    stylizer.budget = StructureBudget.from_state(state.get("budget"))
    if state["optimizer"] is not None and state["dc_only"] == stylizer.config.dc_only:
        stylizer.restart_optimizer()
        saved = [group.get("name") for group in state["optimizer"]["param_groups"]]
        if saved == [group["name"] for group in stylizer.optimizer.param_groups]:
            stylizer.optimizer.load_state_dict(state["optimizer"])
