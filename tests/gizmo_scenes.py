"""Small models for the gizmo and scene-model tests: the demo scene's model and a moved copy of it."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def similarity(angle_deg: float, axis, scale: float, shift) -> np.ndarray:
    """4x4 s R x + t with R a rotation of ``angle_deg`` about ``axis``."""
    x, y, z = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    a = np.radians(angle_deg)
    m = np.eye(4)
    m[:3, :3] = scale * (np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * (k @ k))
    m[:3, 3] = shift
    return m


def moved_copy(model: Path, matrix: np.ndarray, out: Path) -> Path:
    """The model file moved by ``matrix`` (training/model/transform.py), written as a PLY."""
    from training.model.ply_io import read_ply, write_ply
    from training.model.transform import transform_gaussians

    write_ply(out, transform_gaussians(read_ply(model), matrix))
    return out
