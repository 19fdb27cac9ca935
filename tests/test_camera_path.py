"""Camera paths: the spline passes through its keyframes, rotations stay rigid, an orbit circles its centre at a
steady speed, JSON round-trips, and a bad file is one InputError line naming it."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from app.camera_path import CameraPath, dataset_path, keyframe_from, orbit_path
from training.core.errors import InputError
from training.scene.camera import Camera
from training.scene.pose import look_at, matrix_to_quat, quat_to_matrix, slerp


def key(eye, target=(0, 0, 0), w=640, h=360, f=500.0) -> Camera:
    return Camera("keyframe", w, h, f, f, w / 2, h / 2, look_at(eye, target, (0, -1, 0)))


def rotation_angle(r: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


def test_path_passes_through_its_keyframes_and_stays_rigid():
    keys = [key((4, -1, 0)), key((0, -1, 4)), key((-4, -2, 1), w=320, h=180, f=200), key((0, -1, -5))]
    path = CameraPath(keys, duration=3.0, fps=20)  # one second per segment
    for i, k in enumerate(keys):
        cam = path.camera_at(float(i), 640, 360)
        assert np.allclose(cam.world_to_camera, k.world_to_camera, atol=1e-9)
        assert np.allclose([cam.fx, cam.cx], [k.fx * 640 / k.width, k.cx * 640 / k.width])
    cams = path.cameras()
    assert len(cams) == 60 and np.allclose(cams[-1].world_to_camera, keys[-1].world_to_camera)
    for cam in cams:
        r = cam.world_to_camera[:3, :3]
        assert np.allclose(r @ r.T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(r), 1)
    # halfway between keys 1 and 2 the focal length is halfway (relative to the image width)
    mid = path.camera_at(1.5, 640, 360)
    assert np.isclose(mid.fx / 640, 0.5 * (500 / 640 + 200 / 320))
    # smooth: no step between frames much larger than its neighbours
    centres = np.stack([c.center for c in cams])
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    assert np.abs(np.diff(steps)).max() < 0.5 * steps.mean()


def test_slerp_and_quaternions():
    axis_angle = lambda deg: quat_to_matrix([math.cos(math.radians(deg) / 2), 0, math.sin(math.radians(deg) / 2), 0])
    q0, q1 = matrix_to_quat(np.eye(3)), matrix_to_quat(axis_angle(90))
    assert np.isclose(rotation_angle(quat_to_matrix(slerp(q0, q1, 0.5))), 45)
    assert np.isclose(rotation_angle(quat_to_matrix(slerp(q0, -q1, 0.25))), 22.5)  # the shorter arc, either sign
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        back = matrix_to_quat(quat_to_matrix(q))
        assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9


def test_orbit_circles_its_centre_at_a_steady_speed():
    centre = np.array([1.0, 2.0, 3.0])
    path = orbit_path(centre, 5.0, up=(0, -1, 0), seconds=4, fps=25, elevation_deg=10)
    cams = path.cameras()
    assert len(cams) == 100 and path.loop
    d = np.array([np.linalg.norm(c.center - centre) for c in cams])
    assert np.abs(d / 5.0 - 1).max() < 0.01
    for c in cams:  # the centre projects near the image centre
        p = c.world_to_camera[:3, :3] @ centre + c.world_to_camera[:3, 3]
        assert p[2] > 0 and abs(c.fx * p[0] / p[2]) < 0.05 * c.width and abs(c.fy * p[1] / p[2]) < 0.05 * c.height
    steps = np.linalg.norm(np.diff(np.stack([c.center for c in cams] + [cams[0].center]), axis=0), axis=1)
    assert steps.max() / steps.min() < 1.1  # includes the wrap from the last frame back to the first
    assert np.linalg.norm(cams[-1].center - cams[0].center) > 0.5 * steps.mean()  # no duplicated first frame


def test_dataset_path_and_camera_like_objects():
    from assets.demo.scene import demo_cameras

    cams = demo_cameras(5, 64, 48)
    path = dataset_path(cams, fps=10)
    assert path.duration == pytest.approx(4 * 0.25) and len(path.keyframes) == 5
    assert np.allclose(path.camera_at(0.25).world_to_camera, cams[1].world_to_camera)
    k = keyframe_from(cams[2])
    assert np.allclose(k.center, cams[2].center)


def test_json_round_trip(tmp_path):
    path = orbit_path((0, 0, 0), 3.0, up=(0, -1, 0), seconds=2.5, fps=24, keyframes=6)
    path.save(tmp_path / "p.json")
    back = CameraPath.load(tmp_path / "p.json")
    assert (back.duration, back.fps, back.loop, len(back.keyframes)) == (2.5, 24.0, True, 6)
    for a, b in zip(path.cameras(), back.cameras()):
        assert np.allclose(a.world_to_camera, b.world_to_camera) and a.fx == b.fx


def good() -> dict:
    return orbit_path((0, 0, 0), 3.0, up=(0, -1, 0), keyframes=3).to_dict()


@pytest.mark.parametrize("damage,words", [
    (lambda d: "not json {", "not valid JSON"),
    (lambda d: [1, 2], "JSON object"),
    (lambda d: {**d, "keyframes": []}, "non-empty"),
    (lambda d: {**d, "fps": 0}, "fps"),
    (lambda d: {**d, "duration": "long"}, "duration"),
    (lambda d: {**d, "version": 7}, "version"),
    (lambda d: {**d, "keyframes": [{**d["keyframes"][0], "world_to_camera": [[2, 0, 0, 0], [0, 1, 0, 0],
                                                                             [0, 0, 1, 0], [0, 0, 0, 1]]}]},
     "rigid"),
    (lambda d: {**d, "keyframes": [{**d["keyframes"][0], "world_to_camera": [[1, 0], [0, 1]]}]}, "4x4"),
    (lambda d: {**d, "keyframes": [{k: v for k, v in d["keyframes"][0].items() if k != "fx"}]}, "lacks fx"),
    (lambda d: {**d, "keyframes": [{**d["keyframes"][0], "width": 640.5}]}, "whole numbers"),
    (lambda d: {**d, "keyframes": [{**d["keyframes"][0], "fy": -1}]}, "positive"),
    (lambda d: '{"keyframes": ' + "[" * 100_000 + "]" * 100_000 + "}", "nests its JSON too deeply"),
])
def test_bad_path_files_are_one_line(tmp_path, damage, words):
    bad = damage(good())
    p = tmp_path / "bad.json"
    p.write_text(bad if isinstance(bad, str) else json.dumps(bad))
    with pytest.raises(InputError) as err:
        CameraPath.load(p)
    assert words in str(err.value) and "bad.json" in str(err.value) and "\n" not in str(err.value)


def test_orbit_and_look_at_keep_the_given_up_at_the_top_of_the_image():
    """A point above the centre (along ``up``) projects above the image centre, and one to the camera's right of it
    to the right: the frames are neither upside down nor mirrored."""
    up = np.array([0.1, -1.0, 0.2])
    up /= np.linalg.norm(up)
    for key in orbit_path((1.0, 2.0, 3.0), 4.0, up=up, keyframes=5).keyframes:
        w2c = key.world_to_camera
        above = w2c[:3, :3] @ (np.array([1.0, 2.0, 3.0]) + 0.5 * up) + w2c[:3, 3]
        v = key.fy * above[1] / above[2] + key.cy
        assert v < key.cy - 1.0
        assert np.isclose(np.linalg.det(w2c[:3, :3]), 1.0)  # a rotation, not a reflection


def test_the_timing_is_checked_without_keyframes_and_frames_are_made_one_at_a_time():
    """A path with no keyframes yet (a project's; the viewer adds them) still gets its duration and fps checked;
    ``iter_cameras`` makes the frames' cameras lazily, the same ones ``cameras`` lists."""
    with pytest.raises(InputError, match="fps must be in"):
        CameraPath([], duration=1e7, fps=1e6).validate_timing("p.json")
    with pytest.raises(InputError, match="600000 frames"):
        CameraPath([], duration=1e4, fps=60).validate_timing("p.json")
    CameraPath([], duration=8, fps=30).validate_timing("p.json")
    path = orbit_path((0, 0, 0), 3.0, up=(0, -1, 0), seconds=2.0, fps=10, keyframes=4)
    frames = path.iter_cameras(64, 48)
    first = next(frames)
    assert np.allclose(first.world_to_camera, path.camera_at(0.0, 64, 48).world_to_camera)
    assert [c.world_to_camera.tolist() for c in [first, *frames]] == [c.world_to_camera.tolist()
                                                                     for c in path.cameras(64, 48)]
