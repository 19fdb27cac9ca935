"""CUDA-GL interop for the CUDA display path: an image on the GPU written straight into the GL texture the view
draws, with no copy through host memory.

Neither torch nor moderngl exposes CUDA's graphics interop; cuda-python's runtime bindings (``cuda.bindings.runtime``,
the ``[cuda]`` extra) do. A moderngl RGBA8 texture is registered once (``cudaGraphicsGLRegisterImage``, write-discard:
each frame overwrites all of it); each frame maps it on the caller's CUDA stream, copies the (H, W, 4) uint8 tensor
into its array (``cudaMemcpy2DToArrayAsync`` from the tensor's pointer, on that stream) and unmaps it on that stream.
CUDA orders the map after the GL work issued before it, and the GL work issued after the unmap after the copy
(the CUDA programming guide's graphics interoperability section), so nothing waits on the host: no stream or device
synchronisation per frame. CUDA accepts 1, 2 or 4 channel textures, not RGB8: hence RGBA.

Every failure is an ``InteropError`` with one line naming the call and CUDA's error: cuda-python missing, a driver
older than the bindings, or a GL context that is not on the CUDA device (Mesa's GL beside an NVIDIA GPU, a second
GPU). The caller (cuda.py) then copies through pinned host memory instead and says why.
"""

from __future__ import annotations

GL_TEXTURE_2D = 0x0DE1
INSTALL_HINT = 'pip install -e ".[cuda]"'


class InteropError(RuntimeError):
    """A CUDA-GL interop call failed, or interop cannot be had here; the message is one line for the user."""


def load_runtime():
    """cuda-python's runtime bindings, or InteropError saying why there are none."""
    try:
        from cuda.bindings import runtime
    except ImportError as exc:  # not installed, or a cuda-python older than 12.6 (no cuda.bindings namespace)
        raise InteropError(f"cuda-python is not installed ({INSTALL_HINT}): {exc}".splitlines()[0]) from exc
    return runtime


def check(rt, result, call: str):
    """The values of a cuda-python call's result tuple after its error code; InteropError unless it succeeded."""
    err, *values = result if isinstance(result, tuple) else (result,)
    if err != rt.cudaError_t.cudaSuccess:
        raise InteropError(f"{call}: {_error_text(rt, err)}")
    return values[0] if len(values) == 1 else values


def _error_text(rt, err) -> str:
    try:
        name = rt.cudaGetErrorName(err)[1].decode()
        text = rt.cudaGetErrorString(err)[1].decode()
        return f"{name} ({text})"
    except Exception:  # an error code the bindings cannot name: its number is still worth reporting
        return f"CUDA error {int(err)}"


class RegisteredTexture:
    """A moderngl RGBA8 texture registered with CUDA; ``write`` copies an (H, W, 4) uint8 tensor into it.

    ``rt``: the runtime bindings (``load_runtime()``); ``device``: the CUDA device index the GL context runs on (None:
    leave the thread's current device as it is). The GL context must be current on the calling thread."""

    def __init__(self, rt, texture, device: int | None = None):
        if texture.components != 4 or texture.dtype != "f1":
            raise ValueError("CUDA registers RGBA8 textures here (components=4, dtype f1)")
        self.rt = rt
        self.texture = texture
        if device is not None:
            check(rt, rt.cudaSetDevice(int(device)), "cudaSetDevice")
        flags = rt.cudaGraphicsRegisterFlags.cudaGraphicsRegisterFlagsWriteDiscard
        self.resource = check(rt, rt.cudaGraphicsGLRegisterImage(texture.glo, GL_TEXTURE_2D, flags),
                              "cudaGraphicsGLRegisterImage")

    def write(self, rgba, stream: int = 0) -> None:
        """Copy ``rgba`` (a contiguous (H, W, 4) uint8 torch tensor of the texture's size, top row first as it will
        be sampled) into the texture, on the CUDA stream whose handle is ``stream`` (0: the legacy default stream).
        Returns once the work is queued; GL work issued afterwards sees the new picture."""
        rt = self.rt
        h, w, c = rgba.shape
        if (w, h) != tuple(self.texture.size) or c != 4 or not rgba.is_contiguous():
            raise ValueError(f"expected a contiguous {self.texture.size[1]}x{self.texture.size[0]}x4 tensor, got "
                             f"{tuple(rgba.shape)}")
        check(rt, rt.cudaGraphicsMapResources(1, self.resource, stream), "cudaGraphicsMapResources")
        try:
            array = check(rt, rt.cudaGraphicsSubResourceGetMappedArray(self.resource, 0, 0),
                          "cudaGraphicsSubResourceGetMappedArray")
            row = w * 4
            # cudaMemcpyDefault: the pointer says where the bytes are (device memory, or host memory on the torch
            # backend's CPU tensors), as unified addressing allows
            check(rt, rt.cudaMemcpy2DToArrayAsync(array, 0, 0, rgba.data_ptr(), row, row, h,
                                                  rt.cudaMemcpyKind.cudaMemcpyDefault, stream),
                  "cudaMemcpy2DToArrayAsync")
        except BaseException:
            rt.cudaGraphicsUnmapResources(1, self.resource, stream)  # already failing: its own error adds nothing
            raise
        check(rt, rt.cudaGraphicsUnmapResources(1, self.resource, stream), "cudaGraphicsUnmapResources")

    def release(self) -> None:
        """Unregister (the texture itself stays the caller's). Errors are ignored: this runs while dropping
        interop after a failure too, when the resource may already be unusable."""
        if self.resource is not None:
            try:
                self.rt.cudaGraphicsUnregisterResource(self.resource)
            except Exception:
                pass
            self.resource = None
