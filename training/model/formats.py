"""The model file formats, each declared once: its name, what a user calls it, its file suffix, how many SH bands it
holds, its reader and its writer. Everything that lists, names, reads or writes model files (read_model, export,
the commands' help, the viewer's file dialogs and export panel) reads this table, so a new format is its reader and
writer module and one entry here (and, where its bytes carry a signature, a line in model_io.model_format).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable


@dataclass(frozen=True)
class ModelFormat:
    name: str  # what --format takes and read_model reports
    label: str  # what a user calls it
    suffix: str  # the file name's end that asks for it
    max_sh_bands: int  # the SH bands it holds at most
    read: Callable[..., Any]  # (path, **options) -> Gaussians
    write: Callable[..., Any]  # (path, gaussians, **options) -> None, or the write's own result


def _read_ply(path, **_):
    from training.model.ply_io import read_ply

    return read_ply(path)


def _write_ply(path, g, pad_sh=True, **_):
    from training.model.ply_io import write_ply

    return write_ply(path, g, pad_sh=pad_sh)


def _read_compressed(path, **_):
    from training.model.compressed_ply import read_compressed_ply

    return read_compressed_ply(path)


def _write_compressed(path, g, **_):
    from training.model.compressed_ply import write_compressed_ply

    return write_compressed_ply(path, g)


def _read_splat(path, **_):
    from training.model.splat_io import read_splat

    return read_splat(path)


def _write_splat(path, g, **_):
    from training.model.splat_io import write_splat

    return write_splat(path, g)


def _read_spz(path, spz_axes=None, **_):
    from training.model.spz_io import read_spz

    return read_spz(path, axes=spz_axes)


def _write_spz(path, g, spz_version=None, spz_axes=None, **_):
    from training.model.spz_io import LATEST_SPZ_VERSION, SPZ_AXES, write_spz

    return write_spz(path, g, version=LATEST_SPZ_VERSION if spz_version is None else spz_version,
                     axes=SPZ_AXES if spz_axes is None else spz_axes)


def _read_glb(path, **_):
    from training.model.gltf_io import read_glb

    return read_glb(path)


def _write_glb(path, g, **_):
    from training.model.gltf_io import write_glb

    return write_glb(path, g)


FORMATS: tuple[ModelFormat, ...] = (
    ModelFormat("ply", "PLY", ".ply", 3, _read_ply, _write_ply),
    ModelFormat("compressed-ply", "compressed PLY", ".compressed.ply", 3, _read_compressed, _write_compressed),
    ModelFormat("splat", ".splat", ".splat", 0, _read_splat, _write_splat),
    ModelFormat("spz", "SPZ", ".spz", 3, _read_spz, _write_spz),
    ModelFormat("glb", "glTF (.glb, KHR_gaussian_splatting)", ".glb", 3, _read_glb, _write_glb),
)
BY_NAME = {f.name: f for f in FORMATS}
NAMES = tuple(BY_NAME)
# the suffixes a file dialog or a drop knows a model by (.compressed.ply ends in .ply)
SUFFIXES = tuple(dict.fromkeys(f.suffix if f.suffix.count(".") == 1 else Path(f.suffix).suffix for f in FORMATS))
SUFFIX_LIST = ", ".join(f.suffix for f in FORMATS[:-1]) + f" or {FORMATS[-1].suffix}"
FILE_DIALOG_PATTERN = " ".join("*" + s for s in SUFFIXES)
MODEL_FILE = f"model file: {SUFFIX_LIST}"  # a command's help for a model argument
WHAT_MODELS_ARE = f"a Gaussian model file ({SUFFIX_LIST})"


def format_for_path(path: str | Path) -> str | None:
    """The format a file name asks for (the longest suffix that matches: ``a.compressed.ply`` is compressed-ply),
    None for anything else."""
    name = Path(path).name.lower()
    matches = [f for f in FORMATS if name.endswith(f.suffix)]
    return max(matches, key=lambda f: len(f.suffix)).name if matches else None


def has_model_suffix(path: str | Path) -> bool:
    """Whether the name is a model file's (what a file dialog or a drop checks before reading)."""
    return Path(path).suffix.lower() in SUFFIXES
