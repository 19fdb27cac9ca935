"""The reconstruction's checkpoint, OUT/checkpoint.pt: the Reconstructor's ``state_dict()`` (model, optimizer, step,
config, RNG) and what the reconstruct command keeps beside it, in the trainers' checkpoint file
(training/core/checkpoint.py: atomic, ``weights_only`` loading)."""

from __future__ import annotations

from training.core.checkpoint import load_checkpoint, save_checkpoint

CHECKPOINT_NAME = "checkpoint.pt"

__all__ = ["CHECKPOINT_NAME", "load_checkpoint", "save_checkpoint"]
