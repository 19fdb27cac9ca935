"""A video of the document's camera path (MP4 or PNG frames), rendered a few frames per UI frame so the window
stays live (GL draws on this thread only), with a before/after split when the model before stylization is there."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

FRAME_BUDGET_S = 0.15  # rendering time spent per UI frame on a video, so input still gets answered


class VideoJob:
    """An MP4/PNG render of a path, advanced by ``step()`` from the UI loop; ``cancel()`` removes a partial MP4."""

    def __init__(self, view, messages, path, out: Path, width: int, height: int, split: bool):
        from app.video_output import frame_writer, render_frames

        self.view, self.messages = view, messages
        path = path.copy()  # the frames follow the path as it was when Render was pressed
        self.total = path.frame_count
        self.done = 0
        self.out = out
        self.started = time.perf_counter()
        self._stack = contextlib.ExitStack()
        self._write = self._stack.enter_context(frame_writer(out, width, height, path.fps))
        # each frame's camera is made as the frame is rendered: up to MAX_FRAMES of them up front would hold the
        # UI thread
        self._frames = render_frames(view.renderer, path.iter_cameras(width, height), width, height,
                                     split=0.5 if split else None, split_left=1,
                                     background=view.settings.background,
                                     max_sh_degree=view.settings.max_sh_degree)
        self.finished = False

    def step(self) -> None:
        t0 = time.perf_counter()
        while not self.finished and time.perf_counter() - t0 < FRAME_BUDGET_S:
            frame = next(self._frames, None)
            if frame is None:
                self._stack.close()
                self.finished = True
                seconds = time.perf_counter() - self.started
                self.messages.say(f"wrote {self.out} ({self.total} frames, {seconds / max(self.total, 1):.2f} s a "
                                  "frame)")
                break
            self._write(frame)
            self.done += 1
        self.view.dirty = True  # the renderer's targets were used for the video

    def cancel(self) -> None:
        from training.core.messages import Cancelled

        self._frames.close()
        with contextlib.suppress(Cancelled):
            self._stack.__exit__(Cancelled, Cancelled(), None)  # an MP4 under way is removed; PNGs written stay
        self.finished = True
        self.messages.say(f"video cancelled after {self.done} of {self.total} frames")


def start_video(doc, ui) -> None:
    st = ui.video
    doc.camera_path.validate()  # keyframes, and a duration and fps within the limits (the frames are counted)
    w, h = (int(v) for v in st.size)
    if w < 16 or h < 16 or w % 2 or h % 2:
        raise ValueError(f"video size must be even and at least 16x16, got {w}x{h}")
    before = ui.training.before
    if st.split and before is not None:
        ui.view.show(before, 1)
    out = Path(st.video)
    out.parent.mkdir(parents=True, exist_ok=True)
    st.job = VideoJob(ui.view, ui.messages, doc.camera_path, out, w, h, st.split and before is not None)


def step_video(ui) -> None:
    """A video under way renders its next frames (every frame, whether or not its panel is shown)."""
    job = ui.video.job
    if job is not None and not job.finished:
        ui.messages.guarded("video", job.step)
        if job.finished:
            ui.video.job = None
