"""The CUDA display path: the view drawn by the training rasterizer (gsplat on a GPU) and shown as a texture.

On an NVIDIA GPU ``rasterize(backend="cuda")`` renders a million splats at 1080p in about 2.4 ms (docs/gpu.md),
far less than the GL renderer's splat pass there; this path renders forward only (``torch.no_grad``), converts the
image to 8 bits on the device, copies it through pinned host memory and writes it into a moderngl texture, which a
fullscreen quad draws into the caller's framebuffer and viewport (upsampled when the view renders at a lower scale
while the camera moves), as the graphdeco SIBR viewer and GaussianSplattingViewer do. The model's tensors stay on
the device between frames and are uploaded again only for a new snapshot version (colours alone when only they
changed).

It draws the colour and alpha modes of one model. What it cannot draw (``unsupported`` says why: the points,
ellipsoids and depth modes, the split view, the ground-truth photo, selection tint or hidden Gaussians) the caller
draws with the GL renderer. Overlay lines go on top through the GL renderer's ``draw_lines``.

The same code runs on the ``torch`` (or ``cpu``) rasterizer backend on CPU tensors: that is how CI tests it.
"""

from __future__ import annotations

import time

import numpy as np

import moderngl

DRAWABLE_MODES = ("color", "alpha")

_VERT = """
#version 330 core
in vec2 a_corner;
out vec2 v_uv;
void main() { v_uv = 0.5 * (a_corner + 1.0); gl_Position = vec4(a_corner, 0.0, 1.0); }
"""
_FRAG = """
#version 330 core
in vec2 v_uv;
uniform sampler2D u_image;  // uploaded bottom row first, as GL textures are
out vec4 f_color;
void main() { f_color = vec4(texture(u_image, v_uv).rgb, 1.0); }
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


class CudaDisplay:
    """Renders one model with ``training.raster.rasterize`` into a moderngl texture; see the module docstring.

    ``backend``: "cuda" (gsplat, CUDA tensors) or "torch" / "cpu" (CPU tensors: tests, machines without CUDA).
    Every method runs on the GL thread.
    """

    def __init__(self, ctx: moderngl.Context, backend: str = "cuda"):
        import torch

        if backend not in ("cuda", "torch", "cpu"):
            raise ValueError(f"backend must be cuda, torch or cpu, got {backend!r}")
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
        self._texture = None
        self._pinned = None  # page-locked host buffer the image is copied through (CUDA only)
        # A stream of its own: the default stream is shared by every thread, so waiting on it would wait for the
        # training steps a trainer thread has queued too; a frame waits only for its own work.
        self._stream = torch.cuda.Stream(self.device) if self.device.type == "cuda" else None
        self._prog = ctx.program(vertex_shader=_VERT, fragment_shader=_FRAG)
        self._corners = ctx.buffer(np.array([-1, -1, 1, -1, -1, 1, 1, 1], dtype=np.float32).tobytes())
        self._quad = ctx.vertex_array(self._prog, [(self._corners, "2f", "a_corner")])
        self.uploads = 0  # geometry or colour uploads to the device so far
        self.last_frame_s = 0.0

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
        return self._render_u8(camera, background, max_sh_degree, mode, flip=False)

    def _render_u8(self, camera, background, max_sh_degree: int, mode: str, flip: bool) -> np.ndarray:
        import torch

        if mode not in DRAWABLE_MODES:
            raise ValueError(f"the CUDA display path draws {' and '.join(DRAWABLE_MODES)}, not {mode!r}")
        with torch.no_grad(), self._on_stream():
            img = self._render_float(camera, background, max_sh_degree, mode)
            if flip:
                img = torch.flip(img, dims=(0,))  # GL textures start at the bottom row
            u8 = (img.clamp(0.0, 1.0) * 255.0 + 0.5).to(torch.uint8).contiguous()  # 4x less to copy than float
            if self.device.type != "cuda":
                return u8.numpy()
            if self._pinned is None or self._pinned.shape != u8.shape:
                self._pinned = torch.empty(u8.shape, dtype=torch.uint8, pin_memory=True)
            self._pinned.copy_(u8, non_blocking=True)
            self._stream.synchronize()
            return self._pinned.numpy()

    def _render_float(self, camera, background, max_sh_degree: int, mode: str):
        """(H, W, 3) float image on the device: colour over ``background``, or accumulated alpha as grey."""
        import torch

        from training.raster.rasterize import rasterize

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

    def texture(self, camera, background=(0.0, 0.0, 0.0), max_sh_degree: int = 3,
                mode: str = "color") -> moderngl.Texture:
        """Render ``camera`` and upload the picture into this display's RGB8 texture (bottom row first)."""
        pixels = self._render_u8(camera, background, max_sh_degree, mode, flip=True)
        size = (int(camera.width), int(camera.height))
        if self._texture is None or self._texture.size != size:
            if self._texture is not None:
                self._texture.release()
            self._texture = self.ctx.texture(size, 3, dtype="f1")
            self._texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self._texture.write(memoryview(pixels), alignment=1)
        return self._texture

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
        if overlays is not None and lines_renderer is not None:
            lines_renderer.draw_lines(_camera_for(camera, w, h, 1.0), overlays)
        self.last_frame_s = time.perf_counter() - t0
        return self.last_frame_s

    def release(self) -> None:
        for obj in (self._texture, self._quad, self._corners, self._prog):
            if obj is not None:
                obj.release()
        self._texture = None
        self._tensors = None
        self._pinned = None


def _camera_for(camera, width: int, height: int, scale: float):
    """A training Camera: ``camera(w, h)`` of a ViewerCamera at the scaled size, or a camera as it is."""
    if hasattr(camera, "camera") and callable(camera.camera):
        return camera.camera(max(1, int(round(width * scale))), max(1, int(round(height * scale))))
    return camera
