"""Loads the GLSL sources shipped in renderer_gl/shaders and prefixes them with the shared constants, so the
shaders and the training rasterizer take their numbers from one place (training.raster.constants and
training.model.sh_constants, through renderer_gl/constants.py)."""

from __future__ import annotations

import functools
import math
from pathlib import Path

from renderer_gl import constants as C

SHADER_DIR = Path(__file__).parent / "shaders"


def _defines() -> str:
    log2e = 1.0 / math.log(2.0)
    lines = [
        f"#define ALPHA_MIN {C.ALPHA_MIN!r}",
        f"#define ALPHA_MAX {C.ALPHA_MAX!r}",
        f"#define LOG2E {log2e!r}",
        # exp(-q/2) = exp2(-|w|^2) for w = the whitened offset times this (splat.frag.glsl)
        f"#define WHITE_SCALE {math.sqrt(0.5 * log2e)!r}",
        f"#define SH_C0 {C.SH_C0!r}",
        f"#define SH_C1 {C.SH_C1!r}",
    ]
    lines += [f"#define SH_C2_{i} {v!r}" for i, v in enumerate(C.SH_C2)]
    lines += [f"#define SH_C3_{i} {v!r}" for i, v in enumerate(C.SH_C3)]
    return "\n".join(lines) + "\n"


@functools.lru_cache(maxsize=None)
def source(*names: str, version: int = 330, defines: tuple[str, ...] = ()) -> str:
    """The named files concatenated after a #version line, the constant defines and ``#define`` of each name in
    ``defines`` (a shader's compile-time variants)."""
    body = "\n".join((SHADER_DIR / name).read_text(encoding="utf-8") for name in names)
    extra = "".join(f"#define {name}\n" for name in defines)
    return f"#version {version} core\n{_defines()}{extra}#line 1\n{body}"
