"""``read_model(path)``: every Gaussian model file, read under one rule; the only way a model file enters.

The rule: **the file's first bytes decide**, its name only where the format has no signature.

==================  ====================================================  =================================
format              recognised by                                         read by
==================  ====================================================  =================================
``ply``             starts with ``ply``; header without a ``chunk``       training/model/ply_io.py
``compressed-ply``  starts with ``ply``; ``chunk`` + ``packed_position``  training/model/compressed_ply.py
``spz``             starts with ``NGSP`` (v4) or a gzip header (v1-3)     training/model/spz_io.py
``glb``             starts with ``glTF``                                  training/model/gltf_io.py
``splat``           the name ends in ``.splat`` (the format has no        training/model/splat_io.py
                    header)
==================  ====================================================  =================================

A ``.splat`` has no header: its first bytes are a float32 centre, which may by chance spell another format's
signature (gzip's two bytes once in 65,536 files). So a file named ``.splat`` is another format only when that
format's header holds up beyond the signature: a gzip stream that inflates to ``NGSP``, ``NGSP`` followed by
version 4, ``glTF`` followed by version 2 and the file's length, a PLY header that parses. A file whose bytes match
none gets the error of the format its name asks for (``x.spz: not an SPZ file ...``), or says which files are
models. What comes back is validated once here: at least one Gaussian, every value finite, log-scales whose
covariance float32 holds (each reader also refuses what its format rules out), on ``device``, with RDF axes
(training/model/axes.py); a model too large for the memory left is one line naming the file too.
"""

from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path

import numpy as np
import torch

from training.core.errors import InputError
from training.model.formats import BY_NAME, WHAT_MODELS_ARE
from training.model.gaussians import Gaussians

_SNIFF_BYTES = 1 << 16  # enough gzip input to inflate a header's first bytes
_GZIP = b"\x1f\x8b"
# The largest log-scale a model may hold: its scale squared (the covariance every renderer builds) and the scale
# itself (what .splat and .glb store) stay finite in float32. A finite log-scale of 100 was read before, and its
# .splat or .glb export held an infinite scale that the readers then refused.
MAX_LOG_SCALE = math.log(float(np.finfo(np.float32).max)) / 2  # 44.36: a scale of 1.8e19


def model_format(path: str | Path) -> str | None:
    """The format of the model file at ``path`` by the rule above, None for a file that is no model (a scene's
    transforms.json, an image). InputError for a missing path or a PLY whose header does not parse."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "does not exist")
    if not path.is_file():
        return None
    try:
        with open(path, "rb") as f:
            head = f.read(_SNIFF_BYTES)
        size = path.stat().st_size
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    splat = path.suffix.lower() == ".splat"
    if head[:4] in (b"ply\n", b"ply\r"):
        from training.model.compressed_ply import is_compressed_layout
        from training.model.ply_io import ply_elements

        try:
            elements = ply_elements(path)
        except InputError:
            if splat:
                return "splat"
            raise
        return "compressed-ply" if is_compressed_layout(elements) else "ply"
    if head[:4] == b"NGSP" and (not splat or head[4:8] == struct.pack("<I", 4)):
        return "spz"
    if head[:2] == _GZIP and (not splat or _inflates_to_spz(head)):
        return "spz"
    if head[:4] == b"glTF" and (not splat or head[4:12] == struct.pack("<II", 2, size)):
        return "glb"
    if splat:
        return "splat"
    return None


def _inflates_to_spz(head: bytes) -> bool:
    """Whether a gzip stream's first inflated bytes are an SPZ header's ``NGSP``."""
    try:
        return zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(head, 4) == b"NGSP"
    except zlib.error:
        return False


def _not_a_model(path: Path) -> InputError:
    """The error for a file whose bytes are no model's: the one of the format its name asks for."""
    suffix = path.suffix.lower()
    if suffix == ".ply":
        from training.model.ply_io import read_ply

        read_ply(path)  # raises the precise "not a PLY file" error
    if suffix == ".spz":
        return InputError(path, "not an SPZ file: it starts with neither 'NGSP' (version 4) nor a gzip header "
                                "(versions 1-3)")
    if suffix == ".glb":
        return InputError(path, "not a binary glTF (.glb) file: it does not start with 'glTF'")
    if suffix == ".gltf":
        return InputError(path, "a text .gltf is not read; export or convert it to a binary .glb")
    return InputError(path, f"is not {WHAT_MODELS_ARE}")


def checked_format(path: str | Path) -> str:
    """The format of the model file at ``path``; the error ``read_model`` would give when it is none (checks a
    command line's model before a window opens, without reading the whole file)."""
    path = Path(path)
    fmt = model_format(path)
    if fmt is None:
        if path.is_dir():
            raise InputError(path, f"is a folder; expected {WHAT_MODELS_ARE}")
        raise _not_a_model(path)
    return fmt


def read_model(path: str | Path, device: str | torch.device = "cpu", spz_axes: str | None = None) -> Gaussians:
    """The Gaussians of the model file at ``path`` (any format in the table), validated, on ``device``;
    ``spz_axes``: the axes of an SPZ file that does not name its own (default RDF; training/model/spz_io.py).
    InputError naming the file, in one line, for anything that is not a readable model, including one too large
    for the memory left."""
    path = Path(path)
    fmt = checked_format(path)
    try:
        gaussians = BY_NAME[fmt].read(path, spz_axes=spz_axes)
    except MemoryError:
        raise InputError(path, "too large for the memory left to read it") from None
    n = len(gaussians)
    if n == 0:
        raise InputError(path, "holds no Gaussians")
    for name, t in gaussians.parameters().items():
        if t.numel() and not bool(torch.isfinite(t).all()):
            bad = int((~torch.isfinite(t)).reshape(n, -1).any(dim=1).sum())
            raise InputError(path, f"{bad} of {n} Gaussians have NaN or infinite {name}")
    big = gaussians.log_scales > MAX_LOG_SCALE
    if bool(big.any()):
        raise InputError(path, f"{int(big.any(dim=1).sum())} of {n} Gaussians have a log-scale above "
                               f"{MAX_LOG_SCALE:.2f} (up to {float(gaussians.log_scales.max()):.4g}): their "
                               "covariance, the scale squared, is infinite in float32")
    return gaussians.to(device)
