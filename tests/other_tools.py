"""Readers and writers we did not write, for the format tests: PlayCanvas's splat-transform (its own SPZ decoder, the
SPZ reference's encoder built to WebAssembly as ``@adobe/spz``, a .glb writer), the SPZ reference library itself
(``@adobe/spz``, decoding with its coordinate conversions: js/spz_reference.mjs) and the Khronos glTF validator.
They come from npm, pinned by tests/js/package-lock.json, and are installed (``npm ci``, ~15 s) on first use; the
tests that need them skip only where node and npm are missing."""

from __future__ import annotations

import fcntl
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

JS = Path(__file__).resolve().parent / "js"
SPLAT_TRANSFORM = JS / "node_modules" / "@playcanvas" / "splat-transform" / "bin" / "cli.mjs"
VALIDATOR = JS / "node_modules" / "gltf-validator" / "package.json"
SPZ_LIBRARY = JS / "node_modules" / "@adobe" / "spz" / "package.json"


def _node() -> str:
    from tests.system_deps import missing_program

    missing = missing_program("node", "nodejs npm") or missing_program("npm", "nodejs npm")
    if missing:
        pytest.skip(f"{missing}: the readers we did not write come from npm (tests/js/package.json)")
    node = shutil.which("node")
    # `npm ci` first deletes node_modules: two test processes (pytest-xdist) installing at once would each remove
    # what the other is using, so the check and the install happen under one lock.
    with open(JS / ".npm-ci.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not SPLAT_TRANSFORM.exists() or not VALIDATOR.exists() or not SPZ_LIBRARY.exists():
            proc = subprocess.run(["npm", "ci", "--no-audit", "--no-fund", "--ignore-scripts"], cwd=JS,
                                  capture_output=True, text=True, timeout=900)
            assert proc.returncode == 0, f"npm ci in {JS} failed:\n{proc.stderr[-2000:]}"
    return node


def splat_transform(*args) -> str:
    """Run splat-transform's CLI (overwriting outputs); its output, or an AssertionError with it."""
    proc = subprocess.run([_node(), str(SPLAT_TRANSFORM), "-w", *map(str, args)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, f"splat-transform {args} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
    return proc.stdout + proc.stderr


def validate_gltf(path: Path) -> dict:
    """The Khronos glTF validator's report of the file at ``path``."""
    proc = subprocess.run([_node(), str(JS / "validate_gltf.cjs"), str(path)], cwd=JS, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def _spz_reference(*args) -> None:
    proc = subprocess.run([_node(), str(JS / "spz_reference.mjs"), *map(str, args)], cwd=JS, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, f"spz_reference {args} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"


def spz_reference_decode(path: Path, to: str, workdir: Path) -> dict:
    """The SPZ file at ``path`` as the reference library's ``loadSpz`` gives it with ``UnpackOptions.to = to``
    (an axes name, or UNSPECIFIED for the bytes as stored): numPoints, shDegree, extensions and the float arrays
    (positions, log scales, x y z w rotations, logit alphas, DC colours, SH coefficient-major)."""
    out = Path(workdir) / f"ref-{Path(path).stem}-{to}"
    _spz_reference("decode", path, out, to)
    result = json.loads((out / "meta.json").read_text())
    n = result["numPoints"]
    for name, width in [("positions", 3), ("scales", 3), ("rotations", 4), ("alphas", 1), ("colors", 3), ("sh", None)]:
        values = np.fromfile(out / f"{name}.f32", dtype="<f4")
        result[name] = values.reshape(n, -1, 3) if width is None else values.reshape(n, width)
    return result


def spz_reference_reencode(source: Path, target: Path, to: str, version: int = 4) -> None:
    """``source`` loaded by the reference turned to ``to``, saved as ``target`` as it stands (from UNSPECIFIED, no
    extension): the reference's own conversion, in a file that does not name its axes."""
    _spz_reference("reencode", source, target, to, version)
