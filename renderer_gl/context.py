"""Standalone GL contexts with no display (EGL, or OSMesa where EGL is absent) and an offscreen target to draw
into and read back. A window's own context needs nothing from here: the renderer draws into whatever
framebuffer it is given, in whatever context is current."""

from __future__ import annotations

import numpy as np

import moderngl

BACKENDS = ("auto", "egl", "osmesa")
GL_REQUIRE = 330  # the shaders are GLSL 3.30 core; compute-shader sorting would need 430


def create_context(backend: str = "auto", require: int = GL_REQUIRE) -> moderngl.Context:
    """A standalone context. ``auto`` tries EGL, then OSMesa; the error lists what each attempt said."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown GL backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    errors = []
    for name in ("egl", "osmesa") if backend == "auto" else (backend,):
        try:
            if name == "egl":
                return moderngl.create_standalone_context(backend="egl", require=require)
            from renderer_gl.osmesa import OSMesaLoader

            ctx = moderngl.create_context(standalone=True, require=require, context=OSMesaLoader())
            ctx.extra = {"gl_direct": False}  # OSMesa's functions are not reachable through glvnd's libGL
            return ctx
        except Exception as exc:  # each backend fails in its own way (OSError, moderngl.Error, ValueError)
            errors.append(f"{name}: {exc}")
    raise RuntimeError("no OpenGL context could be created (" + "; ".join(errors) + ")")


def context_backend(ctx: moderngl.Context) -> str:
    """A short description of the GL implementation (renderer and version)."""
    info = ctx.info
    return f"{info.get('GL_RENDERER', '?')}, GL {info.get('GL_VERSION', '?')}"


def is_software_gl(ctx: moderngl.Context) -> bool:
    """Whether the context renders on the CPU (Mesa's llvmpipe, softpipe or swrast)."""
    renderer = str(ctx.info.get("GL_RENDERER", "")).lower()
    return any(name in renderer for name in ("llvmpipe", "softpipe", "swrast", "software"))


class Offscreen:
    """An RGBA8 colour target with its framebuffer, of a fixed size, read back as top-row-first arrays."""

    def __init__(self, ctx: moderngl.Context, width: int, height: int):
        self.ctx = ctx
        self.size = (int(width), int(height))
        self.texture = ctx.texture(self.size, 4, dtype="f1")
        self.fbo = ctx.framebuffer(color_attachments=[self.texture])

    def read(self) -> np.ndarray:
        """(H, W, 3) uint8, image row 0 at the top."""
        data = self.fbo.read(components=3, alignment=1)
        img = np.frombuffer(data, dtype=np.uint8).reshape(self.size[1], self.size[0], 3)
        return np.ascontiguousarray(img[::-1])

    def release(self) -> None:
        self.fbo.release()
        self.texture.release()
