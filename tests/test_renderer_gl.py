"""renderer_gl against the training rasterizer, and one property test per render mode. Display-free: EGL
(llvmpipe on CI). Images are small because software GL is slow."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.system_deps import requires_library

from renderer_gl import Offscreen, SplatRenderer, create_context, frustum, look_at, polyline, view
from tests.gl_scenes import BG, camera, psnr, reference_render, separated_grid

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ctx():
    context = create_context("egl")
    yield context
    context.release()


@pytest.fixture(params=["instanced", "geometry"])
def renderer(ctx, request):
    """Both ways of making quads must draw the same pictures."""
    r = SplatRenderer(ctx, sort_tolerance_deg=0.0, quads=request.param)
    yield r
    r.release()


def test_import_loads_no_torch_nor_window_code():
    code = ("import sys, renderer_gl; bad = [m for m in ('torch', 'glfw', 'imgui_bundle', 'training.raster.rasterize')"
            " if m in sys.modules]; print(bad)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_shaders_carry_the_training_constants():
    """The GLSL header is written from the engine's constants: change one there and the shaders follow."""
    import re

    from renderer_gl.shader_source import source
    from training.model import sh_constants
    from training.raster import constants

    header = source("splat.frag.glsl")
    defines = {m[0]: float(m[1]) for m in re.findall(r"#define (\w+) ([-0-9.e]+)", header)}
    assert defines["ALPHA_MIN"] == constants.ALPHA_MIN and defines["ALPHA_MAX"] == constants.ALPHA_MAX
    assert defines["SH_C0"] == sh_constants.SH_C0 and defines["SH_C3_6"] == sh_constants.SH_C3[6]


@pytest.mark.parametrize("sh_degree", [None, 0, 1, 3])
def test_parity_on_separated_gaussians(renderer, sh_degree):
    rng = np.random.default_rng(11 + (sh_degree or 0))
    cam, w2c, K = camera()
    means, scales, quats, opac, sh = separated_grid(rng, sh_degree=sh_degree or 0)
    if sh_degree is None:
        sh = rng.uniform(0, 1, (len(means), 3)).astype(np.float32)
    renderer.set_splats(means, scales, quats, opac, sh, sh_degree)
    out = renderer.render_arrays(cam, ("rgb", "alpha", "depth"), background=BG)
    ref, ref_alpha = reference_render(means, scales, quats, opac, sh, sh_degree, w2c, K, cam.width, cam.height,
                                      mode="RGB+ED")
    assert psnr(out["rgb"], ref[..., :3]) >= 45.0
    assert np.abs(out["alpha"] - ref_alpha).max() < 1e-3
    covered = ref_alpha > 0.5
    assert covered.sum() > 50
    np.testing.assert_allclose(out["depth"][covered], ref[..., 3][covered], rtol=1e-4)


def test_max_sh_degree_drops_higher_bands(renderer):
    rng = np.random.default_rng(5)
    cam, w2c, K = camera()
    means, scales, quats, opac, sh = separated_grid(rng, sh_degree=3)
    sh[:, 1:] *= 4.0  # make the view-dependent bands matter
    renderer.set_splats(means, scales, quats, opac, sh, 3)
    out1 = renderer.render_arrays(cam, ("rgb",), background=BG, max_sh_degree=1)["rgb"]
    out3 = renderer.render_arrays(cam, ("rgb",), background=BG, max_sh_degree=3)["rgb"]
    ref1, _ = reference_render(means, scales, quats, opac, sh[:, :4], 1, w2c, K, cam.width, cam.height)
    assert psnr(out1, ref1) >= 45.0
    assert psnr(out3, ref1) < 40.0


def test_parity_on_overlapping_random_gaussians(renderer):
    """Overlap: the global per-Gaussian order equals the rasterizer's per-tile order here (one camera, sorting
    by the same z); what differs is the early stop at transmittance 1e-4, so the bound is lower."""
    rng = np.random.default_rng(3)
    cam, w2c, K = camera()
    n = 400
    means = (rng.uniform(-1, 1, (n, 3)) * [1.3, 1.0, 0.8]).astype(np.float32)
    scales = np.exp(rng.normal(-2.8, 0.5, (n, 3))).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    opac = rng.uniform(0.05, 0.95, n).astype(np.float32)
    sh = (rng.normal(size=(n, 9, 3)) * 0.3).astype(np.float32)
    renderer.set_splats(means, scales, quats, opac, sh, 2)
    out = renderer.render_arrays(cam, ("rgb",), background=BG)["rgb"]
    ref, _ = reference_render(means, scales, quats, opac, sh, 2, w2c, K, cam.width, cam.height)
    assert psnr(out, ref) >= 40.0


def _wall(renderer, rgb=(0.9, 0.2, 0.1), slot=0, opacity=0.99, z=0.0, size=0.6):
    """A square of overlapping opaque Gaussians facing the camera, centred on the optical axis."""
    g = np.arange(-size, size + 1e-6, 0.1)
    gx, gy = np.meshgrid(g, g)
    n = gx.size
    means = np.stack([gx.ravel(), gy.ravel(), np.full(n, z)], 1).astype(np.float32)
    scales = np.full((n, 3), 0.08, np.float32)
    quats = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
    opac = np.full(n, opacity, np.float32)
    colors = np.tile(np.asarray(rgb, np.float32), (n, 1))
    renderer.set_splats(means, scales, quats, opac, colors, None, slot=slot)


def test_alpha_mode_is_one_behind_an_opaque_wall_and_zero_off_it(ctx, renderer):
    cam, _, _ = camera(eye=(0, 0, -4))
    _wall(renderer)
    arrays = renderer.render_arrays(cam, ("alpha",))
    a = arrays["alpha"]
    assert a[48, 64] > 0.999  # centre: behind several opaque splats
    assert a[0, 0] == 0.0 and a[-1, -1] == 0.0  # corners: nothing there
    off = Offscreen(ctx, cam.width, cam.height)
    renderer.render(cam, off.fbo, mode="alpha", background=(0.5, 0.5, 0.5))
    img = off.read()
    assert img[48, 64].min() >= 254 and img[0, 0].max() == 0  # alpha mode shows alpha, not the background
    off.release()


def test_depth_increases_away_from_the_camera(ctx, renderer):
    """A floor receding from the camera: expected depth grows from the bottom rows to the top rows, in the
    float output and in the depth mode's colour map (darker = nearer)."""
    g = np.linspace(-1.5, 1.5, 31)
    gx, gz = np.meshgrid(g, np.linspace(-1.5, 6.0, 76))  # reaches below the bottom image row
    n = gx.size
    means = np.stack([gx.ravel(), np.full(n, 0.8), gz.ravel()], 1).astype(np.float32)
    scales = np.full((n, 3), 0.07, np.float32)
    quats = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
    renderer.set_splats(means, scales, quats, np.full(n, 0.9, np.float32), np.full((n, 3), 0.5, np.float32), None)
    cam = view(world_to_camera=look_at((0, 0, -2.0), (0, 0.3, 2.0)), K=[[100, 0, 64], [0, 100, 48], [0, 0, 1]],
               width=128, height=96)
    depth = renderer.render_arrays(cam, ("depth", "alpha"))
    rows = [r for r in range(96) if depth["alpha"][r, 64] > 0.9]
    assert len(rows) > 20
    column = depth["depth"][rows, 64]
    assert np.all(np.diff(column) < 0)  # image rows go down the screen, towards the camera on a floor
    off = Offscreen(ctx, 128, 96)
    info = renderer.render(cam, off.fbo, mode="depth")
    lum = off.read().astype(np.float64).sum(axis=2)[rows, 64]
    assert info.depth_range[0] < info.depth_range[1]
    assert np.corrcoef(column, lum)[0, 1] > 0.95
    off.release()


def test_split_view_shows_each_model_on_its_side(ctx, renderer):
    cam, _, _ = camera(eye=(0, 0, -3))
    _wall(renderer, rgb=(1, 0, 0), slot=0, size=1.5)
    _wall(renderer, rgb=(0, 1, 0), slot=1, size=1.5)
    off = Offscreen(ctx, cam.width, cam.height)
    for split in (0.5, 0.3):
        renderer.render(cam, off.fbo, split=split, divider_color=(0, 0, 1, 1))
        img = off.read().astype(int)
        x = int(round(split * cam.width))
        left, right = img[48, x - 6], img[48, x + 6]
        assert left[0] > 200 and left[1] < 30, left
        assert right[1] > 200 and right[0] < 30, right
        assert img[48, x, 2] > 200  # the divider
    off.release()


def test_points_mode_draws_centres_only(ctx, renderer):
    cam, w2c, K = camera(eye=(0, 0, -4))
    rng = np.random.default_rng(2)
    means, scales, quats, opac, _ = separated_grid(rng, cols=5, rows=4, scale=(0.1, 0.15))
    renderer.set_splats(means, scales, quats, opac, np.ones((len(means), 3), np.float32), None)
    off = Offscreen(ctx, cam.width, cam.height)
    renderer.render(cam, off.fbo, mode="points", point_size=1.0)
    lit = off.read().max(axis=2) > 128
    p = means @ w2c[:3, :3].T + w2c[:3, 3]
    px = np.floor(p[:, 0] / p[:, 2] * K[0, 0] + K[0, 2]).astype(int)
    py = np.floor(p[:, 1] / p[:, 2] * K[1, 1] + K[1, 2]).astype(int)
    assert lit.sum() == len(means)  # one pixel per centre, none of the splats' footprints
    assert lit[py, px].all()
    off.release()


def test_ellipsoid_outlines_are_rings(ctx, renderer):
    cam, _, _ = camera(eye=(0, 0, -4))
    means = np.zeros((1, 3), np.float32)
    renderer.set_splats(means, np.full((1, 3), 0.2, np.float32), np.array([[1, 0, 0, 0]], np.float32),
                        np.array([0.9], np.float32), np.ones((1, 3), np.float32), None)
    off = Offscreen(ctx, cam.width, cam.height)
    renderer.render(cam, off.fbo, mode="ellipsoids", outline_sigma=2.0)
    lit = off.read().max(axis=2) > 60
    assert lit.sum() > 40
    cx, cy = int(cam.cx), int(cam.cy)
    assert not lit[cy, cx]  # the inside of the outline is empty
    radius_px = 2.0 * 0.2 * cam.fx / 4.0  # 2 sigma at depth 4
    ys, xs = np.nonzero(lit)
    r = np.hypot(xs + 0.5 - cam.cx, ys + 0.5 - cam.cy)
    assert np.abs(np.median(r) - radius_px) < 1.5
    off.release()


def test_frustum_and_path_overlays_are_drawn(ctx, renderer):
    cam, _, _ = camera(eye=(0, 0, -4))
    _wall(renderer, rgb=(0.1, 0.1, 0.1), size=0.3)
    off = Offscreen(ctx, cam.width, cam.height)
    renderer.render(cam, off.fbo)
    plain = off.read().astype(int)
    other = view(world_to_camera=look_at((0.5, 0.2, -1.5), (0, 0, 0)), K=[[60, 0, 32], [0, 60, 24], [0, 0, 1]],
                 width=64, height=48)
    path = polyline([(-1.0, 0.8, 0.0), (0.0, 0.8, 0.0), (1.0, 0.8, 0.0)], color=(0, 1, 0, 1))
    renderer.render(cam, off.fbo, overlays=[frustum(other, 0.5, color=(1, 0, 1, 1)), path])
    img = off.read().astype(int)
    changed = np.abs(img - plain).sum(axis=2) > 0
    green = (img[..., 1] > 200) & (img[..., 0] < 50)
    magenta = (img[..., 0] > 200) & (img[..., 2] > 200) & (img[..., 1] < 50)
    assert green.sum() > 30 and magenta.sum() > 30
    # The path runs along world y = 0.8, i.e. one image row below the centre by f * 0.8 / 4 pixels.
    row = int(cam.cy + cam.fy * 0.8 / 4.0)
    assert green[row - 1: row + 2].sum() >= 30
    assert changed.sum() == (green | magenta | changed).sum()


def test_update_colors_rewrites_only_colours(renderer):
    cam, _, _ = camera(eye=(0, 0, -4))
    _wall(renderer, rgb=(1, 0, 0))
    model = renderer._slots[0]
    geom = model._geom
    before = renderer.render_arrays(cam, ("rgb", "alpha"))
    n = renderer.count()
    renderer.update_colors(np.tile(np.array([0, 0, 1], np.float32), (n, 1)), None)
    after = renderer.render_arrays(cam, ("rgb", "alpha"))
    assert model._geom is geom and model.order_forward is not None  # no geometry upload, no re-sort needed
    np.testing.assert_array_equal(before["alpha"], after["alpha"])
    assert before["rgb"][48, 64, 0] > 0.9 and after["rgb"][48, 64, 2] > 0.9 and after["rgb"][48, 64, 0] < 0.02


def test_flags_hide_and_tint(renderer):
    cam, _, _ = camera(eye=(0, 0, -4))
    _wall(renderer, rgb=(1, 1, 1))
    n = renderer.count()
    assert not renderer.flagged()
    renderer.set_flags(np.full(n, 2, np.uint8))
    assert renderer.flagged() and not renderer.flagged(slot=1)
    assert renderer.render_arrays(cam, ("alpha",))["alpha"].max() == 0.0
    renderer.set_flags(np.full(n, 1, np.uint8))
    rgb = renderer.render_arrays(cam, ("rgb",), tint=(0.0, 0.0, 1.0, 1.0))["rgb"]
    assert rgb[48, 64, 2] > 0.9 and rgb[48, 64, 0] < 0.02


def test_photo_blend_and_side_by_side(ctx, renderer):
    cam, _, _ = camera(eye=(0, 0, -4))
    _wall(renderer, rgb=(0, 0, 0), size=2.0)
    photo = np.zeros((cam.height, cam.width, 3), np.float32)
    photo[:, :, 1] = 1.0
    renderer.set_photo(photo)
    off = Offscreen(ctx, cam.width, cam.height)
    renderer.render(cam, off.fbo, photo="blend", photo_alpha=0.5)
    assert abs(int(off.read()[48, 64, 1]) - 128) <= 2
    renderer.render(cam, off.fbo, photo="side")
    img = off.read()
    assert img[48, 32, 1] < 5 and img[48, 96, 1] == 255
    off.release()


def test_lower_resolution_pass_resembles_the_full_one(ctx, renderer):
    rng = np.random.default_rng(8)
    cam, _, _ = camera()
    means, scales, quats, opac, sh = separated_grid(rng, scale=(0.04, 0.08))
    renderer.set_splats(means, scales, quats, opac, sh, 3)
    off = Offscreen(ctx, cam.width, cam.height)
    info_full = renderer.render(cam, off.fbo)
    full = off.read() / 255.0
    info_half = renderer.render(cam, off.fbo, scale=0.5)
    half = off.read() / 255.0
    assert info_half.size == (64, 48) and info_full.size == (128, 96)
    assert 20.0 < psnr(full, half) < 60.0
    off.release()


def test_moving_preview_draws_the_most_important_fraction_in_depth_order(renderer):
    """lod=f draws the f most important Gaussians (opacity x footprint) and nothing else: the picture equals a
    full render of just that subset."""
    rng = np.random.default_rng(11)
    cam, _, _ = camera()
    n = 400
    means = (rng.uniform(-1, 1, (n, 3)) * [1.3, 1.0, 0.8]).astype(np.float32)
    scales = np.exp(rng.normal(-2.8, 0.5, (n, 3))).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    opac = rng.uniform(0.05, 0.95, n).astype(np.float32)
    sh = (rng.normal(size=(n, 4, 3)) * 0.3).astype(np.float32)
    renderer.set_splats(means, scales, quats, opac, sh, 1)
    info = renderer.splat_pass(cam, lod=0.25)
    preview = renderer._read_accum()
    assert info.instances == 100
    keep = np.argsort(-(opac * scales.max(axis=1) ** 2))[:100]
    renderer.set_splats(means[keep], scales[keep], quats[keep], opac[keep], sh[keep], 1)
    subset = renderer.render_arrays(cam, ("rgb", "alpha"))
    assert np.allclose(preview[..., 3], subset["alpha"], atol=1e-5)
    assert np.allclose(preview[..., :3], subset["rgb"], atol=1e-5)


def test_sort_is_redone_only_when_the_view_turns(ctx):
    r = SplatRenderer(ctx, sort_tolerance_deg=1.0)
    rng = np.random.default_rng(4)
    r.set_splats(*separated_grid(rng), 3)
    cam, _, K = camera()
    assert r.splat_pass(cam).sorted
    assert not r.splat_pass(cam).sorted
    moved = view(world_to_camera=look_at((0.6, 0.05, -4.0), (0.5, 0.0, 0.0)), K=K, width=128, height=96)
    assert not r.splat_pass(moved).sorted  # translation only: the z order is unchanged
    turned_cam = view(world_to_camera=look_at((0.1, 0.05, -4.0), (0.5, 0.0, 0.0)), K=K, width=128, height=96)
    assert r.splat_pass(turned_cam).sorted  # about 7 degrees
    r.set_splats(*separated_grid(rng), 3)
    assert r.splat_pass(turned_cam).sorted  # new geometry
    r.release()


def test_background_sort_draws_with_the_previous_order_meanwhile(ctx):
    r = SplatRenderer(ctx, sort_tolerance_deg=0.0, background_sort=True)
    rng = np.random.default_rng(6)
    cam, w2c, K = camera()
    means, scales, quats, opac, sh = separated_grid(rng)
    r.set_splats(means, scales, quats, opac, sh, 3)
    first = r.render_arrays(cam, ("rgb",), background=BG)["rgb"]  # the first order is sorted at once
    turned_cam = view(world_to_camera=look_at((0.1, 0.05, -4.0), (0.3, 0.0, 0.0)), K=K, width=128, height=96)
    info = r.splat_pass(turned_cam)
    assert not info.sorted and info.instances == len(means)
    r._sorter._pool.submit(lambda: None).result()  # wait for the worker
    assert r.splat_pass(turned_cam).sorted
    ref, _ = reference_render(means, scales, quats, opac, sh, 3, w2c, K, 128, 96)
    assert psnr(first, ref) >= 45.0
    r.release()


def test_quad_paths_agree_and_auto_picks_geometry_on_software_gl(ctx):
    cam, _, _ = camera()
    images = []
    for quads in ("instanced", "geometry", "auto"):
        r = SplatRenderer(ctx, quads=quads)
        r.set_splats(*separated_grid(np.random.default_rng(9), scale=(0.05, 0.3)), 3)  # overlapping: big scales
        images.append(r.render_arrays(cam, ("rgb",), background=BG)["rgb"])
        if quads == "auto":
            assert r.quads == ("geometry" if "llvmpipe" in ctx.info["GL_RENDERER"] else "instanced")
        r.release()
    np.testing.assert_allclose(images[0], images[1], atol=1e-4)


def test_bad_input_is_refused(renderer):
    with pytest.raises(ValueError, match="means"):
        renderer.set_splats(np.zeros((3, 2)), np.zeros((3, 3)), np.zeros((3, 4)), np.zeros(3), np.zeros((3, 3)), None)
    with pytest.raises(ValueError, match="SH"):
        renderer.set_splats(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 4)), np.zeros(3),
                            np.zeros((3, 4, 3)), 3)
    with pytest.raises(ValueError, match="render mode"):
        renderer.set_splats(np.zeros((1, 3)), np.ones((1, 3)), np.array([[1.0, 0, 0, 0]]), np.ones(1),
                            np.zeros((1, 3)), None)
        renderer.splat_pass(camera()[0], "normals")


@requires_library("OSMesa", "libosmesa6", ("libOSMesa.so.8", "libOSMesa.so.6"))
def test_osmesa_renders_what_egl_renders(tmp_path):
    """OSMesa in a process of its own (two GL libraries current in one process is asking for trouble)."""
    code = f"""
import numpy as np
from renderer_gl import SplatRenderer, create_context
from tests.gl_scenes import camera, separated_grid
ctx = create_context("osmesa")
print(ctx.info["GL_RENDERER"], ctx.version_code)
r = SplatRenderer(ctx)
r.set_splats(*separated_grid(np.random.default_rng(1)), 3)
np.save({str(tmp_path / "osmesa.npy")!r}, r.render_arrays(camera()[0], ("rgb",))["rgb"])
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    print("OSMesa:", out.stdout.strip())
    osmesa_rgb = np.load(tmp_path / "osmesa.npy")
    ctx = create_context("egl")
    r = SplatRenderer(ctx)
    r.set_splats(*separated_grid(np.random.default_rng(1)), 3)
    egl_rgb = r.render_arrays(camera()[0], ("rgb",))["rgb"]
    r.release()
    ctx.release()
    assert osmesa_rgb.shape == egl_rgb.shape and egl_rgb.max() > 0.1
    np.testing.assert_allclose(osmesa_rgb, egl_rgb, atol=1e-5)


def test_an_empty_renderer_draws_the_background(ctx):
    """The viewer draws before any model arrives: every mode shows the background, nothing raises."""
    r = SplatRenderer(ctx)
    off = Offscreen(ctx, 32, 24)
    cam = view(world_to_camera=np.eye(4), K=[[30, 0, 16], [0, 30, 12], [0, 0, 1]], width=32, height=24)
    for mode in ("color", "depth", "points", "ellipsoids"):
        assert r.render(cam, off.fbo, mode=mode, background=(0.5, 0.5, 0.5)).instances == 0
        assert (off.read() == 128).all()
    off.release()
    r.release()
