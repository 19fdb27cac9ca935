"""Crafted .spz, .glb and .splat files (issue 38, items 9, 10, 14 and 16), made here byte by byte from the formats'
specs, run through `splatstyler info` and `splatstyler export` in one child process held to 1.5 GB of address
space (RLIMIT_AS). The rule for every reader: sizes come from the file, offsets are checked at both ends, and a
bad file fails in one line naming itself, exit 2: no traceback, no bare MemoryError, and not by running into the
limit (the reader's peak resident memory may not grow by more than GROWTH_LIMIT while it refuses one).

The child resets its peak-memory mark (``/proc/self/clear_refs``) before each command and reports the growth.
It runs with one OpenMP thread and two malloc arenas: each thread or arena reserves address space it never uses,
which RLIMIT_AS counts and a user's memory does not.
"""

from __future__ import annotations

import functools
import gzip
import json
import os
import resource
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
ADDRESS_SPACE = int(1.5 * 2**30)
GROWTH_LIMIT = 200 * 2**20
EXT_COORDINATES = 0xADBE0003


# ------------------------------------------------------------------------------------------------------ the child
def _rss(field: str) -> int:
    for line in open("/proc/self/status"):
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise RuntimeError(field)


def _child() -> None:
    """Run `splatstyler info F` and `splatstyler export F -o OUT.ply` for each file named in argv (as a user's shell
    would, through app.cli.main), and print one JSON line per command: exit code, stdout, stderr, memory growth."""
    import contextlib
    import io

    from app.cli import main

    # what the first command would import, loaded first so that the growth measured is the reader's own
    import torch  # noqa: F401
    import zstandard  # noqa: F401

    import training.model.gltf_io  # noqa: F401
    import training.model.model_io  # noqa: F401
    import training.model.splat_io  # noqa: F401
    import training.model.spz_io  # noqa: F401

    out_dir = Path(sys.argv[1])
    for name in sys.argv[2:]:
        for command in ("info", "export"):
            argv = ["info", name] if command == "info" else ["export", name, "-o", str(out_dir / "out.ply")]
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")  # the peak resident mark starts again from here
            before = _rss("VmRSS")
            stdout, stderr = io.StringIO(), io.StringIO()
            with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
                code = main(argv)
            print(json.dumps({"file": name, "command": command, "code": code, "stdout": stdout.getvalue(),
                              "stderr": stderr.getvalue(), "growth": _rss("VmHWM") - before}), flush=True)


def run_bounded(files: list[Path], out_dir: Path) -> dict[tuple[str, str], dict]:
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))

    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "MALLOC_ARENA_MAX": "2"}
    code = "import sys; from tests.test_spz_gltf_crafted import _child; _child()"
    proc = subprocess.run([sys.executable, "-c", code, str(out_dir), *map(str, files)], cwd=REPO, env=env,
                          preexec_fn=limit, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    return {(Path(r["file"]).name, r["command"]): r for r in rows}


# ------------------------------------------------------------------------------------------------------ SPZ files
def sections(n: int, degree: int = 0, version: int = 3) -> list[bytes]:
    """Valid packed sections of n Gaussians: centres along x, mid alpha and colour, identity rotations, SH 0."""
    x = (np.arange(n) * 16).astype("<i4")
    pos = np.zeros((n, 3, 3), np.uint8)
    pos[:, 0, 0], pos[:, 0, 1], pos[:, 0, 2] = x & 0xFF, (x >> 8) & 0xFF, (x >> 16) & 0xFF
    rot = np.full(n, 3 << 30, "<u4").tobytes() if version >= 3 else bytes(3 * n)  # w largest, the rest 0
    sh = bytes([128]) * (n * 3 * ((degree + 1) ** 2 - 1))
    return [pos.tobytes(), bytes([200]) * n, bytes([128]) * 3 * n, bytes([80]) * 3 * n, rot] + ([sh] if sh else [])


def legacy_header(n: int, degree: int = 0, version: int = 3, flags: int = 0) -> bytes:
    return struct.pack("<4sIIBBBB", b"NGSP", version, n, degree, 12, flags, 0)


def spz_v4(n: int, streams: list[bytes], degree: int = 0, zone: bytes = b"", flags: int = 0,
           toc: int | None = None, sizes: list[tuple[int, int]] | None = None) -> bytes:
    import zstandard

    packed = [zstandard.ZstdCompressor(level=3).compress(s) for s in streams]
    toc = 32 + len(zone) if toc is None else toc
    header = struct.pack("<4sIIBBBBI12s", b"NGSP", 4, n, degree, 12, flags, len(streams), toc, bytes(12))
    sizes = sizes or [(len(p), len(s)) for p, s in zip(packed, streams)]
    return header + zone + b"".join(struct.pack("<QQ", *s) for s in sizes) + b"".join(packed)


def gzip_bomb(prefix: bytes, zeros_mib: int) -> bytes:
    """One gzip member: ``prefix``, then ``zeros_mib`` MiB of zeros (about 1 KB of stream per MiB: the same full-
    flushed block repeated), with a valid CRC and length."""
    zero = bytes(1 << 20)
    head = zlib.compressobj(9, zlib.DEFLATED, -15)
    first = head.compress(prefix) + head.flush(zlib.Z_FULL_FLUSH)
    z = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = z.compress(zero) + z.flush(zlib.Z_FULL_FLUSH)
    crc = zlib.crc32(prefix)
    for _ in range(zeros_mib):
        crc = zlib.crc32(zero, crc)
    end = zlib.compressobj(9, zlib.DEFLATED, -15).flush(zlib.Z_FINISH)
    size = (len(prefix) + (zeros_mib << 20)) & 0xFFFFFFFF
    return b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\xff" + first + block * zeros_mib + end + struct.pack("<II", crc, size)


def record(kind: int, payload: bytes, length: int | None = None) -> bytes:
    return struct.pack("<II", kind, len(payload) if length is None else length) + payload


def spz_files() -> dict[str, tuple[bytes, str]]:
    """name -> (bytes, what must happen: 'read N' or a piece of the one-line error)."""
    n_big = 20_000_000
    positions_etc = [bytes(n_big * 9), bytes(n_big), bytes(n_big * 3), bytes(n_big * 3), bytes(n_big * 4)]
    tiny = [b"\0" * 9, b"\0", b"\0" * 3, b"\0" * 3, b"\0" * 4]
    rng = np.random.default_rng(0)
    n_mem = 4_000_000
    heavy = [bytes(n_mem * 9), rng.integers(0, 256, n_mem, dtype=np.uint8).tobytes(), bytes(n_mem * 3),
             bytes(n_mem * 3), np.full(n_mem, 3 << 30, "<u4").tobytes(), bytes([128]) * (n_mem * 45)]
    truncated = b"".join(sections(1000, 3))
    truncated = rng.integers(0, 256, 9000, dtype=np.uint8).tobytes() + truncated[9000:30000]  # barely compressible
    return {
        # item 9: 2 GiB of zeros after a valid 1000-Gaussian payload, in 2 MB: read, without inflating the zeros
        "bomb-after-payload.spz": (gzip_bomb(legacy_header(1000) + b"".join(sections(1000)), 2048), "read 1000"),
        # the same zeros declared as Gaussians (2 GiB / 20 bytes each)
        "bomb-declared.spz": (gzip_bomb(legacy_header(2**31 // 20), 2048), "more than 128 to 1"),
        # a v4 file of ~12 KB declaring 20M Gaussians whose ZSTD streams really unpack to them
        "v4-20M.spz": (spz_v4(n_big, positions_etc), "more than 128 to 1"),
        # 2^32-1 Gaussians in a couple of hundred bytes, both containers
        "v4-max-count.spz": (spz_v4(2**32 - 1, tiny, sizes=[(len(t) + 9, len(t)) for t in tiny]),
                             "declares 4294967295 Gaussians"),
        "v3-max-count.spz": (gzip.compress(legacy_header(2**32 - 1) + bytes(100)), "declares 4294967295 Gaussians"),
        # a consistent file (62 to 1) whose model the memory left cannot hold (4M Gaussians, SH 3: 1.1 GB)
        "v4-too-big-for-memory.spz": (spz_v4(n_mem, heavy, degree=3), "of memory to read"),
        "v3-truncated.spz": (gzip.compress(legacy_header(1000, 3) + truncated), "ends inside its 'sh' section"),
        "v4-record-past-zone.spz": (spz_v4(10, sections(10, version=4), zone=record(EXT_COORDINATES, b"", 100),
                                           flags=2), "past the end of its extension zone"),
        "v4-unknown-axes.spz": (spz_v4(10, sections(10, version=4),
                                       zone=record(EXT_COORDINATES, struct.pack("<I", 99)), flags=2),
                                "names system 99"),
        "v4-toc-outside.spz": (spz_v4(10, sections(10, version=4), toc=10**9), "table of contents"),
        "v4-stream-past-end.spz": (spz_v4(10, sections(10, version=4), sizes=[(2**62, 90)] + [(1, s) for s in
                                                                            (10, 30, 30, 40)]),
                                   "runs past the end of the file"),
    }


# ----------------------------------------------------------------------------------------------------- glTF files
def glb(doc: dict | str, binary: bytes) -> bytes:
    text = (doc if isinstance(doc, str) else json.dumps(doc)).encode()
    text += b" " * (-len(text) % 4)
    binary += bytes(-len(binary) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


def splat_doc(count: int, views: bool = True, offsets: dict | None = None) -> tuple[dict, bytes]:
    """A glTF of ``count`` degree-0 splats, one float view per attribute (or none: zero accessors)."""
    names = [("POSITION", "VEC3"), ("KHR_gaussian_splatting:ROTATION", "VEC4"),
             ("KHR_gaussian_splatting:SCALE", "VEC3"), ("KHR_gaussian_splatting:OPACITY", "SCALAR"),
             ("KHR_gaussian_splatting:SH_DEGREE_0_COEF_0", "VEC3")]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}
    accessors, bufferviews, data = [], [], bytearray()
    for i, (name, kind) in enumerate(names):
        acc = {"componentType": 5126, "count": count, "type": kind}
        if views:
            values = np.full((count, width[kind]), 0.5, "<f4")
            if name.endswith("ROTATION"):
                values[:] = (0.0, 0.0, 0.0, 1.0)
            bufferviews.append({"buffer": 0, "byteOffset": len(data), "byteLength": values.nbytes})
            data += values.tobytes()
            acc["bufferView"] = i
        acc.update((offsets or {}).get(name, {}))
        accessors.append(acc)
    doc = {"asset": {"version": "2.0"}, "extensionsUsed": ["KHR_gaussian_splatting"], "scene": 0,
           "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {name: i for i, (name, _) in enumerate(names)}, "mode": 0,
                                       "extensions": {"KHR_gaussian_splatting": {
                                           "kernel": "ellipse", "colorSpace": "srgb_rec709_display"}}}]}],
           "buffers": [{"byteLength": len(data)}], "bufferViews": bufferviews, "accessors": accessors}
    return doc, bytes(data)


def glb_files() -> dict[str, tuple[bytes, str]]:
    def changed(edit, count: int = 10) -> bytes:
        doc, data = splat_doc(count)
        edit(doc)
        return glb(doc, data)

    def many_primitives(doc):
        doc["meshes"][0]["primitives"] *= 1000

    return {
        "valid.glb": (changed(lambda d: None), "read 10"),
        # item 10: 10M Gaussians in accessors without buffer views, in a file of under 1 KB
        "count-without-views.glb": (glb(*splat_doc(10_000_000, views=False)), "declares 10000000 Gaussians"),
        # SCALE read 4 bytes before its view: the scales would shift into the rotations
        "negative-offset.glb": (changed(lambda d: d["accessors"][2].update(byteOffset=-4)),
                                "'byteOffset' is -4, not a whole number"),
        "offset-not-a-number.glb": (changed(lambda d: d["bufferViews"][2].update(byteOffset="x")),
                                    "'byteOffset' is 'x'"),
        "offset-past-view.glb": (changed(lambda d: d["accessors"][2].update(byteOffset=8)), "reads bytes"),
        "view-past-chunk.glb": (changed(lambda d: d["bufferViews"][4].update(byteLength=10**12)), "reads bytes"),
        "matrix-not-numbers.glb": (changed(lambda d: d["nodes"][0].update(matrix="identity")),
                                   "'matrix' is not 16 numbers"),
        "meshes-not-array.glb": (changed(lambda d: d.update(meshes={"a": 1})), "'meshes' is an object"),
        "attributes-not-object.glb": (changed(lambda d: d["meshes"][0]["primitives"][0].update(attributes=[1])),
                                      "'attributes' is an array"),
        "count-not-a-number.glb": (changed(lambda d: d["accessors"][0].update(count=1.5)), "'count' is 1.5"),
        # one view's Gaussians read by 1000 primitives: 1000 times the memory the file pays for
        "shared-by-1000-primitives.glb": (changed(many_primitives, 1000), "declares 1000000 Gaussians"),
        "deep-json.glb": (glb("[" * 100_000 + "]" * 100_000, b""), "nested too deeply"),
        "unknown-colour-space.glb": (changed(lambda d: d["meshes"][0]["primitives"][0]["extensions"][
            "KHR_gaussian_splatting"].update(colorSpace="acescg")), "colorSpace 'acescg'"),
    }


# ---------------------------------------------------------------------------------------------------- .splat files
def splat_starting_with(magic: bytes, count: int = 5) -> bytes:
    """A valid .splat whose first bytes (the first centre's x, a float32) spell ``magic``."""
    from training.model.splat_io import SPLAT_DTYPE

    rec = np.zeros(count, SPLAT_DTYPE)
    rec["position"] = np.arange(count * 3, dtype=np.float32).reshape(count, 3)
    rec["scale"], rec["rgba"], rec["rotation"] = 0.01, 200, (255, 128, 128, 128)
    data = bytearray(rec.tobytes())
    data[: len(magic)] = magic
    return bytes(data)


def splat_files() -> dict[str, tuple[bytes, str]]:
    # item 14: one .splat in 65,536 starts with gzip's two bytes; one in 2^32 with 'NGSP' or 'glTF'
    return {"gzip-magic.splat": (splat_starting_with(b"\x1f\x8b"), "read 5"),
            "gzip-magic-more.splat": (splat_starting_with(b"\x1f\x8b\x08\x00"), "read 5"),
            "ngsp.splat": (splat_starting_with(b"NGSP"), "read 5"),
            "gltf.splat": (splat_starting_with(b"glTF"), "read 5")}


NAMES = ["bomb-after-payload.spz", "bomb-declared.spz", "v4-20M.spz", "v4-max-count.spz", "v3-max-count.spz",
         "v4-too-big-for-memory.spz", "v3-truncated.spz", "v4-record-past-zone.spz", "v4-unknown-axes.spz",
         "v4-toc-outside.spz", "v4-stream-past-end.spz",
         "valid.glb", "count-without-views.glb", "negative-offset.glb", "offset-not-a-number.glb",
         "offset-past-view.glb", "view-past-chunk.glb", "matrix-not-numbers.glb", "meshes-not-array.glb",
         "attributes-not-object.glb", "count-not-a-number.glb", "shared-by-1000-primitives.glb", "deep-json.glb",
         "unknown-colour-space.glb",
         "gzip-magic.splat", "gzip-magic-more.splat", "ngsp.splat", "gltf.splat"]


@functools.cache
def crafted() -> dict[str, tuple[bytes, str]]:
    """Every crafted file, made once per run when a test asks (some take a second and a few hundred MB to make)."""
    files = {**spz_files(), **glb_files(), **splat_files()}
    assert sorted(files) == sorted(NAMES)
    return files


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> dict[tuple[str, str], dict]:
    folder = tmp_path_factory.mktemp("crafted")
    for name, (data, _) in crafted().items():
        (folder / name).write_bytes(data)
    return run_bounded([folder / name for name in NAMES], tmp_path_factory.mktemp("out"))


@pytest.mark.slow
@pytest.mark.parametrize("command", ["info", "export"])
@pytest.mark.parametrize("name", NAMES)
def test_crafted_file_is_refused_in_one_line_within_bounded_memory(results, name, command):
    data, expected = crafted()[name]
    assert len(data) < 20 * 2**20  # "a small file must not take gigabytes"
    r = results[(name, command)]
    assert r["growth"] < GROWTH_LIMIT, f"{name}: {command} grew resident memory by {r['growth'] / 2**20:.0f} MB"
    assert "Traceback" not in r["stderr"] and "MemoryError" not in r["stderr"]
    if expected.startswith("read "):
        assert r["code"] == 0, r["stderr"]
        count = int(expected.split()[1])
        if command == "info":
            assert f"Gaussians     {count}" in r["stdout"]
        else:
            assert f"({count} Gaussians" in r["stdout"]
        return
    lines = r["stderr"].splitlines()
    assert r["code"] == 2 and len(lines) == 1, r["stderr"]
    assert lines[0].startswith(f"splatstyler: error: {r['file']}: "), lines[0]
    assert expected in lines[0], lines[0]
    assert "memory left" not in lines[0]  # refused from what the file declares, not by running out


# --------------------------------------------------------------------------------- in-process checks of the same
def test_gzip_bomb_stops_where_the_header_says(tmp_path):
    """The 2 GiB after the payload are never inflated: reading takes about what 1000 Gaussians take."""
    from training.model.model_io import read_model

    data = gzip_bomb(legacy_header(1000) + b"".join(sections(1000)), 2048)
    assert len(data) < 3 * 2**20
    path = tmp_path / "bomb.spz"
    path.write_bytes(data)
    del data
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
    before = _rss("VmRSS")
    g = read_model(path)
    assert _rss("VmHWM") - before < 100 * 2**20
    assert len(g) == 1000 and g.sh_degree == 0
    assert np.allclose(g.means[:, 0].numpy(), np.arange(1000) * 16 / 4096)


@pytest.mark.parametrize("name", ["gzip-magic.splat", "gzip-magic-more.splat", "ngsp.splat", "gltf.splat"])
def test_splat_whose_first_bytes_spell_a_signature_is_a_splat(tmp_path, name):
    """Item 14: the name decides for a headerless .splat unless the other format's header holds up beyond its
    signature; the file reads as the splats it holds."""
    from training.model.model_io import model_format, read_model
    from training.model.splat_io import SPLAT_DTYPE

    path = tmp_path / name
    data = splat_files()[name][0]
    path.write_bytes(data)
    assert model_format(path) == "splat"
    g = read_model(path)
    x = np.frombuffer(data, SPLAT_DTYPE)["position"]
    assert len(g) == 5 and np.array_equal(g.means.numpy(), x)


def test_real_spz_named_splat_is_still_spz(tmp_path):
    from tests.test_spz_gltf import l_model
    from training.model.export import write_export
    from training.model.model_io import model_format

    for version in (3, 4):
        write_export(tmp_path / "m.spz", l_model(), spz_version=version)
        (tmp_path / "m.spz").rename(tmp_path / "m.splat")
        assert model_format(tmp_path / "m.splat") == "spz"


def _srgb(c):
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.maximum(c, 0.0031308) ** (1 / 2.4) - 0.055)


def test_linear_colour_space_is_read_as_the_srgb_it_shows(tmp_path):
    """Item 16: a .glb whose colorSpace is lin_rec709_display holds linear colours; read, each Gaussian shows the
    sRGB encoding of its linear colour (exactly for the DC colour; to first order from each direction for the SH),
    where reading it as sRGB (the old behaviour) would show it darker."""
    import torch

    from tests.test_spz_gltf import l_model
    from training.model.export import write_export
    from training.model.model_io import read_model
    from training.model.sh import sh_to_rgb

    g = l_model()
    g.shN.mul_(0.05)
    write_export(tmp_path / "srgb.glb", g)
    data = (tmp_path / "srgb.glb").read_bytes()
    assert data.count(b'"srgb_rec709_display"') == 1
    (tmp_path / "lin.glb").write_bytes(data.replace(b'"srgb_rec709_display"', b'"lin_rec709_display" '))
    as_srgb, as_linear = read_model(tmp_path / "srgb.glb"), read_model(tmp_path / "lin.glb")
    d = torch.nn.functional.normalize(torch.randn(len(g), 3, dtype=torch.float64), dim=1)
    origin = torch.zeros(3, dtype=torch.float64)
    linear = sh_to_rgb(3, as_srgb.sh.double(), d, origin).numpy()  # the file's values, seen from d
    shown = sh_to_rgb(3, as_linear.sh.double(), d, origin).numpy()
    dc_linear = 0.5 + 0.28209479177387814 * as_srgb.sh0[:, 0].double().numpy()
    dc_shown = 0.5 + 0.28209479177387814 * as_linear.sh0[:, 0].double().numpy()
    assert np.abs(dc_shown - _srgb(dc_linear)).max() < 1e-5
    lit = linear > 0.05  # away from the curve's knee, where its slope changes fast
    assert np.abs(shown - _srgb(linear))[lit].max() < 0.01
    assert (shown - linear)[lit & (linear < 0.9)].min() > 0.02  # sRGB encoding brightens: the change is seen
    assert torch.equal(as_linear.means, as_srgb.means) and torch.equal(as_linear.quats, as_srgb.quats)
