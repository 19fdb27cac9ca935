"""Which way the viewer draws, chosen by timing each way on the user's machine with the loaded model.

Candidates (``PATHS``):

- ``gl-cpu-sort``: renderer_gl with the numpy sort (every machine; the only one that suits software GL);
- ``gl-gpu-sort``: renderer_gl with its compute-shader sort (GL 4.3, not on a software renderer, where it is far
  slower than numpy);
- ``cuda``: the training rasterizer through gsplat, shown as a texture (app/viewer/display/cuda.py), where torch
  sees a CUDA device and gsplat imports; timed with each way into the texture (``cuda/pinned``: a copy through
  pinned host memory; ``cuda/interop``: CUDA-GL interop, no host copy, where cuda-python imports and the GL context
  can be registered with CUDA).

A GL path is timed with each accumulation format that shows no visible loss (f4, and f2: 46 dB against the
training rasterizer on the fox, docs/gpu.md) and keeps the faster; on software GL with f4 alone (f2 is slower
there), so that a machine with one candidate spends no time choosing. Each candidate draws a few frames of a turning
camera (so the sort is in each frame, as when the user turns the view), in turn; the fastest median wins, unless
an earlier candidate (in the order above, f4 before f2, pinned before interop) is within 5% of it. A candidate that
cannot run, or raises, is skipped with its reason (a CUDA-GL registration refused by the driver, say). An override
(``override=``, or the environment variable ``SPLATSTYLER_DISPLAY_PATH``) names the path to use without timing the
others; ``cuda`` alone means interop where it works, else the pinned copy (the display says why).
"""

from __future__ import annotations

import os
import statistics
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

PATHS = ("gl-cpu-sort", "gl-gpu-sort", "cuda")
ENV = "SPLATSTYLER_DISPLAY_PATH"
MARGIN = 0.05  # a candidate must be this much faster than an earlier one to be chosen over it
GL_FORMATS = ("f4", "f2")  # accumulation formats without visible loss; f1 loses faint splats (docs/gpu.md)
CUDA_TRANSFERS = ("pinned", "interop")  # how the CUDA path's picture reaches its texture (cuda.py)


@dataclass
class DisplayChoice:
    """What ``choose_display_path`` decided. ``path``: one of PATHS; ``accum_dtype``: the GL renderer's format for
    a GL path (None for cuda); ``frame_ms``: the median turning-camera frame of every candidate timed, by label
    ("gl-cpu-sort/f4", "cuda/interop", ...); ``skipped``: path or label -> why it was not timed or failed;
    ``reason``: how the choice was made (one line, for the UI); ``transfer``: the cuda path's way into its
    texture (None for a GL path)."""

    path: str
    accum_dtype: str | None
    frame_ms: dict[str, float] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    reason: str = ""
    transfer: str | None = None

    @property
    def sort_on(self) -> str | None:
        return {"gl-cpu-sort": "cpu", "gl-gpu-sort": "gpu"}.get(self.path)

    def renderer_options(self) -> dict:
        """Keyword arguments for ``SplatRenderer`` on a GL path (sort_on, accum_dtype); {} for cuda."""
        return {} if self.path == "cuda" else {"sort_on": self.sort_on, "accum_dtype": self.accum_dtype}

    def cuda_options(self) -> dict:
        """Keyword arguments for ``CudaDisplay`` on the cuda path (transfer; it falls back to pinned by itself)."""
        return {"transfer": self.transfer or "pinned"}

    def label(self) -> str:
        return _label(self.path, self.accum_dtype, self.transfer)

    def interop_note(self, cuda_display=None) -> str | None:
        """One line for the UI when the cuda path draws without CUDA-GL interop: why (``cuda_display``: the view's
        CudaDisplay, which may have dropped interop in the middle of a session), or None."""
        if self.path != "cuda":
            return None
        reason = getattr(cuda_display, "fallback_reason", None)
        if reason:
            return f"CUDA-GL interop off: {reason}"
        if self.transfer == "interop":
            return None
        if "cuda/interop" in self.skipped:
            return f"CUDA-GL interop not used: {self.skipped['cuda/interop']}"
        timed = self.frame_ms.get("cuda/interop"), self.frame_ms.get("cuda/pinned")
        if None not in timed:
            return f"CUDA-GL interop not used: {timed[0]:.1f} ms a frame against {timed[1]:.1f} ms pinned"
        return None


def _label(path: str, accum_dtype: str | None, transfer: str | None) -> str:
    suffix = accum_dtype or transfer
    return path if suffix is None else f"{path}/{suffix}"


@dataclass
class Candidate:
    """A way to draw: ``make()`` builds it with the model loaded and returns (frame(camera) -> None that draws and
    waits for the GPU, release() -> None)."""

    path: str
    accum_dtype: str | None
    make: Callable[[], tuple[Callable, Callable]]
    transfer: str | None = None

    @property
    def label(self) -> str:
        return _label(self.path, self.accum_dtype, self.transfer)


def unavailable(path: str, ctx) -> str | None:
    """Why ``path`` cannot run on this machine and context, or None."""
    if path not in PATHS:
        raise ValueError(f"unknown display path {path!r}; expected one of {', '.join(PATHS)}")
    if path == "gl-gpu-sort":
        from renderer_gl.context import is_software_gl

        if ctx.version_code < 430:
            return f"needs OpenGL 4.3 compute shaders (context is {ctx.version_code})"
        if is_software_gl(ctx):
            return "software GL: its compute-shader sort is slower than numpy's"
    if path == "cuda":
        import torch

        from training.raster.rasterize import have_gsplat

        if not torch.cuda.is_available():
            return "torch sees no CUDA device"
        if not have_gsplat():
            return "gsplat does not import"
    return None


def interop_unavailable() -> str | None:
    """Why the cuda path cannot try CUDA-GL interop here (cuda-python missing), or None: whether the GL context
    can be registered is found out by trying, when the candidate is timed."""
    from app.viewer.display.interop import InteropError, load_runtime

    try:
        load_runtime()
    except InteropError as exc:
        return str(exc)
    return None


def _offscreen(ctx, draw: Callable, release_drawer: Callable) -> tuple[Callable, Callable]:
    """A candidate's (frame, release): ``draw(camera, fbo)`` into a framebuffer of the camera's size, waiting for
    the GPU, as the viewer's view does."""
    target = {}

    def release_target():
        if "fbo" in target:
            target.pop("fbo").release()
            target.pop("tex").release()

    def frame(camera):
        size = (int(camera.width), int(camera.height))
        if target.get("size") != size:
            release_target()
            target["tex"] = ctx.texture(size, 4)
            target["fbo"] = ctx.framebuffer(color_attachments=[target["tex"]])
            target["size"] = size
        draw(camera, target["fbo"])
        ctx.finish()

    def release():
        release_drawer()
        release_target()

    return frame, release


def gl_candidate(ctx, snap, path: str, accum_dtype: str) -> Candidate:
    def make():
        from renderer_gl import SplatRenderer

        r = SplatRenderer(ctx, accum_dtype=accum_dtype, sort_on={"gl-cpu-sort": "cpu", "gl-gpu-sort": "gpu"}[path],
                          sort_tolerance_deg=0.0)
        r.set_splats(snap.means, snap.scales, snap.quats, snap.opacities, snap.sh, snap.sh_degree)
        return _offscreen(ctx, r.render, r.release)

    return Candidate(path, accum_dtype, make)


def cuda_candidate(ctx, snap, backend: str = "cuda", transfer: str = "pinned", runtime=None) -> Candidate:
    """The CUDA display path with one ``transfer`` (``backend`` "torch" or "cpu" runs the same code on CPU tensors:
    tests; ``runtime``: cuda-python's runtime bindings, None to import them). It does not fall back: an interop
    failure is this candidate's failure, so that its time is never the pinned copy's under another name."""
    def make():
        from app.viewer.display.cuda import CudaDisplay

        d = CudaDisplay(ctx, backend=backend, transfer=transfer, fallback=False, runtime=runtime)
        try:
            d.set_model(snap)
        except BaseException:
            d.release()
            raise
        return _offscreen(ctx, d.draw, d.release)

    return Candidate("cuda", None, make, transfer)


def default_candidates(ctx, snap) -> tuple[list[Candidate], dict[str, str]]:
    """The candidates this machine can run, and path -> reason for those it cannot."""
    candidates, skipped = [], {}
    for path in PATHS:
        why = unavailable(path, ctx)
        if why is not None:
            skipped[path] = why
        elif path == "cuda":
            candidates.append(cuda_candidate(ctx, snap, transfer="pinned"))
            why_not = interop_unavailable()
            if why_not is None:
                candidates.append(cuda_candidate(ctx, snap, transfer="interop"))
            else:
                skipped["cuda/interop"] = why_not
        else:
            candidates += [gl_candidate(ctx, snap, path, fmt) for fmt in gl_formats(ctx)]
    return candidates, skipped


def gl_formats(ctx) -> tuple[str, ...]:
    """The accumulation formats worth timing: f4 alone on software GL, where f2 measured 4-10% slower (llvmpipe
    converts half floats in its blend code; docs/gpu.md), so that its only candidate needs no timing at all."""
    from renderer_gl.context import is_software_gl

    return ("f4",) if is_software_gl(ctx) else GL_FORMATS


def turning_cameras(camera, frames: int, size: tuple[int, int], degrees: float = 1.0) -> list:
    """``frames`` + 1 training Cameras of ``camera`` (a ViewerCamera) orbiting by ``degrees`` each, at ``size``:
    every frame turns the view past any sort tolerance, so each one sorts."""
    cam = camera.copy()
    out = []
    for _ in range(frames + 1):
        out.append(cam.camera(*size))
        cam.orbit(np.radians(degrees) / 0.005, 0.0)  # orbit's speed is 0.005 radians per pixel
    return out


def time_candidates(candidates: list[Candidate], cameras: list, skipped: dict[str, str]) -> dict[str, float]:
    """Median milliseconds of a frame of each candidate over ``cameras[1:]`` after a warm-up frame on
    ``cameras[0]``, the candidates drawing in turn (a change in a shared machine's load then falls on all of them
    alike). A candidate that raises is dropped, its reason in ``skipped``."""
    live: dict[str, tuple[Callable, Callable]] = {}
    times: dict[str, list[float]] = {}

    def fail(label: str, exc: Exception) -> None:
        skipped[label] = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
        frame_release = live.pop(label, None)
        if frame_release is not None:
            try:
                frame_release[1]()
            except Exception:  # already failing; its reason is recorded
                pass

    try:
        for cand in candidates:
            try:
                live[cand.label] = cand.make()
                live[cand.label][0](cameras[0])  # shader compiles, first upload, allocations
                times[cand.label] = []
            except Exception as exc:  # a path that fails on this machine (driver, CUDA, gsplat build)
                fail(cand.label, exc)
        for cam in cameras[1:]:
            for label in list(live):
                try:
                    t0 = time.perf_counter()
                    live[label][0](cam)
                    times[label].append(time.perf_counter() - t0)
                except Exception as exc:
                    fail(label, exc)
                    times.pop(label, None)
    finally:
        for _, release in live.values():
            release()
    return {k: 1000.0 * statistics.median(v) for k, v in times.items() if v}


def pick(candidates: list[Candidate], times: dict[str, float]) -> Candidate:
    """The first candidate (in PATHS order, f4 before f2) within MARGIN of the fastest: a later one must be clearly
    faster to displace it, so that timing noise on a busy machine does not trade exact f4 for f2, or the GL
    renderer's every mode for the CUDA path's few."""
    fastest = min(times.values())
    return next(c for c in candidates if c.label in times and times[c.label] <= fastest * (1.0 + MARGIN))


def choose_display_path(ctx, snap, camera, size: tuple[int, int], *, override: str | None = None,
                        frames: int = 3, candidates: list[Candidate] | None = None,
                        skipped: dict[str, str] | None = None, always_time: bool = False) -> DisplayChoice:
    """Time each candidate drawing ``snap`` (a ModelSnapshot) for ``frames`` frames of ``camera`` (a ViewerCamera)
    turning at ``size``, and return the fastest. ``override`` ("auto" or None: measure; a name from PATHS, or
    "PATH/FORMAT" for a GL path, "cuda/pinned" or "cuda/interop": use that, unless this machine cannot run it:
    then measure, and say so in ``reason``; "cuda" alone: interop, falling back to pinned) defaults to the
    environment variable SPLATSTYLER_DISPLAY_PATH.
    ``candidates``/``skipped`` replace ``default_candidates`` (tests, benchmarks). A single candidate is returned
    untimed unless ``always_time`` (benchmarks)."""
    if override is None:
        override = os.environ.get(ENV, "auto").strip().lower() or "auto"
    if candidates is None:
        candidates, found_skipped = default_candidates(ctx, snap)
        skipped = {**found_skipped, **(skipped or {})}
    skipped = dict(skipped or {})
    if override != "auto":
        path, _, fmt = override.partition("/")
        allowed = CUDA_TRANSFERS if path == "cuda" else ("f4", "f2", "f1")
        if path not in PATHS or (fmt and fmt not in allowed):
            raise ValueError(f"unknown display path {override!r}; expected auto, "
                             f"{', '.join(PATHS)} (or gl-...-sort/f4|f2|f1, cuda/pinned|interop)")
        if path not in skipped:
            if path == "cuda":
                return DisplayChoice(path, None, skipped=skipped, reason=f"set by the setting ({override})",
                                     transfer=fmt or "interop")
            return DisplayChoice(path, fmt or "f4", skipped=skipped, reason=f"set by the setting ({override})")
        # asked for a path this machine cannot run: say so, and choose as if nothing were asked
        note = f"{override} was asked for but cannot run here ({skipped[path]}); "
    else:
        note = ""
    if len(candidates) == 1 and not always_time:  # nothing to choose between: no frames spent timing
        c = candidates[0]
        return DisplayChoice(c.path, c.accum_dtype, skipped=skipped,
                             reason=note + "the only candidate on this machine (others: see skipped)",
                             transfer=c.transfer)
    cameras = turning_cameras(camera, frames, size)
    times = time_candidates(candidates, cameras, skipped)
    if not times:
        return DisplayChoice("gl-cpu-sort", "f4", skipped=skipped,
                             reason=note + "no candidate could be timed; the GL renderer with the CPU sort")
    c = pick(candidates, times)
    return DisplayChoice(c.path, c.accum_dtype, times, skipped,
                         reason=note + f"fastest of {len(times)} timed at {size[0]}x{size[1]} (within "
                                       f"{MARGIN:.0%}): {times[c.label]:.1f} ms a frame", transfer=c.transfer)
