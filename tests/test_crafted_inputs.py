"""The probe list: crafted PLY, compressed PLY, .splat, .npy selections, projects and camera paths, each through the
commands that read it (``info``, ``export``, ``export --mask``, ``export --project``, ``video --path``) in a
process of its own under a 1.5 GB address-space limit (tests/crafted_probe.py): one line naming the file (and a
project's member), exit 2, no traceback, memory bounded by the file rather than by what it declares. A case for
another format is one more ``Case`` in ``CASES``.

21 of the first 34 failed on the code before (issue 38): a MemoryError after gigabytes (a .npy header of 1e9 bytes,
200 colour regions reading one member 200 times, 60 distinct 10-million-row members, a mask declaring 10^12 rows), an
exception's class name with exit 1 (an empty or zipped mask, a repeated PLY property, nested JSON, a model SPZ cannot
place), a file written though it should not be (200 MB extracted from a 200 kB project), an error naming a deleted
temporary file, or a file accepted whose export our own readers then refused (a log-scale of 100). The others
(declared counts a file cannot hold, truncations, a manifest of 1 GB) keep what already held.

The cases after them (issue 49) failed with exit 1 and an exception's name, or were read wrong without a word: whole
numbers of 400 digits (beyond a float) anywhere in a project, a camera path or a .glb, and a .glb count of 5000
digits; .glb attributes of the wrong accessor type (broadcast, truncated or a numpy error) and a parent node that
moves the splats (its transform was ignored); a project member encrypted or compressed with PPMd; a 60 MB manifest of
``{},`` that json would make 1.9 GB of; a .txt mask of 1e19 or inf; an ASCII PLY of no vertices.
"""

from __future__ import annotations

import io
import json
import struct
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import torch

from tests.crafted_probe import Case, check_case
from tests.test_spz_gltf_crafted import glb, splat_doc
from training.model.gaussians import Gaussians
from training.model.ply_io import write_ply

N = 64
REQUIRED = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1",
            "rot_2", "rot_3"]


def gaussians(n: int = N, **change) -> Gaussians:
    g = torch.Generator().manual_seed(0)
    params = dict(means=torch.randn(n, 3, generator=g), log_scales=torch.randn(n, 3, generator=g) - 4,
                  quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g),
                  sh0=torch.randn(n, 1, 3, generator=g), shN=torch.zeros(n, 0, 3))
    for name, (row, value) in change.items():
        params[name][row] = value
    return Gaussians(**params, sh_degree=0)


def ply(path: Path, **change) -> Path:
    write_ply(path.with_suffix(".ply"), gaussians(**change))
    return path.with_suffix(".ply")


def ply_header(*lines: str) -> bytes:
    return ("\n".join(["ply", "format binary_little_endian 1.0", *lines, "end_header"]) + "\n").encode()


def vertex(count: int, names=REQUIRED, kind: str = "float") -> list[str]:
    return [f"element vertex {count}"] + [f"property {kind} {name}" for name in names]


def raw(suffix: str, data: bytes) -> Callable:
    def make(path: Path) -> Path:
        out = path.with_suffix(suffix)
        out.write_bytes(data)
        return out

    return make


def npy(header: dict | None = None, data: bytes = b"", version=(1, 0), header_length: int | None = None) -> bytes:
    """A .npy file's bytes: numpy's header for ``header``, or a declared header length with nothing behind it."""
    buf = io.BytesIO()
    if header_length is not None:
        buf.write(b"\x93NUMPY" + bytes(version) + struct.pack("<H" if version == (1, 0) else "<I", header_length))
    else:
        writer = np.lib.format.write_array_header_1_0 if version == (1, 0) else np.lib.format.write_array_header_2_0
        writer(buf, header)
    return buf.getvalue() + data


def saved(array) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=True)
    return buf.getvalue()


# ---------------------------------------------------------------------------------------------------- projects
def project(manifest: dict | str, members: dict[str, bytes | Callable] | None = None, deflate: bool = True):
    """A .splatproj whose model is ``m.ply`` beside it (valid), with ``members`` written as given (a callable is
    handed the member's open stream: large members are streamed, as a crafted one would be)."""
    def make(path: Path) -> Path:
        ply(path.parent / "m")
        out = path.with_suffix(".splatproj")
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED) as z:
            z.writestr("project.json", manifest if isinstance(manifest, str) else json.dumps(manifest))
            for name, content in (members or {}).items():
                if callable(content):
                    with z.open(name, "w", force_zip64=True) as f:
                        content(f)
                else:
                    z.writestr(name, content)
        return out

    return make


def with_model(**fields) -> dict:
    return {"version": 1, "models": [{"path": "m.ply", **fields}]}


def zeros(count: int, header: bytes = b""):
    def write(f) -> None:
        f.write(header)
        block = bytes(1 << 24)
        for _ in range(count // len(block)):
            f.write(block)
        f.write(bytes(count % len(block)))

    return write


def bool_rows(rows: int):
    return zeros(rows, npy({"descr": "|b1", "fortran_order": False, "shape": (rows,)}))


def huge_header_member(f) -> None:  # a v2 header declaring 1e9 bytes, and the spaces it declares
    zeros(0, npy(version=(2, 0), header_length=10**9))(f)
    block = b" " * (1 << 24)
    for _ in range(10**9 // len(block)):
        f.write(block)
    f.write(b" " * (10**9 % len(block)))


DEEP = "[" * 100_000 + "]" * 100_000
KEY = {"world_to_camera": np.eye(4).tolist(), "fx": 100, "fy": 100, "cx": 50, "cy": 50, "width": 100, "height": 100}


def splat_records(scale: float) -> bytes:
    rec = np.zeros(4, dtype=[("position", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)),
                             ("rotation", "u1", (4,))])
    rec["scale"] = 0.01
    rec["scale"][0] = scale
    rec["rotation"] = (255, 128, 128, 128)
    return rec.tobytes()


def compressed_ply(scale_bound: float = 0.0, chunks: int = 1, vertices: int = 4, repeat: bool = False) -> bytes:
    from training.model.compressed_ply import CHUNK_PROPERTIES, VERTEX_PROPERTIES

    chunk = np.zeros((chunks, len(CHUNK_PROPERTIES)), "<f4")
    chunk[:, 9:12] = scale_bound  # max_scale_x..z: the log-scale a word of all ones decodes to
    words = np.full((vertices, 4), 0xFFFFFFFF, "<u4")
    props = CHUNK_PROPERTIES + (["min_x"] if repeat else [])
    if repeat:
        chunk = np.concatenate([chunk, np.zeros((chunks, 1), "<f4")], axis=1)
    header = ply_header(f"element chunk {chunks}", *[f"property float {p}" for p in props],
                        f"element vertex {vertices}", *[f"property uint {p}" for p in VERTEX_PROPERTIES])
    return header + chunk.tobytes() + words.tobytes()


def npz(path: Path) -> Path:
    out = path.with_suffix(".npy")  # an .npz under a .npy name: np.load hands back an NpzFile
    with open(out, "wb") as f:
        np.savez(f, mask=np.ones(N, bool))
    return out


def manifest_bomb(path: Path) -> Path:
    out = path.with_suffix(".splatproj")
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z, z.open("project.json", "w", force_zip64=True) as f:
        f.write(b'{"version": 1, "layout": "')
        zeros(10**9)(f)
        f.write(b'"}')
    return out


# ------------------------------------------------------------------------------------------- numbers beyond a float
BIG = "1" + "0" * 400  # a whole number no float holds (a float reaches about 1.8e308)


def big_in(manifest: dict, where: str) -> str:
    """``manifest`` as JSON with the placeholder string ``where`` stands for replaced by BIG, unquoted."""
    return json.dumps(manifest).replace(f'"{where}"', BIG)


def project_with_big(**fields) -> Callable:
    return project(big_in({"version": 1, "models": [{"path": "m.ply"}], **fields}, "@BIG@"))


def model_with_big(**fields) -> Callable:
    return project(big_in({"version": 1, "models": [{"path": "m.ply", **fields}]}, "@BIG@"))


def camera_path_with_big(key: dict | None = None, **fields) -> Callable:
    return raw(".json", big_in({"keyframes": [key or KEY, KEY], **fields}, "@BIG@").encode())


EYE_BIG = [[1, 0, 0, "@BIG@"], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


# ------------------------------------------------------------------------------------------------------ .glb files
def glb_file(edit=None, text_edit=None, count: int = 10) -> Callable:
    """A valid .glb of ``count`` splats (tests/test_spz_gltf_crafted.py), its glTF changed by ``edit(doc)`` and its
    JSON text by ``text_edit(text)``."""
    def make(path: Path) -> Path:
        doc, data = splat_doc(count)
        if edit is not None:
            edit(doc)
        text = json.dumps(doc)
        return raw(".glb", glb(text_edit(text) if text_edit else text, data))(path)

    return make


def accessor_type(attribute: str, kind: str, count: int = 10) -> Callable:
    """The attribute's accessor of type ``kind``, with a view of its own as long as that type needs (so no bounds
    check refuses it first: only the type is wrong)."""
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[kind]

    def make(path: Path) -> Path:
        doc, data = splat_doc(count)
        index = doc["meshes"][0]["primitives"][0]["attributes"][attribute]
        values = np.full((count, width), 0.5, "<f4").tobytes()
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(data), "byteLength": len(values)})
        doc["accessors"][index].update(type=kind, bufferView=len(doc["bufferViews"]) - 1)
        data += values
        doc["buffers"][0]["byteLength"] = len(data)
        return raw(".glb", glb(doc, data))(path)

    return make


def parent_moves_splats(doc: dict) -> None:
    doc["nodes"] = [{"children": [1], "translation": [5.0, 0.0, 0.0]}, {"mesh": 0}]


def zip_member_flags(make: Callable, member: str, flag: int = 0, method: int | None = None) -> Callable:
    """A project from ``make`` whose ``member`` is marked encrypted (``flag``) or compressed with ``method``, as
    another zip tool would write it: the bits patched in its local and central headers."""
    def patched(path: Path) -> Path:
        out = make(path)
        data = bytearray(out.read_bytes())
        name = member.encode()
        for signature, flags_at, method_at, name_at in ((b"PK\x03\x04", 6, 8, 30), (b"PK\x01\x02", 8, 10, 46)):
            at = data.find(signature)
            while at >= 0:
                if data[at + name_at: at + name_at + len(name)] == name:
                    bits = struct.unpack_from("<H", data, at + flags_at)[0] | flag
                    struct.pack_into("<H", data, at + flags_at, bits)
                    if method is not None:
                        struct.pack_into("<H", data, at + method_at, method)
                at = data.find(signature, at + 4)
        out.write_bytes(bytes(data))
        return out

    return patched


def empty_objects_manifest(path: Path) -> Path:
    out = path.with_suffix(".splatproj")
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z, z.open("project.json", "w", force_zip64=True) as f:
        f.write(b'{"version": 1, "layout": [')
        block = b"{}," * (1 << 20)
        for _ in range(20):  # 60 MB of "{}," deflated to some 60 kB
            f.write(block)
        f.write(b'{}]}')
    return out


def ascii_ply_of_no_vertices(path: Path) -> Path:
    return raw(".ply", ply_header(*vertex(0)).replace(b"binary_little_endian", b"ascii"))(path)


CASES = [
    # PLY
    Case("ply repeated property", "model",
         raw(".ply", ply_header(*vertex(1, ["x"] + REQUIRED)) + bytes(4 * 15))),
    Case("ply declares 2^40 vertices", "model", raw(".ply", ply_header(*vertex(2**40)) + bytes(4 * 14 * 8))),
    Case("ply ascii declares 2^40 vertices", "model",
         raw(".ply", ply_header(*vertex(2**40)).replace(b"binary_little_endian", b"ascii") + b"0 " * 14)),
    Case("ply element before vertex declares 2^50 rows", "model",
         raw(".ply", ply_header("element face 1125899906842624", "property float a", *vertex(1)) + bytes(56))),
    Case("ply log-scale 100", "model", lambda p: ply(p, log_scales=(0, 100.0))),
    Case("ply doubles beyond float32", "model",
         raw(".ply", ply_header(*vertex(1, kind="double")) + np.full(14, 1e300).tobytes())),
    Case("ply far for spz", "model", lambda p: ply(p, means=(0, 1e9)),
         commands=(("export", "{file}", "-o", "{out}.spz"),)),
    Case("ply header without end", "model", raw(".ply", b"ply\nformat ascii 1.0\n" + b"comment x\n" * 200_000)),
    # compressed PLY
    Case("compressed ply log-scale bound 100", "model", raw(".ply", compressed_ply(scale_bound=100.0))),
    Case("compressed ply declares 2^40 vertices", "model", raw(".ply", compressed_ply(vertices=4).replace(
        b"element vertex 4", b"element vertex 1099511627776"))),
    Case("compressed ply repeated property", "model", raw(".ply", compressed_ply(repeat=True))),
    # .splat
    Case("splat scale 3e38", "model", raw(".splat", splat_records(3e38))),
    Case("splat not whole records", "model", raw(".splat", splat_records(0.01)[:-5])),
    # .npy selections (--mask)
    Case("mask empty", "mask", raw(".npy", b"")),
    Case("mask npz", "mask", npz),
    Case("mask header of 1e9 bytes", "mask", raw(".npy", npy(version=(2, 0), header_length=10**9) + b" " * 4096)),
    Case("mask declares 10^12 rows", "mask",
         raw(".npy", npy({"descr": "|b1", "fortran_order": False, "shape": (10**12,)}, bytes(N)))),
    Case("mask of objects", "mask", raw(".npy", saved(np.array([{"a": 1}] * N, dtype=object)))),
    Case("mask 2-D", "mask", raw(".npy", saved(np.zeros((N, 2), bool)))),
    Case("mask shorter than its header", "mask",
         raw(".npy", npy({"descr": "<i8", "fortran_order": False, "shape": (1000,)}, bytes(80)))),
    # projects
    Case("project npy header of 1e9 bytes", "project",
         project(with_model(selected="arrays/s.npy"), {"arrays/s.npy": huge_header_member}), names=("arrays/s.npy",)),
    Case("project 200 regions of one 10M-row member", "project",
         project(with_model(colour=[{"region": "arrays/r.npy", "hue": 1}] * 200),
                 {"arrays/r.npy": bool_rows(10_000_000)})),
    Case("project 60 distinct 10M-row members", "project",
         project(with_model(colour=[{"region": f"arrays/r{i}.npy", "hue": 1} for i in range(60)]),
                 {f"arrays/r{i}.npy": bool_rows(10_000_000) for i in range(60)}), names=("arrays/r",)),
    Case("project embedded model of 200 MB zeros", "project",
         project(with_model(embedded="models/0-m.ply"), {"models/0-m.ply": zeros(200 << 20)}),
         names=("models/0-m.ply",)),
    Case("project embedded model that is none", "project",
         project(with_model(embedded="models/0-m.ply"), {"models/0-m.ply": b"ply\nformat ascii 1.0\nend_header\n"}),
         names=("models/0-m.ply",)),
    Case("project embedded ply with a repeated property", "project",
         project(with_model(embedded="models/0-m.ply"),
                 {"models/0-m.ply": ply_header(*vertex(1, ["x"] + REQUIRED)) + bytes(4 * 15)}),
         names=("models/0-m.ply",)),
    Case("project nested json", "project", project('{"version": 1, "models": ' + DEEP + "}")),
    Case("project up beyond the float range", "project",
         project({"version": 1, "models": [{"path": "m.ply"}], "up": [1e308, 1e308, 0]})),
    Case("project empty camera path of 1e7 s at 1e6 fps", "project",
         project({"version": 1, "models": [{"path": "m.ply"}],
                  "camera_path": {"keyframes": [], "duration": 1e7, "fps": 1e6}})),
    Case("project manifest of 1 GB", "project", manifest_bomb),
    # camera paths (video --path)
    Case("camera path nested json", "camera path", raw(".json", ('{"keyframes": ' + DEEP + "}").encode())),
    Case("camera path 1e7 s at 1e6 fps", "camera path",
         raw(".json", json.dumps({"keyframes": [KEY, KEY], "duration": 1e7, "fps": 1e6}).encode())),
    Case("camera path matrix 60 deep", "camera path",
         raw(".json", json.dumps({"keyframes": [{**KEY, "world_to_camera": json.loads("[" * 60 + "]" * 60)}]})
             .encode())),
    Case("camera path infinite duration", "camera path",
         raw(".json", b'{"keyframes": [' + json.dumps(KEY).encode() + b'], "duration": Infinity}')),
    # whole numbers beyond a float (issue 49 item 8)
    Case("project camera fx of 400 digits", "project", project_with_big(camera={**KEY, "fx": "@BIG@"})),
    Case("project keyframe of 400 digits", "project",
         project_with_big(camera_path={"keyframes": [{**KEY, "world_to_camera": EYE_BIG}, KEY]})),
    Case("project transform of 400 digits", "project", model_with_big(transform=EYE_BIG)),
    Case("project world of 400 digits", "project", project_with_big(world=EYE_BIG)),
    Case("project up of 400 digits", "project", project_with_big(up=[0, "@BIG@", 0])),
    Case("project strength of 400 digits", "project", model_with_big(strength="@BIG@")),
    Case("project colour of 400 digits", "project", model_with_big(colour=[{"region": None, "hue": "@BIG@"}])),
    Case("project stylize setting of 400 digits", "project", project_with_big(stylize={"lambda_content": "@BIG@"})),
    Case("project path duration of 400 digits", "project",
         project_with_big(camera_path={"keyframes": [], "duration": "@BIG@"})),
    Case("project camera distance of 400 digits", "project",
         project_with_big(camera={**KEY, "target_distance": "@BIG@"})),
    Case("camera path duration of 400 digits", "camera path", camera_path_with_big(duration="@BIG@")),
    Case("camera path fx of 400 digits", "camera path", camera_path_with_big({**KEY, "fx": "@BIG@"})),
    Case("camera path matrix of 400 digits", "camera path", camera_path_with_big({**KEY, "world_to_camera": EYE_BIG})),
    Case("glb translation of 400 digits", "model",
         glb_file(lambda d: d["nodes"][0].update(translation=[0, 0, "@BIG@"]),
                  lambda t: t.replace('"@BIG@"', BIG))),
    Case("glb count of 5000 digits", "model",
         glb_file(lambda d: d["accessors"][0].update(count="@COUNT@"),
                  lambda t: t.replace('"@COUNT@"', "1" + "0" * 5000))),
    # .glb accessor types and node transforms (items 5 and 9)
    Case("glb position VEC2", "model", accessor_type("POSITION", "VEC2")),
    Case("glb position VEC4", "model", accessor_type("POSITION", "VEC4")),
    Case("glb position SCALAR", "model", accessor_type("POSITION", "SCALAR")),
    Case("glb rotation VEC3", "model", accessor_type("KHR_gaussian_splatting:ROTATION", "VEC3")),
    Case("glb scale SCALAR", "model", accessor_type("KHR_gaussian_splatting:SCALE", "SCALAR")),
    Case("glb opacity VEC3", "model", accessor_type("KHR_gaussian_splatting:OPACITY", "VEC3")),
    Case("glb parent node moves the splats", "model", glb_file(parent_moves_splats)),
    # project members another zip tool wrote, and a manifest that parses into gigabytes (item 10)
    Case("project member encrypted", "project",
         zip_member_flags(project(with_model(selected="arrays/s.npy"), {"arrays/s.npy": saved(np.ones(N, bool))}),
                          "arrays/s.npy", flag=0x1), names=("arrays/s.npy",)),
    Case("project manifest compressed with PPMd", "project",
         zip_member_flags(project(with_model()), "project.json", method=98), names=("project.json",)),
    Case("project manifest of 60 MB of empty objects", "project", empty_objects_manifest),
    # masks and PLYs (item 11)
    Case("mask txt 1e19", "mask", raw(".txt", b"1e19\n")),
    Case("mask txt inf", "mask", raw(".txt", b"3 inf\n")),
    Case("ply ascii of no vertices", "model", ascii_ply_of_no_vertices, names=("holds no Gaussians",)),
]


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    return ply(tmp_path_factory.mktemp("model") / "model")


@pytest.mark.parametrize("case", CASES, ids=str)
def test_a_crafted_file_is_one_line_naming_it_within_bounded_memory(case, tmp_path, model):
    check_case(case, tmp_path, model)
