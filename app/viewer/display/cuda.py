"""The CUDA display path: the view drawn by the training rasterizer (gsplat on a GPU) and shown as a texture.

On an NVIDIA GPU ``rasterize(backend="cuda")`` renders a million splats at 1080p in about 2.4 ms (docs/gpu.md),
far less than the GL renderer's splat pass there; this path renders forward only (``torch.no_grad``), converts the
image to 8 bits on the device and puts it into a moderngl texture, which a fullscreen quad draws into the caller's
framebuffer and viewport (upsampled when the view renders at a lower scale while the camera moves), as the graphdeco
SIBR viewer and GaussianSplattingViewer do. Two ways (``transfer``) take the picture into the texture:

- ``pinned``: copied into page-locked host memory, then uploaded into an RGB8 texture (two copies over PCIe and a
  wait for the display's stream every frame);
- ``interop``: copied on the GPU into a registered RGBA8 texture through CUDA-GL interop (interop.py,
  cuda-python), on torch's current stream, without a host copy or any synchronisation on the host.

With ``fallback`` (the viewer), an interop failure (cuda-python missing, registration refused, a mapping error in
the middle of a session) switches this display to ``pinned`` for good and keeps the reason in ``fallback_reason``
(the Scene panel shows it); without it (the chooser's timing, the benchmarks) the failure is raised.

The model's tensors stay on the device between frames and are uploaded again only for a new snapshot version
(colours alone when only they changed). ``profile`` times the stages of each frame into ``last_stages`` (raster,
convert, transfer, draw: seconds, with a wait after each, so their sum exceeds an unprofiled frame).

It draws the colour and alpha modes of one model. What it cannot draw (``unsupported`` says why: the points,
ellipsoids and depth modes, the split view, the ground-truth photo, selection tint or hidden Gaussians) the caller
draws with the GL renderer. Overlay lines go on top through the GL renderer's ``draw_lines``.

The same code runs on the ``torch`` (or ``cpu``) rasterizer backend on CPU tensors: that is how CI tests it.
"""

from __future__ import annotations

import time

import numpy as np

import moderngl

from app.viewer.display.interop import InteropError, RegisteredTexture, load_runtime

DRAWABLE_MODES = ("color", "alpha")
TRANSFERS = ("pinned", "interop")
MAX_TARGETS = 2  # textures kept (the view alternates between its moving and still sizes): registering costs

_VERT = """
#version 330 core
in vec2 a_corner;
out vec2 v_uv;
void main() { v_uv = 0.5 * (a_corner + 1.0); gl_Position = vec4(a_corner, 0.0, 1.0); }
"""
_FRAG = """
#version 330 core
in vec2 v_uv;
uniform sampler2D u_image;  // the image's top row first, as the rasterizer writes it: flipped here, not copied
out vec4 f_color;
void main() { f_color = vec4(texture(u_image, vec2(v_uv.x, 1.0 - v_uv.y)).rgb, 1.0); }
"""


def unsupported(mode: str, *, split: bool = False, photo: str | None = None, flags: bool = False) -> str | None:
    """Why the CUDA path cannot draw these settings (the caller then uses the GL renderer), or None if it can.
    ``flags``: the model has selected (tinted) or hidden Gaussians."""
    if mode not in DRAWABLE_MODES:
        return f"the {mode} mode is drawn by the GL renderer"
    if split:
        return "the split view is drawn by the GL renderer"
    if photo not in (None, "off"):
        return "the ground-truth photo is drawn by the GL renderer"
    if flags:
        return "selected or hidden Gaussians are drawn by the GL renderer"
    return None


class _Target:
    """A texture of one size for one transfer; for interop its CUDA registration and the RGBA8 tensor copied in."""

    def __init__(self, texture, registered=None, rgba=None):
        self.texture = texture
        self.registered = registered
        self.rgba = rgba

    def release(self) -> None:
        if self.registered is not None:
            self.registered.release()  # before the GL texture goes
        self.texture.release()


class CudaDisplay:
    """Renders one model with ``training.raster.rasterize`` into a moderngl texture; see the module docstring.

    ``backend``: "cuda" (gsplat, CUDA tensors) or "torch" / "cpu" (CPU tensors: tests, machines without CUDA).
    ``transfer``: "pinned" or "interop"; ``runtime``: cuda-python's runtime bindings to use (None: import them).
    Every method runs on the GL thread.
    """

    def __init__(self, ctx: moderngl.Context, backend: str = "cuda", transfer: str = "pinned",
                 fallback: bool = True, runtime=None):
        import torch

        if backend not in ("cuda", "torch", "cpu"):
            raise ValueError(f"backend must be cuda, torch or cpu, got {backend!r}")
        if transfer not in TRANSFERS:
            raise ValueError(f"transfer must be {' or '.join(TRANSFERS)}, got {transfer!r}")
        if backend == "cuda":
            from training.raster.rasterize import have_gsplat

            if not torch.cuda.is_available():
                raise RuntimeError("the CUDA display path needs a CUDA device; torch sees none")
            if not have_gsplat():
                raise RuntimeError("the CUDA display path needs gsplat (pip install -e \".[cuda]\")")
        self.ctx = ctx
        self.backend = backend
        self.device = torch.device("cuda" if backend == "cuda" else "cpu")
        self._tensors = None  # means, quats, scales, opacities, sh on the device
        self.sh_degree = 0
        self._key = None  # (version, geometry_version) of the model on the device
        self._targets: dict[tuple[str, tuple[int, int]], _Target] = {}  # oldest first
        self._texture = None  # the texture of the last frame
        self._pinned = None  # page-locked host buffer the image is copied through (CUDA, pinned transfer)
        # A stream of its own: the default stream is shared by every thread, so waiting on it would wait for the
        # training steps a trainer thread has queued too; a frame waits only for its own work.
        self._stream = torch.cuda.Stream(self.device) if self.device.type == "cuda" else None
        self._prog = ctx.program(vertex_shader=_VERT, fragment_shader=_FRAG)
        self._corners = ctx.buffer(np.array([-1, -1, 1, -1, -1, 1, 1, 1], dtype=np.float32).tobytes())
        self._quad = ctx.vertex_array(self._prog, [(self._corners, "2f", "a_corner")])
        self.uploads = 0  # geometry or colour uploads to the device so far
        self.last_frame_s = 0.0
        self.profile = False
        self.last_stages: dict[str, float] = {}
        self._stage_t = 0.0
        self.fallback = fallback
        self.fallback_reason: str | None = None  # why this display went from interop to pinned
        self.transfer = transfer
        self._runtime = None
        if transfer == "interop":
            try:
                self._runtime = runtime if runtime is not None else load_runtime()
            except InteropError as exc:
                self._interop_failed(exc)

    # ------------------------------------------------------------------ model
    def set_model(self, snap) -> bool:
        """Put a ``ModelSnapshot`` (or anything with its fields) on the device if its version is new: the colours
        alone when only they changed. Returns whether anything was uploaded."""
        version = getattr(snap, "version", None)
        geometry = getattr(snap, "geometry_version", None)
        key = (version, geometry)
        if version is not None and key == self._key:
            return False

        with self._on_stream():
            self._upload(snap, key, geometry)
        return True

    def _on_stream(self):
        import contextlib

        import torch

        return torch.cuda.stream(self._stream) if self._stream is not None else contextlib.nullcontext()

    def _upload(self, snap, key, geometry) -> None:
        import torch

        def put(a):
            t = torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))
            return t.to(self.device) if self.device.type == "cuda" else t

        n = len(snap.means)
        same_geometry = (self._tensors is not None and geometry is not None and self._key is not None
                         and self._key[1] == geometry and self._tensors[0].shape[0] == n)
        sh = put(snap.sh)
        if same_geometry:
            self._tensors = (*self._tensors[:4], sh)
        else:
            self._tensors = (put(snap.means), put(snap.quats), put(snap.scales), put(np.reshape(snap.opacities, -1)),
                             sh)
        self.sh_degree = int(snap.sh_degree)
        self._key = key
        self.uploads += 1

    def clear(self) -> None:
        self._tensors = None
        self._key = None

    @property
    def has_model(self) -> bool:
        return self._tensors is not None and self._tensors[0].shape[0] > 0

    # ------------------------------------------------------------------ drawing
    def render_image(self, camera, background=(0.0, 0.0, 0.0), max_sh_degree: int = 3,
                     mode: str = "color") -> np.ndarray:
        """(H, W, 3) uint8 of ``camera`` (a training ``Camera``), top row first, as it goes to the texture."""
        import torch

        with torch.no_grad(), self._on_stream():
            return self._to_host(_to_u8(self._render_float(camera, background, max_sh_degree, mode)))

    def _render_float(self, camera, background, max_sh_degree: int, mode: str):
        """(H, W, 3) float image on the device: colour over ``background``, or accumulated alpha as grey."""
        import torch

        from training.raster.rasterize import rasterize

        if mode not in DRAWABLE_MODES:
            raise ValueError(f"the CUDA display path draws {' and '.join(DRAWABLE_MODES)}, not {mode!r}")
        w, h = int(camera.width), int(camera.height)
        bg = torch.tensor([float(c) for c in background[:3]], dtype=torch.float32, device=self.device)
        if not self.has_model:
            return bg.expand(h, w, 3) if mode == "color" else torch.zeros(h, w, 3, device=self.device)
        means, quats, scales, opac, sh = self._tensors
        viewmat = torch.as_tensor(np.asarray(camera.world_to_camera), dtype=torch.float32, device=self.device)
        K = torch.tensor([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]],
                         dtype=torch.float32, device=self.device)
        img, alpha, _ = rasterize(means, quats, scales, opac, sh, viewmat, K, w, h,
                                  sh_degree=min(int(max_sh_degree), self.sh_degree), background=bg,
                                  backend=self.backend)
        return alpha.expand(h, w, 3) if mode == "alpha" else img

    def _to_host(self, u8) -> np.ndarray:
        """A uint8 device tensor as a numpy array, through pinned memory on CUDA (waiting for this stream only)."""
        if self.device.type != "cuda":
            return u8.numpy()
        import torch

        if self._pinned is None or self._pinned.shape != u8.shape:
            self._pinned = torch.empty(u8.shape, dtype=torch.uint8, pin_memory=True)
        self._pinned.copy_(u8, non_blocking=True)
        self._stream.synchronize()
        return self._pinned.numpy()

    def texture(self, camera, background=(0.0, 0.0, 0.0), max_sh_degree: int = 3,
                mode: str = "color") -> moderngl.Texture:
        """Render ``camera`` and put the picture into this display's texture of its size (top row first)."""
        import torch

        size = (int(camera.width), int(camera.height))
        with torch.no_grad(), self._on_stream():
            self._stage_t = time.perf_counter()
            self.last_stages = {}
            img = self._render_float(camera, background, max_sh_degree, mode)
            self._mark("raster")
            tex = None
            if self.transfer == "interop":
                try:
                    tex = self._through_interop(img, size)
                except InteropError as exc:  # raised again unless this display may fall back
                    self._interop_failed(exc)
            if tex is None:
                tex = self._through_host(img, size)
        self._texture = tex
        return tex

    def _through_interop(self, img, size) -> moderngl.Texture:
        import torch

        target = self._target("interop", size)
        _to_u8(img, out=target.rgba[..., :3])
        self._mark("convert")
        stream = torch.cuda.current_stream(self.device).cuda_stream if self.device.type == "cuda" else 0
        target.registered.write(target.rgba, stream)
        self._mark("transfer", gl=True)
        return target.texture

    def _through_host(self, img, size) -> moderngl.Texture:
        u8 = _to_u8(img)
        self._mark("convert")
        pixels = self._to_host(u8)
        target = self._target("pinned", size)
        target.texture.write(memoryview(pixels), alignment=1)
        self._mark("transfer", gl=True)
        return target.texture

    def _target(self, transfer: str, size: tuple[int, int]) -> _Target:
        """This transfer's texture of ``size``, made (and registered) on first use; the least recently used goes
        beyond MAX_TARGETS."""
        key = (transfer, size)
        target = self._targets.pop(key, None)
        if target is None:
            target = self._make_target(transfer, size)
        self._targets[key] = target
        while len(self._targets) > MAX_TARGETS:
            self._targets.pop(next(iter(self._targets))).release()
        return target

    def _make_target(self, transfer: str, size: tuple[int, int]) -> _Target:
        import torch

        tex = self.ctx.texture(size, 4 if transfer == "interop" else 3, dtype="f1")
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        if transfer == "pinned":
            return _Target(tex)
        try:
            index = None
            if self.device.type == "cuda":
                index = self.device.index if self.device.index is not None else torch.cuda.current_device()
            registered = RegisteredTexture(self._runtime, tex, index)
        except BaseException:
            tex.release()
            raise
        rgba = torch.full((size[1], size[0], 4), 255, dtype=torch.uint8, device=self.device)  # alpha stays 255
        return _Target(tex, registered, rgba)

    def _interop_failed(self, exc: InteropError) -> None:
        """Raise ``exc``, or with ``fallback`` go on with the pinned copy, keeping why."""
        if not self.fallback:
            raise exc
        self.fallback_reason = str(exc)
        self.transfer = "pinned"
        self._runtime = None
        for key in [k for k in self._targets if k[0] == "interop"]:
            target = self._targets.pop(key)
            if self._texture is target.texture:
                self._texture = None
            target.release()

    def _mark(self, stage: str, gl: bool = False) -> None:
        """With ``profile``: the seconds since the previous mark, after waiting for this display's stream (and GL)."""
        if not self.profile:
            return
        if self._stream is not None:
            self._stream.synchronize()
        if gl:
            self.ctx.finish()
        now = time.perf_counter()
        self.last_stages[stage] = now - self._stage_t
        self._stage_t = now

    def draw(self, camera, framebuffer: moderngl.Framebuffer, *, viewport=None, background=(0.0, 0.0, 0.0),
             max_sh_degree: int = 3, mode: str = "color", scale: float = 1.0, overlays=None,
             lines_renderer=None) -> float:
        """Render ``camera`` (a ViewerCamera, drawn at ``framebuffer``'s or ``viewport``'s size times ``scale``, or
        a training Camera at its own size) into ``framebuffer`` and return the seconds it took. ``overlays``
        (renderer_gl Lines) are drawn on top with ``lines_renderer.draw_lines``."""
        t0 = time.perf_counter()
        x, y, w, h = viewport if viewport is not None else (0, 0, *framebuffer.size)
        cam = _camera_for(camera, w, h, scale)
        tex = self.texture(cam, background, max_sh_degree, mode)
        framebuffer.use()
        framebuffer.viewport = (x, y, w, h)
        self.ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
        tex.use(location=0)
        self._prog["u_image"].value = 0
        self._quad.render(moderngl.TRIANGLE_STRIP)
        self._mark("draw", gl=True)
        if overlays is not None and lines_renderer is not None:
            lines_renderer.draw_lines(_camera_for(camera, w, h, 1.0), overlays)
        self.last_frame_s = time.perf_counter() - t0
        return self.last_frame_s

    def release(self) -> None:
        for target in self._targets.values():
            target.release()
        self._targets.clear()
        for obj in (self._quad, self._corners, self._prog):
            if obj is not None:
                obj.release()
        self._texture = None
        self._tensors = None
        self._pinned = None


def _to_u8(img, out=None):
    """A float image in [0, 1] as uint8, rounded to nearest (the copy into uint8 truncates: hence + 0.5); into
    ``out`` (a uint8 view, e.g. the RGB channels of an RGBA tensor) when given."""
    import torch

    scaled = img.clamp(0.0, 1.0).mul_(255.0).add_(0.5)
    if out is None:
        return scaled.to(torch.uint8).contiguous()
    return out.copy_(scaled)


def _camera_for(camera, width: int, height: int, scale: float):
    """A training Camera: ``camera(w, h)`` of a ViewerCamera at the scaled size, or a camera as it is."""
    if hasattr(camera, "camera") and callable(camera.camera):
        return camera.camera(max(1, int(round(width * scale))), max(1, int(round(height * scale))))
    return camera
