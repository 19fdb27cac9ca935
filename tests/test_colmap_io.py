"""COLMAP models through pycolmap: write/read round trips, rigs, undistortion against pycolmap's own, bad input."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from scipy.ndimage import gaussian_filter
from scipy.spatial.transform import Rotation

from training.scene.colmap_io import read_colmap_model, write_colmap_model
from training.core.errors import InputError
from training.scene.image_io import write_image
from training.scene.scene import Camera
from training.scene.loader import load_scene


def _cameras(n=5, seed=0) -> list[Camera]:
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        w2c = np.eye(4)
        w2c[:3, :3] = Rotation.random(random_state=seed * 100 + i).as_matrix()
        w2c[:3, 3] = rng.normal(size=3)
        # two distinct intrinsics (shared cameras) plus one odd one
        fx = 40.0 if i % 2 else 41.5
        cams.append(Camera(f"view_{i:02d}.png", 48, 32, fx, fx * 1.01, 24.3, 15.7 + (i == 3), w2c))
    return cams


def _textured(h, w, seed=0, channels=3):
    rng = np.random.default_rng(seed)
    img = gaussian_filter(rng.random((h, w, channels)), (1.5, 1.5, 0))
    return np.clip((img - 0.5) * 5 + 0.5, 0, 1).astype(np.float32)


def _scene_folder(root: Path, cameras, binary=True, points=None, colors=None) -> Path:
    write_colmap_model(root / "sparse" / "0", cameras, points, colors, binary=binary)
    for i, cam in enumerate(cameras):
        write_image(root / "images" / cam.name, _textured(cam.height, cam.width, seed=i))
    return root


def _assert_same_cameras(loaded: list[Camera], expected: list[Camera]) -> None:
    assert [c.name for c in loaded] == [c.name for c in expected]
    for a, b in zip(loaded, expected):
        assert (a.width, a.height) == (b.width, b.height)
        np.testing.assert_allclose([a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.world_to_camera, b.world_to_camera, atol=1e-9)


@pytest.mark.parametrize("binary", [True, False])
def test_write_read_round_trip(tmp_path, binary):
    cams = _cameras()
    rng = np.random.default_rng(1)
    points = rng.normal(size=(200, 3)).astype(np.float32)
    colors = rng.random((200, 3)).astype(np.float32)
    _scene_folder(tmp_path, cams, binary, points, colors)
    ext = "bin" if binary else "txt"
    names = sorted(p.name for p in (tmp_path / "sparse" / "0").iterdir())
    assert names == sorted(f"{n}.{ext}" for n in ("cameras", "images", "points3D", "rigs", "frames"))

    scene = load_scene(tmp_path)
    _assert_same_cameras(scene.cameras, cams)
    np.testing.assert_allclose(scene.points, points, atol=1e-6)
    assert np.abs(scene.point_colors - colors).max() <= 0.5 / 255 + 1e-6
    assert len(scene.images) == 5 and scene.images[0].shape == (32, 48, 3)
    model = read_colmap_model(tmp_path / "sparse" / "0")
    cams_used = {(v.lens.width, tuple(v.lens.params)) for v in model.views}
    assert len(cams_used) == 3  # identical intrinsics share one COLMAP camera

    # Re-writing in the other format must not leave the old files for a reader to prefer.
    write_colmap_model(tmp_path / "sparse" / "0", cams[:2], binary=not binary)
    assert not any(p.suffix == f".{ext}" for p in (tmp_path / "sparse" / "0").iterdir())
    assert len(load_scene(tmp_path, load_images=False).cameras) == 2


def test_classic_three_file_text_model(tmp_path):
    cams = _cameras(3)
    _scene_folder(tmp_path, cams, binary=False, points=np.zeros((4, 3)))
    for name in ("rigs.txt", "frames.txt"):  # what COLMAP 3.x writes: only cameras/images/points3D
        (tmp_path / "sparse" / "0" / name).unlink()
    scene = load_scene(tmp_path, load_images=False)
    _assert_same_cameras(scene.cameras, cams)
    assert scene.num_points == 4 and scene.images == []


def test_model_folder_given_directly_and_plain_sparse(tmp_path):
    cams = _cameras(2)
    _scene_folder(tmp_path, cams)
    _assert_same_cameras(load_scene(tmp_path / "sparse" / "0", load_images=False).cameras, cams)
    os.replace(tmp_path / "sparse" / "0", tmp_path / "model")
    (tmp_path / "sparse").rmdir()
    os.replace(tmp_path / "model", tmp_path / "sparse")  # sparse/ holding the files, no 0/
    _assert_same_cameras(load_scene(tmp_path, load_images=False).cameras, cams)


def test_rig_with_two_cameras_composes_frame_and_sensor_poses(tmp_path):
    rec = pycolmap.Reconstruction()
    for cid in (1, 2):
        rec.add_camera(pycolmap.Camera(camera_id=cid, model="PINHOLE", width=40, height=30, params=[30, 31, 20, 15]))
    rig = pycolmap.Rig(rig_id=1)
    rig.add_ref_sensor(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, 1))
    sensor_from_rig = np.eye(4)
    sensor_from_rig[:3, :3] = Rotation.from_euler("y", 90, degrees=True).as_matrix()
    sensor_from_rig[:3, 3] = [0.1, 0.0, 0.02]
    rig.add_sensor(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, 2), pycolmap.Rigid3d(sensor_from_rig[:3]))
    rec.add_rig(rig)
    expected = {}
    image_id = 1
    for frame_id in (1, 2):
        rig_from_world = np.eye(4)
        rig_from_world[:3, :3] = Rotation.from_euler("zx", [10 * frame_id, 5], degrees=True).as_matrix()
        rig_from_world[:3, 3] = [0.3, -0.2, frame_id]
        frame = pycolmap.Frame(frame_id=frame_id, rig_id=1)
        frame.rig_from_world = pycolmap.Rigid3d(rig_from_world[:3])
        for cid in (1, 2):
            frame.add_data_id(pycolmap.data_t(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, cid), image_id))
            expected[f"f{frame_id}_c{cid}.png"] = rig_from_world if cid == 1 else sensor_from_rig @ rig_from_world
            image_id += 1
        rec.add_frame(frame)
    image_id = 1
    for frame_id in (1, 2):
        for cid in (1, 2):
            rec.add_image(pycolmap.Image(name=f"f{frame_id}_c{cid}.png", camera_id=cid, image_id=image_id,
                                         frame_id=frame_id))
            image_id += 1
    (tmp_path / "sparse" / "0").mkdir(parents=True)
    rec.write_text(str(tmp_path / "sparse" / "0"))
    for name in expected:
        write_image(tmp_path / "images" / name, _textured(30, 40))

    scene = load_scene(tmp_path)
    assert sorted(c.name for c in scene.cameras) == sorted(expected)
    for cam in scene.cameras:
        np.testing.assert_allclose(cam.world_to_camera, expected[cam.name], atol=1e-12)


def _distorted_scene(root: Path, model: str, params: list[float], w=96, h=64) -> np.ndarray:
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=1, model=model, width=w, height=h, params=params))
    pose = pycolmap.Rigid3d(np.c_[np.eye(3), [0.0, 0.0, 2.0]])
    rec.add_image_with_trivial_frame(pycolmap.Image(name="a.png", camera_id=1, image_id=1), pose)
    (root / "sparse" / "0").mkdir(parents=True)
    rec.write_binary(str(root / "sparse" / "0"))
    img8 = (_textured(h, w, seed=5) * 255).round().astype(np.uint8)
    write_image(root / "images" / "a.png", img8.astype(np.float32) / 255)
    return img8


@pytest.mark.parametrize("model,params", [
    ("OPENCV", [80.0, 82.0, 49.0, 31.0, -0.2, 0.05, 0.001, -0.002]),
    ("SIMPLE_RADIAL", [85.0, 47.5, 32.5, 0.15]),
    ("OPENCV_FISHEYE", [60.0, 60.0, 48.0, 32.0, 0.05, 0.01, 0.0, 0.0]),
])
def test_undistortion_matches_pycolmap_undistorter(tmp_path, model, params):
    img8 = _distorted_scene(tmp_path, model, params)
    distorted = pycolmap.Camera(model=model, width=96, height=64, params=params)
    ref_bitmap, ref_camera = pycolmap.undistort_image(pycolmap.UndistortCameraOptions(),
                                                      pycolmap.Bitmap.from_array(img8), distorted)
    reference = ref_bitmap.to_array().astype(np.float32) / 255

    scene = load_scene(tmp_path)
    cam = scene.cameras[0]
    assert (cam.width, cam.height) == (ref_camera.width, ref_camera.height)
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], list(ref_camera.params), atol=1e-9)
    # pycolmap rounds its 8-bit result; ours stays float: half an 8-bit step apart at most
    assert np.abs(scene.images[0] - reference).max() <= 0.5 / 255 + 1e-5
    cheap = load_scene(tmp_path, load_images=False).cameras[0]  # same camera without decoding anything
    assert (cheap.width, cheap.height) == (cam.width, cam.height)
    np.testing.assert_array_equal(cheap.K, cam.K)


def test_unsupported_camera_model_is_refused(tmp_path):
    _distorted_scene(tmp_path, "EQUIRECTANGULAR", [96.0, 64.0])
    with pytest.raises(InputError) as info:
        load_scene(tmp_path)
    message = str(info.value)
    assert "EQUIRECTANGULAR" in message and "\n" not in message and str(tmp_path) in message


def test_image_names_not_matching_the_model(tmp_path):
    cams = _cameras(3)
    _scene_folder(tmp_path, cams)
    for p in (tmp_path / "images").iterdir():
        p.rename(p.with_name("renamed_" + p.name))
    with pytest.raises(InputError) as info:
        load_scene(tmp_path)
    assert "do not match" in str(info.value) and "\n" not in str(info.value)


def test_missing_image_is_named(tmp_path):
    cams = _cameras(3)
    _scene_folder(tmp_path, cams)
    (tmp_path / "images" / cams[1].name).unlink()
    with pytest.raises(InputError) as info:
        load_scene(tmp_path, load_images=False)
    assert info.value.path == tmp_path / "images" / cams[1].name and "missing" in str(info.value)


def test_truncated_image_in_scene_is_named(tmp_path):
    cams = _cameras(2)
    _scene_folder(tmp_path, cams)
    bad = tmp_path / "images" / cams[0].name
    bad.write_bytes(bad.read_bytes()[:200])
    with pytest.raises(InputError) as info:
        load_scene(tmp_path)
    assert info.value.path == bad and "\n" not in str(info.value)


def test_missing_model_file_and_corrupt_model(tmp_path):
    cams = _cameras(2)
    _scene_folder(tmp_path, cams)
    for name in ("images.bin", "points3D.bin", "frames.bin"):
        data = (tmp_path / "sparse" / "0" / name).read_bytes()
        (tmp_path / "sparse" / "0" / name).unlink()
        with pytest.raises(InputError) as info:
            load_scene(tmp_path)
        assert info.value.path == tmp_path / "sparse" / "0" / name and "missing" in str(info.value)
        (tmp_path / "sparse" / "0" / name).write_bytes(data)
    (tmp_path / "sparse" / "0" / "images.bin").write_bytes(b"\x01\x02garbage")
    with pytest.raises(InputError) as info:
        load_scene(tmp_path)
    assert "cannot read COLMAP model" in str(info.value) and "\n" not in str(info.value)


def test_image_of_other_aspect_ratio_is_refused(tmp_path):
    cams = _cameras(2)
    _scene_folder(tmp_path, cams)
    write_image(tmp_path / "images" / cams[0].name, _textured(32, 32))
    for downscale in (1, 2):
        with pytest.raises(InputError) as info:
            load_scene(tmp_path, downscale=downscale)
        assert "aspect ratio" in str(info.value) and info.value.path == tmp_path / "images" / cams[0].name
