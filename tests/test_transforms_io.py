"""transforms.json scenes: OpenGL -> OpenCV poses, intrinsics and overrides, distortion, the real fox scene."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from scipy.ndimage import gaussian_filter

from training.core.errors import InputError
from training.scene.image_io import write_image
from training.scene.loader import load_scene
from training.scene.transforms_io import opengl_c2w_to_opencv_w2c

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
FOX = SHARED / "data" / "scenes" / "fox"
needs_fox = pytest.mark.skipif(not (FOX / "transforms.json").exists(), reason="shared fox scene not available")


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    """The fox folder is read-only, so a downscaled copy would go to the user cache: keep it in tmp instead."""
    monkeypatch.setenv("SPLATSTYLER_CACHE", str(tmp_path / "cache"))


def _project(cam, p):
    pc = cam.world_to_camera[:3, :3] @ p + cam.world_to_camera[:3, 3]
    return np.array([cam.fx * pc[0] / pc[2] + cam.cx, cam.fy * pc[1] / pc[2] + cam.cy]), pc[2]


def _gl_look_at(eye, target, up):
    """OpenGL camera-to-world: x right, y up, camera looking along -z toward target."""
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    true_up = np.cross(back, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, true_up, back, eye
    return c2w


def _write_scene(root: Path, frames: list[dict], size=(40, 30), **top) -> Path:
    (root / "images").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for f in frames:
        path = root / f["file_path"]
        if path.suffix == "":
            path = path.with_name(path.name + ".png")
        w, h = f.get("w", top.get("w", size[0])), f.get("h", top.get("h", size[1]))
        write_image(path, gaussian_filter(rng.random((int(h), int(w), 3)), (1, 1, 0)))
    (root / "transforms.json").write_text(json.dumps({**top, "frames": frames}))
    return root


def test_identity_opengl_camera_converts_to_known_opencv_matrix():
    c2w_gl = np.eye(4)
    c2w_gl[:3, 3] = [0.0, 0.0, 5.0]  # at z=5 looking down -z, toward the origin, y up
    expected = np.array([[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 5], [0, 0, 0, 1]], dtype=float)
    np.testing.assert_allclose(opengl_c2w_to_opencv_w2c(c2w_gl), expected, atol=1e-15)


@pytest.mark.parametrize("seed", range(4))
def test_look_at_frames_see_target_centered_and_up_above(tmp_path, seed):
    rng = np.random.default_rng(seed)
    eye = rng.normal(size=3) * 4
    target = rng.normal(size=3)
    up = np.array([0.0, 0.0, 1.0])
    frame = {"file_path": "images/a.png", "transform_matrix": _gl_look_at(eye, target, up).tolist()}
    _write_scene(tmp_path, [frame], fl_x=30.0, fl_y=30.0, cx=20.0, cy=15.0, w=40, h=30)
    cam = load_scene(tmp_path, load_images=False).cameras[0]
    np.testing.assert_allclose(cam.center, eye, atol=1e-12)
    uv, depth = _project(cam, target)
    np.testing.assert_allclose(uv, [20.0, 15.0], atol=1e-9)  # the target is on the optical axis
    np.testing.assert_allclose(depth, np.linalg.norm(target - eye), atol=1e-12)  # in front (+z), at its distance
    forward = target - eye
    right_dir = np.cross(forward, up)
    up_dir = np.cross(right_dir, forward)
    above, _ = _project(cam, target + 0.01 * up_dir / np.linalg.norm(up_dir))
    assert above[1] < 15.0 and abs(above[0] - 20.0) < 1e-9  # world up: smaller row (image y points down)
    right, _ = _project(cam, target + 0.01 * right_dir / np.linalg.norm(right_dir))
    assert right[0] > 20.0 and abs(right[1] - 15.0) < 1e-9


def test_intrinsics_overrides_and_angle_fallback(tmp_path):
    c2w = _gl_look_at(np.array([0, -3.0, 0]), np.zeros(3), np.array([0, 0, 1.0])).tolist()
    frames = [
        {"file_path": "images/a.png", "transform_matrix": c2w},
        {"file_path": "images/b.png", "transform_matrix": c2w, "fl_x": 50.0, "fl_y": 52.0, "cx": 30.0,
         "cy": 21.0, "w": 60, "h": 44},
        {"file_path": "images/c", "transform_matrix": c2w},  # NeRF-synthetic style: no extension
    ]
    angle = 2 * math.atan(20 / 35.0)
    _write_scene(tmp_path, frames, camera_angle_x=angle, aabb_scale=16)  # no w/h: from the image headers
    cams = load_scene(tmp_path, load_images=False).cameras
    a, b, c = cams
    assert (a.width, a.height) == (40, 30) and c.name == "images/c.png"
    np.testing.assert_allclose([a.fx, a.fy, a.cx, a.cy], [35.0, 35.0, 20.0, 15.0], atol=1e-9)
    assert (b.width, b.height) == (60, 44)
    np.testing.assert_allclose([b.fx, b.fy, b.cx, b.cy], [50.0, 52.0, 30.0, 21.0])


def test_distortion_is_removed_like_pycolmap(tmp_path):
    c2w = np.eye(4).tolist()
    params = dict(fl_x=40.0, fl_y=41.0, cx=24.5, cy=16.0, k1=-0.15, k2=0.03, p1=0.002, p2=-0.001, w=48, h=32)
    _write_scene(tmp_path, [{"file_path": "images/a.png", "transform_matrix": c2w}], **params)
    scene = load_scene(tmp_path)
    lens = pycolmap.Camera(model="OPENCV", width=48, height=32, params=[40.0, 41.0, 24.5, 16.0, -0.15, 0.03,
                                                                       0.002, -0.001])
    img8 = (np.clip(_read(tmp_path / "images" / "a.png"), 0, 1) * 255).round().astype(np.uint8)
    ref_bitmap, ref_cam = pycolmap.undistort_image(pycolmap.UndistortCameraOptions(),
                                                   pycolmap.Bitmap.from_array(img8), lens)
    cam = scene.cameras[0]
    assert (cam.width, cam.height) == (ref_cam.width, ref_cam.height)
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], list(ref_cam.params), atol=1e-9)
    assert np.abs(scene.images[0] - ref_bitmap.to_array() / 255.0).max() <= 0.5 / 255 + 1e-5
    assert scene.points is None and scene.num_points == 0


def _read(path):
    from training.scene.image_io import read_image

    return read_image(path)


@pytest.mark.parametrize("content,problem", [
    ({"frames": []}, "no frames"),
    ({"fl_x": 10}, "no frames"),
    ({"frames": [{"file_path": "images/a.png"}]}, "transform_matrix"),
    ({"frames": [{"file_path": "images/a.png", "transform_matrix": [[1, 0], [0, 1]]}]}, "4x4"),
    ({"frames": [{"file_path": "images/a.png", "transform_matrix": np.diag([1, 1, -1, 1]).tolist()}],
      "fl_x": 10}, "not a rotation"),
])
def test_bad_transforms_json(tmp_path, content, problem):
    (tmp_path / "transforms.json").write_text(json.dumps(content))
    with pytest.raises(InputError) as info:
        load_scene(tmp_path)
    assert problem in str(info.value) and "\n" not in str(info.value)
    assert info.value.path == tmp_path / "transforms.json"


def test_invalid_json_and_missing_images(tmp_path):
    (tmp_path / "transforms.json").write_text("{ not json")
    with pytest.raises(InputError, match="not valid JSON"):
        load_scene(tmp_path / "transforms.json")
    c2w = np.eye(4).tolist()
    _write_scene(tmp_path, [{"file_path": "images/a.png", "transform_matrix": c2w},
                            {"file_path": "images/b.png", "transform_matrix": c2w}], fl_x=30.0)
    (tmp_path / "images" / "b.png").unlink()
    with pytest.raises(InputError) as info:
        load_scene(tmp_path)
    assert info.value.path == tmp_path / "images" / "b.png"
    shutil.rmtree(tmp_path / "images")
    with pytest.raises(InputError, match="image"):
        load_scene(tmp_path, load_images=False)


# ---- the real fox scene (instant-ngp) --------------------------------------------------------------------------

@needs_fox
def test_fox_loads_all_frames_with_undistorted_intrinsics():
    scene = load_scene(FOX, load_images=False)
    assert len(scene.cameras) == 67 and scene.images == [] and scene.points is None
    data = json.loads((FOX / "transforms.json").read_text())
    lens = pycolmap.Camera(model="OPENCV", width=1080, height=1920,
                           params=[data[k] for k in ("fl_x", "fl_y", "cx", "cy", "k1", "k2", "p1", "p2")])
    ref = pycolmap.undistort_camera(pycolmap.UndistortCameraOptions(), lens)
    for cam in scene.cameras:
        assert (cam.width, cam.height) == (ref.width, ref.height)
        np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], list(ref.params))
    assert len(scene.train_indices) + len(scene.test_indices) == 67 and 0 in scene.test_indices


@needs_fox
@pytest.mark.parametrize("n", [2, 4])
def test_fox_downscale_scales_intrinsics(n):
    full = load_scene(FOX, load_images=False).cameras[0]
    cam = load_scene(FOX, downscale=n, load_images=False).cameras[0]
    sx, sy = round(1080 / n) / 1080, round(1920 / n) / 1920  # the images_N size, as the loader makes it
    np.testing.assert_allclose([cam.fx, cam.fy], [full.fx * sx, full.fy * sy], rtol=1e-12)
    # undistortion crops a few pixels at every size, so the centre and size follow to within a pixel
    assert abs(cam.cx - full.cx * sx) < 1.0 and abs(cam.cy - full.cy * sy) < 1.0
    assert abs(cam.width - full.width * sx) <= 2 and abs(cam.height - full.height * sy) <= 2
    np.testing.assert_array_equal(cam.world_to_camera, full.world_to_camera)


@needs_fox
def test_fox_cameras_look_at_the_object():
    cams = load_scene(FOX, load_images=False).cameras
    centers = np.stack([c.center for c in cams])
    dirs = np.stack([c.forward for c in cams])
    # the point closest (least squares) to every optical axis
    proj = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
    focus = np.linalg.solve(proj.sum(0), np.einsum("nij,nj->i", proj, centers))
    to_focus = focus - centers
    dist = np.linalg.norm(to_focus, axis=1)
    assert np.all(np.einsum("ni,ni->n", to_focus, dirs) > 0)  # in front of every camera
    angles = np.degrees(np.arccos(np.einsum("ni,ni->n", to_focus, dirs) / dist))
    assert angles.max() < 30.0
    # the cameras' image-up directions agree (a flipped y would scatter or invert them)
    ups = np.stack([-c.world_to_camera[1, :3] for c in cams])
    assert np.linalg.norm(ups.mean(0)) > 0.8
    # and the cameras orbit the object at similar distances
    assert dist.max() / dist.min() < 2.5


@needs_fox
def test_fox_subset_loads_images_matching_cameras(tmp_path):
    data = json.loads((FOX / "transforms.json").read_text())
    data["frames"] = data["frames"][:3]
    (tmp_path / "images").mkdir()
    for f in data["frames"]:
        shutil.copy(FOX / f["file_path"], tmp_path / f["file_path"])
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    scene = load_scene(tmp_path, downscale=4)
    cheap = load_scene(tmp_path, downscale=4, load_images=False)
    assert (tmp_path / "images_4" / "0001.jpg").is_file()
    for cam, cheap_cam, img in zip(scene.cameras, cheap.cameras, scene.images):
        assert img.shape == (cam.height, cam.width, 3) and img.dtype == np.float32
        np.testing.assert_array_equal(cam.K, cheap_cam.K)
        assert 0.05 < img.mean() < 0.95
