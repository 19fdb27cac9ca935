"""Similarity transforms of a Gaussian model (training/model/transform.py): the same picture from the moved camera,
covariances and SH bands transformed exactly, and what is not a similarity refused."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from training.scene.pose import quat_to_matrix
from tests.raster_scenes import random_scene
from training.model.gaussians import Gaussians
from training.model.rotation import quat_to_rotmat
from training.model.sh import sh_to_rgb
from training.model.transform import sh_rotation, split_similarity, transform_gaussians
from training.raster.rasterize import rasterize


def model(n=60, degree=3, seed=0, dtype=torch.float64) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g, dtype=dtype), log_scales=torch.randn(n, 3, generator=g,
                     dtype=dtype) - 3, quats=torch.randn(n, 4, generator=g, dtype=dtype),
                     opacity_logits=torch.randn(n, generator=g, dtype=dtype),
                     sh0=torch.randn(n, 1, 3, generator=g, dtype=dtype),
                     shN=torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g, dtype=dtype), sh_degree=degree)


def similarity(scale=1.7, q=(0.3, 0.5, -0.2, 0.7), t=(1.0, 2.0, -3.0)) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = scale * quat_to_matrix(np.array(q))
    m[:3, 3] = t
    return m


def test_centres_covariances_and_view_dependent_colours_move_with_the_model():
    g = model()
    m = similarity()
    h = transform_gaussians(g, m)
    a = torch.from_numpy(m[:3, :3])
    assert torch.allclose(h.means, g.means @ a.T + torch.from_numpy(m[:3, 3]), atol=1e-12)
    cov = lambda x: quat_to_rotmat(x.quats) @ torch.diag_embed(x.scales ** 2) @ quat_to_rotmat(x.quats).mT  # noqa
    assert torch.allclose(cov(h), a @ cov(g) @ a.T, atol=1e-12)
    for cam in ([0.3, -4.0, 2.0], [5.0, 1.0, -1.0]):
        c = torch.tensor(cam, dtype=torch.float64)
        moved = torch.from_numpy(m[:3, :3] @ c.numpy() + m[:3, 3])
        assert torch.allclose(sh_to_rgb(3, h.sh, h.means, moved), sh_to_rgb(3, g.sh, g.means, c), atol=1e-12)
    assert torch.equal(h.sh0, g.sh0) and torch.equal(h.opacity_logits, g.opacity_logits)


def test_the_rotated_model_renders_the_same_picture_from_the_rotated_camera():
    means, quats, scales, opac, colors, viewmat, K = random_scene(300, 80, 60, seed=5, sh_degree=3)
    g = Gaussians(means, scales.log(), quats, torch.logit(opac), colors[:, :1].contiguous(),
                  colors[:, 1:].contiguous(), 3)
    m = similarity(scale=1.0, q=(0.9, 0.1, -0.3, 0.2), t=(0.4, -0.2, 1.0))
    h = transform_gaussians(g, m)
    before, _, _ = rasterize(g.means, g.quats, g.scales, g.opacities, g.sh, viewmat, K, 80, 60, sh_degree=3,
                             backend="cpu")
    moved_view = viewmat @ torch.from_numpy(np.linalg.inv(m)).float()
    after, _, _ = rasterize(h.means, h.quats, h.scales, h.opacities, h.sh, moved_view, K, 80, 60, sh_degree=3,
                            backend="cpu")
    assert before.abs().mean() > 0.05
    assert (before - after).abs().max() < 2e-3  # float32 model and camera


def test_identity_and_translation_keep_everything_else_bit_for_bit():
    g = model(dtype=torch.float32)
    assert transform_gaussians(g, np.eye(4)) is g
    m = np.eye(4)
    m[:3, 3] = [1, 2, 3]
    h = transform_gaussians(g, m)
    assert all(torch.equal(getattr(h, k), getattr(g, k)) for k in ("quats", "log_scales", "sh0", "shN"))


def test_sh_rotation_is_orthogonal_per_band_and_refuses_non_similarities():
    x = sh_rotation(quat_to_matrix(np.array([0.2, -0.4, 0.8, 0.1])), 3)
    assert np.allclose(x @ x.T, np.eye(15), atol=1e-12)
    assert np.allclose(sh_rotation(np.eye(3), 3), np.eye(15), atol=1e-12)
    s, r, t = split_similarity(similarity(scale=2.5))
    assert s == pytest.approx(2.5) and np.allclose(r.T @ r, np.eye(3))
    for bad, why in ((np.diag([1.0, 2.0, 1.0, 1.0]), "no shear or non-uniform"),
                     (np.diag([-1.0, 1.0, 1.0, 1.0]), "mirror"), (np.zeros((3, 3)), "4x4")):
        with pytest.raises(ValueError, match=why):
            split_similarity(bad)
