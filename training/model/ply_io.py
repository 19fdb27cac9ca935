"""Gaussian models as PLY files in the standard 3D Gaussian Splatting layout.

Layout (one ``vertex`` element, binary little-endian float32, parameters stored *before* activation, as the 3DGS
reference code writes them so that other viewers and tools load our files unchanged)::

    x y z  nx ny nz  f_dc_0..2  f_rest_0..44  opacity  scale_0..2  rot_0..3

- ``f_dc_c`` is ``sh0[:, 0, c]``.
- ``f_rest`` is channel-major: for a model with K = (d+1)^2 coefficients, ``f_rest[c*(K-1) + k] = shN[:, k, c]``.
- We always write all 45 ``f_rest`` (degree 3), zero-padded for lower degrees, because several viewers assume 45.
  The model's own degree goes into a header comment (``comment splatstyler sh_degree D``), which other tools
  ignore, so that our files read back with the degree they were written with.
- ``nx ny nz`` are zeros (3DGS writes them; nobody reads them).

Reading accepts what other tools write: binary little- or big-endian or ASCII, any scalar property types, extra
properties (ignored), other elements before or after ``vertex`` as long as those before it hold no lists, and 0, 9,
24 or 45 ``f_rest`` (SH degree 0..3). Everything else is refused with an :class:`InputError` naming the file.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch

from training.core.atomic_write import atomic_open
from training.core.errors import InputError
from training.model.gaussians import Gaussians, num_sh_coeffs

MAX_SH_DEGREE = 3
NUM_F_REST = 3 * (num_sh_coeffs(MAX_SH_DEGREE) - 1)  # 45

# The standard attribute order; tools that index properties by position rely on it.
STANDARD_ATTRIBUTES: list[str] = (
    ["x", "y", "z", "nx", "ny", "nz"]
    + [f"f_dc_{i}" for i in range(3)]
    + [f"f_rest_{i}" for i in range(NUM_F_REST)]
    + ["opacity"]
    + [f"scale_{i}" for i in range(3)]
    + [f"rot_{i}" for i in range(4)]
)
_REQUIRED = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"]
_DEGREE_COMMENT = "splatstyler sh_degree"

# PLY scalar type names (both spellings of the spec) -> numpy kind+size
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_MAX_HEADER_BYTES = 1 << 20


# ----------------------------------------------------------------------------------------------------- writing
def ply_attributes(degree: int, pad_sh: bool = True) -> list[str]:
    """The vertex properties written for a model of SH ``degree``: all 45 f_rest when ``pad_sh``, else only the
    degree's own 3 * ((d+1)^2 - 1), as graphdeco writes a lower-degree model and SuperSplat a lowered export."""
    if pad_sh:
        return list(STANDARD_ATTRIBUTES)
    keep = {f"f_rest_{i}" for i in range(3 * (num_sh_coeffs(degree) - 1))}
    return [a for a in STANDARD_ATTRIBUTES if not a.startswith("f_rest_") or a in keep]


def _ply_header(n: int, degree: int, pad_sh: bool) -> bytes:
    header = ["ply", "format binary_little_endian 1.0", f"comment {_DEGREE_COMMENT} {degree}", f"element vertex {n}"]
    header += [f"property float {name}" for name in ply_attributes(degree, pad_sh)]
    return ("\n".join(header + ["end_header"]) + "\n").encode("ascii")


def ply_file_size(num_gaussians: int, degree: int, pad_sh: bool = True) -> int:
    """Bytes ``write_ply`` writes for ``num_gaussians`` of SH ``degree``."""
    n = int(num_gaussians)
    return len(_ply_header(n, degree, pad_sh)) + 4 * n * len(ply_attributes(degree, pad_sh))


def write_ply(path: str | Path, gaussians: Gaussians, pad_sh: bool = True) -> None:
    """Write ``gaussians`` (any device, sh_degree 0..3) to ``path`` in the standard 3DGS layout, atomically.
    ``pad_sh=False`` writes only the model's own f_rest instead of all 45 (smaller; the module's docstring says why
    45 is the default).

    Raises ValueError if the model holds non-finite values (a file other tools would choke on is worse than none).
    """
    d = int(gaussians.sh_degree)
    if not 0 <= d <= MAX_SH_DEGREE:
        raise ValueError(f"PLY files hold SH degree 0..{MAX_SH_DEGREE}, the model has degree {d}")
    n = len(gaussians)
    arrays = {k: v.detach().to("cpu", torch.float32).numpy() for k, v in gaussians.parameters().items()}
    for name, a in arrays.items():
        bad = int((~np.isfinite(a)).reshape(n, -1).any(axis=1).sum()) if n else 0
        if bad:
            raise ValueError(f"cannot write a PLY: {bad} Gaussians have non-finite {name}")

    width = num_sh_coeffs(MAX_SH_DEGREE if pad_sh else d) - 1  # coefficients per channel in the file
    rest = np.zeros((n, 3, width), dtype=np.float32)  # (N, channel, coefficient)
    rest[:, :, : num_sh_coeffs(d) - 1] = arrays["shN"].transpose(0, 2, 1)

    names = ply_attributes(d, pad_sh)
    data = np.zeros(n, dtype=np.dtype([(name, "<f4") for name in names]))
    for i, axis in enumerate("xyz"):
        data[axis] = arrays["means"][:, i]
    for c in range(3):
        data[f"f_dc_{c}"] = arrays["sh0"][:, 0, c]
    rest_flat = rest.reshape(n, 3 * width)
    for i in range(3 * width):
        data[f"f_rest_{i}"] = rest_flat[:, i]
    data["opacity"] = arrays["opacity_logits"]
    for i in range(3):
        data[f"scale_{i}"] = arrays["log_scales"][:, i]
    for i in range(4):
        data[f"rot_{i}"] = arrays["quats"][:, i]

    with atomic_open(path, "wb") as f:
        f.write(_ply_header(n, d, pad_sh))
        f.write(data.tobytes())


# ----------------------------------------------------------------------------------------------------- reading
class _Element:
    def __init__(self, name: str, count: int):
        self.name = name
        self.count = count
        self.properties: list[tuple[str, str]] = []  # (name, numpy kind like "f4")
        self.has_list = False


def _parse_header(path: Path, head: bytes) -> tuple[str, list[_Element], list[str], int]:
    """Returns (format, elements, comments, offset of the first data byte)."""
    if not (head.startswith(b"ply\n") or head.startswith(b"ply\r\n")):
        raise InputError(path, "not a PLY file (it does not start with 'ply')")
    m = re.search(rb"(?m)^end_header\r?\n", head)
    if m is None:
        raise InputError(path, "PLY header has no 'end_header' line (truncated or not a PLY file)")
    try:
        lines = head[: m.start()].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise InputError(path, "PLY header is not ASCII text") from None
    fmt = None
    elements: list[_Element] = []
    comments: list[str] = []
    for lineno, line in enumerate(lines[1:], start=2):
        words = line.split()
        if not words or words[0] in ("obj_info",):
            continue
        if words[0] == "comment":
            comments.append(line.strip()[len("comment"):].strip())
        elif words[0] == "format" and len(words) == 3:
            fmt = words[1]
            if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
                raise InputError(path, f"unknown PLY format '{fmt}'")
        elif words[0] == "element" and len(words) == 3:
            try:
                count = int(words[2])
            except ValueError:
                count = -1
            if count < 0:
                raise InputError(path, f"PLY header line {lineno}: bad element count '{words[2]}'")
            if any(e.name == words[1] for e in elements):
                raise InputError(path, f"PLY header line {lineno}: a second element '{words[1]}'")
            elements.append(_Element(words[1], count))
        elif words[0] == "property" and elements:
            if words[-1] in (name for name, _ in elements[-1].properties):
                raise InputError(path, f"PLY header line {lineno}: element '{elements[-1].name}' has a second "
                                       f"property '{words[-1]}'")
            if len(words) >= 2 and words[1] == "list":
                elements[-1].has_list = True
                elements[-1].properties.append((words[-1], "list"))
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                elements[-1].properties.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise InputError(path, f"PLY header line {lineno}: cannot parse '{line.strip()}'")
        else:
            raise InputError(path, f"PLY header line {lineno}: cannot parse '{line.strip()}'")
    if fmt is None:
        raise InputError(path, "PLY header has no 'format' line")
    return fmt, elements, comments, m.end()


def _read_vertex_table(path: Path, fmt: str, elements: list[_Element], start: int) -> np.ndarray:
    """The vertex element as a structured array with the file's own property types, native byte order."""
    names = [e.name for e in elements]
    if "vertex" not in names:
        raise InputError(path, "PLY file has no 'vertex' element")
    vi = names.index("vertex")
    vertex = elements[vi]
    if vertex.has_list:
        raise InputError(path, "the PLY 'vertex' element has list properties; a Gaussian PLY has none")
    for e in elements[:vi]:
        if e.has_list:
            raise InputError(path, f"PLY element '{e.name}' before 'vertex' has list properties; cannot skip it")

    if fmt == "ascii":
        tokens = path.read_bytes()[start:].split()
        skip = sum(e.count * len(e.properties) for e in elements[:vi])
        need = vertex.count * len(vertex.properties)
        if len(tokens) < skip + need:
            raise InputError(path, f"PLY file is truncated: header declares {vertex.count} vertices, "
                                   f"the data holds {max(0, len(tokens) - skip) // max(1, len(vertex.properties))}")
        try:
            values = np.array(tokens[skip: skip + need], dtype=np.float64).reshape(vertex.count,
                                                                                 len(vertex.properties))
        except ValueError:
            raise InputError(path, "PLY ASCII data holds a value that is not a number") from None
        table = np.empty(vertex.count, dtype=[(n, t) for n, t in vertex.properties])
        for i, (n, _) in enumerate(vertex.properties):
            table[n] = values[:, i]
        return table

    order = "<" if fmt == "binary_little_endian" else ">"
    offset = start
    for e in elements[:vi]:
        offset += e.count * np.dtype([(n, order + t) for n, t in e.properties]).itemsize
    dtype = np.dtype([(n, order + t) for n, t in vertex.properties])
    need = vertex.count * dtype.itemsize
    available = path.stat().st_size - offset
    if available < need:
        got = max(0, available) // dtype.itemsize
        raise InputError(path, f"PLY file is truncated: header declares {vertex.count} vertices "
                               f"({need} bytes), the file holds {max(0, available)} bytes (~{got} vertices)")
    if vi == len(elements) - 1 and available > need:
        raise InputError(path, f"PLY file has {available - need} bytes after its {vertex.count} vertices "
                               "(wrong vertex count or corrupt file)")
    # np.fromfile instead of reading the whole file: PLYs of a few million Gaussians are close to a gigabyte.
    table = np.fromfile(path, dtype=dtype, count=vertex.count, offset=offset)
    if len(table) != vertex.count:
        raise InputError(path, f"PLY file is truncated: read {len(table)} of {vertex.count} vertices")
    return table.astype(dtype.newbyteorder("="))


def _check_attributes(path: Path, props: set[str], elements: list[_Element]) -> tuple[list[str], int]:
    """The f_rest names in order and the SH degree they give; InputError for missing or odd attributes."""
    missing = [a for a in _REQUIRED if a not in props]
    if missing:
        hint = ""
        if "packed_position" in props or any(e.name == "chunk" for e in elements):
            hint = " (this looks like a compressed PLY; decompress it to a standard 3DGS PLY first)"
        raise InputError(path, f"not a 3DGS Gaussian PLY: missing attribute(s) {', '.join(missing)}{hint}")
    rest_names = sorted((p for p in props if p.startswith("f_rest_")), key=lambda s: (len(s), s))
    n_rest = len(rest_names)
    if rest_names != [f"f_rest_{i}" for i in range(n_rest)]:
        raise InputError(path, "f_rest attributes are not numbered 0..M-1 without gaps")
    degrees = {3 * (num_sh_coeffs(d) - 1): d for d in range(MAX_SH_DEGREE + 1)}
    if n_rest not in degrees:
        raise InputError(path, f"has {n_rest} f_rest attributes; SH degrees 0..3 need 0, 9, 24 or 45")
    return rest_names, degrees[n_rest]


def read_ply(path: str | Path, device: str | torch.device = "cpu") -> Gaussians:
    """Read a Gaussian PLY (standard 3DGS layout, SH degree 0..3) into float32 tensors on ``device``.

    The SH degree is the one the file's ``f_rest`` count gives (0, 9, 24, 45 -> 0..3), lowered to the degree our
    header comment records when the file was written by us (its padding is then zero by construction). Raises
    InputError naming the file for anything that is not a valid Gaussian PLY: missing attributes, NaN/inf values,
    a vertex count the data does not match, a truncated file, an unknown format.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(path, "file does not exist")
    if path.is_dir():
        raise InputError(path, "is a folder, expected a .ply file")
    try:
        with open(path, "rb") as f:
            head = f.read(_MAX_HEADER_BYTES)
        fmt, elements, comments, start = _parse_header(path, head)
        vertex = next((e for e in elements if e.name == "vertex"), None)
        if vertex is None:
            raise InputError(path, "PLY file has no 'vertex' element")
        # Attributes are checked from the header first: a file missing them is refused before its data is read.
        rest_names, file_degree = _check_attributes(path, {name for name, _ in vertex.properties}, elements)
        table = _read_vertex_table(path, fmt, elements, start)
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    n = len(table)
    if n == 0:
        raise InputError(path, "PLY file holds no Gaussians (vertex count 0)")

    used = _REQUIRED + rest_names
    for name in used:
        col = table[name]
        if col.dtype.kind == "f":
            bad = int((~np.isfinite(col)).sum())
            if bad:
                raise InputError(path, f"{bad} of {n} Gaussians have NaN or infinite '{name}'")
            if col.dtype.itemsize > 4:  # doubles: the model holds float32, where 1e300 is infinite
                bad = int((np.abs(col) > np.finfo(np.float32).max).sum())
                if bad:
                    raise InputError(path, f"{bad} of {n} Gaussians have '{name}' beyond float32's range (up to "
                                           f"{float(np.abs(col).max()):.3g})")

    def cols(names: list[str]) -> np.ndarray:
        return np.stack([table[c].astype(np.float32) for c in names], axis=1) if names else np.zeros((n, 0), np.float32)

    k1 = num_sh_coeffs(file_degree) - 1
    shN = cols(rest_names).reshape(n, 3, k1).transpose(0, 2, 1)  # channel-major in the file
    degree = file_degree
    recorded = _recorded_degree(comments)
    if recorded is not None and recorded < file_degree and not shN[:, num_sh_coeffs(recorded) - 1:].any():
        degree = recorded
        shN = shN[:, : num_sh_coeffs(degree) - 1]

    def t(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)).to(device)

    return Gaussians(
        means=t(cols(["x", "y", "z"])),
        log_scales=t(cols(["scale_0", "scale_1", "scale_2"])),
        quats=t(cols(["rot_0", "rot_1", "rot_2", "rot_3"])),
        opacity_logits=t(table["opacity"]),
        sh0=t(cols(["f_dc_0", "f_dc_1", "f_dc_2"])[:, None, :]),
        shN=t(shN),
        sh_degree=degree,
    )


def _recorded_degree(comments: list[str]) -> int | None:
    for c in comments:
        if c.startswith(_DEGREE_COMMENT):
            try:
                d = int(c[len(_DEGREE_COMMENT):].strip())
            except ValueError:
                return None
            return d if 0 <= d <= MAX_SH_DEGREE else None
    return None


# ------------------------------------------------------------------ the header and whole tables, for other layouts
def ply_elements(path: str | Path) -> list[tuple[str, int, list[str]]]:
    """(name, count, property names) of each element a PLY header declares; InputError naming the file for a
    missing or unreadable file or a header that does not parse. Reads only the header."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(_MAX_HEADER_BYTES)
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    _, elements, _, _ = _parse_header(path, head)
    return [(e.name, e.count, [name for name, _ in e.properties]) for e in elements]


def read_binary_elements(path: str | Path) -> dict[str, np.ndarray]:
    """Every element of a binary PLY without list properties, as structured arrays in native byte order, the file's
    size checked against the header first (the compressed PLY's chunk/vertex/sh tables)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(_MAX_HEADER_BYTES)
        fmt, elements, _, start = _parse_header(path, head)
        if fmt == "ascii":
            raise InputError(path, "is an ASCII PLY; this layout is binary")
        order = "<" if fmt == "binary_little_endian" else ">"
        dtypes = []
        for e in elements:
            if e.has_list:
                raise InputError(path, f"PLY element '{e.name}' has list properties")
            dtypes.append(np.dtype([(n, order + t) for n, t in e.properties]))
        need = sum(e.count * d.itemsize for e, d in zip(elements, dtypes))
        size = path.stat().st_size - start
        if size != need:
            what = "truncated" if size < need else f"{size - need} bytes longer than its header says"
            raise InputError(path, f"PLY file is {what}: the header declares {need} bytes of data, the file holds "
                                   f"{size}")
        tables, offset = {}, start
        for e, d in zip(elements, dtypes):
            tables[e.name] = np.fromfile(path, dtype=d, count=e.count, offset=offset).astype(d.newbyteorder("="))
            offset += e.count * d.itemsize
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    return tables
