"""load_scene: format detection, the images_N downscale cache, errors for folders that are not scenes."""

from __future__ import annotations

import os
import stat
import time

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from training.scene.colmap_io import write_colmap_model
from training.core.errors import InputError
from training.scene.image_io import image_size, read_image, write_image
from training.scene.scene import Camera
from training.scene.loader import load_scene


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SPLATSTYLER_CACHE", str(tmp_path / "user-cache"))


def _scene(root, n=4, w=65, h=49):
    cams = []
    for i in range(n):
        w2c = np.eye(4)
        w2c[:3, 3] = [0.2 * i, 0.0, 3.0]
        cams.append(Camera(f"v{i}.png", w, h, 60.0, 61.0, 32.0, 24.5, w2c))
    write_colmap_model(root / "sparse" / "0", cams, np.zeros((3, 3)), np.ones((3, 3)))
    rng = np.random.default_rng(0)
    for c in cams:
        write_image(root / "images" / c.name, gaussian_filter(rng.random((h, w, 3)), (1, 1, 0)))
    return cams


def test_downscale_creates_then_reuses_images_n(tmp_path):
    cams = _scene(tmp_path)
    scene = load_scene(tmp_path, downscale=2)
    cache = tmp_path / "images_2"
    assert sorted(p.name for p in cache.iterdir()) == [c.name for c in cams]
    cam = scene.cameras[0]
    assert (cam.width, cam.height) == (32, 24) == image_size(cache / "v0.png")  # round(65/2), round(49/2)
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy],
                               [60.0 * 32 / 65, 61.0 * 24 / 49, 32.0 * 32 / 65, 24.5 * 24 / 49])
    assert scene.images[0].shape == (24, 32, 3)
    # the cached image is the downscaled original
    full = read_image(tmp_path / "images" / "v0.png")
    assert abs(scene.images[0].mean() - full.mean()) < 0.01

    # reused: not rewritten on the next load, and the same pixels as the load that built it
    stamp = (cache / "v1.png").stat().st_mtime_ns
    time.sleep(0.01)
    reused = load_scene(tmp_path, downscale=2)
    assert (cache / "v1.png").stat().st_mtime_ns == stamp
    for a, b in zip(scene.images, reused.images):
        np.testing.assert_array_equal(a, b)

    # out of date (source newer): rebuilt from the new source
    write_image(tmp_path / "images" / "v1.png", np.ones((49, 65, 3), np.float32))
    future = time.time() + 5
    os.utime(tmp_path / "images" / "v1.png", (future, future))
    again = load_scene(tmp_path, downscale=2)
    assert np.allclose(again.images[1], 1.0)
    # and load_images=False describes the same cameras without decoding anything
    cheap = load_scene(tmp_path, downscale=2, load_images=False)
    for a, b in zip(cheap.cameras, again.cameras):
        np.testing.assert_array_equal(a.K, b.K)
        assert (a.width, a.height) == (b.width, b.height)
    assert cheap.images == [] and cheap.num_points == 3


def test_existing_cache_of_other_rounding_sets_the_intrinsics(tmp_path):
    cams = _scene(tmp_path)
    for c in cams:  # another tool made images_2 with floor rounding: 32x24 from 65x49
        write_image(tmp_path / "images_2" / c.name, np.full((24, 32, 3), 0.5, np.float32))
    write_colmap_model(tmp_path / "sparse" / "0", [Camera(c.name, 65, 49, 60.0, 61.0, 32.0, 24.5,
                                                          c.world_to_camera) for c in cams])
    for c in cams:  # sources older than the cache
        os.utime(tmp_path / "images" / c.name, (1e9, 1e9))
    write_image(tmp_path / "images_2" / cams[0].name, np.full((25, 33, 3), 0.5, np.float32))
    scene = load_scene(tmp_path, downscale=2)
    cam = scene.cameras[0]
    assert (cam.width, cam.height) == (33, 25)
    np.testing.assert_allclose([cam.fx, cam.fy], [60.0 * 33 / 65, 61.0 * 25 / 49])
    assert np.allclose(scene.images[0], 0.5, atol=1 / 255)
    assert load_scene(tmp_path, downscale=2, load_images=False).cameras[0].width == 33


def test_read_only_scene_caches_in_user_folder(tmp_path):
    root = tmp_path / "scene"
    _scene(root, n=2)
    root.chmod(stat.S_IRUSR | stat.S_IXUSR | stat.S_IRGRP | stat.S_IXGRP)
    try:
        scene = load_scene(root, downscale=4)
        assert not (root / "images_4").exists()
        cached = list((tmp_path / "user-cache").rglob("images_4/*.png"))
        assert len(cached) == 2 and scene.images[0].shape == (12, 16, 3)
    finally:
        root.chmod(stat.S_IRWXU)


def test_rgba_images_give_masks(tmp_path):
    cams = _scene(tmp_path, n=2, w=20, h=10)
    rgba = np.zeros((10, 20, 4), np.float32)
    rgba[..., :3] = 0.7
    rgba[:, :10, 3] = 1.0
    write_image(tmp_path / "images" / cams[0].name, rgba)
    scene = load_scene(tmp_path)
    assert scene.masks[1] is None
    mask = scene.masks[0]
    assert mask.shape == (10, 20) and mask[:, :10].min() == 1.0 and mask[:, 10:].max() == 0.0
    assert np.allclose(scene.images[0], 0.7, atol=1 / 255)


def test_folders_that_are_not_scenes(tmp_path):
    cases = {}
    empty = tmp_path / "empty"
    empty.mkdir()
    cases[empty] = "empty"
    photos = tmp_path / "photos"
    write_image(photos / "a.png", np.zeros((4, 4, 3)))
    cases[photos] = f"splatstyler sfm {photos} -o"
    nested = tmp_path / "nested"
    write_image(nested / "images" / "a.jpg", np.zeros((4, 4, 3)))
    cases[nested] = f"splatstyler sfm {nested / 'images'} -o"
    other = tmp_path / "other"
    (other / "stuff").mkdir(parents=True)
    (other / "notes.txt").write_text("hello")
    cases[other] = "not a scene"
    cases[tmp_path / "nope"] = "no such file"
    cases[other / "notes.txt"] = "not a scene"
    for path, problem in cases.items():
        with pytest.raises(InputError) as info:
            load_scene(path)
        assert problem in str(info.value) and "\n" not in str(info.value), path
        assert info.value.path == path


def test_model_without_images_folder_and_bad_downscale(tmp_path):
    cams = _scene(tmp_path, n=2)
    with pytest.raises(InputError, match="downscale"):
        load_scene(tmp_path, downscale=0)
    with pytest.raises(InputError, match="downscale"):
        load_scene(tmp_path, downscale=1.5)
    for c in cams:
        (tmp_path / "images" / c.name).unlink()
    (tmp_path / "images").rmdir()
    with pytest.raises(InputError, match="no images/ folder"):
        load_scene(tmp_path)
