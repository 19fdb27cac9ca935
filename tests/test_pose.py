"""The pose maths every part of the project shares (training/scene/pose.py), checked on the real fox capture: the
numpy EWA footprint is the rasterizer's projection, the video paths and the path consistency protocol follow one
curve, and virtual views sit on the straight line between their cameras."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from training.scene.pose import interpolate_camera, look_at, path_camera, splat_footprints

FOX = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "scenes" / "fox"


@pytest.fixture(scope="module")
def fox_cameras():
    if not FOX.is_dir():
        pytest.skip(f"{FOX} is not here")
    from training.scene.loader import load_scene

    return load_scene(FOX, downscale=8, load_images=False).cameras


def test_splat_footprints_are_the_rasterizers_projection(fox_cameras):
    """Centres and inverse covariances (conics) of Gaussians around the scene, some far to the side where the
    Jacobian's clamp matters, as the reference rasterizer computes them."""
    from training.raster.constants import EPS2D, FOV_CLAMP_MARGIN, NEAR_PLANE
    from training.raster.reference import project_gaussians
    from training.raster.rasterize import camera_matrices

    camera = fox_cameras[5]
    rng = np.random.default_rng(0)
    means = camera.unproject(rng.uniform(-0.8, 1.8, 500) * camera.width, rng.uniform(-0.8, 1.8, 500) * camera.height,
                             rng.uniform(0.5, 4.0, 500))
    q = rng.normal(size=(500, 4))
    quats = q / np.linalg.norm(q, axis=1, keepdims=True)
    scales = rng.uniform(0.005, 0.2, (500, 3))
    uv, cov = splat_footprints(camera, means, quats, scales, EPS2D, FOV_CLAMP_MARGIN)
    viewmat, K = camera_matrices(camera, torch.float64)
    ref = project_gaussians(*(torch.as_tensor(a, dtype=torch.float64) for a in (means, quats, scales)),
                            torch.ones(500, dtype=torch.float64), viewmat, K, camera.width, camera.height,
                            NEAR_PLANE, 1e10, EPS2D)
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det = a * c - b * b
    conics = np.stack([c / det, -b / det, a / det], axis=1)
    drawn = ref.radii.numpy().reshape(len(means), -1).max(axis=1) > 0  # the reference zeroes what it culls
    assert drawn.sum() > 100
    assert np.allclose(uv[drawn], ref.means2d.numpy()[drawn], rtol=1e-9, atol=1e-7)
    assert np.allclose(conics[drawn], ref.conics.numpy()[drawn], rtol=1e-7, atol=1e-9)


def test_video_paths_and_the_path_protocol_follow_one_curve(fox_cameras):
    """``splatstyler video``'s dataset path and the evaluation's smooth path through the same cameras: the same
    cameras wherever both are sampled (the protocol's frames are evenly spaced in the spline's parameter, the video's
    in time, one segment per unit of both)."""
    from app.camera_path import CameraPath
    from training.evaluate.path_consistency import smooth_path

    keys = fox_cameras[:7]
    frames = smooth_path(keys, range(len(keys)), frames=13)  # every half segment
    video = CameraPath(list(keys), duration=6.0, fps=10)
    for k, cam in enumerate(frames):
        same = video.camera_at(k * 0.5, cam.width, cam.height)
        assert np.allclose(same.world_to_camera, cam.world_to_camera, atol=1e-12)
        assert np.allclose(same.K, cam.K, rtol=1e-12)


def test_a_path_passes_through_its_keys_and_an_interpolated_camera_lies_between(fox_cameras):
    a, b = fox_cameras[0], fox_cameras[9]
    assert np.allclose(path_camera([a, b], 1.0, "end").world_to_camera, b.world_to_camera, atol=1e-6)
    mid = interpolate_camera(a, b, 0.25, "quarter")
    assert np.allclose(mid.center, 0.75 * a.center + 0.25 * b.center)
    # the quarter rotation: a quarter of the angle from a, three quarters to b
    angle = lambda r: np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))  # noqa: E731
    whole = angle(a.rotation.T @ b.rotation)
    assert angle(a.rotation.T @ mid.rotation) == pytest.approx(0.25 * whole, rel=1e-4)
    assert angle(mid.rotation.T @ b.rotation) == pytest.approx(0.75 * whole, rel=1e-4)


def test_look_at_puts_the_target_at_the_image_centre_up_side_up():
    from training.scene.camera import Camera

    w2c = look_at((1.0, -2.0, 3.0), (0.2, 0.1, -0.4), up=(0.0, 0.0, 1.0))
    cam = Camera("c", 64, 48, 50.0, 50.0, 32.0, 24.0, w2c)
    (uv,), (front,) = cam.project([(0.2, 0.1, -0.4)])
    assert front and np.allclose(uv, (32.0, 24.0))
    above, _ = cam.project([(0.2, 0.1, -0.3)])  # a point above the target is higher in the image
    assert above[0, 1] < 24.0
