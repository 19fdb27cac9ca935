"""The built-in demo assets: the procedural scene loads through the normal loader with exactly the cameras it was
rendered from, its points land on pixels of their colour, its images and the style painting are textured, and
generation is deterministic and cached atomically."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

import assets.demo.assets as demo_assets_module
from assets.demo.assets import MANIFEST, DemoAssets, demo_assets
from assets.demo.scene import DemoWorld, demo_cameras, make_demo_scene, write_demo_scene
from assets.demo.painting import make_style_image
from training.core.errors import InputError
from training.scene.image_io import read_image
from training.scene.loader import load_scene

# Fewer views than the demo but its image size: the texture scale relative to the pixels is what ships.
SMALL = {"num_views": 6, "width": 256, "height": 192, "num_points": 1500, "seed": 0, "supersample": 2}


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    scene = make_demo_scene(**SMALL)
    folder = write_demo_scene(tmp_path_factory.mktemp("demo") / "scene", scene)
    return scene, folder


def _project(camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole projection written out here, independent of the generator: (P, 3) -> pixel (P, 2), depth (P,)."""
    pc = points.astype(np.float64) @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
    uv = pc[:, :2] / pc[:, 2:3] * [camera.fx, camera.fy] + [camera.cx, camera.cy]
    return uv, pc[:, 2]


def _best_neighbour_error(image: np.ndarray, uv: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """Smallest max-channel colour difference between each colour and the 3x3 pixels around its pixel -> (P,)."""
    h, w, _ = image.shape
    ix, iy = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    best = np.full(len(uv), np.inf)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            px = image[np.clip(iy + dy, 0, h - 1), np.clip(ix + dx, 0, w - 1)]
            best = np.minimum(best, np.abs(px - colours).max(axis=1))
    return best


def test_scene_loads_with_the_cameras_it_was_rendered_from(small_scene):
    scene, folder = small_scene
    loaded = load_scene(folder)
    assert len(loaded.cameras) == SMALL["num_views"] == len(scene.cameras)
    by_name = {c.name: (c, im) for c, im in zip(loaded.cameras, loaded.images)}
    assert set(by_name) == {c.name for c in scene.cameras}
    for truth, image in zip(scene.cameras, scene.images):
        cam, loaded_image = by_name[truth.name]
        assert (cam.width, cam.height) == (truth.width, truth.height) == (SMALL["width"], SMALL["height"])
        np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [truth.fx, truth.fy, truth.cx, truth.cy],
                                   rtol=0, atol=1e-9)
        np.testing.assert_allclose(cam.world_to_camera, truth.world_to_camera, rtol=0, atol=1e-6)
        assert loaded_image.shape == (truth.height, truth.width, 3)
        # 8-bit PNG: within half a quantisation step of what was rendered
        assert np.abs(loaded_image - image).max() <= 0.5 / 255 + 1e-6
    assert loaded.num_points == len(scene.points) == SMALL["num_points"]
    np.testing.assert_allclose(loaded.points, scene.points, rtol=0, atol=1e-6)
    assert np.abs(loaded.point_colors - scene.point_colors).max() <= 0.5 / 255 + 1e-6


def test_cameras_circle_the_objects_and_look_at_them():
    cameras = demo_cameras(32, 256, 192)
    centres = np.stack([c.center for c in cameras])
    to_middle = np.array([0.0, 0.3, 0.55]) - centres
    to_middle /= np.linalg.norm(to_middle, axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", np.stack([c.forward for c in cameras]), to_middle) > 0.999)
    for c in cameras:  # proper rotations: no mirrored camera
        R = c.world_to_camera[:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        assert c.world_to_camera[1, 2] < 0  # image y (down) points against world z (up): the scene is upright
    angles = np.degrees(np.unwrap(np.arctan2(centres[:, 0], -(centres[:, 1] - 0.3))))
    assert angles[-1] - angles[0] == pytest.approx(150.0)
    steps = np.diff(angles)
    assert np.all(steps > 0) and steps.max() - steps.min() < 1e-6  # a smooth, evenly sampled arc


def test_points_reproject_onto_pixels_of_their_colour(small_scene):
    scene, folder = small_scene
    loaded = load_scene(folder)
    world = DemoWorld(SMALL["seed"])
    seen_by = np.zeros(loaded.num_points, dtype=int)
    errors, shifted_errors = [], []
    for i, (camera, image) in enumerate(zip(loaded.cameras, loaded.images)):
        visible = world.visible(loaded.points.astype(np.float64), camera)
        seen_by += visible
        uv, depth = _project(camera, loaded.points[visible])
        assert np.all(depth > 0)
        assert np.all((uv >= 0) & (uv < [camera.width, camera.height]))
        errors.append(_best_neighbour_error(image, uv, loaded.point_colors[visible]))
        # Control: the same points through the next camera along the arc must mostly miss their colours,
        # otherwise this test could not tell a right camera from a wrong one.
        other = loaded.cameras[(i + 1) % len(loaded.cameras)]
        uv2, _ = _project(other, loaded.points[visible])
        ok = np.all((uv2 >= 0) & (uv2 < [other.width, other.height]), axis=1)
        shifted_errors.append(_best_neighbour_error(image, uv2[ok], loaded.point_colors[visible][ok]))
    assert np.all(seen_by >= 1), "every SfM point must be visible from at least one camera"
    errors = np.concatenate(errors)
    shifted = np.concatenate(shifted_errors)
    assert len(errors) > 2 * loaded.num_points  # most points are seen by several views
    # Points on sharp texture edges and silhouettes meet anti-aliased (blended) pixels: most, not all, match.
    match = np.mean(errors < 0.1)
    assert match > 0.85, f"only {match:.1%} of visible points land on a pixel of their colour"
    assert np.median(errors) < 0.02
    assert np.mean(shifted < 0.1) < 0.5 * match


def _texture_stats(image: np.ndarray) -> tuple[float, float, int]:
    """Mean gradient magnitude, fraction of 16x16 blocks with texture (std > 0.03), distinct 5-bit colours."""
    gx = np.diff(image, axis=1)[:-1]
    gy = np.diff(image, axis=0)[:, :-1]
    gradient = float(np.sqrt((gx**2 + gy**2).sum(-1)).mean())
    h, w = (image.shape[0] // 16) * 16, (image.shape[1] // 16) * 16
    blocks = image[:h, :w].mean(-1).reshape(h // 16, 16, w // 16, 16).std(axis=(1, 3))
    q = np.round(image * 31).astype(np.int64)
    distinct = len(np.unique(q[..., 0] * 1024 + q[..., 1] * 32 + q[..., 2]))
    return gradient, float(np.mean(blocks > 0.03)), distinct


def test_demo_views_are_richly_textured():
    world = DemoWorld(0)
    cameras = demo_cameras(32, 256, 192)  # the size the demo ships with
    for camera in (cameras[0], cameras[16], cameras[31]):
        gradient, textured_blocks, distinct = _texture_stats(world.render(camera))
        assert gradient > 0.06, f"{camera.name}: mean gradient {gradient:.3f}"
        assert textured_blocks > 0.85, f"{camera.name}: only {textured_blocks:.0%} of blocks are textured"
        assert distinct > 1500, f"{camera.name}: only {distinct} distinct colours"
    # A plain surface would not pass: the thresholds above are meaningful.
    flat = np.full((192, 256, 3), 0.5, np.float32) + np.linspace(0, 0.2, 256, dtype=np.float32)[None, :, None]
    gradient, textured_blocks, distinct = _texture_stats(flat)
    assert gradient < 0.06 and textured_blocks < 0.85 and distinct < 1500


def test_style_painting_is_textured_and_colourful():
    style = make_style_image(512, seed=0)
    assert style.shape == (512, 512, 3) and style.dtype == np.float32
    assert style.min() >= 0.0 and style.max() <= 1.0
    gradient, textured_blocks, distinct = _texture_stats(style)
    assert gradient > 0.1 and textured_blocks > 0.95 and distinct > 4000
    mx, mn = style.max(-1), style.min(-1)
    saturation = (mx - mn) / np.maximum(mx, 1e-6)
    assert saturation.mean() > 0.5
    # Several distinct hues, each covering a real part of the picture (not one colour with noise).
    r, g, b = style[..., 0], style[..., 1], style[..., 2]
    hue = np.degrees(np.arctan2(np.sqrt(3) * (g - b), 2 * r - g - b)) % 360
    coverage = np.histogram(hue[saturation > 0.4], bins=6, range=(0, 360))[0] / hue.size
    assert np.sum(coverage > 0.03) >= 3, coverage


def _folder_digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def tiny_params(monkeypatch):
    monkeypatch.setattr(demo_assets_module, "SCENE_PARAMS",
                        {"num_views": 3, "width": 48, "height": 36, "num_points": 200, "seed": 0, "supersample": 1})
    monkeypatch.setattr(demo_assets_module, "STYLE_PARAMS", {"size": 64, "seed": 0})


def test_generation_is_deterministic_byte_for_byte(tmp_path, tiny_params):
    a = demo_assets(tmp_path / "a")
    b = demo_assets(tmp_path / "b")
    digest_a, digest_b = _folder_digest(a.root), _folder_digest(b.root)
    assert digest_a == digest_b
    assert "style.png" in digest_a and "scene/images/view_002.png" in digest_a
    assert any(name.startswith("scene/sparse/0/points3D") for name in digest_a)


def test_assets_are_cached_and_regenerated_atomically(tmp_path, tiny_params, monkeypatch):
    root = tmp_path / "cache" / "demo"
    assets = demo_assets(root)
    assert isinstance(assets, DemoAssets)
    assert assets.style_image.is_file() and (assets.scene_dir / "sparse" / "0").is_dir()
    assert load_scene(assets.scene_dir, load_images=False).num_points == 200
    assert read_image(assets.style_image).shape == (64, 64, 3)
    before = _folder_digest(root)

    # Reused: a second call must not generate anything.
    def refuse(*args, **kwargs):
        raise AssertionError("regenerated although the cache is complete")

    generate = demo_assets_module.generate_demo_assets
    monkeypatch.setattr(demo_assets_module, "generate_demo_assets", refuse)
    assert demo_assets(root) == assets
    # A failing regeneration leaves the previous set untouched and no temporary folders behind.
    with pytest.raises(AssertionError):
        demo_assets(root, force=True)
    assert _folder_digest(root) == before
    assert [p.name for p in root.parent.iterdir()] == ["demo"]
    monkeypatch.setattr(demo_assets_module, "generate_demo_assets", generate)

    # A stale version is regenerated.
    manifest = root / MANIFEST
    manifest.write_text(manifest.read_text().replace('"version": "1"', '"version": "0"'))
    demo_assets(root)
    assert _folder_digest(root) == before


def test_refuses_a_foreign_folder(tmp_path, tiny_params):
    target = tmp_path / "mine"
    target.mkdir()
    (target / "notes.txt").write_text("my files")
    with pytest.raises(InputError, match="not empty"):
        demo_assets(target)
    with pytest.raises(InputError, match="not empty"):
        demo_assets(target, force=True)
    assert [p.name for p in target.iterdir()] == ["notes.txt"]
    file_target = tmp_path / "a_file"
    file_target.write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        demo_assets(file_target)


def test_default_location_is_the_cache(tmp_path, tiny_params, monkeypatch):
    monkeypatch.setenv("SPLATSTYLER_CACHE", str(tmp_path / "cache"))
    assets = demo_assets()
    assert assets.root == tmp_path / "cache" / "demo" / demo_assets_module.VERSION
    assert assets.style_image.is_file()


@pytest.mark.slow
def test_sfm_registers_the_demo_views(tmp_path):
    """The texture is SfM-friendly: pycolmap registers 10 demo views and recovers the known camera path."""
    try:
        from training.scene.sfm import run_sfm
    except ImportError as exc:
        pytest.skip(f"training.scene.sfm is not available: {exc}")
    from training.scene.image_io import write_image

    world = DemoWorld(0)
    cameras = demo_cameras(32, 256, 192)[1::3]  # 11 views spread along the whole arc
    photos = tmp_path / "photos"
    for camera in cameras:
        write_image(photos / camera.name, world.render(camera))
    result = run_sfm(photos, tmp_path / "sfm", log=lambda line: None, progress=False)
    assert result.num_registered >= 0.8 * len(cameras)

    recovered = load_scene(tmp_path / "sfm", load_images=False)
    # SfM estimated the focal length from the images alone (measured 219.9 px against the true 221.7 px).
    assert recovered.cameras[0].fx == pytest.approx(cameras[0].fx, rel=0.03)
    truth = {c.name: c.center for c in cameras}
    names = [c.name for c in recovered.cameras]
    estimated = np.stack([c.center for c in recovered.cameras])
    true = np.stack([truth[n] for n in names])
    # Similarity alignment (SfM fixes cameras up to scale, rotation and translation), then compare centres.
    mu_e, mu_t = estimated.mean(0), true.mean(0)
    e, t = estimated - mu_e, true - mu_t
    U, S, Vt = np.linalg.svd(t.T @ e)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    scale = np.trace(np.diag(S) @ D) / (e**2).sum()
    residual = np.linalg.norm(scale * e @ R.T - t, axis=1)
    assert residual.max() < 0.02 * 5.6, f"camera centres off by up to {residual.max():.3f} (arc radius 5.6)"
