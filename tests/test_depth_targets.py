"""Depth targets: SfM points project where a known camera puts them; mono alignment; scenes without points."""

import numpy as np
import pytest

from training.reconstruct.depth_targets import (DepthTarget, align_inverse_depth, compute_depth_targets, project_points,
                                    sparse_depth)
from training.core.errors import InputError
from training.scene.scene import Camera, Scene


def _camera(w=4, h=4, f=10.0, c=2.0):
    return Camera("a.png", w, h, f, f, c, c, np.eye(4))


def test_points_land_in_the_expected_pixels_nearest_wins():
    cam = _camera()
    pts = np.array([
        [0.0, 0.0, 1.0],      # u = v = 2.0 -> pixel (2, 2), z 1
        [0.05, 0.0, 2.0],     # u = 2.25 -> pixel (2, 2) too, but farther: hidden
        [-0.15, -0.15, 1.0],  # u = v = 0.5 -> pixel (0, 0) (pixel centres at +0.5)
        [0.0, 0.0, -1.0],     # behind the camera
        [1.0, 0.0, 1.0],      # u = 12: outside
        [0.19, 0.0, 1.0],     # u = 3.9 -> pixel (3, 2)
    ])
    t = sparse_depth(pts, cam)
    assert t.valid.sum() == 3
    assert t.valid[2, 2] and t.depth[2, 2] == pytest.approx(1.0)
    assert t.valid[0, 0] and t.depth[0, 0] == pytest.approx(1.0)
    assert t.valid[2, 3] and t.depth[2, 3] == pytest.approx(1.0)
    assert (t.depth[~t.valid] == 0).all()


def test_projection_with_a_rotated_translated_camera():
    # camera at (0, 0, -5) looking along +z after a 90-degree turn about the world y axis
    R = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # world x -> camera z
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = [0.0, 0.0, 3.0]
    cam = Camera("b.png", 20, 10, 5.0, 5.0, 10.0, 5.0, w2c)
    px, py, z = project_points(np.array([[2.0, 1.0, 3.0]]), cam)
    pc = R @ np.array([2.0, 1.0, 3.0]) + [0.0, 0.0, 3.0]   # (-3, 1, 5)
    assert z[0] == pytest.approx(pc[2])
    assert px[0] == int(np.floor(5.0 * pc[0] / pc[2] + 10.0)) and py[0] == int(np.floor(5.0 * pc[1] / pc[2] + 5.0))
    # by hand: camera coordinates (-3, 1, 5), u = 5 * (-3/5) + 10 = 7, v = 5 * (1/5) + 5 = 6
    assert (int(px[0]), int(py[0]), float(z[0])) == (7, 6, 5.0)


def test_inverse_depth_alignment_recovers_scale_and_shift():
    rng = np.random.default_rng(0)
    z = rng.uniform(1.0, 5.0, (30, 40)).astype(np.float32)
    s, t = 2.5, 0.05
    rel = ((1.0 / z) - t) / s  # what a relative inverse-depth predictor might output
    valid = np.zeros_like(z, dtype=bool)
    valid.flat[rng.choice(z.size, 50, replace=False)] = True
    sparse = DepthTarget(np.where(valid, z, 0).astype(np.float32), valid)
    out = align_inverse_depth(rel, sparse)
    assert out.valid.all()
    np.testing.assert_allclose(out.depth, z, rtol=1e-4)
    assert align_inverse_depth(rel, DepthTarget(sparse.depth, np.zeros_like(valid))) is None


def _scene(points):
    cams = [_camera(), _camera()]
    imgs = [np.zeros((4, 4, 3), np.float32)] * 2
    return Scene(cams, imgs, points=points, point_colors=None if points is None else np.zeros_like(points))


def test_scene_without_points_sfm_falls_back_with_a_warning():
    with pytest.warns(UserWarning, match="no SfM points"):
        targets, used = compute_depth_targets(_scene(None), "sfm")
    assert targets is None and used == "none"


def test_scene_without_points_mono_is_an_input_error():
    with pytest.raises(InputError, match="no(ne| SfM)"):
        compute_depth_targets(_scene(None), "mono")


def test_mono_without_transformers_or_weights_says_how_to_provide_them():
    pts = np.array([[0.0, 0.0, 1.0]] * 20, dtype=np.float32)
    with pytest.raises(InputError, match="--mono-depth-model"):
        compute_depth_targets(_scene(pts), "mono", mono_model="/nonexistent/model/folder")


def test_sfm_targets_per_view():
    pts = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 3.0]], dtype=np.float32)
    targets, used = compute_depth_targets(_scene(pts), "sfm")
    assert used == "sfm" and len(targets) == 2
    assert targets[0].depth[2, 2] == pytest.approx(1.0)
    assert compute_depth_targets(_scene(pts), "none") == (None, "none")
