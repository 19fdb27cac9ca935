"""renderer_gl's accumulation formats (f4, f2, f1 with and without dithering) and its GPU sort, against f4 and the
training rasterizer. Display-free: EGL (llvmpipe on CI)."""

from __future__ import annotations

import numpy as np
import pytest

from renderer_gl import SplatRenderer, create_context, look_at, view
from tests.gl_scenes import BG, camera, psnr, reference_render


@pytest.fixture(scope="module")
def ctx():
    context = create_context("egl", require=430)
    yield context
    context.release()


def overlapping(seed=3, n=400):
    rng = np.random.default_rng(seed)
    means = (rng.uniform(-1, 1, (n, 3)) * [1.3, 1.0, 0.8]).astype(np.float32)
    scales = np.exp(rng.normal(-2.8, 0.5, (n, 3))).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    opac = rng.uniform(0.05, 0.95, n).astype(np.float32)
    sh = (rng.normal(size=(n, 9, 3)) * 0.3).astype(np.float32)
    return means, scales, quats, opac, sh


def fog(n=400, seed=0):
    """Large faint Gaussians, each adding less than half an 8-bit step of colour: a haze, a sky's soft edge."""
    rng = np.random.default_rng(seed)
    means = np.stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1, 1, n), rng.uniform(0, 3, n)], 1).astype(np.float32)
    scales = np.full((n, 3), 0.6, np.float32)
    quats = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
    return means, scales, quats, np.full(n, 0.015, np.float32), np.tile(np.float32([0.08, 0.1, 0.12]), (n, 1))


def render(ctx, arrays, sh_degree, cam, **kw):
    r = SplatRenderer(ctx, sort_tolerance_deg=0.0, **kw)
    r.set_splats(*arrays, sh_degree)
    out = r.render_arrays(cam, ("rgb", "alpha"), background=BG)
    r.release()
    return out


def test_half_float_accumulation_matches_float_within_a_small_error(ctx):
    cam, w2c, K = camera()
    arrays = overlapping()
    ref, _ = reference_render(*arrays, 2, w2c, K, cam.width, cam.height)
    f4 = render(ctx, arrays, 2, cam)
    f2 = render(ctx, arrays, 2, cam, accum_dtype="f2")
    assert psnr(f4["rgb"], ref) >= 45.0
    assert psnr(f2["rgb"], ref) >= 42.0 and psnr(f2["rgb"], f4["rgb"]) >= 42.0
    assert np.abs(f2["alpha"] - f4["alpha"]).max() < 4e-3


def test_dithering_keeps_the_light_of_faint_splats_in_an_8_bit_target(ctx):
    """Rounding to nearest drops every contribution under half a step: the haze vanishes. Stochastic rounding
    keeps its brightness on average, at the price of noise (and the 8-bit target still cannot darken small values
    by a factor near 1, so it errs bright)."""
    cam = view(world_to_camera=look_at((0, 0, -4), (0, 0, 0)), K=[[150, 0, 64], [0, 150, 48], [0, 0, 1]],
               width=128, height=96)
    arrays = fog()
    f4 = render(ctx, arrays, None, cam)
    haze = f4["rgb"] - (1.0 - f4["alpha"][..., None]) * np.asarray(BG, np.float32)
    plain = render(ctx, arrays, None, cam, accum_dtype="f1", dither=False)
    dithered = render(ctx, arrays, None, cam, accum_dtype="f1")  # dither is on by default for f1
    plain_haze = plain["rgb"] - (1.0 - plain["alpha"][..., None]) * np.asarray(BG, np.float32)
    dithered_haze = dithered["rgb"] - (1.0 - dithered["alpha"][..., None]) * np.asarray(BG, np.float32)
    assert haze.mean() > 0.03
    assert plain_haze.mean() < 0.1 * haze.mean()
    assert 0.7 * haze.mean() < dithered_haze.mean() < 1.7 * haze.mean()
    assert psnr(dithered["rgb"], f4["rgb"]) > psnr(plain["rgb"], f4["rgb"])


def test_gpu_sort_draws_what_the_cpu_sort_draws(ctx):
    cam, w2c, K = camera()
    arrays = overlapping(seed=5)
    cpu = render(ctx, arrays, 2, cam)
    r = SplatRenderer(ctx, sort_on="gpu", sort_tolerance_deg=0.0)
    r.set_splats(*arrays, 2)
    info = r.splat_pass(cam)
    assert info.sorted and r._slots[0].order is None  # sorted on the GPU; nothing read back
    gpu = r.render_arrays(cam, ("rgb", "alpha"), background=BG)
    np.testing.assert_allclose(gpu["rgb"], cpu["rgb"], atol=1e-5)
    # the moving preview reads the GPU's order back once and draws the same subset as the CPU path
    r_cpu = SplatRenderer(ctx, sort_tolerance_deg=0.0)
    r_cpu.set_splats(*arrays, 2)
    for renderer in (r, r_cpu):
        renderer.splat_pass(cam, lod=0.3)
    np.testing.assert_allclose(r._read_accum(), r_cpu._read_accum(), atol=1e-5)
    r.set_splats(*overlapping(seed=6), 2)  # new geometry: a new sort buffer
    ref, _ = reference_render(*overlapping(seed=6), 2, w2c, K, cam.width, cam.height)
    assert psnr(r.render_arrays(cam, ("rgb",), background=BG)["rgb"], ref) >= 40.0
    r.release()
    r_cpu.release()


def test_bad_settings_are_refused(ctx):
    with pytest.raises(ValueError, match="accum_dtype"):
        SplatRenderer(ctx, accum_dtype="f8")
    with pytest.raises(ValueError, match="sort_on"):
        SplatRenderer(ctx, sort_on="tpu")


def test_the_moving_and_still_sizes_keep_their_accumulation_targets(ctx):
    """The viewer alternates between half size (moving) and full size (still): neither target is re-created."""
    cam, _, _ = camera()
    r = SplatRenderer(ctx)
    r.set_splats(*overlapping(), 2)
    r.splat_pass(cam)
    full = r._accum
    r.splat_pass(cam, scale=0.5)
    half = r._accum
    r.splat_pass(cam)
    assert r._accum is full and half is not full and half.size == (64, 48)
    r.splat_pass(cam, scale=0.25)  # a third size: the least recently used one (half) goes
    assert set(r._accum_targets) == {(128, 96), (32, 24)}
    r.release()
