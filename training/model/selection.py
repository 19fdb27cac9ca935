"""Selections of Gaussians as (N,) boolean masks: world-space box and sphere, and mask files. numpy only, so the
viewer (which holds numpy snapshots) and the CLI share it without torch.

A mask file is a ``.npy`` holding either an (N,) bool array (True = selected) or a 1-D integer array of the
selected Gaussians' indices (0-based, in the model's order), or a ``.txt`` with whitespace-separated indices. The
viewer's "save selection" writes the bool form (``save_mask``); the index forms are for scripts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from training.core.atomic_write import atomic_path
from training.core.errors import InputError
from training.core.npy_io import read_npy


def _means(means) -> np.ndarray:
    if hasattr(means, "detach"):  # a torch tensor: the model's means
        means = means.detach().cpu().numpy()
    m = np.asarray(means, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != 3:
        raise ValueError(f"means must be (N, 3), got {m.shape}")
    return m


def box_mask(means, lo, hi, invert: bool = False) -> np.ndarray:
    """(N,) bool: centres inside the axis-aligned box [lo, hi] (bounds included); outside it with ``invert``.
    Corners in either order: the box is the one they span."""
    m = _means(means)
    a, b = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if a.shape != (3,) or b.shape != (3,) or not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("a box needs two finite 3-vectors")
    lo3, hi3 = np.minimum(a, b), np.maximum(a, b)
    inside = np.all((m >= lo3) & (m <= hi3), axis=1)
    return ~inside if invert else inside


def sphere_mask(means, centre, radius: float, invert: bool = False) -> np.ndarray:
    """(N,) bool: centres within ``radius`` of ``centre`` (boundary included); outside it with ``invert``."""
    m = _means(means)
    c = np.asarray(centre, dtype=np.float64)
    if c.shape != (3,) or not np.isfinite(c).all() or not (np.isfinite(radius) and radius >= 0):
        raise ValueError("a sphere needs a finite centre and a radius >= 0")
    inside = np.sum((m - c) ** 2, axis=1) <= float(radius) ** 2
    return ~inside if invert else inside


def indices_to_mask(indices, n: int, name=None) -> np.ndarray:
    """(N,) bool from selected indices; InputError naming ``name`` for an index outside 0..N-1."""
    idx = np.asarray(indices)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise InputError(name, f"selection index {int(idx.min() if idx.min() < 0 else idx.max())} is outside "
                               f"0..{n - 1} (the model has {n} Gaussians)")
    mask = np.zeros(n, dtype=bool)
    mask[idx.astype(np.int64)] = True
    return mask


def load_mask(path: str | Path, n: int) -> np.ndarray:
    """(N,) bool from a mask file (see the module's docstring); InputError naming the file when it does not fit a
    model of ``n`` Gaussians."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file does not exist" if not path.exists() else "is not a file")
    if path.suffix.lower() == ".txt":
        try:
            values = np.array(path.read_text().split(), dtype=np.float64)
        except (ValueError, UnicodeDecodeError):
            raise InputError(path, "a .txt selection holds whitespace-separated Gaussian indices; found something "
                                   "else") from None
        if not np.all(values == np.round(values)):  # NaN is no whole number, and infinity is checked below
            raise InputError(path, "selection indices must be whole numbers")
        outside = values[(values < 0) | (values >= n)]
        if len(outside):  # before the cast: 1e19 or inf would wrap to some int64, with numpy's warnings
            raise InputError(path, f"selection index {outside[0]:g} is outside 0..{n - 1} (the model has {n} "
                                   "Gaussians)")
        return indices_to_mask(values.astype(np.int64), n, path)
    if path.suffix.lower() != ".npy":
        raise InputError(path, "a selection file is .npy (bool mask or indices) or .txt (indices)")

    def check(shape: tuple[int, ...], dtype: np.dtype) -> None:
        if len(shape) != 1:
            raise InputError(path, f"a selection is 1-D (a mask or indices), this array has shape {shape}")
        if dtype != bool and not np.issubdtype(dtype, np.integer):
            raise InputError(path, f"a selection holds bool or integer values, not {dtype}")
        if dtype == bool and shape[0] != n:
            raise InputError(path, f"the mask has {shape[0]} entries; the model has {n} Gaussians")

    try:  # bounded by the file's size: its header is checked before the data is read
        with open(path, "rb") as f:
            array = read_npy(f, path.stat().st_size, check)
    except ValueError as exc:
        raise InputError(path, f"not a readable .npy file ({str(exc).splitlines()[0]})") from None
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    return array if array.dtype == bool else indices_to_mask(array, n, path)


def save_mask(path: str | Path, mask) -> None:
    """Write an (N,) bool mask as .npy, atomically."""
    m = np.asarray(mask)
    if m.ndim != 1 or m.dtype != bool:
        raise ValueError(f"a mask is (N,) bool, got {m.dtype} {m.shape}")
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.save(f, m, allow_pickle=False)


def parse_floats(text: str, count: int, flag: str) -> tuple[float, ...]:
    """``count`` comma-separated finite numbers (a CLI value like ``--box x0,y0,z0,x1,y1,z1``); InputError naming
    the flag otherwise."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(np.isfinite(values)):
        raise InputError(None, f"{flag} takes {count} comma-separated numbers, got {text!r}")
    return values
