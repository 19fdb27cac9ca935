"""An OSMesa (Mesa's off-screen software GL, Debian ``libosmesa6``) context that moderngl accepts.

glcontext, which moderngl uses to make contexts, has EGL, X11, WGL and CGL backends but none for OSMesa.
moderngl takes any loader object instead (``moderngl.create_context(standalone=True, context=loader)``): it
calls ``__enter__`` to make the context current, ``load_opengl_function(name)`` for every GL entry point, and
``release()`` when the context is released. This class is that loader, on ctypes. OSMesa needs a colour buffer
to make a context current; a 1x1 one does, since everything is drawn into framebuffer objects.
"""

from __future__ import annotations

import ctypes
import ctypes.util

_OSMESA_RGBA = 0x1908
_OSMESA_FORMAT = 0x22
_OSMESA_DEPTH_BITS = 0x30
_OSMESA_PROFILE = 0x33
_OSMESA_CORE_PROFILE = 0x34
_OSMESA_CONTEXT_MAJOR_VERSION = 0x36
_OSMESA_CONTEXT_MINOR_VERSION = 0x37
_GL_UNSIGNED_BYTE = 0x1401
_LIBRARY_NAMES = ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")


def load_library() -> ctypes.CDLL:
    """libOSMesa, or OSError naming the Debian package that provides it."""
    names = list(_LIBRARY_NAMES)
    found = ctypes.util.find_library("OSMesa")
    if found:
        names.insert(0, found)
    for name in names:
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        lib.OSMesaCreateContextAttribs.restype = ctypes.c_void_p
        lib.OSMesaCreateContextAttribs.argtypes = [ctypes.POINTER(ctypes.c_int), ctypes.c_void_p]
        lib.OSMesaMakeCurrent.restype = ctypes.c_ubyte
        lib.OSMesaMakeCurrent.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_int]
        lib.OSMesaGetProcAddress.restype = ctypes.c_void_p
        lib.OSMesaGetProcAddress.argtypes = [ctypes.c_char_p]
        lib.OSMesaDestroyContext.restype = None
        lib.OSMesaDestroyContext.argtypes = [ctypes.c_void_p]
        return lib
    raise OSError("libOSMesa not found (Debian/Ubuntu: apt-get install libosmesa6)")


class OSMesaLoader:
    """A core-profile OSMesa context of at least ``major.minor``, current once constructed."""

    def __init__(self, major: int = 4, minor: int = 5):
        self._lib = load_library()
        attrs = [_OSMESA_FORMAT, _OSMESA_RGBA, _OSMESA_DEPTH_BITS, 24, _OSMESA_PROFILE, _OSMESA_CORE_PROFILE,
                 _OSMESA_CONTEXT_MAJOR_VERSION, major, _OSMESA_CONTEXT_MINOR_VERSION, minor, 0]
        self._ctx = self._lib.OSMesaCreateContextAttribs((ctypes.c_int * len(attrs))(*attrs), None)
        if not self._ctx:
            raise OSError(f"OSMesaCreateContextAttribs failed for a GL {major}.{minor} core context")
        self._buffer = ctypes.create_string_buffer(4)
        self.__enter__()

    def __enter__(self):
        if not self._lib.OSMesaMakeCurrent(self._ctx, self._buffer, _GL_UNSIGNED_BYTE, 1, 1):
            raise OSError("OSMesaMakeCurrent failed")
        return self

    def __exit__(self, *exc) -> None:
        # moderngl wraps calls in enter/exit; the context stays current, like glcontext's standalone ones.
        pass

    def load_opengl_function(self, name: str) -> int:
        return self._lib.OSMesaGetProcAddress(name.encode("ascii")) or 0

    def release(self) -> None:
        if self._ctx:
            self._lib.OSMesaDestroyContext(self._ctx)
            self._ctx = None
