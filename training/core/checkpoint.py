"""The trainers' checkpoint file: one file holding a plain state (a trainer's ``state_dict()`` and what its caller
keeps beside it), the reconstruction's OUT/checkpoint.pt and the stylization's OUT/stylize_checkpoint.pt alike.

Written atomically (a crash or Ctrl-C while saving leaves the previous checkpoint intact) and read back with
``torch.load(weights_only=True)``, so a checkpoint can hold tensors, numbers, strings, lists and dicts only and
loading one never runs code.
"""

from __future__ import annotations

from pathlib import Path

import torch

from training.core.atomic_write import atomic_path
from training.core.errors import InputError

FORMAT = "splatstyler-checkpoint"
VERSION = 1


def save_checkpoint(path: str | Path, state: dict) -> None:
    """Write ``state`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        torch.save({"format": FORMAT, "version": VERSION, "state": state}, tmp)


def load_checkpoint(path: str | Path, mmap: bool = False) -> dict:
    """The state saved by :func:`save_checkpoint`; InputError when the file is missing or not a checkpoint.
    ``mmap``: the tensors are mapped, not read (for a look at its step and settings)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "no checkpoint here (nothing to resume; run without --resume to start fresh)")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True, mmap=mmap)
    except Exception as exc:  # truncated, foreign or tampered files all surface differently from torch
        raise InputError(path, f"not a readable checkpoint ({type(exc).__name__}: {str(exc).splitlines()[0]})"
                         ) from None
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        raise InputError(path, "not a splatstyler checkpoint")
    if blob.get("version") != VERSION:
        raise InputError(path, f"checkpoint version {blob.get('version')} is not supported (expected {VERSION})")
    return blob["state"]
