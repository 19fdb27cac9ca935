"""A ``.npy`` array read from a stream whose real size is known (a file, a zip member), bounded by that size.

``np.load`` reads a header of whatever length the file declares (up to 4 GB in versions 2 and 3) before its own
size check, and allocates the data the header declares before it finds the file too short. Here the header's
declared length is checked against numpy's own limit and the stream's size first, and the data's against what is
left, before either is read; a caller's ``check(shape, dtype)`` sees the header before the data is read. Pickled
(object) arrays are refused.
"""

from __future__ import annotations

import io
import math
import struct
from typing import IO, Callable

import numpy as np

MAGIC = b"\x93NUMPY"
MAX_HEADER_BYTES = 10_000  # numpy's own limit on a header (np.lib.format's max_header_size)
_CHUNK = 1 << 20


def _read_exact(f: IO[bytes], n: int, what: str) -> bytes:
    data = f.read(n)
    if len(data) != n:
        raise ValueError(f"it ends inside its {what}")
    return data


def read_npy(f: IO[bytes], size: int,
             check: Callable[[tuple[int, ...], np.dtype], None] | None = None) -> np.ndarray:
    """The array in the binary stream ``f``, which holds ``size`` bytes from its current position. ValueError, in
    one line saying what is wrong, for anything that is not a plain .npy array of exactly that size; ``check``
    may raise on the header's shape and dtype before any data is read."""
    if size < len(MAGIC) + 2:
        raise ValueError("empty" if size == 0 else f"{size} bytes, too short for a .npy header")
    magic = _read_exact(f, len(MAGIC) + 2, "signature")
    if magic[:len(MAGIC)] != MAGIC:
        what = ": it is a zip, as .npz files are" if magic.startswith(b"PK") else ""
        raise ValueError(f"it does not start with \\x93NUMPY{what}")
    version = (magic[-2], magic[-1])
    if version not in ((1, 0), (2, 0), (3, 0)):
        raise ValueError(f".npy version {version[0]}.{version[1]}; versions 1.0, 2.0 and 3.0 are read")
    length_format = "<H" if version == (1, 0) else "<I"
    length_bytes = _read_exact(f, struct.calcsize(length_format), "header length")
    header_length = struct.unpack(length_format, length_bytes)[0]
    start = len(magic) + len(length_bytes) + header_length  # where the data begins
    if header_length > MAX_HEADER_BYTES or start > size:
        raise ValueError(f"its header declares {header_length:,} bytes; a .npy header is at most "
                         f"{MAX_HEADER_BYTES:,} and this array holds {size:,} bytes in all")
    header = io.BytesIO(length_bytes + _read_exact(f, header_length, "header"))
    parse = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, fortran, dtype = parse(header)  # ValueError for a header that is not one
    if dtype.hasobject:
        raise ValueError("it holds Python objects, which are not read")
    if any(s < 0 for s in shape):
        raise ValueError(f"its header declares the shape {shape}")
    if check is not None:
        check(shape, dtype)
    need = math.prod(shape) * dtype.itemsize
    if size - start != need:
        raise ValueError(f"it holds {size - start:,} bytes of data; its header declares {dtype} {shape}, "
                         f"{need:,} bytes")
    out = np.empty(math.prod(shape), dtype=dtype)
    view = memoryview(out.view(np.uint8)) if need else memoryview(b"")
    done = 0
    while done < need:  # in chunks: a zip member's readinto would hold the whole array twice
        n = f.readinto(view[done:done + _CHUNK])
        if not n:
            raise ValueError(f"it ends after {done:,} of its {need:,} bytes of data")
        done += n
    if f.read(1):  # also: a zip member's checksum is checked at its end
        raise ValueError("it runs on past the data its header declares")
    return out.reshape(shape, order="F" if fortran else "C")
