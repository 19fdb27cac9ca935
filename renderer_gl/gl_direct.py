"""The few GL calls that do a frame's heavy work, issued through ctypes so that they release Python's GIL.

moderngl holds the GIL for every call. On software GL (llvmpipe) the vertex and geometry stages run inside the draw
call and rasterization inside the call that waits for it, so a viewer drawing beside a Python trainer thread would
stop that thread for the whole frame (measured: 3-4x more trainer steps while the camera moves when these two calls
let go of the GIL). ctypes releases the GIL around foreign calls. libGL (glvnd) dispatches to whichever context is
current on this thread, GLX or EGL. An OSMesa context is not glvnd's: ``create_context`` marks it
(``ctx.extra["gl_direct"] = False``) and moderngl's own calls are used, as they are where libGL cannot be loaded.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

GL_POINTS = 0x0000
GL_TRIANGLE_STRIP = 0x0005


@functools.lru_cache(maxsize=1)
def _lib():
    for name in ("libGL.so.1", ctypes.util.find_library("GL"), "libOpenGL.so.0"):
        if not name:
            continue
        try:
            lib = ctypes.CDLL(name)
            for fn, args in (("glFinish", []), ("glDrawArrays", [ctypes.c_uint, ctypes.c_int, ctypes.c_int]),
                             ("glDrawArraysInstanced",
                              [ctypes.c_uint, ctypes.c_int, ctypes.c_int, ctypes.c_int])):
                getattr(lib, fn).argtypes = args
                getattr(lib, fn).restype = None
            return lib
        except (OSError, AttributeError):
            continue
    return None


def _for(ctx):
    extra = getattr(ctx, "extra", None)
    if isinstance(extra, dict) and extra.get("gl_direct") is False:
        return None
    return _lib()


def draw(vao, mode: int, vertices: int, instances: int | None = None) -> None:
    """``vao.render(mode, vertices, instances=...)`` with the GIL released during the draw itself."""
    lib = _for(vao.ctx)
    if lib is None:
        if instances is None:
            vao.render(mode, vertices=vertices)
        else:
            vao.render(mode, vertices=vertices, instances=instances)
        return
    # moderngl binds the program, the vertex array and the textures' units and issues an empty draw; the real
    # draw then runs with that same state, outside the GIL
    vao.render(mode, vertices=0)
    if instances is None:
        lib.glDrawArrays(mode, 0, vertices)
    else:
        lib.glDrawArraysInstanced(mode, 0, vertices, instances)


def finish(ctx) -> None:
    """Wait for the queued GL work, releasing the GIL while waiting."""
    lib = _for(ctx)
    if lib is None:
        ctx.finish()
    else:
        lib.glFinish()
