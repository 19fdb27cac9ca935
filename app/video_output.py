"""Frames of a camera path, rendered by renderer_gl into an MP4 (imageio-ffmpeg's bundled ffmpeg, H.264) or a folder
of PNGs; shared by ``splatstyler video`` and the viewer's video export, which pass their own renderer.

Cancelling (``cancel()`` turning true between frames, or Ctrl-C) leaves no MP4 at all: it is written under a
temporary name and renamed only when complete. A PNG folder keeps the frames finished so far (each is written
atomically, so none is half-written); frames of an earlier, longer run into the same folder are removed when a
run completes.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from training.core import stop
from training.core.atomic_write import atomic_path
from training.core.messages import check_cancel

FRAME_PATTERN = "frame_{:05d}.png"
MP4_QUALITY = 8  # imageio-ffmpeg's 0..10 scale; 8 keeps splat edges crisp at a few MB per minute of 720p


def is_video_file(path: Path) -> bool:
    return path.suffix.lower() == ".mp4"


@contextlib.contextmanager
def frame_writer(out: Path, width: int, height: int, fps: float) -> Iterator[Callable[[np.ndarray], None]]:
    """Yields ``write(frame)`` for (H, W, 3) uint8 frames: into the MP4 ``out`` (atomic) or the folder ``out``."""
    out = Path(out)
    if is_video_file(out):
        import imageio_ffmpeg

        with atomic_path(out) as tmp:
            # macro_block_size=2: H.264 in yuv420p needs even sides, and the default (16) would rescale 640x360
            gen = imageio_ffmpeg.write_frames(str(tmp), (width, height), fps=fps, codec="libx264", pix_fmt_in="rgb24",
                                              pix_fmt_out="yuv420p", quality=MP4_QUALITY, macro_block_size=2,
                                              ffmpeg_log_level="error")
            gen.send(None)
            def send(frame: np.ndarray) -> None:
                stop.check()
                gen.send(np.ascontiguousarray(frame, dtype=np.uint8))

            try:
                yield send
            except BaseException:
                with contextlib.suppress(Exception):  # ffmpeg may be gone already (Ctrl-C reaches it too)
                    gen.close()
                raise
            gen.close()  # flushes and waits for ffmpeg: the file is complete before it is renamed into place
        return
    from training.scene.image_io import write_image

    out.mkdir(parents=True, exist_ok=True)
    written = []

    def write(frame: np.ndarray) -> None:
        stop.check()
        path = out / FRAME_PATTERN.format(len(written))
        write_image(path, frame.astype(np.float32) / 255.0)
        written.append(path.name)

    yield write
    for stale in out.glob("frame_[0-9][0-9][0-9][0-9][0-9].png"):
        if stale.name not in written:
            stale.unlink()


def render_frames(renderer, cameras, width: int, height: int, *, split: float | None = None, split_left: int = 0,
                  background=(0.0, 0.0, 0.0), max_sh_degree: int = 3, cancel=None) -> Iterator[np.ndarray]:
    """(H, W, 3) uint8 frames of ``cameras`` (camera-like objects at ``width`` x ``height``) from ``renderer``'s
    model in slot 0 (or slots 0 | 1 split at ``split``); ``cancel()`` is asked before each frame (Cancelled)."""
    from renderer_gl import Offscreen, view

    off = Offscreen(renderer.ctx, width, height)
    try:
        for cam in cameras:
            check_cancel(cancel)
            renderer.render(view(cam), off.fbo, mode="color", background=background, max_sh_degree=max_sh_degree,
                            split=split, split_left=split_left)
            yield off.read()
    finally:
        off.release()


def write_path_video(renderer, cameras, out: Path, width: int, height: int, fps: float, progress=None,
                     **render_kwargs) -> dict:
    """Render ``cameras`` into ``out`` (MP4 or PNG folder); ``progress(i, n)`` after each frame. Returns
    {"frames", "seconds", "seconds_per_frame", "render_seconds_per_frame"} (render: GPU draw and read-back alone,
    encoding excluded)."""
    t0 = time.perf_counter()
    render_s = 0.0
    count = 0
    with frame_writer(out, width, height, fps) as write:
        frames = render_frames(renderer, cameras, width, height, **render_kwargs)
        while True:
            t = time.perf_counter()
            frame = next(frames, None)
            render_s += time.perf_counter() - t
            if frame is None:
                break
            write(frame)
            count += 1
            if progress is not None:
                progress(count, len(cameras))
    total = time.perf_counter() - t0
    return {"frames": count, "seconds": total, "seconds_per_frame": total / max(count, 1),
            "render_seconds_per_frame": render_s / max(count, 1)}
