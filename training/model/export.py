"""Export a model (or a selection of it) in one of the formats other tools load, with a chosen number of SH bands,
and know the file's size before writing it: the API behind ``splatstyler export`` and the viewer's export dialog.

Formats: ``ply`` (standard 3DGS PLY, float32, 248 bytes per Gaussian with all 45 f_rest, fewer with ``pad_sh``
off), ``compressed-ply`` (PlayCanvas's chunked layout, 16 bytes per Gaussian + 3 per SH coefficient kept;
training/model/compressed_ply.py), ``splat`` (antimatter15's 32 bytes per Gaussian, colour only), ``spz`` (Niantic's
SPZ, version 4 or 3, quantised and compressed: its size is known only once written; training/model/spz_io.py) and
``glb`` (glTF 2.0 with KHR_gaussian_splatting, float32, 60 bytes per Gaussian + 12 per higher SH coefficient
(RGB); training/model/gltf_io.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from training.model.formats import BY_NAME, NAMES, SUFFIX_LIST, format_for_path
from training.model.gaussians import Gaussians, num_sh_coeffs

def max_sh_bands(fmt: str) -> int:
    """The most SH bands a format holds (.splat: colour only)."""
    return BY_NAME[fmt].max_sh_bands


def export_size(fmt: str, sh_bands: int, count: int, pad_sh: bool = True) -> int | None:
    """Bytes of the file ``write_export`` writes for ``count`` Gaussians keeping ``sh_bands`` (0-3) bands; None for
    SPZ, whose size its compression decides."""
    _check(fmt, sh_bands)
    if fmt == "spz":
        return None
    if fmt == "glb":
        from training.model.gltf_io import glb_size

        return glb_size(count, sh_bands)
    if fmt == "ply":
        from training.model.ply_io import ply_file_size

        return ply_file_size(count, sh_bands, pad_sh)
    if fmt == "compressed-ply":
        from training.model.compressed_ply import compressed_size

        return compressed_size(count, sh_bands)
    from training.model.splat_io import SPLAT_DTYPE

    return int(count) * SPLAT_DTYPE.itemsize


def with_sh_bands(gaussians: Gaussians, bands: int) -> Gaussians:
    """The same model keeping SH coefficients up to degree ``bands`` (<= gaussians.sh_degree)."""
    if not 0 <= bands <= gaussians.sh_degree:
        raise ValueError(f"cannot keep {bands} SH bands of a model with {gaussians.sh_degree}")
    params = gaussians.parameters()
    params["shN"] = params["shN"][:, : num_sh_coeffs(bands) - 1].contiguous()
    return Gaussians(**params, sh_degree=bands)


def selected(gaussians: Gaussians, mask) -> Gaussians:
    """The Gaussians ``mask`` (N,) bool selects, in model order; the whole model for None."""
    if mask is None:
        return gaussians
    m = torch.as_tensor(np.asarray(mask))
    if m.dtype != torch.bool or m.shape != (len(gaussians),):
        raise ValueError(f"the mask must be ({len(gaussians)},) bool, got {m.dtype} {tuple(m.shape)}")
    return gaussians.subset(m.to(gaussians.device))


@dataclass
class ExportResult:
    path: Path
    format: str
    sh_bands: int
    count: int
    size: int  # bytes written
    order: np.ndarray | None = None  # compressed-ply: model index (after the mask) of each Gaussian in the file


def write_export(path: str | Path, gaussians: Gaussians, fmt: str | None = None, sh_bands: int | None = None,
                 mask=None, pad_sh: bool = True, spz_version: int | None = None,
                 spz_axes: str | None = None) -> ExportResult:
    """Write ``gaussians`` (only ``mask``'s when given) to ``path`` in ``fmt`` (default: from the file name) keeping
    ``sh_bands`` (default: all the format and the model hold), atomically; for SPZ ``spz_version`` 3 or 4 (default:
    the current, 4) and ``spz_axes``, the axes the file stores (default RDF, as SuperSplat and splat-transform read
    SPZ; training/model/spz_io.py). ValueError for an unknown format, bands the model or format lacks, an empty
    selection, unknown axes or a non-finite model."""
    fmt = fmt or format_for_path(path)
    if fmt is None:
        raise ValueError(f"cannot tell the format from {Path(path).name!r}; name it {SUFFIX_LIST}")
    g = selected(gaussians, mask)
    bands = min(g.sh_degree, max_sh_bands(fmt)) if sh_bands is None else int(sh_bands)
    _check(fmt, bands)
    if len(g) == 0:
        raise ValueError("the selection is empty: nothing to export")
    g = with_sh_bands(g, bands)
    written = BY_NAME[fmt].write(path, g, pad_sh=pad_sh, spz_version=spz_version, spz_axes=spz_axes)
    order = written if fmt == "compressed-ply" else None  # the file's order of the Gaussians
    return ExportResult(Path(path), fmt, bands, len(g), Path(path).stat().st_size, order)


def _check(fmt: str, sh_bands: int) -> None:
    if fmt not in BY_NAME:
        raise ValueError(f"unknown format {fmt!r}; expected one of {', '.join(NAMES)}")
    if not 0 <= sh_bands <= max_sh_bands(fmt):
        raise ValueError(f"{BY_NAME[fmt].label} holds 0..{max_sh_bands(fmt)} SH bands, not {sh_bands}")


def human_size(size: int) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if size < 1000 or unit == "GB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1000
    return f"{size} B"
