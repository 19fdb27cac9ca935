"""Initial Gaussians: 3DGS's 3-NN scale against a float64 brute force, random init inside the camera frustums,
and errors for empty or degenerate point clouds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from training.core.errors import InputError
from training.model.gaussian_init import (MIN_SCALE_RELATIVE, RANDOM_NEAR, gaussians_from_points, gaussians_random,
                                          random_view_points)
from training.model.gaussians import sh0_to_rgb
from training.scene.pose import look_at as look_at_matrix
from training.scene.scene import Camera, Scene


def brute_force_rms_3nn(points: np.ndarray) -> np.ndarray:
    p = points.astype(np.float64)
    d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    return np.sqrt(np.sort(d2, axis=1)[:, :3].mean(axis=1))


@pytest.mark.parametrize("degree", [0, 3])
def test_from_points_matches_3dgs_init(degree):
    rng = np.random.default_rng(0)
    # Anisotropic, clustered cloud so that spacings vary by orders of magnitude.
    pts = np.concatenate([rng.normal(size=(200, 3)) * [5.0, 1.0, 0.2], rng.normal(size=(100, 3)) * 0.01 + 3.0])
    cols = rng.uniform(size=(300, 3))
    g = gaussians_from_points(pts, cols, sh_degree=degree)
    assert g.sh_degree == degree and len(g) == 300
    expect = brute_force_rms_3nn(pts)
    for axis in range(3):  # isotropic
        np.testing.assert_allclose(g.scales[:, axis].double().numpy(), expect, rtol=1e-5)
    np.testing.assert_allclose(g.means.numpy(), pts, rtol=1e-6)
    assert torch.equal(g.rotations, torch.tensor([[1.0, 0, 0, 0]]).expand(300, 4))
    np.testing.assert_allclose(g.opacities.numpy(), 0.1, rtol=1e-6)  # 3DGS: inverse_sigmoid(0.1)
    np.testing.assert_allclose(sh0_to_rgb(g.sh0[:, 0]).numpy(), cols, atol=1e-6)
    assert g.shN.shape == (300, (degree + 1) ** 2 - 1, 3) and not g.shN.any()


def test_uint8_colours_and_torch_input():
    rng = np.random.default_rng(1)
    pts = torch.from_numpy(rng.normal(size=(20, 3)).astype(np.float32))
    cols = rng.integers(0, 256, size=(20, 3)).astype(np.uint8)
    g = gaussians_from_points(pts, cols)
    np.testing.assert_allclose(sh0_to_rgb(g.sh0[:, 0]).numpy(), cols / 255.0, atol=1e-6)


def test_coincident_points_get_a_small_positive_scale():
    rng = np.random.default_rng(2)
    pts = np.concatenate([np.zeros((5, 3)), rng.uniform(-1, 1, size=(50, 3))])
    g = gaussians_from_points(pts, None)
    scales = g.scales[:, 0].double().numpy()
    diag = np.linalg.norm(pts.max(0) - pts.min(0))
    assert torch.isfinite(g.log_scales).all()
    np.testing.assert_allclose(scales[:5], MIN_SCALE_RELATIVE * diag, rtol=1e-5)
    np.testing.assert_allclose(scales[5:], np.maximum(brute_force_rms_3nn(pts)[5:], MIN_SCALE_RELATIVE * diag),
                               rtol=1e-5)


def test_two_points_use_the_one_neighbour():
    g = gaussians_from_points(np.array([[0.0, 0, 0], [0, 0, 2.0]]), None)
    np.testing.assert_allclose(g.scales.numpy(), 2.0, rtol=1e-6)


@pytest.mark.parametrize("pts, words", [
    (np.zeros((0, 3)), "empty"),
    (np.array([[0.0, 0, 0], [1, np.nan, 0], [1, 1, 1]]), "1 of 3 points have NaN"),
    (np.ones((7, 3)), "all 7 points lie at one position"),
    (np.ones((1, 3)), "all 1 points"),
])
def test_degenerate_point_clouds_name_the_source(pts, words):
    with pytest.raises(InputError) as info:
        gaussians_from_points(pts, None, source="scene/sparse/0/points3D.bin")
    assert str(info.value).startswith("scene/sparse/0/points3D.bin: ")
    assert words in str(info.value)


def look_at(center, target, name, w=64, h=48, f=40.0) -> Camera:
    """A camera at ``center`` looking at ``target``, world -z up in its image, its principal point off centre."""
    return Camera(name, w, h, f, f * 1.1, w * 0.45, h * 0.55, look_at_matrix(center, target, up=(0.0, 0.0, -1.0)))


def ring_scene(n=9) -> Scene:
    cams = [look_at([4 * np.cos(a), 4 * np.sin(a), 1.0 + 0.3 * np.sin(3 * a)], [0.2, -0.1, 0.0], f"c{i}")
            for i, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False))]
    return Scene(cameras=cams, images=[])


def project(cam: Camera, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pc = pts @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
    uv = pc[:, :2] / pc[:, 2:3] * [cam.fx, cam.fy] + [cam.cx, cam.cy]
    return uv, pc[:, 2]


def test_random_init_lies_inside_the_training_frustums():
    scene = ring_scene()
    train = [scene.cameras[i] for i in scene.train_indices]
    assert scene.test_indices == [0, 8]
    n = 4000
    pts = random_view_points(scene, n, seed=3)
    inside_any = np.zeros(n, bool)
    hits_per_camera = []
    for cam in train:
        uv, z = project(cam, pts)
        far = np.linalg.norm(cam.center - scene.center) + scene.extent
        ok = ((uv[:, 0] >= 0) & (uv[:, 0] <= cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] <= cam.height)
              & (z >= RANDOM_NEAR * scene.extent * (1 - 1e-9)) & (z <= far * (1 + 1e-9)))
        inside_any |= ok
        hits_per_camera.append(int(ok.sum()))
    assert inside_any.all()
    # Every training camera contributed its own share (~n / 7 points each, plus overlaps).
    assert min(hits_per_camera) > n / len(train) * 0.8


def test_random_depths_are_uniform_in_frustum_volume():
    cam = look_at([0.0, 0, 0], [0.0, 5, 0], "only")
    scene = Scene(cameras=[cam], images=[], extent=2.0)
    pts = random_view_points(scene, 20000, seed=0)
    _, z = project(cam, pts)
    near, far = RANDOM_NEAR * 2.0, 0.0 + 2.0
    assert z.min() >= near * (1 - 1e-9) and z.max() <= far * (1 + 1e-9)
    # For density ~ z^2 the CDF is (z^3 - near^3) / (far^3 - near^3); a uniform-in-depth draw would fail this.
    for q in (0.1, 0.5, 0.9):
        expect = np.cbrt(near**3 + q * (far**3 - near**3))
        assert abs(np.quantile(z, q) - expect) < 0.02 * far, q


def test_random_init_model_is_deterministic_and_valid():
    scene = ring_scene()
    a = gaussians_random(scene, 500, sh_degree=1, seed=7)
    b = gaussians_random(scene, 500, sh_degree=1, seed=7)
    c = gaussians_random(scene, 500, sh_degree=1, seed=8)
    assert len(a) == 500 and a.sh_degree == 1
    for name, t in a.parameters().items():
        assert torch.equal(t, b.parameters()[name]), name
    assert not torch.equal(a.means, c.means)
    assert torch.isfinite(a.log_scales).all()
    np.testing.assert_allclose(a.scales[:, 0].double().numpy(), brute_force_rms_3nn(a.means.double().numpy()),
                               rtol=1e-4)
    rgb = sh0_to_rgb(a.sh0[:, 0])
    assert rgb.min() >= -1e-6 and rgb.max() <= 1 + 1e-6 and rgb.std() > 0.2


def test_random_init_needs_cameras():
    with pytest.raises(InputError, match="no cameras"):
        gaussians_random(Scene(cameras=[], images=[], source=None), 100)


def test_random_init_on_fox_lands_in_its_training_views():
    fox = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "scenes" / "fox"
    if not fox.exists():
        pytest.skip(f"shared data not found at {fox}")
    from training.scene.loader import load_scene

    scene = load_scene(fox, load_images=False)
    g = gaussians_random(scene, 3000, sh_degree=3, seed=0)
    pts = g.means.double().numpy()
    inside = np.zeros(len(pts), bool)
    for i in scene.train_indices:
        cam = scene.cameras[i]
        uv, z = project(cam, pts)
        inside |= ((z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= cam.width) & (uv[:, 1] >= 0)
                   & (uv[:, 1] <= cam.height))
    assert inside.all()
    assert torch.isfinite(g.log_scales).all() and len(g) == 3000
