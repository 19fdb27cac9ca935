"""Which window system the viewer opens on: X11 (a display, real or Xvfb) or, with no display at all, GLFW's null
platform with an EGL context (GLFW 3.5.1, bundled with imgui-bundle), in which the whole window, panels included,
renders off screen. Tests and headless machines use the second; nothing else in the app knows the difference.
"""

from __future__ import annotations

import os

PLATFORM_ENV = "SPLATSTYLER_VIEWER_PLATFORM"  # x11 | null | auto (default)


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def choose_platform() -> str:
    wanted = os.environ.get(PLATFORM_ENV, "auto").strip().lower() or "auto"
    if wanted not in ("auto", "x11", "null"):
        raise ValueError(f"{PLATFORM_ENV} must be auto, x11 or null, got {wanted!r}")
    if wanted == "auto":
        return "x11" if has_display() else "null"
    return wanted


def prepare_glfw(platform: str) -> None:
    """Load imgui-bundle's GLFW (3.5.1) for pyGLFW too, and pre-initialise it for ``platform``.

    imgui-bundle's runner links its own libglfw; pyGLFW must load that same library (a second GLFW would be a
    separate state: its null platform has no EGL). hello_imgui's own glfwInit is a no-op once we initialised, so
    the platform and context hints set here survive."""
    import imgui_bundle

    lib = os.path.join(os.path.dirname(imgui_bundle.__file__), "libglfw.so.3")
    if os.path.exists(lib):
        os.environ.setdefault("PYGLFW_LIBRARY", lib)
    import glfw

    if platform == "null":
        glfw.init_hint(glfw.PLATFORM, glfw.PLATFORM_NULL)
        if not glfw.init():
            raise RuntimeError("GLFW's null platform could not start (no EGL?)")
        glfw.window_hint(glfw.CONTEXT_CREATION_API, glfw.EGL_CONTEXT_API)
