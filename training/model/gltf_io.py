"""Binary glTF 2.0 (``.glb``) with Khronos's ``KHR_gaussian_splatting``: one file a general 3D pipeline can carry,
loaded by the PlayCanvas engine and written by SplatTransform.

Our own code: no Python glTF library decodes accessors, and a GLB is three small pieces (pyproject.toml says which
libraries were looked at). The rules, cited from the specs:

- **GLB** (glTF 2.0, "GLB File Format Specification"): a 12-byte header (magic ``glTF``, version 2, total length),
  then chunks of (length, type, data): first JSON (``JSON``, padded with spaces to 4 bytes), then the binary buffer
  (``BIN\\0``, padded with zeros), which is buffer 0 when that buffer has no ``uri``.
- **The primitive** (KHR_gaussian_splatting, "Ellipse Kernel"): ``mode`` POINTS (0), the extension object with
  ``kernel: "ellipse"`` and ``colorSpace`` (we write ``srgb_rec709_display``: 3DGS trains on display-referred
  sRGB photos); attributes ``POSITION`` (VEC3 float, with ``min``/``max``, which glTF requires for positions),
  ``KHR_gaussian_splatting:ROTATION`` (VEC4, unit quaternion in glTF's x, y, z, w order), ``:SCALE`` (VEC3,
  *linear*, not negative), ``:OPACITY`` (SCALAR, *linear* in [0, 1]), ``:SH_DEGREE_0_COEF_0`` (VEC3) and, per
  degree l kept, ``:SH_DEGREE_l_COEF_n`` for n = 0..2l (VEC3, ordered from the lowest m, as the 3DGS f_rest),
  plus ``COLOR_0`` for viewers without the extension ("Fallback Behavior": the DC colour, clamped, decoded from
  sRGB to linear because COLOR_0 is linear, and the opacity as alpha).
- **Axes**: glTF is "+Y up ... the front of a glTF asset faces +Z" and right-handed, so +X is the asset's left:
  left-up-front (LUF). splat-transform writes LUF too (a PLY turned half about z, as SuperSplat shows a PLY), and
  so do we: training/model/axes.py turns our RDF half about z on the way out and back on the way in.
- **Colour space** (the extension's ``colorSpace``): ``srgb_rec709_display`` is read as it is;
  ``lin_rec709_display`` is turned to sRGB per Gaussian (exact for the DC colour, first order for the SH; the
  spec blends before the transfer curve, which no per-Gaussian colour can express); other values are refused.

We write every attribute as float32 (COLOR_0 as normalised bytes), one tightly packed buffer view each. Reading
takes what the extension allows: floats or the normalised/unnormalised integer types its table lists, strided
views, any number of splat primitives (joined, at the lowest SH degree among them); it refuses what it cannot
apply (node transforms, sparse accessors, external buffers, a required extension other than this one). Every
JSON value is checked for its type, every offset at both ends against its buffer view and the binary chunk, and
the Gaussians declared against the binary chunk (each needs its 12-byte float SH_DEGREE_0) before anything is
allocated; a failure is one line naming the file.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import torch

from training.core.atomic_write import atomic_open
from training.core.errors import InputError
from training.core.json_numbers import NumberOutOfRange, parse_json
from training.core.memory import check_fits
from training.model.axes import MODEL_AXES, convert_axes
from training.model.gaussians import Gaussians, num_sh_coeffs
from training.model.sh_constants import SH_C0

EXTENSION = "KHR_gaussian_splatting"
GLB_MAGIC, GLB_VERSION = b"glTF", 2
CHUNK_JSON, CHUNK_BIN = 0x4E4F534A, 0x004E4942
FLOAT, UNSIGNED_BYTE, ARRAY_BUFFER, POINTS = 5126, 5121, 34962, 0
MAX_SH_DEGREE = 3
_COMPONENTS = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
# each attribute's accessor type, as the extension defines it (its SH coefficients are all VEC3)
_ATTRIBUTE_TYPES = {"POSITION": "VEC3", "ROTATION": "VEC4", "SCALE": "VEC3", "OPACITY": "SCALAR"}
_NUMBER = "{: .8e}"  # 9 significant digits give float32 back exactly; a fixed width keeps the JSON's size known
_IDENTITY = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
GLTF_AXES = "LUF"  # glTF 2.0: +Y up, the asset's front facing +Z, right-handed (x to the asset's left)
SRGB, LINEAR = "srgb_rec709_display", "lin_rec709_display"
COLOR_SPACES = (SRGB, LINEAR)


def sh_attribute(degree: int, n: int) -> str:
    return f"{EXTENSION}:SH_DEGREE_{degree}_COEF_{n}"


def _layout(sh_bands: int) -> list[tuple[str, str, int]]:
    """(attribute, accessor type, component type) in the order written."""
    out = [("POSITION", "VEC3", FLOAT), ("COLOR_0", "VEC4", UNSIGNED_BYTE),
           (f"{EXTENSION}:ROTATION", "VEC4", FLOAT), (f"{EXTENSION}:SCALE", "VEC3", FLOAT),
           (f"{EXTENSION}:OPACITY", "SCALAR", FLOAT), (sh_attribute(0, 0), "VEC3", FLOAT)]
    out += [(sh_attribute(d, i), "VEC3", FLOAT) for d in range(1, sh_bands + 1) for i in range(2 * d + 1)]
    return out


def _json_chunk(count: int, sh_bands: int, lo, hi) -> bytes:
    """The JSON chunk, space-padded to 4 bytes. Its length depends on count and bands only."""
    views, accessors, attributes, offset = [], [], {}, 0
    for i, (name, kind, component) in enumerate(_layout(sh_bands)):
        size = count * _WIDTH[kind] * (4 if component == FLOAT else 1)
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": size, "target": ARRAY_BUFFER})
        acc = {"bufferView": i, "componentType": component, "count": count, "type": kind}
        if component == UNSIGNED_BYTE:
            acc["normalized"] = True
        if name == "POSITION":
            acc["min"], acc["max"] = "@MIN@", "@MAX@"
        accessors.append(acc)
        attributes[name] = i
        offset += size
    doc = {"asset": {"version": "2.0", "generator": "splatstyler"}, "extensionsUsed": [EXTENSION],
           "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": attributes, "mode": POINTS, "extensions": {EXTENSION: {
               "kernel": "ellipse", "colorSpace": "srgb_rec709_display", "projection": "perspective",
               "sortingMethod": "cameraDistance"}}}]}],
           "buffers": [{"byteLength": offset}], "bufferViews": views, "accessors": accessors}
    text = json.dumps(doc, separators=(",", ":"))
    numbers = lambda v: "[" + ",".join(_NUMBER.format(float(x)) for x in v) + "]"  # noqa: E731
    text = text.replace('"@MIN@"', numbers(lo)).replace('"@MAX@"', numbers(hi))
    data = text.encode("utf-8")
    return data + b" " * (-len(data) % 4)


def glb_size(count: int, sh_bands: int) -> int:
    """Bytes ``write_glb`` writes for ``count`` Gaussians keeping ``sh_bands`` (0-3) bands."""
    n = int(count)
    body = sum(n * _WIDTH[kind] * (4 if comp == FLOAT else 1) for _, kind, comp in _layout(sh_bands))
    return 12 + 8 + len(_json_chunk(n, sh_bands, (0, 0, 0), (0, 0, 0))) + 8 + body


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def write_glb(path: str | Path, gaussians: Gaussians) -> None:
    """Write ``gaussians`` (SH degree 0..3, RDF axes) as a .glb with KHR_gaussian_splatting, atomically.
    ValueError for an empty or non-finite model."""
    if len(gaussians) == 0:
        raise ValueError("cannot write a .glb of no Gaussians")
    if gaussians.sh_degree > MAX_SH_DEGREE:
        raise ValueError(f".glb export holds SH degree 0..{MAX_SH_DEGREE}, the model has {gaussians.sh_degree}")
    for name, t in gaussians.parameters().items():
        if t.numel() and not bool(torch.isfinite(t).all()):
            raise ValueError(f"cannot write a .glb: the model has non-finite {name}")
    g = convert_axes(gaussians, MODEL_AXES, GLTF_AXES)
    a = {k: v.detach().to("cpu", torch.float64).numpy() for k, v in g.parameters().items()}
    n, bands = len(g), g.sh_degree
    quats = a["quats"] / np.linalg.norm(a["quats"], axis=1, keepdims=True).clip(1e-30)
    quats[~np.isfinite(quats).all(axis=1) | ~a["quats"].any(axis=1)] = (1.0, 0.0, 0.0, 0.0)
    opacity = 1.0 / (1.0 + np.exp(-a["opacity_logits"]))
    dc = a["sh0"][:, 0, :]
    colour = np.concatenate([_srgb_to_linear(np.clip(0.5 + SH_C0 * dc, 0.0, 1.0)), opacity[:, None]], axis=1)
    columns = [a["means"], np.round(colour * 255.0), quats[:, [1, 2, 3, 0]], np.exp(a["log_scales"]),
               opacity, dc]
    columns += [a["shN"][:, k, :] for k in range(num_sh_coeffs(bands) - 1)]
    pos32 = a["means"].astype(np.float32)
    head = _json_chunk(n, bands, pos32.min(axis=0), pos32.max(axis=0))
    total = glb_size(n, bands)
    with atomic_open(path, "wb") as f:
        f.write(GLB_MAGIC + struct.pack("<II", GLB_VERSION, total))
        f.write(struct.pack("<II", len(head), CHUNK_JSON) + head)
        f.write(struct.pack("<II", total - 20 - len(head) - 8, CHUNK_BIN))
        for (_, _, component), col in zip(_layout(bands), columns):
            f.write(np.ascontiguousarray(col, dtype="<f4" if component == FLOAT else "u1").tobytes())


# ----------------------------------------------------------------------------------------------------- reading
def _chunks(path: Path, raw: bytes) -> tuple[dict, memoryview]:
    if len(raw) < 12 or raw[:4] != GLB_MAGIC:
        raise InputError(path, "not a binary glTF (.glb) file: it does not start with 'glTF'")
    version, length = struct.unpack_from("<II", raw, 4)
    if version != GLB_VERSION:
        raise InputError(path, f"glTF version {version}; only glTF 2.0 is read")
    if length != len(raw):
        raise InputError(path, f"the GLB header says {length} bytes, the file has {len(raw)} (truncated or "
                               "damaged)")
    offset, found = 12, []
    while offset < length:
        if offset + 8 > length:
            raise InputError(path, "GLB chunk header runs past the end of the file")
        size, kind = struct.unpack_from("<II", raw, offset)
        if offset + 8 + size > length:
            raise InputError(path, f"GLB chunk at byte {offset} declares {size} bytes past the end of the file")
        found.append((kind, memoryview(raw)[offset + 8: offset + 8 + size]))
        offset += 8 + size + (-size % 4 if kind != CHUNK_JSON else 0)
    if not found or found[0][0] != CHUNK_JSON:
        raise InputError(path, "GLB file has no JSON chunk first")
    try:
        doc = parse_json(bytes(found[0][1]).decode("utf-8"))
    except NumberOutOfRange as exc:
        raise InputError(path, f"the GLB's JSON chunk {exc}") from None
    except (UnicodeDecodeError, ValueError) as exc:
        raise InputError(path, f"the GLB's JSON chunk is not valid JSON ({exc})") from None
    except RecursionError:
        raise InputError(path, "the GLB's JSON chunk is nested too deeply to read (damaged, or made to exhaust "
                               "the reader)") from None
    if not isinstance(doc, dict):
        raise InputError(path, "the GLB's JSON chunk is not a glTF object")
    binary = next((data for kind, data in found[1:] if kind == CHUNK_BIN), memoryview(b""))
    return doc, binary


def _kind(value) -> str:
    return {dict: "an object", list: "an array", str: "a string", bool: "a boolean", type(None): "null"}.get(
        type(value), "a number")


def _array(path: Path, owner: dict, key: str, where: str) -> list:
    value = owner.get(key, [])
    if not isinstance(value, list):
        raise InputError(path, f"{where} '{key}' is {_kind(value)}, not an array")
    return value


def _object(path: Path, value, where: str) -> dict:
    if not isinstance(value, dict):
        raise InputError(path, f"{where} is {_kind(value)}, not an object")
    return value


def _whole(path: Path, owner: dict, key: str, where: str, default=None) -> int:
    """A non-negative whole number of the JSON (glTF's offsets, lengths, counts, indices)."""
    value = owner.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        shown = "missing" if key not in owner else f"{value!r}"
        raise InputError(path, f"{where} '{key}' is {shown}, not a whole number >= 0")
    return value


def _get(path: Path, items, index, what: str) -> dict:
    if not isinstance(items, list) or isinstance(index, bool) or not isinstance(index, int) \
            or not 0 <= index < len(items) or not isinstance(items[index], dict):
        raise InputError(path, f"glTF {what} {index!r} does not exist")
    return items[index]


def _accessor_shape(path: Path, doc: dict, index, name: str) -> tuple[dict, np.dtype, int, int]:
    """(accessor, component dtype, width, count), checked from the JSON alone."""
    acc = _get(path, doc.get("accessors"), index, f"accessor (of {name})")
    if "sparse" in acc:
        raise InputError(path, f"{name}: sparse accessors are not read")
    component, kind = acc.get("componentType"), acc.get("type")
    if isinstance(component, bool) or component not in _COMPONENTS or not isinstance(kind, str) \
            or kind not in _WIDTH:
        raise InputError(path, f"{name}: accessor {index} has componentType {component!r}, type {kind!r}")
    count = _whole(path, acc, "count", f"{name}: accessor {index}")
    return acc, np.dtype(_COMPONENTS[component]), _WIDTH[kind], count


def _accessor(path: Path, doc: dict, binary: memoryview, index, name: str) -> np.ndarray:
    """Accessor ``index`` as float32 (count, width), normalised integers mapped to [0, 1] / [-1, 1]. Every offset
    is checked at both ends against its buffer view and the binary chunk before a byte is read."""
    acc, dtype, width, count = _accessor_shape(path, doc, index, name)
    if "bufferView" not in acc:  # glTF: an accessor without a buffer view holds zeros
        return np.zeros((count, width), np.float32)
    where = f"{name}: buffer view {acc['bufferView']!r}"
    view = _get(path, doc.get("bufferViews"), acc["bufferView"], f"bufferView (of {name})")
    buffer_index = _whole(path, view, "buffer", where)
    buffer = _get(path, doc.get("buffers"), buffer_index, f"buffer (of {name})")
    if "uri" in buffer or buffer_index != 0:
        raise InputError(path, f"{name} lies in an external or data-URI buffer; only the GLB's own binary chunk "
                               "(buffer 0) is read")
    elem = dtype.itemsize * width
    view_start = _whole(path, view, "byteOffset", where, 0)
    view_length = _whole(path, view, "byteLength", where)
    stride = _whole(path, view, "byteStride", where, elem)
    offset = _whole(path, acc, "byteOffset", f"{name}: accessor {index}", 0)
    span = stride * (count - 1) + elem if count else 0
    if stride < elem or offset + span > view_length or view_start + view_length > len(binary):
        raise InputError(path, f"{name}: accessor {index} reads bytes {view_start + offset}.."
                               f"{view_start + offset + span} of a buffer view of bytes {view_start}.."
                               f"{view_start + view_length}, in a binary chunk of {len(binary)} bytes (truncated or "
                               "damaged)")
    values = np.ndarray((count, width), dtype=dtype, buffer=binary, offset=view_start + offset,
                        strides=(stride, dtype.itemsize))
    out = values.astype(np.float32)
    normalized = acc.get("normalized", False)
    if not isinstance(normalized, bool):
        raise InputError(path, f"{name}: accessor {index} 'normalized' is {_kind(normalized)}, not a boolean")
    if normalized and dtype.kind in "iu":
        out /= np.float32(np.iinfo(dtype).max)
        np.maximum(out, np.float32(-1.0), out=out)
    return out


class _Plan:
    """A splat primitive checked from the JSON: its attributes' accessors, count, SH degree and colour space."""

    def __init__(self, path: Path, doc: dict, prim: dict, where: str):
        attrs = _object(path, prim.get("attributes", {}), f"{where} 'attributes'")
        mode = prim.get("mode", 4)
        if mode != POINTS or isinstance(mode, bool):
            raise InputError(path, f"a {EXTENSION} primitive has mode {mode!r}; the extension needs POINTS (0)")
        needed = ["POSITION", f"{EXTENSION}:ROTATION", f"{EXTENSION}:SCALE", f"{EXTENSION}:OPACITY",
                  sh_attribute(0, 0)]
        missing = [a for a in needed if a not in attrs]
        if missing:
            raise InputError(path, f"{EXTENSION} primitive lacks {', '.join(missing)}")
        degree = 0
        while degree < MAX_SH_DEGREE and sh_attribute(degree + 1, 0) in attrs:
            names = [sh_attribute(degree + 1, i) for i in range(2 * degree + 3)]
            if not all(a in attrs for a in names):
                raise InputError(path, f"SH degree {degree + 1} is partly defined (the extension needs all "
                                       f"{len(names)} coefficients or none)")
            needed += names
            degree += 1
        shapes = {a: _accessor_shape(path, doc, attrs[a], a) for a in needed}
        for a, (acc, _, width, _) in shapes.items():
            kind = _ATTRIBUTE_TYPES.get(a.removeprefix(f"{EXTENSION}:"), "VEC3")  # every SH coefficient is VEC3
            if width != _WIDTH[kind]:
                raise InputError(path, f"{a}: accessor {attrs[a]} is {acc['type']}; {EXTENSION} needs {kind}")
        counts = {a: shape[3] for a, shape in shapes.items()}
        if len(set(counts.values())) != 1:
            raise InputError(path, f"{EXTENSION} attributes differ in count: {counts}")
        ext = _object(path, prim["extensions"][EXTENSION], f"{where} {EXTENSION}")
        space = ext.get("colorSpace", SRGB)  # required by the extension; drafts before it meant sRGB
        if space not in COLOR_SPACES:
            raise InputError(path, f"{EXTENSION} colorSpace {space!r} is not one this reader applies "
                                   f"({', '.join(COLOR_SPACES)})")
        self.attrs, self.count, self.degree, self.linear = attrs, counts["POSITION"], degree, space == LINEAR


def _check_nodes(path: Path, doc: dict) -> None:
    """Refuse a transform on any node the splats hang under: a mesh's node and every node above it (a parent's
    transform moves its children's meshes as much as their own does, glTF 2.0 "Transformations"). Nodes that lead
    to no mesh (a camera, a light) may move freely."""
    shapes = {"matrix": 16, "translation": 3, "rotation": 4, "scale": 3}
    neutral = {"matrix": _IDENTITY, "translation": [0, 0, 0], "rotation": [0, 0, 0, 1], "scale": [1, 1, 1]}
    nodes = [_object(path, node, f"glTF node {i}") for i, node in enumerate(_array(path, doc, "nodes", "glTF"))]
    parent: dict[int, int] = {}
    for i, node in enumerate(nodes):
        for child in _array(path, node, "children", f"glTF node {i}"):
            if isinstance(child, bool) or not isinstance(child, int) or not 0 <= child < len(nodes):
                raise InputError(path, f"glTF node {i} has child {child!r}, which does not exist")
            if child in parent or child == i:
                raise InputError(path, f"glTF node {child} has more than one parent (the node tree is a tree)")
            parent[child] = i
    carrying: set[int] = set()  # the mesh nodes and every node above them
    for i, node in enumerate(nodes):
        if "mesh" not in node:
            continue
        at = i
        while at not in carrying:
            carrying.add(at)
            if at not in parent:
                break
            at = parent[at]
    for i in sorted(carrying):
        node = nodes[i]
        for key, size in shapes.items():
            if key not in node:
                continue
            value = node[key]
            if not isinstance(value, list) or len(value) != size \
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
                raise InputError(path, f"glTF node {i} '{key}' is not {size} numbers")
            if [float(v) for v in value] != [float(v) for v in neutral[key]]:
                what = "places its splats" if "mesh" in node else "moves the splats of a node below it"
                raise InputError(path, f"glTF node {i} {what} with a transform ('{key}'); only untransformed splat "
                                       "meshes are read")


def _splat_primitives(path: Path, doc: dict) -> list[tuple[dict, str]]:
    out = []
    for m, mesh in enumerate(_array(path, doc, "meshes", "glTF")):
        mesh = _object(path, mesh, f"glTF mesh {m}")
        for p, prim in enumerate(_array(path, mesh, "primitives", f"glTF mesh {m}")):
            where = f"glTF mesh {m} primitive {p}"
            prim = _object(path, prim, where)
            if EXTENSION in _object(path, prim.get("extensions", {}), f"{where} 'extensions'"):
                out.append((prim, where))
    return out


def _to_srgb(dc: np.ndarray, rest: np.ndarray) -> None:
    """Linear (``lin_rec709_display``) splat colours as the sRGB ones our renderer blends, in place: the DC colour
    exactly, the view-dependent part to first order (scaled by the transfer curve's slope at the DC colour). Exact
    would be to blend in linear and encode after, which no per-Gaussian colour can express."""
    c = np.float32(0.5) + np.float32(SH_C0) * dc
    low = c <= 0.0031308
    safe = np.maximum(c, np.float32(0.0031308))
    srgb = np.where(low, 12.92 * c, 1.055 * safe ** (1 / 2.4) - 0.055)
    slope = np.where(low, 12.92, 1.055 / 2.4 * safe ** (1 / 2.4 - 1))
    dc[...] = (srgb - 0.5) / SH_C0
    if rest.size:
        rest *= slope[:, None, :].astype(np.float32)


def read_glb(path: str | Path, device: str | torch.device = "cpu") -> Gaussians:
    """Read the KHR_gaussian_splatting primitives of a .glb into one model with RDF axes (from glTF's LUF), its
    colours in sRGB. InputError naming the file, in one line, for a damaged file, one without splats, one that
    declares more than it holds, or one that needs what this reader does not do (module doc)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    doc, binary = _chunks(path, raw)
    other = [e for e in _array(path, doc, "extensionsRequired", "glTF") if e != EXTENSION]
    if other:
        raise InputError(path, f"needs glTF extension(s) {', '.join(map(str, other))}, which this reader does "
                               "not support")
    _check_nodes(path, doc)
    prims = _splat_primitives(path, doc)
    if not prims:
        raise InputError(path, f"glTF file holds no {EXTENSION} primitive (no Gaussian splats)")
    plans = [_Plan(path, doc, prim, where) for prim, where in prims]
    n = sum(p.count for p in plans)
    if n == 0:
        raise InputError(path, "glTF file holds no Gaussians (count 0)")
    if n * 12 > len(binary):
        raise InputError(path, f"the glTF declares {n} Gaussians, but its binary chunk of {len(binary)} bytes holds "
                               f"at most {len(binary) // 12} (each needs a float {sh_attribute(0, 0)}; damaged, or "
                               "made to exhaust memory)")
    degree = min(p.degree for p in plans)
    k = num_sh_coeffs(degree) - 1
    check_fits(path, n, 4 * (2 * (3 + 4 + 3 + 1 + 3) + 3 * k), f"{n} Gaussians of SH degree {degree}")

    means, xyzw = np.empty((n, 3), np.float32), np.empty((n, 4), np.float32)
    scales, opacity = np.empty((n, 3), np.float32), np.empty(n, np.float32)
    dc, rest = np.empty((n, 3), np.float32), np.empty((n, k, 3), np.float32)
    at = 0
    for plan in plans:
        part = slice(at, at + plan.count)

        def fill(name: str) -> np.ndarray:
            return _accessor(path, doc, binary, plan.attrs[name], name)

        means[part] = fill("POSITION")
        xyzw[part] = fill(f"{EXTENSION}:ROTATION")
        scales[part] = fill(f"{EXTENSION}:SCALE")
        opacity[part] = fill(f"{EXTENSION}:OPACITY")[:, 0]
        dc[part] = fill(sh_attribute(0, 0))
        j = 0
        for d in range(1, degree + 1):
            for i in range(2 * d + 1):
                rest[part, j] = fill(sh_attribute(d, i))
                j += 1
        if plan.linear:
            _to_srgb(dc[part], rest[part])
        at += plan.count
    for name, v in [("POSITION", means), ("ROTATION", xyzw), ("SCALE", scales), ("OPACITY", opacity),
                    ("SH", dc), ("SH", rest)]:
        bad = int((~np.isfinite(v)).reshape(n, -1).any(axis=1).sum())
        if bad:
            raise InputError(path, f"{bad} of {n} Gaussians have NaN or infinite {name}")
    if (scales < 0).any():
        raise InputError(path, f"{int((scales < 0).any(axis=1).sum())} of {n} Gaussians have a negative SCALE")
    if ((opacity < 0) | (opacity > 1)).any():
        raise InputError(path, f"{int(((opacity < 0) | (opacity > 1)).sum())} of {n} Gaussians have an OPACITY "
                               "outside 0..1")
    # float32's ends: a zero scale or an opacity of exactly 0 or 1 still gets a finite log / logit
    eps = np.float32(2.0 ** -24)
    np.clip(opacity, eps, np.float32(1.0) - eps, out=opacity)
    quats = np.ascontiguousarray(xyzw[:, [3, 0, 1, 2]])
    del xyzw
    quats[~quats.any(axis=1)] = (1.0, 0.0, 0.0, 0.0)
    np.maximum(scales, np.finfo(np.float32).tiny, out=scales)
    np.log(scales, out=scales)
    logits = np.log(opacity / (np.float32(1.0) - opacity))
    g = Gaussians(means=torch.from_numpy(means), log_scales=torch.from_numpy(scales), quats=torch.from_numpy(quats),
                  opacity_logits=torch.from_numpy(logits), sh0=torch.from_numpy(dc[:, None, :]),
                  shN=torch.from_numpy(rest), sh_degree=degree)
    return convert_axes(g, GLTF_AXES, MODEL_AXES, in_place=True).to(device)
