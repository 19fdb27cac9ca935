"""Where a frame of the viewer's CUDA display path goes, for each way into the texture (``pinned``, ``interop``).

For one model and camera, each transfer (app/viewer/display/cuda.py) draws a warm-up frame (allocations, the
texture's CUDA registration), then:

- ``cuda_<transfer>_frame_ms``: the whole frame as the viewer draws it (rasterize, convert to 8 bits, into the
  texture, fullscreen quad), then ``glFinish``; the transfers take turns, so a change in load falls on both;
- ``cuda_<transfer>_<stage>_ms`` for raster, convert, transfer, draw: the same frame with a wait after each stage
  (the display's stream, and GL after the transfer and the draw), so each stage is its own time; their sum
  (``cuda_<transfer>_stages_ms``) exceeds the unprofiled frame by what the waits cost and by what overlaps without
  them;
- ``cuda_<transfer>_skipped``: why a transfer could not run (cuda-python missing, registration refused, ...).

Medians over ``repeat`` frames. ``backend`` "torch" runs the same code on CPU tensors (tests; the interop transfer
then fails for want of CUDA, with its reason).
"""

from __future__ import annotations

import statistics
import time

STAGES = ("raster", "convert", "transfer", "draw")
TRANSFERS = ("pinned", "interop")


def frame_breakdown(ctx, snap, camera, repeat: int, backend: str = "cuda",
                    transfers: tuple[str, ...] = TRANSFERS) -> dict:
    """The figures above for ``snap`` (a ModelSnapshot) seen by ``camera`` (a training Camera, at its size)."""
    from app.viewer.display.cuda import CudaDisplay

    size = (int(camera.width), int(camera.height))
    target = ctx.texture(size, 4)
    fbo = ctx.framebuffer(color_attachments=[target])
    out: dict = {}
    displays: dict[str, CudaDisplay] = {}

    def drop(transfer: str, exc: BaseException) -> None:
        out[f"cuda_{transfer}_skipped"] = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
        d = displays.pop(transfer, None)
        if d is not None:
            d.release()

    def frame(d: CudaDisplay) -> float:
        t0 = time.perf_counter()
        d.draw(camera, fbo)
        ctx.finish()
        return time.perf_counter() - t0

    try:
        for transfer in transfers:
            try:
                displays[transfer] = CudaDisplay(ctx, backend=backend, transfer=transfer, fallback=False)
                displays[transfer].set_model(snap)
                frame(displays[transfer])
            except Exception as exc:  # this transfer cannot run here: its reason is the result
                drop(transfer, exc)
        frames: dict[str, list[float]] = {t: [] for t in displays}
        stages: dict[str, list[dict]] = {t: [] for t in displays}
        for profiled in (False, True):
            for _ in range(max(1, repeat)):
                for transfer, d in list(displays.items()):
                    try:
                        d.profile = profiled
                        seconds = frame(d)
                    except Exception as exc:  # e.g. a mapping error after some frames
                        drop(transfer, exc)
                        continue
                    if profiled:
                        stages[transfer].append(dict(d.last_stages))
                    else:
                        frames[transfer].append(seconds)
        for transfer in displays:
            out[f"cuda_{transfer}_frame_ms"] = 1000.0 * statistics.median(frames[transfer])
            for stage in STAGES:
                out[f"cuda_{transfer}_{stage}_ms"] = 1000.0 * statistics.median(s[stage] for s in stages[transfer])
            out[f"cuda_{transfer}_stages_ms"] = sum(out[f"cuda_{transfer}_{stage}_ms"] for stage in STAGES)
    finally:
        for d in displays.values():
            d.release()
        fbo.release()
        target.release()
    return out
