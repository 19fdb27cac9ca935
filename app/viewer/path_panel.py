"""The camera path panel: keyframes from the current view (reordered, deleted, visited), the dataset's trajectory
or an orbit as ready-made paths, save and load as JSON, and a video of the path (MP4 or PNG frames) rendered a few
frames per UI frame, with a progress bar and Cancel, so the window stays live (GL draws on this thread only).
A before/after video shows the model before stylization left of a divider and the stylized one right of it.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

import numpy as np
from imgui_bundle import imgui

GREY = imgui.ImVec4(0.6, 0.6, 0.6, 1.0)
FRAME_BUDGET_S = 0.15  # rendering time spent per UI frame on a video, so input still gets answered


class VideoJob:
    """An MP4/PNG render of a path, advanced by ``step()`` from the UI loop; ``cancel()`` removes a partial MP4."""

    def __init__(self, app, path, out: Path, width: int, height: int, split: bool):
        from app.video_output import frame_writer, render_frames

        self.app = app
        self.cameras = path.cameras(width, height)
        self.total = len(self.cameras)
        self.done = 0
        self.out = out
        self.started = time.perf_counter()
        self._stack = contextlib.ExitStack()
        self._write = self._stack.enter_context(frame_writer(out, width, height, path.fps))
        renderer = app.view.renderer
        self._frames = render_frames(renderer, self.cameras, width, height,
                                     split=0.5 if split else None, split_left=1,
                                     background=app.view.settings.background,
                                     max_sh_degree=app.view.settings.max_sh_degree)
        self.finished = False

    def step(self) -> None:
        t0 = time.perf_counter()
        while not self.finished and time.perf_counter() - t0 < FRAME_BUDGET_S:
            frame = next(self._frames, None)
            if frame is None:
                self._stack.close()
                self.finished = True
                seconds = time.perf_counter() - self.started
                self.app.say(f"wrote {self.out} ({self.total} frames, {seconds / max(self.total, 1):.2f} s a frame)")
                break
            self._write(frame)
            self.done += 1
        self.app.view.dirty = True  # the renderer's targets were used for the video

    def cancel(self) -> None:
        from training.core.messages import Cancelled

        self._frames.close()
        with contextlib.suppress(Cancelled):
            self._stack.__exit__(Cancelled, Cancelled(), None)  # an MP4 under way is removed; PNGs written stay
        self.finished = True
        self.app.say(f"video cancelled after {self.done} of {self.total} frames")


def path_panel(app) -> None:
    _contents(app)


def step_video(app) -> None:
    """A video under way renders its next frame (every frame, whether or not the panel is shown)."""
    job = app.path.job
    if job is not None and not job.finished:
        app.guarded("video", job.step)
        if job.finished:
            app.path.job = None


def _contents(app) -> None:
    from app.camera_path import CameraPath, dataset_path, keyframe_from, orbit_around

    st = app.path
    keys = app.path.keys
    if imgui.button("Add keyframe") and app.view.camera is not None:
        io = imgui.get_io()
        keys.append(keyframe_from(app.view.camera.camera(int(io.display_size.x), int(io.display_size.y))))
        app.update_overlays()
    imgui.same_line()
    if imgui.button("Dataset trajectory") and app.scene.cameras:
        app.path.keys[:] = dataset_path(app.scene.cameras).keyframes
        app.update_overlays()
    imgui.same_line()
    if imgui.button("Orbit"):
        snap = app._current_model()
        if snap is not None:
            orbit = app.guarded("orbit", orbit_around, snap.means, snap.opacities, app.scene.cameras or None)
            if orbit is not None:
                app.path.keys[:] = orbit.keyframes
                st.loop = True
                app.update_overlays()
    for i in range(len(keys)):
        imgui.push_id(i)
        imgui.text(f"{i:2d}")
        imgui.same_line()
        if imgui.small_button("go"):
            from app.viewer.camera_control import ViewerCamera

            up = app.view.camera.up if app.view.camera is not None else None
            app.view.camera = ViewerCamera.from_camera(_as_camera(keys[i]), up=up)
            app.view.moved()
        imgui.same_line()
        if imgui.small_button("up") and i > 0:
            keys[i - 1], keys[i] = keys[i], keys[i - 1]
            app.update_overlays()
        imgui.same_line()
        if imgui.small_button("down") and i + 1 < len(keys):
            keys[i + 1], keys[i] = keys[i], keys[i + 1]
            app.update_overlays()
        imgui.same_line()
        if imgui.small_button("delete"):
            del keys[i]
            app.update_overlays()
            imgui.pop_id()
            break
        imgui.pop_id()
    _, st.seconds = imgui.slider_float("seconds", st.seconds, 1.0, 60.0)
    _, st.fps = imgui.slider_int("fps", st.fps, 10, 60)
    _, st.loop = imgui.checkbox("loop", st.loop)
    _, st.file = imgui.input_text("path file", st.file)
    if imgui.button("Save path") and len(keys) >= 2:
        app.guarded("save path", lambda: (current_path(app).save(st.file), app.say(f"wrote {st.file}")))
    imgui.same_line()
    if imgui.button("Load path"):
        loaded = app.guarded("load path", CameraPath.load, st.file)
        if loaded is not None:
            app.path.keys[:] = loaded.keyframes
            st.update(seconds=float(loaded.duration), fps=int(round(loaded.fps)), loop=bool(loaded.loop))
            app.update_overlays()
    imgui.separator_text("Video")
    _, st.size = imgui.input_int2("size", st.size)
    _, st.video = imgui.input_text("video file", st.video)
    imgui.set_item_tooltip("a .mp4 file, or a folder for PNG frames")
    imgui.begin_disabled(app.original is None)
    _, st.split = imgui.checkbox("before | after", st.split and app.original is not None)
    imgui.end_disabled()
    job = app.path.job
    if job is None or job.finished:
        imgui.begin_disabled(len(keys) < 2)
        if imgui.button("Render video"):
            app.guarded("video", start_video, app)
        imgui.end_disabled()
    else:
        imgui.progress_bar(job.done / max(job.total, 1), imgui.ImVec2(-80, 0), f"{job.done}/{job.total}")
        imgui.same_line()
        if imgui.button("Cancel"):
            job.cancel()
            app.path.job = None


def current_path(app):
    from app.camera_path import CameraPath

    st = app.path
    return CameraPath(list(app.path.keys), duration=float(st.seconds), fps=float(st.fps), loop=bool(st.loop))


def start_video(app) -> None:
    st = app.path
    w, h = (int(v) for v in st.size)
    if w < 16 or h < 16 or w % 2 or h % 2:
        raise ValueError(f"video size must be even and at least 16x16, got {w}x{h}")
    if st.split and app.original is not None:
        app.view.show(app.original, 1)
    out = Path(st.video)
    out.parent.mkdir(parents=True, exist_ok=True)
    app.path.job = VideoJob(app, current_path(app), out, w, h, st.split and app.original is not None)


def path_line(app):
    """The path's camera centres, densely, for the 3D view (None without two keyframes)."""
    if len(app.path.keys) < 2:
        return None
    path = current_path(app)
    cams = path.cameras(64, 36)
    return np.array([c.center for c in cams])


def _as_camera(key):
    from training.scene.scene import Camera

    return Camera("keyframe", key.width, key.height, key.fx, key.fy, key.cx, key.cy, np.array(key.world_to_camera))
