"""RGBA captures (Blender / NeRF-synthetic style): the colour stored under alpha 0 is arbitrary and must never be
a training or evaluation target; images are composited over the render's background, as 3DGS does."""

import numpy as np
import torch

from training.model.gaussians import Gaussians
from training.reconstruct.metrics import evaluate_views
from training.reconstruct.trainer import ReconstructConfig, Reconstructor
from training.scene.scene import Camera, Scene, over_background


def _rgba_scene() -> Scene:
    w, h = 24, 16
    cams = []
    for k in range(3):
        pose = np.eye(4)
        pose[0, 3] = 0.1 * k
        cams.append(Camera(f"v{k}.png", w, h, 20.0, 20.0, w / 2, h / 2, pose))
    red = np.zeros((h, w, 3), np.float32)
    red[..., 0] = 1.0  # what the file stores under full transparency
    masks = [np.zeros((h, w), np.float32) for _ in cams]
    return Scene(cameras=cams, images=[red.copy() for _ in cams], masks=masks,
                 points=np.random.default_rng(0).normal(0, 0.2, (50, 3)).astype(np.float32) + [0, 0, 3],
                 point_colors=np.full((50, 3), 0.5, np.float32))


def _empty_model() -> Gaussians:
    # a single Gaussian far behind every camera: renders are pure background
    z = torch.zeros
    return Gaussians(means=torch.tensor([[0.0, 0.0, -100.0]]), log_scales=z(1, 3), quats=torch.tensor([[1.0, 0, 0, 0]]),
                     opacity_logits=z(1), sh0=z(1, 1, 3), shN=z(1, 15, 3), sh_degree=3)


def test_over_background_numpy_and_torch_agree():
    rng = np.random.default_rng(1)
    img, a, bg = rng.random((5, 7, 3)), rng.random((5, 7)), rng.random(3)
    want = img * a[..., None] + bg * (1 - a[..., None])
    np.testing.assert_allclose(over_background(img, a, bg), want)
    np.testing.assert_allclose(over_background(torch.from_numpy(img), torch.from_numpy(a), torch.from_numpy(bg)), want)
    np.testing.assert_allclose(over_background(img, a), img * a[..., None])
    assert over_background(img, None, bg) is img


def test_transparent_pixels_are_background_in_evaluation():
    scene = _rgba_scene()
    black = evaluate_views(_empty_model(), scene, [0, 1])
    assert black["psnr"] > 40  # the render is black and so is the composited target
    white = evaluate_views(_empty_model(), scene, [0, 1], background=torch.ones(3))
    assert white["psnr"] > 40


def test_training_target_follows_the_background():
    scene = _rgba_scene()
    for background in ("black", "white"):
        cfg = ReconstructConfig.from_preset("quick", iterations=5, downscale=1, depth="none", backend="cpu",
                                            background=background)
        trainer = Reconstructor(scene, cfg, gaussians=_empty_model())
        m = trainer.step()
        assert m["l1"] < 1e-6, background  # red under alpha 0 would give an L1 of 1/3
