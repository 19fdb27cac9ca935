"""The 3D view: the models on the GPU, the camera under the mouse and keys, and when to draw.

Drawing is the expensive part on software GL (and moderngl holds the GIL while it draws, starving the trainer), so
the view draws only when something it shows changed: the camera, a model upload, a setting. While the camera moves
it draws at ``motion_scale`` of the resolution and, once still for ``settle_s``, once more at full size. The last
picture stays in an offscreen texture that every frame copies to the window for almost nothing.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from app.viewer.camera import ViewerCamera, nearest_camera
from renderer_gl import gl_direct

MODES = ("color", "depth", "alpha", "points", "ellipsoids")
BURST_S = 0.6  # drawing time the view may spend at once after a quiet spell while a trainer runs
PHOTO_MODES = ("off", "blend", "side")


# The span each live-view setting's slider offers (the settings are plain fields: any value in it is valid).
RANGES = {"training_share": (0.05, 0.95), "training_scale": (0.25, 1.0), "motion_lod": (0.05, 1.0),
          "refresh_s": (0.05, 5.0)}


@dataclass
class RenderSettings:
    mode: str = "color"
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_sh_degree: int = 3
    split: bool = False
    split_position: float = 0.5
    show_frustums: bool = True
    show_path: bool = True
    photo: str = "off"
    photo_alpha: float = 0.5
    motion_scale: float = 0.5
    motion_lod: float = 1.0  # the fraction of the Gaussians (the most important) drawn while the camera moves
    training_scale: float = 1.0  # resolution of the still view while a trainer runs (it shares the CPU)
    training_share: float = 0.85  # while a trainer runs, the view draws at most (1 - this) of the time
    settle_s: float = 0.25


class View3D:
    """Owns the GL objects of the 3D view; every method runs on the GL (main) thread."""

    def __init__(self, ctx, background_sort: bool = True):
        from renderer_gl import SplatRenderer

        self.ctx = ctx
        self.renderer = SplatRenderer(ctx, background_sort=background_sort)
        self.settings = RenderSettings()
        self.camera: ViewerCamera | None = None
        self._texture = None
        self._fbo = None
        self._size = (0, 0)
        self.dirty = True
        self._last_move = 0.0
        self._full_res_pending = False
        self._moved_since_draw = False  # a move waits for its picture: drawn at the moving quality, however late
        self._uploaded: dict[int, tuple[int, int]] = {}  # slot -> (version, geometry_version)
        self.overlays = None  # renderer_gl Lines, or None
        self.frames_drawn = 0
        self.last_frame_s = 0.0
        self.flying = False  # a fly or roll key is held
        self._budget = BURST_S  # seconds of drawing the view may still spend now (a token bucket)
        self._budget_at = time.perf_counter()
        self._models: dict[int, object] = {}  # slot -> the ModelSnapshot uploaded there
        self.display = None  # choice.DisplayChoice, made at the first draw of a model
        self.display_override = "auto"  # auto | a path from choice.PATHS (or PATH/FORMAT)
        self.cuda = None  # cuda.CudaDisplay when the chosen path is cuda
        self.gl_thread = threading.get_ident()  # the only thread on which the context is current

    # ------------------------------------------------------------------ models
    def show(self, snap, slot: int = 0) -> bool:
        """Upload a ModelSnapshot into ``slot`` if it is newer than what is there: colours alone when only they
        changed. Returns whether anything was uploaded."""
        key = (snap.version, snap.geometry_version)
        have = self._uploaded.get(slot)
        if have == key:
            return False
        if have is not None and have[1] == snap.geometry_version and self.renderer.count(slot) == len(snap):
            self.renderer.update_colors(snap.sh, snap.sh_degree, slot=slot)
        else:
            self.renderer.set_splats(snap.means, snap.scales, snap.quats, snap.opacities, snap.sh, snap.sh_degree,
                                     slot=slot)
        self._uploaded[slot] = key
        self._models[slot] = snap
        if slot == 0 and self.cuda is not None:
            self.cuda.set_model(snap)
        self.dirty = True
        return True

    # ------------------------------------------------------------------ display path
    def choose_display(self, size: tuple[int, int]) -> None:
        """Time the ways this machine can draw the loaded model and keep the fastest (choice.py); on software
        GL there is one way and nothing is timed. A renderer with other options replaces the current one."""
        from app.viewer.display.choice import choose_display_path
        from renderer_gl import SplatRenderer

        choice = choose_display_path(self.ctx, self._models[0], self.camera, size, override=self.display_override)
        self.release_cuda()
        if choice.path == "cuda":
            from app.viewer.display.cuda import CudaDisplay

            self.cuda = CudaDisplay(self.ctx, **choice.cuda_options())
            self.cuda.set_model(self._models[0])
        elif choice.renderer_options() != self.renderer.options():
            self.renderer.release()
            self.renderer = SplatRenderer(self.ctx, background_sort=True, **choice.renderer_options())
            models, self._uploaded = dict(self._models), {}
            for slot, snap in models.items():
                self.show(snap, slot)
        self.display = choice
        self.dirty = True

    def set_display_override(self, value: str) -> None:
        """The display path setting: "auto" measures again; a path name uses that path (if it can run here)."""
        self.display_override = value
        self.display = None  # chosen again at the next draw

    def release_cuda(self) -> None:
        if self.cuda is not None:
            self.cuda.release()
            self.cuda = None

    def clear(self, slot: int) -> None:
        self.renderer.remove(slot)
        self._uploaded.pop(slot, None)
        self.dirty = True

    def has_model(self, slot: int = 0) -> bool:
        return self.renderer.count(slot) > 0

    # ------------------------------------------------------------------ camera input
    def moved(self) -> None:
        self._last_move = time.perf_counter()
        self._moved_since_draw = True
        self._full_res_pending = True
        self.dirty = True

    def handle_mouse(self, imgui, hovered: bool, active: bool, left_orbits: bool = True) -> None:
        """Orbit (left drag), pan (right or middle drag) from a drag that started on the view; zoom (wheel) over it."""
        if self.camera is None:
            return
        io = imgui.get_io()
        dx, dy = io.mouse_delta.x, io.mouse_delta.y
        if active and (dx or dy):
            if left_orbits and imgui.is_mouse_dragging(imgui.MouseButton_.left):
                self.camera.orbit(dx, dy)
                self.moved()
            elif (imgui.is_mouse_dragging(imgui.MouseButton_.right)
                  or imgui.is_mouse_dragging(imgui.MouseButton_.middle)):
                self.camera.pan(dx, dy, max(self._size[1], 1))
                self.moved()
        if hovered and io.mouse_wheel:
            self.camera.zoom(io.mouse_wheel)
            self.moved()

    def handle_keys(self, imgui, dt: float, fly_speed: float, enabled: bool) -> None:
        """Fly (WASD, Q/E) and roll (Z/C) while a key is held; never while Ctrl or Super is down (Ctrl+Z is undo)."""
        self.flying = False
        io = imgui.get_io()
        if self.camera is None or not enabled or io.key_ctrl or io.key_super:
            return
        k = imgui.Key
        axis = lambda pos, neg: float(imgui.is_key_down(pos)) - float(imgui.is_key_down(neg))  # noqa: E731
        forward, right, up = axis(k.w, k.s), axis(k.d, k.a), axis(k.e, k.q)
        if forward or right or up:
            self.camera.fly(forward, right, up, fly_speed * dt)
            self.moved()
        roll = axis(k.c, k.z)
        if roll:
            self.camera.roll(roll * dt)
            self.moved()
        self.flying = bool(forward or right or up or roll)

    def snap_to(self, camera, cameras) -> None:
        """Put the view at a dataset camera (keeping the orbit centre's distance)."""
        distance = self.camera.target_distance if self.camera is not None else 1.0
        up = self.camera.up if self.camera is not None else None
        self.camera = ViewerCamera.from_camera(camera, up=up, target_distance=distance)
        self.dirty = True

    def nearest(self, cameras) -> int:
        return nearest_camera(self.camera, cameras)

    # ------------------------------------------------------------------ drawing
    def _target(self, size: tuple[int, int]):
        """The offscreen picture at the view's size in framebuffer pixels (it follows the window's resizes)."""
        if size != self._size:
            for obj in (self._fbo, self._texture):
                if obj is not None:
                    obj.release()
            self._texture = self.ctx.texture(size, 4)
            self._fbo = self.ctx.framebuffer(color_attachments=[self._texture])
            self._size = size
            self.dirty = True
        return self._fbo

    def needs_draw(self, training: bool = False) -> bool:
        """Dirty, or the camera has settled after moving and the still picture is finer than the moving one. While
        a trainer runs, the finer picture waits for the next model refresh (a full draw anyway): drawing it twice
        would cost the trainer the time."""
        settled = time.perf_counter() - self._last_move > self.settings.settle_s
        s = self.settings
        still_scale = s.training_scale if training else 1.0
        return self.dirty or (self._full_res_pending and settled and not training
                              and (still_scale != s.motion_scale or s.motion_lod < 1.0))

    def charge(self, seconds: float) -> None:
        """Count work done for the view outside ``draw`` (a model upload) against the drawing budget."""
        self._budget -= seconds

    def draw(self, size: tuple[int, int], split_ready: bool, training: bool = False) -> bool:
        """Render into the offscreen target if needed; returns whether it drew."""
        if size[0] < 1 or size[1] < 1 or self.camera is None:
            self.dirty = False  # nothing to show yet; placing a camera marks the view dirty again
            return False
        fbo = self._target(size)
        if training and not self.may_draw_now():
            return False
        if not self.needs_draw(training):
            if self._full_res_pending and time.perf_counter() - self._last_move > self.settings.settle_s:
                self._full_res_pending = False  # the moving picture is already at the still scale
            return False
        s = self.settings
        moving = self._moved_since_draw or time.perf_counter() - self._last_move <= s.settle_s
        scale = s.motion_scale if moving else (s.training_scale if training else 1.0)
        lod = s.motion_lod if moving else 1.0
        if not moving:
            self._full_res_pending = False
        self._moved_since_draw = False
        # the last frame's GL work (the panels, the view's image) may still be under way on a software renderer:
        # wait for it here with the GIL released, not inside the calls below, which hold it (and with it a trainer)
        gl_direct.finish(self.ctx)
        t0 = time.perf_counter()
        # the caller (imgui's frame) has its own framebuffer bound: draw into ours, then give its binding back
        found = self.ctx.detect_framebuffer()
        try:
            fbo.use()
            fbo.clear(*s.background, 1.0)
            if self.has_model(0):
                if self.display is None:
                    self.choose_display(size)
                cam = self.camera.camera(*size)
                split = s.split_position if (s.split and split_ready) else None
                photo = None if s.photo == "off" else s.photo
                if self.cuda is not None and self.cuda_can_draw(split, photo):
                    self.cuda.draw(self.camera, fbo, background=s.background, max_sh_degree=s.max_sh_degree,
                                   mode=s.mode, scale=scale, overlays=self.overlays, lines_renderer=self.renderer)
                else:  # the GL path, also for what the CUDA path cannot draw (points, ellipsoids, split, tint)
                    self.renderer.render(cam, fbo, mode=s.mode, background=s.background, split=split,
                                         max_sh_degree=s.max_sh_degree, scale=scale, photo=photo,
                                         photo_alpha=s.photo_alpha, overlays=self.overlays, lod=lod,
                                         split_left=1)  # slot 1: the model before stylization, before | after
            gl_direct.finish(self.ctx)
        finally:
            found.use()
        self.last_frame_s = time.perf_counter() - t0
        if training:
            self._budget -= self.last_frame_s
        self.frames_drawn += 1
        self.dirty = False
        return True

    def cuda_can_draw(self, split, photo) -> bool:
        from app.viewer.display.cuda import unsupported

        return unsupported(self.settings.mode, split=split is not None, photo=photo,
                           flags=self.renderer.flagged(0)) is None

    def may_draw_now(self) -> bool:
        """While a trainer runs the view may draw (1 - share) of the time on average: drawing time accrues at that
        rate up to a burst of BURST_S, so a move after a quiet spell is drawn at once (latency) while continuous
        motion settles at the share (the trainer's throughput)."""
        now = time.perf_counter()
        share = min(max(self.settings.training_share, 0.05), 0.95)
        self._budget = min(BURST_S, self._budget + (now - self._budget_at) * (1.0 - share))
        self._budget_at = now
        return self._budget > 0.0

    @property
    def texture(self):
        """The last picture (an RGBA8 texture, bottom row first), or None before the first draw."""
        return self._texture

    def read(self) -> np.ndarray | None:
        """(H, W, 3) uint8 of the last picture, top row first."""
        if self._fbo is None:
            return None
        if threading.get_ident() != self.gl_thread:
            # elsewhere no context is current: glReadPixels does nothing and the bytes would be uninitialised memory
            raise RuntimeError("View3D.read must run on the thread that owns the GL context")
        data = self._fbo.read(components=3, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(self._size[1], self._size[0], 3)[::-1].copy()

    def render_arrays(self, camera, outputs: tuple[str, ...]) -> dict[str, np.ndarray]:
        """The renderer's arrays (alpha, depth, ...) of the shown model for ``camera``, top row first, rendered
        offscreen in the middle of a frame: the frame's own framebuffer binding is given back after."""
        found = self.ctx.detect_framebuffer()
        try:
            return self.renderer.render_arrays(camera, outputs)
        finally:
            found.use()

    def release(self) -> None:
        self.release_cuda()
        self.renderer.release()
        for obj in (self._fbo, self._texture):
            if obj is not None:
                obj.release()
