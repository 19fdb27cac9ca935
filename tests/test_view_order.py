"""View orders, scene kinds and virtual cameras, on known camera layouts and on the real fox capture."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from training.scene.scene import Camera
from training.stylize.view_order import (camera_distance_matrix, greedy_path, nearest_order, path_length, random_order,
                                 scene_kind, two_opt, view_order)
from training.scene.pose import interpolate_camera, look_at as look_at_matrix, matrix_to_quat, quat_to_matrix, slerp
from training.stylize.virtual_views import trajectory

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def look_at(center, target, up=(0.0, 0.0, -1.0), name="cam", size=(64, 48), f=50.0) -> Camera:
    """A camera at ``center`` looking at ``target``, ``up`` up in its image (the layouts here have world z down)."""
    w, h = size
    return Camera(name, w, h, f, f, w / 2, h / 2, look_at_matrix(center, target, up))


def circle_cameras(n: int, radius: float = 4.0, arc_deg: float = 360.0) -> list[Camera]:
    cams = []
    for k in range(n):
        a = np.radians(arc_deg) * k / (n if arc_deg >= 360 else n - 1)
        cams.append(look_at([radius * np.cos(a), radius * np.sin(a), 0.5], [0, 0, 0], name=f"c{k}"))
    return cams


def test_nearest_recovers_circle_order_from_shuffled_cameras():
    n = 24
    cams = circle_cameras(n)
    perm = np.random.default_rng(3).permutation(n)
    shuffled = [cams[i] for i in perm]
    order = nearest_order(shuffled)
    assert sorted(order) == list(range(n))
    circle_pos = perm[order]  # position on the circle of each visited camera
    steps = np.diff(circle_pos) % n
    # An open path along the circle: every step goes to a neighbour, always in the same direction.
    assert set(steps.tolist()) in ({1}, {n - 1}), circle_pos


def test_nearest_orders_a_partial_arc_end_to_end():
    n = 15
    cams = circle_cameras(n, arc_deg=100.0)
    perm = np.random.default_rng(0).permutation(n)
    order = nearest_order([cams[i] for i in perm])
    pos = perm[order]
    assert pos.tolist() in (list(range(n)), list(range(n))[::-1])


def test_two_opt_never_lengthens_and_fixes_a_crossing():
    rng = np.random.default_rng(1)
    for trial in range(20):
        pts = rng.normal(size=(12, 3))
        dist = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
        start = rng.permutation(12).tolist()
        for initial in (start, greedy_path(dist, int(rng.integers(12)))):
            improved = two_opt(initial, dist)
            assert sorted(improved) == list(range(12))
            assert path_length(improved, dist) <= path_length(initial, dist) + 1e-12
    # Points on a line visited as 0 2 1 3: 2-opt must straighten it.
    pts = np.arange(4.0)[:, None]
    dist = np.abs(pts - pts.T)
    assert path_length(two_opt([0, 2, 1, 3], dist), dist) == pytest.approx(3.0)


def test_distance_combines_position_and_angle():
    a = look_at([0, 0, 0], [0, 1, 0], name="a")
    b = look_at([0, 0, 0], [1, 0, 0], name="b")  # same place, 90 degrees turned
    c = look_at([1, 0, 0], [1, 1, 0], name="c")  # moved by 1, same direction
    d = camera_distance_matrix([a, b, c], extent=2.0)
    assert d[0, 1] == pytest.approx(np.pi / 2)
    assert d[0, 2] == pytest.approx(0.5)
    assert np.allclose(d, d.T)


def test_random_order_is_seeded_permutation_and_dataset_is_identity():
    cams = circle_cameras(10)
    assert view_order(cams, "dataset") == list(range(10))
    r1, r2 = view_order(cams, "random", seed=5), random_order(10, seed=5)
    assert r1 == r2 and sorted(r1) == list(range(10)) and r1 != list(range(10))
    # The seed decides the order: the same one again repeats it, others give other orders (not a fixed shuffle).
    assert view_order(cams, "random", seed=5) == r1
    others = {tuple(view_order(cams, "random", seed=s)) for s in range(6, 12)}
    assert tuple(r1) not in others and len(others) == 6
    with pytest.raises(ValueError):
        view_order(cams, "spiral")


def test_scene_kind_forward_facing_layout():
    # LLFF-like: cameras on a small grid in a plane, all looking roughly down +y at a scene 5 units away.
    cams = []
    for i, x in enumerate(np.linspace(-0.5, 0.5, 4)):
        for j, z in enumerate(np.linspace(-0.3, 0.3, 3)):
            cams.append(look_at([x, 0, z], [x * 0.3, 5.0, z * 0.3], name=f"f{i}{j}"))
    assert scene_kind(cams) == "forward"
    assert scene_kind(circle_cameras(30)) == "360"
    assert scene_kind(cams, override="360") == "360"
    with pytest.raises(ValueError):
        scene_kind(cams, override="sideways")


def fox_cameras() -> list[Camera]:
    from training.scene.loader import load_scene

    path = SHARED / "data" / "scenes" / "fox"
    if not path.exists():
        pytest.skip(f"real scene not available: {path}")
    return load_scene(path, load_images=False).cameras


def test_scene_kind_of_fox_partial_orbit_is_360():
    # The fox capture is a ~100 degree arc of cameras looking in at the subject, viewing directions up to ~53
    # degrees from their mean: each view sees the subject from a different side, which is the 360 case.
    assert scene_kind(fox_cameras()) == "360"


def test_nearest_on_fox_is_no_longer_than_dataset_order():
    cams = fox_cameras()
    dist = camera_distance_matrix(cams)
    order = nearest_order(cams)
    assert sorted(order) == list(range(len(cams)))
    assert path_length(order, dist) <= path_length(list(range(len(cams))), dist) + 1e-9


def test_quaternion_round_trip_and_slerp():
    rng = np.random.default_rng(2)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        R = quat_to_matrix(q)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1.0)
        assert np.allclose(quat_to_matrix(matrix_to_quat(R)), R, atol=1e-12)
    # About z: 0 and 90 degrees; the midpoint is 45 degrees, the endpoints come back exactly.
    q0 = np.array([1.0, 0, 0, 0])
    q1 = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    mid = slerp(q0, q1, 0.5)
    assert np.allclose(mid, [np.cos(np.pi / 8), 0, 0, np.sin(np.pi / 8)], atol=1e-12)
    assert np.allclose(slerp(q0, q1, 0.0), q0) and np.allclose(slerp(q0, q1, 1.0), q1)
    assert np.allclose(slerp(q0, -q1, 0.5), mid)  # the short way round, whatever the sign of q1
    # Constant angular speed: at t the angle is t times the whole.
    for t in (0.1, 0.3, 0.8):
        q = slerp(q0, q1, t)
        assert 2 * np.arccos(q[0]) == pytest.approx(t * np.pi / 2)


def test_interpolated_cameras_endpoints_and_midpoint():
    a = look_at([4, 0, 0], [0, 0, 0], name="a", f=40.0)
    b = look_at([0, 4, 0], [0, 0, 0], name="b", f=60.0)
    for t, cam in ((0.0, a), (1.0, b)):
        c = interpolate_camera(a, b, t, "c")
        assert np.allclose(c.world_to_camera, cam.world_to_camera, atol=1e-12)
        assert c.fx == pytest.approx(cam.fx)
    mid = interpolate_camera(a, b, 0.5, "mid")
    assert np.allclose(mid.center, [2, 2, 0])
    assert mid.fx == pytest.approx(50.0)
    # Rotation halfway: the forward direction bisects the two, and stays orthonormal.
    fwd = (a.forward + b.forward) / np.linalg.norm(a.forward + b.forward)
    assert np.allclose(mid.forward, fwd, atol=1e-12)
    R = mid.world_to_camera[:3, :3]
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_trajectory_inserts_virtual_views_between_consecutive_views():
    cams = circle_cameras(4)
    items = trajectory(cams, [2, 0, 1, 3], virtual_views=2)
    assert len(items) == 4 + 3 * 2
    assert [it.source_index for it in items] == [2, None, None, 0, None, None, 1, None, None, 3]
    assert all(it.is_virtual for it in items if it.source_index is None)
    assert np.allclose(items[1].camera.center, cams[2].center + (cams[0].center - cams[2].center) / 3)
    assert [it.source_index for it in trajectory(cams, [1, 0], 0)] == [1, 0]
