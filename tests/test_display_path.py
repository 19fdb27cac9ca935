"""The CUDA display path (app/viewer/display/cuda.py) through the same code on the torch backend on CPU, against
the GL renderer's picture for the same viewer camera; and the display-path chooser's decisions."""

from __future__ import annotations

import ctypes
import enum
import sys
from dataclasses import replace

import numpy as np
import pytest

from app.viewer.camera import ViewerCamera
from app.viewer.display.choice import (Candidate, DisplayChoice, choose_display_path, cuda_candidate,
                                     default_candidates, gl_candidate, pick)
from app.viewer.display.cuda import CudaDisplay, unsupported
from app.viewer.display.interop import InteropError
from renderer_gl import Offscreen, SplatRenderer, create_context
from tests.gl_scenes import psnr
from training.core.messages import ModelSnapshot

BG = (0.2, 0.3, 0.4)


@pytest.fixture(scope="module")
def ctx():
    context = create_context("egl")
    yield context
    context.release()


def snapshot(seed=3, n=400, version=1, geometry_version=1, sh_degree=2) -> ModelSnapshot:
    """Overlapping random Gaussians around the origin, as a trainer's snapshot holds them."""
    rng = np.random.default_rng(seed)
    means = (rng.uniform(-1, 1, (n, 3)) * [1.3, 1.0, 0.8]).astype(np.float32)
    scales = np.exp(rng.normal(-2.8, 0.5, (n, 3))).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    opac = rng.uniform(0.05, 0.95, n).astype(np.float32)
    sh = (rng.normal(size=(n, (sh_degree + 1) ** 2, 3)) * 0.3).astype(np.float32)
    return ModelSnapshot(version, geometry_version, 0, means, scales, quats, opac, sh, sh_degree)


def viewer_camera() -> ViewerCamera:
    return ViewerCamera.looking_at((0.4, -0.3, -4.0), (0.0, 0.0, 0.0), up=(0.0, -1.0, 0.0), fov_y_degrees=40.0)


def gl_picture(ctx, snap, cam, size, **render_kw) -> np.ndarray:
    r = SplatRenderer(ctx)
    r.set_splats(snap.means, snap.scales, snap.quats, snap.opacities, snap.sh, snap.sh_degree)
    off = Offscreen(ctx, *size)
    r.render(cam.camera(*size), off.fbo, background=BG, **render_kw)
    img = off.read()
    off.release()
    r.release()
    return img


def _has_cuda() -> bool:
    import importlib.util

    import torch

    return torch.cuda.is_available() and importlib.util.find_spec("gsplat") is not None


@pytest.mark.parametrize("backend", ["torch", "cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not _has_cuda(), reason="needs a CUDA GPU and gsplat"))])
def test_cuda_path_draws_what_the_gl_renderer_draws(ctx, backend):
    """The CUDA display path's code (camera, upload, texture, quad); on a machine without CUDA the same code runs on
    CPU tensors, where "cuda" differs only in the rasterizer and in the copy through pinned memory."""
    snap = snapshot()
    cam = viewer_camera()
    size = (128, 96)
    d = CudaDisplay(ctx, backend=backend)
    assert d.set_model(snap)
    off = Offscreen(ctx, *size)
    d.draw(cam, off.fbo, background=BG)
    mine = off.read()
    ref = gl_picture(ctx, snap, cam, size)
    assert ref.std() > 10  # the camera sees the model
    assert psnr(mine / 255.0, ref / 255.0) >= 50.0  # 60 dB measured: both round to 8 bits once
    # the texture's rows are the image's, bottom first, and the quad puts them back: the top-left object is there
    np.testing.assert_array_equal(mine, d.render_image(cam.camera(*size), BG))
    # alpha mode: grey levels of accumulated opacity, as the GL renderer's alpha mode
    d.draw(cam, off.fbo, background=BG, mode="alpha")
    assert psnr(off.read() / 255.0, gl_picture(ctx, snap, cam, size, mode="alpha") / 255.0) >= 40.0
    off.release()
    d.release()


def test_cuda_path_draws_a_lower_scale_upsampled_into_the_viewport(ctx):
    snap = snapshot(seed=8)
    cam = viewer_camera()
    d = CudaDisplay(ctx, backend="torch")
    d.set_model(snap)
    off = Offscreen(ctx, 128, 96)
    d.draw(cam, off.fbo, background=BG)
    full = off.read() / 255.0
    off.fbo.clear(1.0, 0.0, 1.0, 1.0)
    d.draw(cam, off.fbo, background=BG, scale=0.5)
    half = off.read() / 255.0
    assert d._texture.size == (64, 48)
    assert 20.0 < psnr(full, half) < 60.0  # the same picture, softer; every pixel drawn (no magenta left)
    assert not ((half[..., 0] == 1.0) & (half[..., 1] == 0.0) & (half[..., 2] == 1.0)).any()
    off.release()
    d.release()


def test_model_stays_on_the_device_until_a_new_version(ctx):
    d = CudaDisplay(ctx, backend="torch")
    snap = snapshot(version=1, geometry_version=1)
    assert d.set_model(snap)
    means = d._tensors[0]
    assert not d.set_model(snap)  # same version: nothing uploaded
    recoloured = replace(snap, version=2, sh=snap.sh[:, :, ::-1].copy())
    assert d.set_model(recoloured)
    assert d._tensors[0] is means  # colours alone
    np.testing.assert_array_equal(d._tensors[4].numpy(), recoloured.sh)
    moved = replace(snap, version=3, geometry_version=2, means=snap.means + 1.0)
    assert d.set_model(moved)
    assert d._tensors[0] is not means and d.uploads == 3
    d.release()


def test_empty_display_draws_the_background(ctx):
    d = CudaDisplay(ctx, backend="torch")
    off = Offscreen(ctx, 32, 24)
    d.draw(viewer_camera(), off.fbo, background=(0.5, 0.5, 0.5))
    assert (off.read() == 128).all()
    off.release()
    d.release()


def test_modes_it_cannot_draw_are_reported(ctx):
    assert unsupported("color") is None and unsupported("alpha", photo="off") is None
    for mode in ("points", "ellipsoids", "depth"):
        assert mode in unsupported(mode)
    assert "split" in unsupported("color", split=True)
    assert "photo" in unsupported("color", photo="blend")
    assert "selected" in unsupported("color", flags=True)
    d = CudaDisplay(ctx, backend="torch")
    d.set_model(snapshot())
    with pytest.raises(ValueError, match="points"):
        d.render_image(viewer_camera().camera(8, 6), BG, mode="points")
    d.release()


def test_cuda_backend_without_cuda_says_why(ctx):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(RuntimeError, match="CUDA device"):
        CudaDisplay(ctx, backend="cuda")


def test_chooser_picks_gl_on_a_machine_without_cuda(ctx):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    snap = snapshot()
    choice = choose_display_path(ctx, snap, viewer_camera(), (64, 48), frames=2)
    assert choice.path.startswith("gl-")
    assert "cuda" in choice.skipped and "CUDA" in choice.skipped["cuda"]
    if "llvmpipe" in ctx.info["GL_RENDERER"]:
        # software GL: one candidate (numpy sort, f4), returned without spending frames on timing it
        assert choice.label() == "gl-cpu-sort/f4" and choice.frame_ms == {}
        assert "software GL" in choice.skipped["gl-gpu-sort"]
        timed = choose_display_path(ctx, snap, viewer_camera(), (64, 48), frames=2, always_time=True)
        assert timed.label() == "gl-cpu-sort/f4" and set(timed.frame_ms) == {"gl-cpu-sort/f4"}
    else:
        assert choice.frame_ms[choice.label()] <= 1.05 * min(choice.frame_ms.values())
    assert choice.renderer_options()["accum_dtype"] in ("f4", "f2")


def test_chooser_times_every_candidate_and_skips_one_that_raises(ctx):
    snap = snapshot()

    def broken():
        raise RuntimeError("driver said no\nsecond line")

    released = []

    def fails_later():
        calls = []

        def frame(camera):
            calls.append(camera)
            if len(calls) == 2:
                raise MemoryError("out of device memory")

        return frame, lambda: released.append(True)

    candidates = [gl_candidate(ctx, snap, "gl-cpu-sort", "f4"), cuda_candidate(ctx, snap, backend="torch"),
                  Candidate("gl-gpu-sort", "f2", broken), Candidate("gl-gpu-sort", "f4", fails_later)]
    choice = choose_display_path(ctx, snap, viewer_camera(), (64, 48), frames=2, candidates=candidates)
    assert set(choice.frame_ms) == {"gl-cpu-sort/f4", "cuda/pinned"}
    assert choice.skipped["gl-gpu-sort/f2"] == "RuntimeError: driver said no"
    assert choice.skipped["gl-gpu-sort/f4"] == "MemoryError: out of device memory" and released == [True]
    fastest = min(choice.frame_ms, key=choice.frame_ms.get)
    first_close = next(c.label for c in candidates if c.label in choice.frame_ms
                       and choice.frame_ms[c.label] <= 1.05 * choice.frame_ms[fastest])
    assert choice.label() == first_close
    assert all(t > 0 for t in choice.frame_ms.values())


def test_an_override_wins_and_one_that_cannot_run_is_measured_instead(ctx, monkeypatch):
    snap = snapshot()
    calls = []

    def counting():
        calls.append(1)
        raise AssertionError("an override must not time anything")

    cands = [Candidate("gl-cpu-sort", "f4", counting), Candidate("cuda", None, counting)]
    choice = choose_display_path(ctx, snap, viewer_camera(), (64, 48), override="cuda", candidates=cands)
    assert (choice.path, choice.accum_dtype, calls) == ("cuda", None, [])
    monkeypatch.setenv("SPLATSTYLER_DISPLAY_PATH", "gl-gpu-sort/f2")
    choice = choose_display_path(ctx, snap, viewer_camera(), (64, 48), candidates=cands)
    assert choice.renderer_options() == {"sort_on": "gpu", "accum_dtype": "f2"} and "setting" in choice.reason
    with pytest.raises(ValueError, match="display path"):
        choose_display_path(ctx, snap, viewer_camera(), (64, 48), override="vulkan", candidates=cands)
    # the real candidates on this machine: a path it cannot run is not forced on it
    real, skipped = default_candidates(ctx, snap)
    if "cuda" in skipped:
        choice = choose_display_path(ctx, snap, viewer_camera(), (64, 48), override="cuda", frames=1,
                                     candidates=real, skipped=skipped)
        assert choice.path.startswith("gl-") and "cannot run here" in choice.reason


def test_a_later_candidate_must_be_clearly_faster_to_be_chosen():
    cands = [Candidate("gl-cpu-sort", "f4", None), Candidate("gl-cpu-sort", "f2", None), Candidate("cuda", None, None)]
    assert pick(cands, {"gl-cpu-sort/f4": 10.4, "gl-cpu-sort/f2": 10.0, "cuda": 10.2}).label == "gl-cpu-sort/f4"
    assert pick(cands, {"gl-cpu-sort/f4": 11.0, "gl-cpu-sort/f2": 10.0, "cuda": 10.4}).label == "gl-cpu-sort/f2"
    assert pick(cands, {"gl-cpu-sort/f4": 48.0, "gl-cpu-sort/f2": 12.0, "cuda": 3.0}).label == "cuda"
    assert pick(cands, {"gl-cpu-sort/f2": 12.0, "cuda": 3.0}).label == "cuda"  # f4 failed: not timed


# ---------------------------------------------------------------------------------------------- CUDA-GL interop
def _registration_refused(ctx) -> str | None:
    """Why CUDA cannot register this GL context's textures here, or None where it can."""
    import torch

    from app.viewer.display.choice import interop_unavailable

    if not torch.cuda.is_available():
        return "torch sees no CUDA device"
    why = interop_unavailable()
    if why:
        return why
    vendor = str(ctx.info.get("GL_VENDOR", ""))
    if "NVIDIA" not in vendor.upper():
        return f"the GL context is {vendor}'s, not NVIDIA's: CUDA cannot register its textures"
    return None


def _interop_skip_reason(ctx) -> str | None:
    return "needs a CUDA GPU and gsplat" if not _has_cuda() else _registration_refused(ctx)


def test_cuda_interop_draws_what_the_pinned_copy_draws(ctx):
    """On an NVIDIA GPU with NVIDIA's GL and cuda-python: the picture written into the texture on the device is the
    pinned copy's, byte for byte, at two sizes (the view's moving and still sizes), and nothing goes through host
    memory."""
    why = _interop_skip_reason(ctx)
    if why:
        pytest.skip(why)
    snap = snapshot(n=2000)
    cam = viewer_camera()
    pinned = CudaDisplay(ctx, backend="cuda", transfer="pinned")
    interop = CudaDisplay(ctx, backend="cuda", transfer="interop", fallback=False)
    off = Offscreen(ctx, 320, 240)
    pictures = {}
    for d in (pinned, interop):
        d.set_model(snap)
        for scale in (1.0, 0.5, 1.0):
            d.draw(cam, off.fbo, background=BG, scale=scale)
            pictures.setdefault(d.transfer, []).append(off.read())
    assert interop.transfer == "interop" and interop.fallback_reason is None
    assert interop._pinned is None  # no page-locked host buffer was ever needed
    assert pictures["pinned"][0].std() > 10
    for a, b in zip(pictures["pinned"], pictures["interop"]):
        np.testing.assert_array_equal(a, b)
    interop.profile = True
    interop.draw(cam, off.fbo, background=BG)
    assert set(interop.last_stages) == {"raster", "convert", "transfer", "draw"}
    off.release()
    pinned.release()
    interop.release()


class HostInteropRuntime:
    """A stand-in for cuda-python's runtime on a machine without CUDA: the six graphics-interop calls with CUDA's
    documented semantics, done on the host (a mapped texture's array takes rows from ``src`` at ``spitch`` bytes
    apart, and GL sees them after the unmap), so that the display's calls and their arguments (pitch, sizes, order,
    unmapping) draw a picture. ``fail_map_at``: the map call (1-based) that returns cudaErrorUnknown, as a driver
    does mid-session."""

    class cudaError_t(enum.IntEnum):
        cudaSuccess = 0
        cudaErrorUnknown = 999

    class cudaGraphicsRegisterFlags(enum.IntEnum):
        cudaGraphicsRegisterFlagsWriteDiscard = 2

    class cudaMemcpyKind(enum.IntEnum):
        cudaMemcpyDefault = 4

    def __init__(self, ctx, fail_map_at: int | None = None):
        self.ctx = ctx
        self.fail_map_at = fail_map_at
        self.registered: dict[int, int] = {}  # resource -> GL texture name
        self.unregistered: list[int] = []
        self.maps = 0
        self.mapped: set[int] = set()
        self.pending: dict[int, tuple] = {}

    def cudaGetErrorName(self, err):
        return self.cudaError_t.cudaSuccess, self.cudaError_t(err).name.encode()

    def cudaGetErrorString(self, err):
        return self.cudaError_t.cudaSuccess, b"unknown error"

    def cudaSetDevice(self, device):
        return (self.cudaError_t.cudaSuccess,)

    def cudaGraphicsGLRegisterImage(self, glo, target, flags):
        assert target == 0x0DE1 and flags == self.cudaGraphicsRegisterFlags.cudaGraphicsRegisterFlagsWriteDiscard
        resource = 100 + len(self.registered) + len(self.unregistered)
        self.registered[resource] = glo
        return self.cudaError_t.cudaSuccess, resource

    def cudaGraphicsMapResources(self, count, resource, stream):
        self.maps += 1
        if self.maps == self.fail_map_at:
            return (self.cudaError_t.cudaErrorUnknown,)
        assert count == 1 and resource in self.registered and resource not in self.mapped
        self.mapped.add(resource)
        return (self.cudaError_t.cudaSuccess,)

    def cudaGraphicsSubResourceGetMappedArray(self, resource, index, level):
        assert resource in self.mapped and (index, level) == (0, 0)
        return self.cudaError_t.cudaSuccess, resource

    def cudaMemcpy2DToArrayAsync(self, array, w_offset, h_offset, src, spitch, width, height, kind, stream):
        assert array in self.mapped and (w_offset, h_offset) == (0, 0)
        assert kind == self.cudaMemcpyKind.cudaMemcpyDefault
        rows = b"".join(ctypes.string_at(src + r * spitch, width) for r in range(height))
        self.pending[array] = (width // 4, height, rows)
        return (self.cudaError_t.cudaSuccess,)

    def cudaGraphicsUnmapResources(self, count, resource, stream):
        self.mapped.discard(resource)
        if resource in self.pending:
            w, h, rows = self.pending.pop(resource)
            self.ctx.external_texture(self.registered[resource], (w, h), 4, 0, "f1").write(rows)
        return (self.cudaError_t.cudaSuccess,)

    def cudaGraphicsUnregisterResource(self, resource):
        self.unregistered.append(resource)
        self.registered.pop(resource)
        return (self.cudaError_t.cudaSuccess,)


def test_interop_calls_draw_the_pinned_picture_and_a_mapping_error_mid_session_falls_back(ctx):
    """The display's interop calls, run against CUDA's semantics on the host (HostInteropRuntime), put the pinned
    copy's picture on screen; when the driver refuses a map on the third frame, that frame and the next ones are
    drawn through the pinned copy, the registrations are dropped, and the display says why."""
    snap = snapshot(seed=5)
    cam = viewer_camera()
    off = Offscreen(ctx, 96, 72)
    pinned = CudaDisplay(ctx, backend="torch", transfer="pinned")
    pinned.set_model(snap)
    pinned.draw(cam, off.fbo, background=BG)
    expected = off.read()
    pinned.draw(cam, off.fbo, background=BG, scale=0.5)
    expected_half = off.read()
    pinned.release()

    rt = HostInteropRuntime(ctx, fail_map_at=3)
    d = CudaDisplay(ctx, backend="torch", transfer="interop", runtime=rt)
    d.set_model(snap)
    for scale, want in ((1.0, expected), (0.5, expected_half)):
        off.fbo.clear(1.0, 0.0, 1.0, 1.0)
        d.draw(cam, off.fbo, background=BG, scale=scale)
        np.testing.assert_array_equal(off.read(), want)
    assert d.transfer == "interop" and len(rt.registered) == 2 and rt.maps == 2
    off.fbo.clear(1.0, 0.0, 1.0, 1.0)
    d.draw(cam, off.fbo, background=BG)  # the map fails: this frame goes through the pinned copy
    np.testing.assert_array_equal(off.read(), expected)
    assert d.transfer == "pinned" and rt.registered == {} and sorted(rt.unregistered) == [100, 101]
    assert d.fallback_reason == "cudaGraphicsMapResources: cudaErrorUnknown (unknown error)"
    d.draw(cam, off.fbo, background=BG, scale=0.5)
    np.testing.assert_array_equal(off.read(), expected_half)
    assert rt.maps == 3  # interop is not tried again
    choice = DisplayChoice("cuda", None, transfer="interop")
    assert choice.interop_note(d) == "CUDA-GL interop off: " + d.fallback_reason
    d.release()

    # without fallback (the chooser's candidates) the same error is the candidate's failure, not a pinned frame
    strict = CudaDisplay(ctx, backend="torch", transfer="interop", fallback=False,
                         runtime=HostInteropRuntime(ctx, fail_map_at=1))
    with pytest.raises(InteropError, match="cudaGraphicsMapResources"):
        strict.draw(cam, off.fbo, background=BG)
    strict.release()
    off.release()


def test_without_cuda_python_the_display_copies_through_the_host_and_says_why(ctx, monkeypatch):
    """cuda-python absent (as the test's interpreter sees it): the interop transfer falls back at once, the
    chooser skips the interop candidate with the reason, and the Scene panel's note says it."""
    for name in ("cuda", "cuda.bindings", "cuda.bindings.runtime"):
        monkeypatch.setitem(sys.modules, name, None)  # import fails, as where the package is not installed
    from app.viewer.display.choice import interop_unavailable

    why = interop_unavailable()
    assert why.startswith("cuda-python is not installed")
    snap = snapshot()
    d = CudaDisplay(ctx, backend="torch", transfer="interop")
    assert d.transfer == "pinned" and d.fallback_reason == why
    d.set_model(snap)
    off = Offscreen(ctx, 64, 48)
    d.draw(viewer_camera(), off.fbo, background=BG)
    assert off.read().std() > 10
    d.release()
    with pytest.raises(InteropError, match="cuda-python"):
        CudaDisplay(ctx, backend="torch", transfer="interop", fallback=False)
    cands = [cuda_candidate(ctx, snap, backend="torch", transfer="pinned"),
             cuda_candidate(ctx, snap, backend="torch", transfer="interop")]
    choice = choose_display_path(ctx, snap, viewer_camera(), (64, 48), frames=1, candidates=cands)
    assert choice.label() == "cuda/pinned" and choice.cuda_options() == {"transfer": "pinned"}
    assert choice.skipped["cuda/interop"].startswith("InteropError: cuda-python is not installed")
    assert choice.interop_note() == "CUDA-GL interop not used: " + choice.skipped["cuda/interop"]
    off.release()


def test_a_gl_context_cuda_cannot_register_falls_back_to_the_pinned_copy(ctx):
    """cuda-python present and the registration refused by the driver: here, a machine without an NVIDIA driver
    (CUDA's answer is cudaErrorInsufficientDriver or cudaErrorNoDevice); on a GPU with Mesa's GL beside it, the same
    call refuses the Mesa texture."""
    from app.viewer.display.choice import interop_unavailable

    why = interop_unavailable()
    if why:
        pytest.skip(why)
    if _registration_refused(ctx) is None:
        pytest.skip("CUDA registers this GL context's textures here (the interop case above runs instead)")
    snap = snapshot()
    off = Offscreen(ctx, 64, 48)
    d = CudaDisplay(ctx, backend="torch", transfer="interop")
    d.set_model(snap)
    d.draw(viewer_camera(), off.fbo, background=BG)
    assert d.transfer == "pinned" and d.fallback_reason.startswith("cudaGraphicsGLRegisterImage: cudaError"), \
        d.fallback_reason
    assert off.read().std() > 10
    d.release()
    cands = [cuda_candidate(ctx, snap, backend="torch", transfer="pinned"),
             cuda_candidate(ctx, snap, backend="torch", transfer="interop")]
    choice = choose_display_path(ctx, snap, viewer_camera(), (64, 48), frames=1, candidates=cands)
    assert choice.label() == "cuda/pinned"
    assert choice.skipped["cuda/interop"].startswith("InteropError: cudaGraphicsGLRegisterImage: cudaError")
    off.release()


def test_profiled_frames_time_each_stage(ctx):
    d = CudaDisplay(ctx, backend="torch")
    d.set_model(snapshot())
    off = Offscreen(ctx, 64, 48)
    d.draw(viewer_camera(), off.fbo, background=BG)
    assert d.last_stages == {}  # not profiled: no waits added to the frame
    d.profile = True
    d.draw(viewer_camera(), off.fbo, background=BG)
    assert set(d.last_stages) == {"raster", "convert", "transfer", "draw"}
    assert all(s > 0 for s in d.last_stages.values()) and sum(d.last_stages.values()) <= d.last_frame_s
    off.release()
    d.release()


def test_overrides_name_the_cuda_transfer(ctx):
    snap = snapshot()
    cands = [Candidate("gl-cpu-sort", "f4", None), Candidate("cuda", None, None, "pinned")]
    for override, transfer in (("cuda", "interop"), ("cuda/pinned", "pinned"), ("cuda/interop", "interop")):
        choice = choose_display_path(ctx, snap, viewer_camera(), (64, 48), override=override, candidates=cands)
        assert (choice.path, choice.transfer, choice.cuda_options()) == ("cuda", transfer, {"transfer": transfer})
    with pytest.raises(ValueError, match="display path"):
        choose_display_path(ctx, snap, viewer_camera(), (64, 48), override="cuda/f2", candidates=cands)
    assert DisplayChoice("gl-cpu-sort", "f4").interop_note() is None
