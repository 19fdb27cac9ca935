"""``SplatRenderer``: draws Gaussian splat models into any moderngl framebuffer.

A frame is two passes. The splat pass composites the sorted Gaussians back to front into a float accumulation
target the size of the (possibly scaled) camera image; the resolve pass turns it into the render mode's picture
in the caller's framebuffer and viewport (background, depth colour map, ground-truth photo, split divider).
Overlay lines follow. Models sit in numbered slots: slot 0 the one shown, slot 1 the second model of the split
view (original left, stylized right).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

import moderngl
from renderer_gl import constants as C
from renderer_gl import gl_direct
from renderer_gl.camera import view
from training.scene.camera import Camera
from training.scene.pose import jacobian_limits
from renderer_gl.context import is_software_gl
from renderer_gl.overlays import Lines
from renderer_gl.shader_source import source
from renderer_gl.sort import BackgroundSorter, back_to_front, turned
from renderer_gl.splats import GPUSplats, SplatArrays

MODES = ("color", "depth", "alpha", "points", "ellipsoids")
# How quads are made: "instanced" (4 vertices per Gaussian, each projecting it: cheap on a GPU) or "geometry" (one
# point per Gaussian expanded by a geometry shader: half the frame time on llvmpipe, whose vertex stage runs on
# one thread). "auto" picks geometry on software GL. Both draw the same pixels.
QUAD_PATHS = ("auto", "instanced", "geometry")
PHOTO_MODES = (None, "blend", "side")
# The accumulation target's texel type: float32, float16, 8-bit unsigned normalised (moderngl's names).
ACCUM_DTYPES = ("f4", "f2", "f1")
SORT_ON = ("cpu", "gpu")
_SPLAT_MODE = {"color": 0, "alpha": 0, "depth": 1, "ellipsoids": 2}
_RESOLVE_MODE = {"color": 0, "points": 0, "ellipsoids": 0, "depth": 1, "alpha": 2}


@dataclass
class FrameInfo:
    """What a ``render`` call did: how many Gaussians it drew and whether (and how long) it sorted."""

    instances: int
    sorted: bool
    sort_s: float
    upload_s: float
    size: tuple[int, int]
    depth_range: tuple[float, float] | None = None


def _set(prog: moderngl.Program, name: str, value) -> None:
    # The GLSL compiler drops uniforms a program does not use; setting them must not fail.
    if name in prog:
        if isinstance(value, np.ndarray):
            prog[name].write(np.ascontiguousarray(value, dtype=np.float32).tobytes())
        else:
            prog[name].value = value


def _mat4(m: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(m, dtype=np.float64).T)  # GLSL reads column-major


class SplatRenderer:
    """Real-time renderer of 3D Gaussians; see renderer_gl/__init__.py and docs/renderer.md.

    ``accum_dtype`` is the accumulation target's texel type: "f4" (float32, the default: parity with the
    training rasterizer), "f2" (half: what a GPU blends at full rate; docs/gpu.md) or "f1" (8-bit, fastest on
    software GL). ``dither``: round each blend into an 8-bit target stochastically (unbiased) rather than to
    nearest, which loses faint splats; None turns it on for "f1" only (the others need none). ``sort_on``: "cpu"
    (numpy, renderer_gl/sort.py) or "gpu" (the compute-shader sort of renderer_gl/gpu_sort.py, whose order never
    leaves the GPU: ten times faster from 500k splats on an H100, far slower on software GL; needs GL 4.3).
    ``sort_tolerance_deg``: the view
    direction may turn this much before the order is recomputed. ``background_sort``: sort on a worker thread
    and draw with the previous order meanwhile (for an interactive loop; off for exact one-off renders).
    """

    def __init__(self, ctx: moderngl.Context, accum_dtype: str = "f4", sort_precision: str = "auto",
                 sort_tolerance_deg: float = 0.1, background_sort: bool = False, quads: str = "auto",
                 dither: bool | None = None, sort_on: str = "cpu"):
        if accum_dtype not in ACCUM_DTYPES:
            raise ValueError(f"accum_dtype must be f1, f2 or f4, got {accum_dtype!r}")
        if quads not in QUAD_PATHS:
            raise ValueError(f"quads must be one of {', '.join(QUAD_PATHS)}, got {quads!r}")
        if sort_on not in SORT_ON:
            raise ValueError(f"sort_on must be one of {', '.join(SORT_ON)}, got {sort_on!r}")
        if sort_on == "gpu" and ctx.version_code < 430:
            raise ValueError(f"sort_on='gpu' needs OpenGL 4.3 compute shaders; this context is {ctx.version_code}")
        self.sort_on = sort_on
        self._gpu_sorts: dict[int, tuple[int, object]] = {}  # slot -> (geometry version, BitonicDepthSort)
        if quads == "auto":
            quads = "geometry" if is_software_gl(ctx) else "instanced"
        self.quads = quads
        self.ctx = ctx
        self.accum_dtype = accum_dtype
        self.dither = (accum_dtype == "f1") if dither is None else bool(dither)
        self.sort_precision = sort_precision
        self.sort_tolerance_deg = float(sort_tolerance_deg)
        self._sorter = BackgroundSorter() if background_sort else None
        self._slots: dict[int, GPUSplats] = {}
        # one splat program per fragment variant (the ellipsoids' outline, built when first drawn)
        self._splat_progs: dict[bool, moderngl.Program] = {False: self._splat_program(outline=False)}
        self._point_prog = ctx.program(vertex_shader=source("common.glsl", "project.glsl", "points.vert.glsl"),
                                       fragment_shader=source("points.frag.glsl"))
        self._resolves: dict[tuple[int, bool, bool], tuple[moderngl.Program, moderngl.VertexArray]] = {}
        self._line_prog = ctx.program(vertex_shader=source("lines.vert.glsl"),
                                      fragment_shader=source("lines.frag.glsl"))
        corners = np.array([-1, -1, 1, -1, -1, 1, 1, 1], dtype=np.float32)
        self._corners = ctx.buffer(corners.tobytes())
        self._vaos: dict[tuple[int, str], tuple[moderngl.Buffer, moderngl.VertexArray]] = {}
        self._accum = None
        self._accum_fbo = None
        self._accum_targets: dict[tuple[int, int], tuple[moderngl.Texture, moderngl.Framebuffer]] = {}
        self._photo = ctx.texture((1, 1), 3, np.zeros(3, np.float32).tobytes(), dtype="f4")
        self._line_vbo = None
        self._line_vao = None

    def _dithers(self) -> bool:
        return self.dither and self.accum_dtype == "f1"

    def _splat_program(self, outline: bool) -> moderngl.Program:
        """The splat program with the fragment code of one kind of draw compiled in, and no other: llvmpipe runs
        both sides of a branch on a uniform for every fragment, so the outline (derivatives, a square root) and the
        dithering hash cost every other draw 14 % and 20 % of its frame (docs/performance.md)."""
        defines = (("OUTLINE",) if outline else ()) + (("DITHER",) if self._dithers() else ())
        frag = source("splat.frag.glsl", defines=defines)
        if self.quads == "instanced":
            return self.ctx.program(vertex_shader=source("common.glsl", "project.glsl", "splat.vert.glsl"),
                                    fragment_shader=frag)
        return self.ctx.program(vertex_shader=source("common.glsl", "project.glsl", "splat_point.vert.glsl"),
                                geometry_shader=source("splat.geom.glsl"), fragment_shader=frag)

    def _resolve(self, mode: int, photo_blend: bool, split: bool) -> tuple[moderngl.Program, moderngl.VertexArray]:
        """The resolve program of one (mode, photo blended, split) and its full-screen quad, compiled when first
        used (the viewer uses two or three of them)."""
        key = (mode, photo_blend, split)
        if key not in self._resolves:
            defines = (f"RESOLVE_MODE {mode}",) + (("PHOTO_BLEND",) if photo_blend else ()) + \
                (("SPLIT",) if split else ())
            prog = self.ctx.program(vertex_shader=source("fullscreen.vert.glsl"),
                                    fragment_shader=source("resolve.frag.glsl", defines=defines))
            self._resolves[key] = (prog, self.ctx.vertex_array(prog, [(self._corners, "2f", "a_corner")]))
        return self._resolves[key]

    def _splat_prog_for(self, mode: str) -> moderngl.Program:
        outline = mode == "ellipsoids"
        if outline not in self._splat_progs:
            self._splat_progs[outline] = self._splat_program(outline)
        return self._splat_progs[outline]

    # ----------------------------------------------------------------------------------------------- models
    def set_splats(self, means, scales, quats, opacities, sh, sh_degree: int | None = 0, slot: int = 0) -> None:
        """Upload a whole model into ``slot`` (replacing what was there). See ``SplatArrays`` for the arrays."""
        arrays = SplatArrays(means, scales, quats, opacities, sh, sh_degree)
        if slot in self._slots:
            self._slots[slot].upload(arrays)
        else:
            self._slots[slot] = GPUSplats(self.ctx, arrays)

    def update_colors(self, sh, sh_degree: int | None = 0, slot: int = 0) -> None:
        """Replace only the colours (SH coefficients, or plain RGB with ``sh_degree=None``) of ``slot``."""
        self._model(slot).update_colors(sh, sh_degree)

    def set_flags(self, flags, slot: int = 0) -> None:
        """Per-Gaussian uint8 flags for ``slot``: bit 0 selected (tinted), bit 1 hidden; None clears them."""
        self._model(slot).set_flags(flags)

    def options(self) -> dict:
        """The construction options a display path chooses (sort_on, accum_dtype)."""
        return {"sort_on": self.sort_on, "accum_dtype": self.accum_dtype}

    def flagged(self, slot: int = 0) -> bool:
        """Whether any Gaussian of ``slot`` is selected or hidden (what a display path without flags cannot show)."""
        return slot in self._slots and self._slots[slot].flagged

    def remove(self, slot: int) -> None:
        if slot in self._gpu_sorts:
            self._gpu_sorts.pop(slot)[1].release()
        if slot in self._slots:
            self._slots.pop(slot).release()
            for key in [k for k in self._vaos if k[0] == slot]:
                self._vaos.pop(key)[1].release()

    def count(self, slot: int = 0) -> int:
        return self._slots[slot].n if slot in self._slots else 0

    def sh_degree(self, slot: int = 0) -> int:
        return self._model(slot).sh_degree

    def set_photo(self, image: np.ndarray | None) -> None:
        """The ground-truth photo for ``photo="blend"|"side"``: (H, W, 3) float in [0, 1] or uint8, top row first."""
        self._photo.release()
        if image is None:
            image = np.zeros((1, 1, 3), np.float32)
        img = np.asarray(image)
        img = img.astype(np.float32) / 255.0 if img.dtype == np.uint8 else img.astype(np.float32)
        img = np.ascontiguousarray(img[..., :3])
        self._photo = self.ctx.texture((img.shape[1], img.shape[0]), 3, img.tobytes(), dtype="f4")

    def _model(self, slot: int) -> GPUSplats:
        if slot not in self._slots:
            raise KeyError(f"no model in slot {slot}")
        return self._slots[slot]

    # ------------------------------------------------------------------------------------------------ sorting
    def _ensure_order(self, slot: int, forward: np.ndarray) -> tuple[bool, float, float]:
        """Re-sort ``slot`` if the view turned past the tolerance. Returns (sorted, sort seconds, upload s)."""
        model = self._model(slot)
        if self.sort_on == "gpu":
            return self._gpu_order(slot, model, forward)
        if self._sorter is not None:
            done = self._sorter.take(slot)
            if done is not None and done[2] == model.version_geometry:
                t0 = time.perf_counter()
                model.write_order(done[0], done[1])
                return True, 0.0, time.perf_counter() - t0
        if not turned(model.order_forward, forward, self.sort_tolerance_deg):
            return False, 0.0, 0.0
        if self._sorter is not None and model.order_forward is not None:
            self._sorter.submit(slot, model.means, forward, self.sort_precision, model.version_geometry)
            return False, 0.0, 0.0
        t0 = time.perf_counter()
        order = back_to_front(model.means, forward, self.sort_precision)
        t1 = time.perf_counter()
        model.write_order(order, forward)
        return True, t1 - t0, time.perf_counter() - t1

    def _gpu_order(self, slot: int, model: GPUSplats, forward: np.ndarray) -> tuple[bool, float, float]:
        if not turned(model.order_forward, forward, self.sort_tolerance_deg):
            return False, 0.0, 0.0
        from renderer_gl.gpu_sort import BitonicDepthSort

        have = self._gpu_sorts.get(slot)
        if have is None or have[0] != model.version_geometry:
            if have is not None:
                have[1].release()
            have = (model.version_geometry, BitonicDepthSort(self.ctx, model.means))
            self._gpu_sorts[slot] = have
        t0 = time.perf_counter()
        have[1].sort(forward)
        model.use_order_buffer(have[1].order, forward, have[1].read)
        return True, time.perf_counter() - t0, 0.0  # (the GPU's sort time shows in the frame's, at its finish)

    # ------------------------------------------------------------------------------------------------ drawing
    def _accum_target(self, size: tuple[int, int]) -> moderngl.Framebuffer:
        # The two latest sizes are kept: the viewer alternates between its moving (half) and still (full) size,
        # and re-creating a 1080p RGBA32F target (33 MB) at every switch costs an allocation each time.
        if self._accum is None or self._accum.size != size:
            cached = self._accum_targets.pop(size, None)
            if cached is None:
                tex = self.ctx.texture(size, 4, dtype=self.accum_dtype)
                cached = (tex, self.ctx.framebuffer(color_attachments=[tex]))
            self._accum_targets[size] = cached
            while len(self._accum_targets) > 2:
                old_size = next(iter(self._accum_targets))
                tex, fbo = self._accum_targets.pop(old_size)
                fbo.release()
                tex.release()
            self._accum, self._accum_fbo = cached
        return self._accum_fbo

    def _vao(self, slot: int, kind: str, index: moderngl.Buffer | None = None) -> moderngl.VertexArray:
        model = self._model(slot)
        index = model.index_buffer if index is None else index
        key = (slot, kind, index is model.index_buffer)
        cached = self._vaos.get(key)
        if cached is not None and cached[0] is index:
            return cached[1]
        if cached is not None:
            cached[1].release()
        if kind != "points" and self.quads == "instanced":
            vao = self.ctx.vertex_array(self._splat_prog_for(kind), [(self._corners, "2f", "a_corner"),
                                                                     (index, "u/i", "a_index")])
        elif kind != "points":
            vao = self.ctx.vertex_array(self._splat_prog_for(kind), [(index, "u", "a_index")])
        else:
            vao = self.ctx.vertex_array(self._point_prog, [(index, "u", "a_index")])
        self._vaos[key] = (index, vao)
        return vao

    def _draw_slot(self, slot: int, v: Camera, mode: str, max_sh_degree: int, params: dict, lod: float = 1.0) -> int:
        model = self._model(slot)
        if model.n == 0:
            return 0
        prog = self._point_prog if mode == "points" else self._splat_prog_for(mode)
        model.bind(prog)
        _set(prog, "u_sh_degree", int(min(max_sh_degree, model.sh_degree)))
        _set(prog, "u_view", _mat4(v.world_to_camera))
        _set(prog, "u_campos", tuple(float(x) for x in v.center))
        _set(prog, "u_intr", (v.fx, v.fy, v.cx, v.cy))
        _set(prog, "u_size", (float(v.width), float(v.height)))
        _set(prog, "u_lim", jacobian_limits(v, C.FOV_CLAMP_MARGIN))
        _set(prog, "u_near", params["near"])
        _set(prog, "u_far", params["far"])
        _set(prog, "u_eps2d", params["eps2d"])
        _set(prog, "u_tint", params["tint"])
        _set(prog, "u_dither", 1.0 / 255.0 if self._dithers() else 0.0)
        if mode == "points":
            _set(prog, "u_point_size", params["point_size"])
            self.ctx.enable(moderngl.PROGRAM_POINT_SIZE)
            self._vao(slot, "points").render(moderngl.POINTS, vertices=model.n)
        else:
            _set(prog, "u_mode", _SPLAT_MODE[mode])
            _set(prog, "u_outline_sigma", params["outline_sigma"])
            index, count = model.lod_buffer(lod) if lod < 1.0 else (None, model.n)
            kind = "ellipsoids" if mode == "ellipsoids" else "splat"
            if self.quads == "instanced":
                gl_direct.draw(self._vao(slot, kind, index), moderngl.TRIANGLE_STRIP, 4, instances=count)
            else:
                gl_direct.draw(self._vao(slot, kind, index), moderngl.POINTS, count)
            return count
        return model.n

    def splat_pass(self, camera, mode: str = "color", *, slot: int = 0, split: float | None = None,
                   max_sh_degree: int = 3, scale: float = 1.0, near: float = C.NEAR_PLANE,
                   far: float = C.FAR_PLANE, eps2d: float = C.EPS2D, tint=(1.0, 0.35, 0.1, 0.6),
                   point_size: float = 2.0, outline_sigma: float = 2.0, lod: float = 1.0,
                   split_left: int = 0) -> FrameInfo:
        """Composite into the accumulation target only (``render`` and ``render_arrays`` call this). ``lod`` < 1
        draws only that fraction of the Gaussians, the most important (opacity x footprint), in depth order: a
        preview while the camera moves, where software GL pays per splat. ``split_left``: the slot shown left of
        a split's divider (0 or 1; the other is on the right)."""
        if mode not in MODES:
            raise ValueError(f"unknown render mode {mode!r}; expected one of {', '.join(MODES)}")
        v = view(camera)
        if scale != 1.0:
            v = v.scaled(scale)
        fbo = self._accum_target((v.width, v.height))
        fbo.use()
        fbo.viewport = (0, 0, v.width, v.height)
        fbo.clear(0.0, 0.0, 0.0, 0.0)
        ctx = self.ctx
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND)
        ctx.blend_equation = moderngl.FUNC_ADD
        ctx.blend_func = moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA
        params = dict(near=float(near), far=float(far), eps2d=float(eps2d), tint=tuple(map(float, tint)),
                      point_size=float(point_size), outline_sigma=float(outline_sigma))
        if split is None:
            parts = [(slot, None)]
        else:
            x = int(round(np.clip(split, 0.0, 1.0) * v.width))
            left = int(split_left)
            parts = [(left, (0, 0, x, v.height)), (1 - left, (x, 0, v.width - x, v.height))]
        forward = v.forward
        info = FrameInfo(0, False, 0.0, 0.0, (v.width, v.height))
        try:
            for s, scissor in parts:
                if s not in self._slots or (scissor is not None and scissor[2] <= 0):
                    continue
                did, t_sort, t_up = self._ensure_order(s, forward)
                info.sorted |= did
                info.sort_s += t_sort
                info.upload_s += t_up
                ctx.scissor = scissor
                info.instances += self._draw_slot(s, v, mode, max_sh_degree, params, lod)
        finally:
            ctx.scissor = None
            ctx.disable(moderngl.BLEND)
        return info

    def depth_range(self, camera, slot: int = 0, near: float = C.NEAR_PLANE) -> tuple[float, float]:
        """The 2nd to 98th percentile of camera depths of the Gaussians in front of ``camera``."""
        v = view(camera)
        model = self._model(slot)
        R, t = v.world_to_camera[:3, :3], v.world_to_camera[:3, 3]
        z = model.means @ R[2].astype(np.float32) + np.float32(t[2])
        z = z[z >= near]
        if len(z) == 0:
            return (near, near + 1.0)
        lo, hi = np.percentile(z, [2.0, 98.0])
        return (float(lo), float(max(hi, lo + 1e-6)))

    def render(self, camera, framebuffer: moderngl.Framebuffer, *, viewport=None, mode: str = "color",
               background=(0.0, 0.0, 0.0), slot: int = 0, split: float | None = None, max_sh_degree: int = 3,
               scale: float = 1.0, depth_range=None, photo: str | None = None, photo_alpha: float = 0.5,
               overlays: Lines | list | None = None, divider_color=(1.0, 1.0, 1.0, 0.9), **splat_params
               ) -> FrameInfo:
        """Draw ``camera``'s view of the model(s) into ``framebuffer`` (its whole area, or ``viewport``
        = (x, y, w, h) in GL pixels, bottom-left origin).

        mode: color | depth (expected depth, colour-mapped over ``depth_range``, default the 2-98th percentile
        of visible depths) | alpha (accumulated opacity, grey) | points (centres) | ellipsoids (outlines at
        ``outline_sigma``). split: None, or the divider position in 0..1: slot 0 left of it, slot 1 right.
        scale: resolution factor of the splat pass (e.g. 0.5 while the camera moves), upsampled linearly.
        photo: None | "blend" (mixed with ``photo_alpha``) | "side" (render left half, photo right half) using
        the image given to ``set_photo``. overlays: ``Lines`` (or a list of them) drawn on top.
        Other keywords (near, far, eps2d, tint, point_size, outline_sigma) go to ``splat_pass``.
        """
        if photo not in PHOTO_MODES:
            raise ValueError(f"unknown photo mode {photo!r}; expected blend, side or None")
        v = view(camera)
        info = self.splat_pass(v, mode, slot=slot, split=split, max_sh_degree=max_sh_degree, scale=scale,
                               **splat_params)
        if mode == "depth":
            range_slot = slot if split is None else 0
            if depth_range is None and range_slot in self._slots:
                depth_range = self.depth_range(v, range_slot)
            if depth_range is not None:
                info.depth_range = tuple(map(float, depth_range))
        x, y, w, h = viewport if viewport is not None else (0, 0, *framebuffer.size)
        rects = [(x, y, w, h)] if photo != "side" else [(x, y, w // 2, h), (x + w // 2, y, w - w // 2, h)]
        framebuffer.use()
        self.ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
        self._accum.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self._accum.use(location=0)
        self._photo.use(location=1)
        for i, rect in enumerate(rects):
            framebuffer.viewport = rect
            photo_only = photo == "side" and i == 1
            prog, quad = self._resolve(3 if photo_only else _RESOLVE_MODE[mode],
                                       photo == "blend" and photo_alpha > 0 and not photo_only,
                                       split is not None and not photo_only)
            _set(prog, "u_accum", 0)
            _set(prog, "u_photo", 1)
            _set(prog, "u_background", tuple(float(c) for c in background[:3]))
            _set(prog, "u_depth_range", tuple(depth_range) if depth_range is not None else (0.0, 1.0))
            _set(prog, "u_divider_color", tuple(map(float, divider_color)))
            _set(prog, "u_photo_alpha", float(photo_alpha))
            _set(prog, "u_split", float(split) if split is not None else -1.0)
            _set(prog, "u_target_size", (float(rect[2]), float(rect[3])))
            quad.render(moderngl.TRIANGLE_STRIP)
        if overlays is not None:
            framebuffer.viewport = rects[0]
            self.draw_lines(v, overlays, splat_params.get("near", C.NEAR_PLANE))
        framebuffer.viewport = (x, y, w, h)
        return info

    def draw_lines(self, camera, lines: Lines | list, near: float = C.NEAR_PLANE, far: float = 1e4) -> None:
        """Draw world-space ``lines`` as ``camera`` sees them into the bound framebuffer and viewport."""
        if isinstance(lines, (list, tuple)):
            lines = Lines.join(list(lines))
        if len(lines.segments) == 0:
            return
        data = lines.vertex_data().tobytes()
        if self._line_vbo is None or self._line_vbo.size < len(data):
            if self._line_vbo is not None:
                self._line_vao.release()
                self._line_vbo.release()
            self._line_vbo = self.ctx.buffer(reserve=max(len(data), 4096), dynamic=True)
            self._line_vao = self.ctx.vertex_array(self._line_prog,
                                                   [(self._line_vbo, "3f 4f", "a_pos", "a_color")])
        self._line_vbo.write(data)
        _set(self._line_prog, "u_clip_from_world", _mat4(view(camera).clip_from_world(near, far)))
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        self._line_vao.render(moderngl.LINES, vertices=2 * len(lines.segments))
        self.ctx.disable(moderngl.BLEND)

    def render_arrays(self, camera, outputs=("rgb", "alpha"), *, background=(0.0, 0.0, 0.0), slot: int = 0,
                      max_sh_degree: int = 3, **splat_params) -> dict[str, np.ndarray]:
        """Float images straight from the accumulation target, top row first, no 8-bit rounding:
        "rgb" (H, W, 3) over ``background``, "alpha" (H, W), "depth" (H, W) expected depth (sum z a T / alpha;
        0 where nothing was drawn). This is what tests and EXR output read."""
        out = {}
        if "rgb" in outputs or "alpha" in outputs:
            self.splat_pass(camera, "color", slot=slot, max_sh_degree=max_sh_degree, **splat_params)
            acc = self._read_accum()
            if "rgb" in outputs:
                out["rgb"] = acc[..., :3] + (1.0 - acc[..., 3:4]) * np.asarray(background, np.float32)[:3]
            if "alpha" in outputs:
                out["alpha"] = acc[..., 3].copy()
        if "depth" in outputs:
            self.splat_pass(camera, "depth", slot=slot, max_sh_degree=max_sh_degree, **splat_params)
            acc = self._read_accum()
            a = acc[..., 3]
            out["depth"] = np.where(a > 1e-6, acc[..., 0] / np.maximum(a, 1e-10), 0.0).astype(np.float32)
        return out

    def _read_accum(self) -> np.ndarray:
        w, h = self._accum.size
        dtype = {"f4": np.float32, "f2": np.float16, "f1": np.uint8}[self.accum_dtype]
        arr = np.frombuffer(self._accum.read(), dtype=dtype).reshape(h, w, 4)
        arr = arr.astype(np.float32) / (255.0 if dtype == np.uint8 else 1.0)
        return np.ascontiguousarray(arr[::-1])

    def release(self) -> None:
        for s in list(self._slots) + list(self._gpu_sorts):
            self.remove(s)
        if self._sorter is not None:
            self._sorter.close()
        for tex, fbo in self._accum_targets.values():
            fbo.release()
            tex.release()
        self._accum_targets.clear()
        for obj in (self._photo, self._line_vao, self._line_vbo, *(q for _, q in self._resolves.values()),
                    self._corners, *self._splat_progs.values(), self._point_prog,
                    *(p for p, _ in self._resolves.values()), self._line_prog):
            if obj is not None:
                obj.release()
