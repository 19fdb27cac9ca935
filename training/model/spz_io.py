"""Niantic's SPZ (``.spz``): about a tenth of a PLY with the SH bands kept, read by Scaniverse, SuperSplat, the
PlayCanvas engine, Spark, Unity Gaussian Splatting and f3d.

Writing packs through gsply (``gsply.write_spz``, MIT, the reference's layout; pyproject.toml says why that
library); reading is ours, from the spec (nianticlabs/spz README, "File Format"; ``load-spz.cc``), because a reader
must be bounded by the file it reads: gsply inflates a version 3 file's whole gzip stream before it looks at the
header (a 2 MB file of zeros took 4.6 GB) and allocates what a version 4 header declares. Ours reads the header
first, refuses a count the file cannot hold (more than ``MAX_PACK_RATIO`` packed bytes per byte of file: a perfect
grid of identical Gaussians packs 48 to 1, gzip cannot pass about 1030 to 1 and the bombs are made of that), then
inflates each section only as far as the header says it reaches, and decodes with numpy (no numba compile, and
reading leaves gsply's JIT out of the process). What is ours, with the spec's rules:

- **Axes**: SPZ files name their axes in the reference's coordinate-system extension (``SPZ_ADOBE_coordinate_
  system``, 0xADBE0003, one of the 16 conventions of training/model/axes.py). Without it the README says RUB, but
  the tools users open SPZ with (SuperSplat and splat-transform, the reference's own ``ply_to_spz`` with its
  default options) store the PLY's RDF unturned (nianticlabs/spz issue 84 asks which is meant): we follow the
  tools, so an unlabelled file is read as RDF unless the caller says otherwise, and we write RDF by default,
  labelled in version 4, so that readers honouring the extension (the reference asked for any axes) turn it right
  too; other axes (e.g. the README's RUB) on request, labelled in both versions.
- **Versions**: 4 (the current spec: a 32-byte "NGSP" header, each attribute its own ZSTD stream) by default, 3
  (one gzip stream, "smallest three" rotations) for older readers. Reading takes 1 to 4.
- **Quantisation** (what a reader gets back): positions 24-bit signed fixed point with ``fractionalBits`` in the
  header; scales 8-bit, ``(log s + 10) * 16``; rotations (v3, v4) the largest component's index in 2 bits and the
  other three as 9 bits of magnitude plus a sign, scaled by 1/sqrt 2; alpha ``sigmoid(logit) * 255``; colour
  ``f_dc * 0.15 * 255 + 127.5``; SH ``round(c * 128) + 128`` rounded to buckets of 5 bits for degree 1 and 4 bits
  for degrees 2 and 3, the reference's default ``sh1Bits``/``shRestBits`` (gsply keeps all 8 bits; the buckets are
  what makes SPZ small, so we round to them before gsply packs the bytes).
- **Fractional bits**: the reference always writes 12 (1/4096 units), which holds centres within +-2048 units and
  wraps beyond; we write 12 where the model fits and fewer where it does not, so a large scene keeps its shape at
  a coarser step (readers take the step from the header).
"""

from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path

import numpy as np
import torch

from training.core.atomic_write import atomic_path
from training.core.errors import InputError
from training.core.memory import check_fits
from training.model.axes import AXES, MODEL_AXES, axes_name, convert_axes
from training.model.gaussians import Gaussians, num_sh_coeffs

SPZ_VERSIONS = (3, 4)
LATEST_SPZ_VERSION = 4
MAX_FRACTIONAL_BITS = 12  # the reference's fixed choice
SH1_BITS, SH_REST_BITS = 5, 4  # the reference's default PackOptions
MAX_SH_DEGREE = 3
SPZ_AXES = MODEL_AXES  # what an unlabelled file holds, and what we write by default (module doc)
MAX_PACK_RATIO = 128
MAX_EXTENSION_BYTES = 1 << 20  # the known records are 4 and 12 bytes

_MAGIC = b"NGSP"
_GZIP = b"\x1f\x8b"
_FLAG_EXTENSIONS = 0x2
_EXT_COORDINATE_SYSTEM = 0xADBE0003
_V4_HEADER = struct.Struct("<4sIIBBBBI12s")
_LEGACY_HEADER = struct.Struct("<4sIIBBBB")
_BLOCK = 1 << 20  # Gaussians decoded at a time (bounds numpy's temporaries)
_INFLATE_CHUNK = 1 << 24


def fractional_bits_for(means: np.ndarray) -> int:
    """The most fractional bits (at most 12) that keep every coordinate within a signed 24-bit integer."""
    reach = float(np.abs(means).max()) if means.size else 0.0
    if reach < 2.0 ** (23 - MAX_FRACTIONAL_BITS) - 1:
        return MAX_FRACTIONAL_BITS
    bits = 23 - math.ceil(math.log2(reach + 1.0))
    if bits < 1:
        raise ValueError(f"cannot write SPZ: a Gaussian centre lies {reach:.3g} units out, beyond the 24-bit "
                         "fixed point's reach")
    return bits


def quantised_sh(shN: np.ndarray) -> np.ndarray:
    """SH coefficients (N, K, 3) rounded as the reference's ``quantizeSH`` rounds them (degree 1 to 5 bits, higher
    degrees to 4), returned as the values those bytes decode to, so that gsply's 8-bit packing stores them as is."""
    q = np.floor(np.abs(shN.astype(np.float64)) * 128.0 + 0.5) * np.sign(shN) + 128.0  # std::round: half away
    buckets = np.full(shN.shape[1], 1 << (8 - SH_REST_BITS), dtype=np.float64)
    buckets[:3] = 1 << (8 - SH1_BITS)
    b = buckets[None, :, None]
    q = np.clip(np.floor((q + b // 2) / b) * b, 0, 255)
    return ((q - 128.0) / 128.0).astype(np.float32)


def _gsdata(gaussians: Gaussians):
    from gsply import GSData, create_ply_format

    a = {k: v.detach().to("cpu", torch.float32).numpy() for k, v in gaussians.parameters().items()}
    return GSData(means=a["means"], scales=a["log_scales"], quats=a["quats"], opacities=a["opacity_logits"],
                  sh0=a["sh0"][:, 0, :], shN=quantised_sh(a["shN"]),
                  _format=create_ply_format(gaussians.sh_degree))


def _coordinate_record(axes: str) -> bytes:
    return struct.pack("<III", _EXT_COORDINATE_SYSTEM, 4, AXES.index(axes) + 1)


def _labelled(data: bytes, version: int, axes: str) -> bytes:
    """gsply's SPZ bytes with the coordinate-system extension naming ``axes`` (flag 0x2): in version 4 between the
    header and the table of contents (``tocByteOffset`` moves past it), in version 3 after the sections, inside the
    gzip stream, where the reference reads it."""
    record = _coordinate_record(axes)
    if version >= 4:
        magic, v, n, degree, bits, flags, streams, toc, reserved = _V4_HEADER.unpack_from(data)
        if toc != _V4_HEADER.size:
            raise ValueError(f"unexpected SPZ layout from the packer (table of contents at byte {toc})")
        head = _V4_HEADER.pack(magic, v, n, degree, bits, flags | _FLAG_EXTENSIONS, streams, toc + len(record),
                               reserved)
        return head + record + data[_V4_HEADER.size:]
    import gzip

    payload = bytearray(gzip.decompress(data))
    payload[14] |= _FLAG_EXTENSIONS
    return _gzip(bytes(payload) + record)


def _gzip(data: bytes, level: int = 6, block: int = 1 << 20) -> bytes:
    """One gzip member (the reference stops at the first), its deflate stream made of blocks compressed on all
    cores: each block but the last ends on a byte boundary (Z_SYNC_FLUSH), so their concatenation is one valid
    stream (what pigz does; gsply's own writer too). Level 6 as gsply."""
    from concurrent.futures import ThreadPoolExecutor
    import os

    view = memoryview(data)
    starts = range(0, max(len(data), 1), block)

    def deflate(start: int) -> bytes:
        z = zlib.compressobj(level, zlib.DEFLATED, -zlib.MAX_WBITS)
        last = start + block >= len(data)
        return z.compress(view[start:start + block]) + z.flush(zlib.Z_FINISH if last else zlib.Z_SYNC_FLUSH)

    with ThreadPoolExecutor(max(1, min(len(starts), os.cpu_count() or 1))) as pool:
        body = b"".join(pool.map(deflate, starts))
    header = b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\xff"  # deflate, no name, no time, unknown OS
    return header + body + struct.pack("<II", zlib.crc32(data) & 0xFFFFFFFF, len(data) & 0xFFFFFFFF)


def write_spz(path: str | Path, gaussians: Gaussians, version: int = LATEST_SPZ_VERSION,
              axes: str = SPZ_AXES) -> None:
    """Write ``gaussians`` (SH degree 0..3, RDF axes) as an SPZ file of ``version`` (3 or 4) storing ``axes`` (one of
    training/model/axes.py's AXES; default RDF, as SuperSplat and splat-transform read SPZ), atomically, naming its
    axes in the coordinate-system extension (readers without it take the bytes as they are). A version 3 file of
    RDF goes unnamed: the reference library (0.2.3) does not find extension records in gzip files, and readers
    that do not name axes take RDF, so naming it would only cost a second compression.

    ValueError for an empty or non-finite model, a version other than 3 or 4, unknown axes, or centres beyond
    24-bit reach."""
    import gsply

    if version not in SPZ_VERSIONS:
        raise ValueError(f"SPZ version must be 3 or 4, not {version}")
    axes = axes_name(axes)
    if len(gaussians) == 0:
        raise ValueError("cannot write an SPZ file of no Gaussians")
    if gaussians.sh_degree > MAX_SH_DEGREE:
        raise ValueError(f"SPZ export holds SH degree 0..{MAX_SH_DEGREE}, the model has {gaussians.sh_degree}")
    for name, t in gaussians.parameters().items():
        if t.numel() and not bool(torch.isfinite(t).all()):
            raise ValueError(f"cannot write an SPZ file: the model has non-finite {name}")
    stored = convert_axes(gaussians, MODEL_AXES, axes)
    bits = fractional_bits_for(stored.means.detach().cpu().numpy())
    with atomic_path(path) as tmp:
        gsply.write_spz(tmp, _gsdata(stored), version=version, fractional_bits=bits)
        if version >= 4 or axes != SPZ_AXES:
            tmp = Path(tmp)
            tmp.write_bytes(_labelled(tmp.read_bytes(), version, axes))


# ----------------------------------------------------------------------------------------------------- reading
def _section_sizes(n: int, version: int, degree: int) -> list[tuple[str, int]]:
    """The packed sections in file order, with their byte sizes (load-spz.cc's ``checkSizes``)."""
    return [("positions", n * (6 if version == 1 else 9)), ("alphas", n), ("colors", n * 3), ("scales", n * 3),
            ("rotations", n * (4 if version >= 3 else 3)), ("sh", n * 3 * (num_sh_coeffs(degree) - 1))]


class _Inflater:
    """A gzip stream read a given number of bytes at a time: never more output than asked for, whatever the
    stream holds beyond (zlib's ``max_length``)."""

    def __init__(self, path: Path, raw: memoryview):
        self._path, self._raw, self._pos = path, raw, 0
        self._z = zlib.decompressobj(16 + zlib.MAX_WBITS)

    def read(self, size: int, what: str, exact: bool = True) -> bytearray:
        out, got = bytearray(size), 0
        while got < size:
            data = self._z.unconsumed_tail
            if not data and self._pos < len(self._raw) and not self._z.eof:
                data = self._raw[self._pos:self._pos + _INFLATE_CHUNK]
                self._pos += len(data)
            try:
                piece = self._z.decompress(data, min(size - got, _INFLATE_CHUNK))
            except zlib.error as exc:
                raise InputError(self._path, f"not a readable SPZ file: its gzip stream is damaged ({exc})") \
                    from None
            out[got:got + len(piece)] = piece
            got += len(piece)
            if not piece and (self._z.eof or (not self._z.unconsumed_tail and self._pos >= len(self._raw))):
                break
        if got < size and exact:
            raise InputError(self._path, f"the SPZ file ends inside its {what}: the header's count needs {size} "
                                         f"bytes there, the gzip stream holds {got} (truncated or damaged)")
        del out[got:]
        return out


class _Header:
    def __init__(self, version: int, n: int, degree: int, bits: int, flags: int):
        self.version, self.n, self.degree, self.bits, self.flags = version, n, degree, bits, flags


def _check_header(path: Path, h: _Header, file_size: int) -> int:
    """The packed bytes the header's count needs; InputError for a header this reader cannot apply or a count the
    file cannot hold."""
    if h.degree > MAX_SH_DEGREE:
        raise InputError(path, f"SPZ file has SH degree {h.degree}; degrees 0..{MAX_SH_DEGREE} are read")
    if h.version >= 2 and h.bits > 24:
        raise InputError(path, f"SPZ header says {h.bits} fractional bits; positions have 24")
    if h.n == 0:
        raise InputError(path, "SPZ file holds no Gaussians")
    need = sum(size for _, size in _section_sizes(h.n, h.version, h.degree))
    if need > MAX_PACK_RATIO * file_size:
        raise InputError(path, f"the SPZ header declares {h.n} Gaussians ({need} bytes once unpacked) in a file of "
                               f"{file_size} bytes: more than {MAX_PACK_RATIO} to 1, which no SPZ file packs "
                               "(damaged, or made to exhaust memory)")
    return need


def _records(path: Path, zone: bytes) -> dict[int, bytes]:
    """Extension records (u32 type, u32 length, payload), the first of each type."""
    out, pos = {}, 0
    while pos + 8 <= len(zone):
        kind, length = struct.unpack_from("<II", zone, pos)
        if pos + 8 + length > len(zone):
            raise InputError(path, f"SPZ extension record 0x{kind:08x} declares {length} bytes, past the end of "
                                   "its extension zone (truncated or damaged)")
        out.setdefault(kind, zone[pos + 8:pos + 8 + length])
        pos += 8 + length
    return out


def _stored_axes(path: Path, records: dict[int, bytes]) -> str | None:
    """The axes the coordinate-system extension names; None without one (or with 0, "unspecified")."""
    payload = records.get(_EXT_COORDINATE_SYSTEM)
    if payload is None:
        return None
    if len(payload) != 4:
        raise InputError(path, f"SPZ coordinate-system extension holds {len(payload)} bytes, not 4")
    code = struct.unpack("<I", payload)[0]
    if code == 0:
        return None
    if code > len(AXES):
        raise InputError(path, f"SPZ coordinate-system extension names system {code}; 1..{len(AXES)} are defined")
    return AXES[code - 1]


def _v4_sections(path: Path, raw: bytes):
    """(header, extension records, section iterator) of a version 4 file."""
    if len(raw) < _V4_HEADER.size:
        raise InputError(path, f"not a readable SPZ file: {len(raw)} bytes, less than the 32-byte header")
    _, version, n, degree, bits, flags, streams, toc, _ = _V4_HEADER.unpack_from(raw)
    if version != 4:
        raise InputError(path, f"SPZ version {version} in an NGSP header; version 4 is read (1-3 are gzip files)")
    h = _Header(version, n, degree, bits, flags)
    _check_header(path, h, len(raw))
    sections = [(name, size) for name, size in _section_sizes(n, version, degree) if size]
    if streams != len(sections):
        raise InputError(path, f"SPZ header lists {streams} streams; SH degree {degree} needs {len(sections)}")
    toc_end = toc + 16 * streams
    if toc < _V4_HEADER.size or toc_end > len(raw):
        raise InputError(path, f"SPZ table of contents at bytes {toc}..{toc_end} lies outside the file's "
                               f"{_V4_HEADER.size}..{len(raw)} (truncated or damaged)")
    records = _records(path, raw[_V4_HEADER.size:toc]) if flags & _FLAG_EXTENSIONS else {}
    spans, offset = [], toc_end
    for i, (name, size) in enumerate(sections):
        packed, unpacked = struct.unpack_from("<QQ", raw, toc + 16 * i)
        if unpacked != size:
            raise InputError(path, f"SPZ stream '{name}' unpacks to {unpacked} bytes; {n} Gaussians need {size}")
        if packed > len(raw) - offset:
            raise InputError(path, f"SPZ stream '{name}' runs past the end of the file (truncated or damaged)")
        spans.append((name, size, offset, packed))
        offset += packed
    if offset != len(raw):
        raise InputError(path, f"SPZ streams end at byte {offset}, the file at {len(raw)} (damaged)")

    def read():
        import zstandard

        view = memoryview(raw)
        for name, size, start, packed in spans:
            reader = zstandard.ZstdDecompressor().stream_reader(view[start:start + packed], read_across_frames=True)
            out, got = bytearray(size), 0
            try:
                while got < size:
                    count = reader.readinto(memoryview(out)[got:])
                    if not count:
                        break
                    got += count
                more = reader.read(1) if got == size else b""
            except zstandard.ZstdError as exc:
                raise InputError(path, f"not a readable SPZ file: stream '{name}' is damaged ({exc})") from None
            if got != size or more:
                raise InputError(path, f"SPZ stream '{name}' unpacks to {'more than ' if more else ''}{got} bytes, "
                                       f"not the {size} its header declares (damaged)")
            yield name, out

    return h, records, read()


def _legacy_sections(path: Path, raw: bytes):
    """(header, extension records (read after the sections), section iterator) of a gzip (version 1-3) file."""
    inflater = _Inflater(path, memoryview(raw))
    head = inflater.read(_LEGACY_HEADER.size, "header")
    magic, version, n, degree, bits, flags, _ = _LEGACY_HEADER.unpack(head)
    if magic != _MAGIC:
        raise InputError(path, "not an SPZ file: its gzip stream does not start with an 'NGSP' header")
    if not 1 <= version <= 3:
        raise InputError(path, f"SPZ version {version} inside a gzip stream; versions 1-3 are gzip files")
    h = _Header(version, n, degree, bits, flags)
    _check_header(path, h, len(raw))
    records: dict[int, bytes] = {}

    def read():
        for name, size in _section_sizes(n, version, degree):
            yield name, inflater.read(size, f"'{name}' section")
        if flags & _FLAG_EXTENSIONS:
            zone = inflater.read(MAX_EXTENSION_BYTES + 1, "extension records", exact=False)
            if len(zone) > MAX_EXTENSION_BYTES:
                raise InputError(path, f"SPZ extension records exceed {MAX_EXTENSION_BYTES} bytes (damaged)")
            records.update(_records(path, zone))

    return h, records, read()


def _decode_positions(data: bytes, n: int, version: int, bits: int) -> np.ndarray:
    if version == 1:  # float16, the never-released first version the reference still reads
        return np.frombuffer(data, "<f2").reshape(n, 3).astype(np.float32)
    out = np.empty((n, 3), np.float32)
    b = np.frombuffer(data, np.uint8).reshape(n, 3, 3)
    step = np.float32(1.0 / (1 << bits))
    for lo in range(0, n, _BLOCK):
        c = b[lo:lo + _BLOCK].astype(np.int32)
        v = c[..., 0] | (c[..., 1] << 8) | (c[..., 2] << 16)
        v -= (v & 0x800000) << 1  # sign of the 24-bit integer
        out[lo:lo + _BLOCK] = v.astype(np.float32) * step
    return out


def _decode_rotations(data: bytes, n: int, version: int) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z)."""
    out = np.empty((n, 4), np.float32)
    if version < 3:  # x, y, z as bytes over [-1, 1], w from the norm
        xyz = np.frombuffer(data, np.uint8).reshape(n, 3).astype(np.float32) / np.float32(127.5) - np.float32(1.0)
        out[:, 1:] = xyz
        out[:, 0] = np.sqrt(np.maximum(0.0, 1.0 - (xyz * xyz).sum(axis=1)))
        return out
    words = np.frombuffer(data, "<u4")
    scale = np.float32(math.sqrt(0.5) / 511.0)
    for lo in range(0, n, _BLOCK):
        w = words[lo:lo + _BLOCK]
        largest = (w >> 30).astype(np.int64)
        xyzw = np.empty((len(w), 4), np.float32)
        rest = w.copy()
        squares = np.zeros(len(w), np.float32)
        for axis in range(3, -1, -1):  # the reference's order: the last stored component first
            here = largest != axis
            value = (rest & 511).astype(np.float32) * scale
            value[((rest >> 9) & 1).astype(bool)] *= -1
            xyzw[here, axis] = value[here]
            squares += np.where(here, value * value, np.float32(0))
            rest = np.where(here, rest >> 10, rest)
        xyzw[np.arange(len(w)), largest] = np.sqrt(np.maximum(np.float32(0), np.float32(1) - squares))
        out[lo:lo + _BLOCK] = xyzw[:, [3, 0, 1, 2]]
    return out


def read_spz(path: str | Path, device: str | torch.device = "cpu", axes: str | None = None) -> Gaussians:
    """Read an SPZ file (versions 1..4) into a model with RDF axes, as its bytes decode (see the module's
    quantisation), turned from the axes the file names in its coordinate-system extension, or from ``axes``
    (default RDF, module doc) when it names none. InputError naming the file, in one line, for a file that is
    not SPZ, is damaged, declares more than it holds, or decodes to no model."""
    path = Path(path)
    assumed = SPZ_AXES if axes is None else axes_name(axes)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    if raw[:4] == _MAGIC:
        h, records, sections = _v4_sections(path, raw)
    elif raw[:2] == _GZIP:
        h, records, sections = _legacy_sections(path, raw)
    else:
        raise InputError(path, "not an SPZ file: it starts with neither 'NGSP' (version 4) nor a gzip header "
                               "(versions 1-3)")
    k = num_sh_coeffs(h.degree) - 1
    check_fits(path, h.n, 4 * (3 + 3 + 4 + 1 + 3 + 3 * k) + 3 * k, f"{h.n} Gaussians of SH degree {h.degree}")
    n = h.n
    decoded: dict[str, np.ndarray] = {}
    for name, data in sections:
        if name == "positions":
            decoded["means"] = _decode_positions(data, n, h.version, h.bits)
        elif name == "alphas":
            # bytes 0 and 255 decode to logits of +-inf in the reference: half a step in, as for .splat
            a = np.clip(np.frombuffer(data, np.uint8).astype(np.float32), 0.5, 254.5)
            decoded["opacity_logits"] = np.log(a / (np.float32(255) - a))
        elif name == "colors":
            c = np.frombuffer(data, np.uint8).reshape(n, 1, 3).astype(np.float32)
            decoded["sh0"] = (c / np.float32(255) - np.float32(0.5)) / np.float32(0.15)
        elif name == "scales":
            s = np.frombuffer(data, np.uint8).reshape(n, 3).astype(np.float32)
            decoded["log_scales"] = s / np.float32(16) - np.float32(10)
        elif name == "rotations":
            decoded["quats"] = _decode_rotations(data, n, h.version)
        else:
            sh = np.frombuffer(data, np.uint8).reshape(n, k, 3).astype(np.float32)
            sh -= np.float32(128)
            sh /= np.float32(128)
            decoded["shN"] = sh
        del data
    decoded.setdefault("shN", np.zeros((n, 0, 3), np.float32))
    stored = _stored_axes(path, records) or assumed

    g = Gaussians(**{key: torch.from_numpy(value) for key, value in decoded.items()}, sh_degree=h.degree)
    g = convert_axes(g, stored, MODEL_AXES, in_place=True)
    return g.to(device)
