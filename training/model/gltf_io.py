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
- **Axes**: glTF is Y-up, right-handed, the asset's front facing +Z: RUB, converted in training/model/axes.py.

We write every attribute as float32 (COLOR_0 as normalised bytes), one tightly packed buffer view each. Reading
takes what the extension allows: floats or the normalised/unnormalised integer types its table lists, strided
views, any number of splat primitives (joined, at the lowest SH degree among them); it refuses what it cannot
apply (node transforms, sparse accessors, external buffers, a required extension other than this one).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import torch

from training.core.atomic_write import atomic_open
from training.core.errors import InputError
from training.model.axes import rdf_rub
from training.model.gaussians import Gaussians, num_sh_coeffs
from training.model.sh_constants import SH_C0

EXTENSION = "KHR_gaussian_splatting"
GLB_MAGIC, GLB_VERSION = b"glTF", 2
CHUNK_JSON, CHUNK_BIN = 0x4E4F534A, 0x004E4942
FLOAT, UNSIGNED_BYTE, ARRAY_BUFFER, POINTS = 5126, 5121, 34962, 0
MAX_SH_DEGREE = 3
_COMPONENTS = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_NUMBER = "{: .8e}"  # 9 significant digits give float32 back exactly; a fixed width keeps the JSON's size known
_IDENTITY = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]


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
    g = rdf_rub(gaussians)
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
        doc = json.loads(bytes(found[0][1]).decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(path, f"the GLB's JSON chunk is not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise InputError(path, "the GLB's JSON chunk is not a glTF object")
    binary = next((data for kind, data in found[1:] if kind == CHUNK_BIN), memoryview(b""))
    return doc, binary


def _get(path: Path, items, index, what: str) -> dict:
    if not isinstance(items, list) or not isinstance(index, int) or not 0 <= index < len(items) \
            or not isinstance(items[index], dict):
        raise InputError(path, f"glTF {what} {index!r} does not exist")
    return items[index]


def _accessor(path: Path, doc: dict, binary: memoryview, index, name: str) -> np.ndarray:
    """Accessor ``index`` as float64 (count, width), normalised integers mapped to [0, 1] / [-1, 1]."""
    acc = _get(path, doc.get("accessors"), index, f"accessor (of {name})")
    if "sparse" in acc:
        raise InputError(path, f"{name}: sparse accessors are not read")
    component, kind, count = acc.get("componentType"), acc.get("type"), acc.get("count")
    if component not in _COMPONENTS or kind not in _WIDTH or not isinstance(count, int) or count < 0:
        raise InputError(path, f"{name}: accessor {index} has componentType {component!r}, type {kind!r}, "
                               f"count {count!r}")
    dtype, width = np.dtype(_COMPONENTS[component]), _WIDTH[kind]
    if "bufferView" not in acc:  # glTF: an accessor without a buffer view holds zeros
        return np.zeros((count, width))
    view = _get(path, doc.get("bufferViews"), acc["bufferView"], f"bufferView (of {name})")
    buffer = _get(path, doc.get("buffers"), view.get("buffer"), f"buffer (of {name})")
    if "uri" in buffer:
        raise InputError(path, f"{name} lies in an external or data-URI buffer; only the GLB's own binary chunk "
                               "is read")
    elem = dtype.itemsize * width
    stride = view.get("byteStride") or elem
    start = int(view.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
    view_end = int(view.get("byteOffset", 0)) + int(view.get("byteLength", -1))
    end = start + (stride * (count - 1) + elem if count else 0)
    if stride < elem or end > view_end or view_end > len(binary):
        raise InputError(path, f"{name}: accessor {index} reads bytes {start}..{end} beyond its buffer view or "
                               f"the binary chunk ({len(binary)} bytes; truncated or damaged)")
    values = np.ndarray((count, width), dtype=dtype, buffer=binary, offset=start, strides=(stride, dtype.itemsize))
    out = values.astype(np.float64)
    if acc.get("normalized") and dtype.kind in "iu":
        top = float(np.iinfo(dtype).max)
        out = np.maximum(out / top, -1.0)
    return out


def _primitive(path: Path, doc: dict, binary: memoryview, prim: dict) -> dict[str, np.ndarray]:
    attrs = prim.get("attributes") or {}
    if prim.get("mode", 4) != POINTS:
        raise InputError(path, f"a {EXTENSION} primitive has mode {prim.get('mode', 4)}; the extension needs "
                               "POINTS (0)")
    needed = ["POSITION", f"{EXTENSION}:ROTATION", f"{EXTENSION}:SCALE", f"{EXTENSION}:OPACITY", sh_attribute(0, 0)]
    missing = [a for a in needed if a not in attrs]
    if missing:
        raise InputError(path, f"{EXTENSION} primitive lacks {', '.join(missing)}")
    out = {a: _accessor(path, doc, binary, attrs[a], a) for a in needed}
    degree = 0
    while degree < MAX_SH_DEGREE and sh_attribute(degree + 1, 0) in attrs:
        names = [sh_attribute(degree + 1, i) for i in range(2 * degree + 3)]
        if not all(a in attrs for a in names):
            raise InputError(path, f"SH degree {degree + 1} is partly defined (the extension needs all "
                                   f"{len(names)} coefficients or none)")
        out.update({a: _accessor(path, doc, binary, attrs[a], a) for a in names})
        degree += 1
    counts = {a: len(v) for a, v in out.items()}
    if len(set(counts.values())) != 1:
        raise InputError(path, f"{EXTENSION} attributes differ in count: {counts}")
    out["degree"] = degree
    return out


def _check_nodes(path: Path, doc: dict) -> None:
    for i, node in enumerate(doc.get("nodes") or []):
        if not isinstance(node, dict) or "mesh" not in node:
            continue
        moved = ("matrix" in node and [float(v) for v in node["matrix"]] != _IDENTITY) \
            or node.get("translation", [0, 0, 0]) != [0, 0, 0] or node.get("scale", [1, 1, 1]) != [1, 1, 1] \
            or node.get("rotation", [0, 0, 0, 1]) != [0, 0, 0, 1]
        if moved:
            raise InputError(path, f"glTF node {i} places its splats with a transform; only untransformed splat "
                                   "meshes are read")


def read_glb(path: str | Path, device: str | torch.device = "cpu") -> Gaussians:
    """Read the KHR_gaussian_splatting primitives of a .glb into one model with RDF axes. InputError naming the
    file for a damaged file, one without splats, or one that needs what this reader does not do (module doc)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    doc, binary = _chunks(path, raw)
    other = [e for e in doc.get("extensionsRequired") or [] if e != EXTENSION]
    if other:
        raise InputError(path, f"needs glTF extension(s) {', '.join(map(str, other))}, which this reader does "
                               "not support")
    _check_nodes(path, doc)
    prims = [p for mesh in doc.get("meshes") or [] if isinstance(mesh, dict)
             for p in mesh.get("primitives") or [] if isinstance(p, dict) and EXTENSION in (p.get("extensions") or {})]
    if not prims:
        raise InputError(path, f"glTF file holds no {EXTENSION} primitive (no Gaussian splats)")
    parts = [_primitive(path, doc, binary, p) for p in prims]
    degree = min(p["degree"] for p in parts)

    def col(name: str) -> np.ndarray:
        return np.concatenate([p[name] for p in parts], axis=0)

    means, quats_xyzw = col("POSITION"), col(f"{EXTENSION}:ROTATION")
    scales, opacity = col(f"{EXTENSION}:SCALE"), col(f"{EXTENSION}:OPACITY")[:, 0]
    n = len(means)
    if n == 0:
        raise InputError(path, "glTF file holds no Gaussians (count 0)")
    rest = [col(sh_attribute(d, i)) for d in range(1, degree + 1) for i in range(2 * d + 1)]
    for name, v in [("POSITION", means), ("ROTATION", quats_xyzw), ("SCALE", scales), ("OPACITY", opacity),
                    ("SH", col(sh_attribute(0, 0)))] + [("SH", r) for r in rest]:
        bad = int((~np.isfinite(v)).reshape(n, -1).any(axis=1).sum())
        if bad:
            raise InputError(path, f"{bad} of {n} Gaussians have NaN or infinite {name}")
    if (scales < 0).any():
        raise InputError(path, f"{int((scales < 0).any(axis=1).sum())} of {n} Gaussians have a negative SCALE")
    if ((opacity < 0) | (opacity > 1)).any():
        raise InputError(path, f"{int(((opacity < 0) | (opacity > 1)).sum())} of {n} Gaussians have an OPACITY "
                               "outside 0..1")
    # float32's ends: a zero scale or an opacity of exactly 0 or 1 still gets a finite log / logit
    eps = 2.0 ** -24
    opacity = opacity.clip(eps, 1.0 - eps)
    quats = quats_xyzw[:, [3, 0, 1, 2]]
    quats[~quats.any(axis=1)] = (1.0, 0.0, 0.0, 0.0)

    def t(x: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)).to(device)

    shN = np.stack(rest, axis=1) if rest else np.zeros((n, 0, 3))
    rub = Gaussians(means=t(means), log_scales=t(np.log(np.maximum(scales, np.finfo(np.float32).tiny))),
                    quats=t(quats), opacity_logits=t(np.log(opacity / (1.0 - opacity))),
                    sh0=t(col(sh_attribute(0, 0))[:, None, :]), shN=t(shN), sh_degree=degree)
    return rdf_rub(rub)

