"""Linear colour transfer: statistics of the result, and the same map applied to SH coefficients and to renders."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from training.stylize.color_transfer import (ColorTransform, apply_to_colors, apply_to_gaussians, apply_to_image,
                                     colour_stats, fit_color_transfer, foreground_pixels)
from training.model.gaussians import Gaussians
from training.raster.rasterize import rasterize
from tests.test_view_order import look_at


def correlated_colours(rng, n, mean, mix):
    return rng.normal(size=(n, 3)) @ np.asarray(mix).T + np.asarray(mean)


def test_transformed_colours_have_the_style_mean_and_covariance():
    rng = np.random.default_rng(0)
    content = correlated_colours(rng, 5000, [0.4, 0.5, 0.3], [[0.1, 0.02, 0], [0.03, 0.08, 0.01], [0, 0.02, 0.05]])
    style = correlated_colours(rng, 3000, [0.6, 0.3, 0.2], [[0.2, 0.0, 0.05], [0.1, 0.05, 0], [0.02, 0.0, 0.1]])
    t = fit_color_transfer(content, style)
    out = content @ t.A.T + t.b  # unclipped: the map's own statistics
    mu_o, cov_o = colour_stats(out)
    mu_s, cov_s = colour_stats(style)
    assert np.allclose(mu_o, mu_s, atol=1e-10)
    assert np.allclose(cov_o, cov_s, atol=1e-10)
    # A list of images pools their pixels.
    t2 = fit_color_transfer([content[:2000].reshape(40, 50, 3), content[2000:]], style)
    assert np.allclose(t2.A, t.A) and np.allclose(t2.b, t.b)
    # Images are clipped to [0, 1] after the map, float32 out.
    img = apply_to_image(content.reshape(50, 100, 3), t)
    assert img.dtype == np.float32 and img.min() >= 0 and img.max() <= 1


def test_identity_when_statistics_already_match_and_grey_content_stays_finite():
    rng = np.random.default_rng(1)
    x = rng.uniform(size=(2000, 3))
    t = fit_color_transfer(x, x)
    assert np.allclose(t.A, np.eye(3), atol=1e-9) and np.allclose(t.b, 0, atol=1e-9)
    grey = np.repeat(rng.uniform(size=(500, 1)), 3, axis=1)  # rank-1 covariance
    tg = fit_color_transfer(grey, x)
    assert np.all(np.isfinite(tg.A)) and np.all(np.isfinite(tg.b))
    assert np.allclose(apply_to_colors(grey, tg).mean(0), x.mean(0), atol=1e-4)


def random_gaussians(n: int, degree: int, seed: int) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return Gaussians(
        means=torch.rand(n, 3, generator=g, dtype=torch.float64) * 2 - 1,
        log_scales=torch.log(torch.rand(n, 3, generator=g, dtype=torch.float64) * 0.15 + 0.05),
        quats=torch.randn(n, 4, generator=g, dtype=torch.float64),
        opacity_logits=torch.randn(n, generator=g, dtype=torch.float64),
        sh0=(torch.rand(n, 1, 3, generator=g, dtype=torch.float64) * 0.6 - 0.3),  # colours 0.42..0.58
        shN=torch.randn(n, k - 1, 3, generator=g, dtype=torch.float64) * 0.05,
        sh_degree=degree,
    )


def render(gs: Gaussians, cam) -> tuple[torch.Tensor, torch.Tensor]:
    img, alpha, _ = rasterize(gs.means, gs.quats, gs.scales, gs.opacities, gs.sh,
                              torch.as_tensor(cam.world_to_camera), torch.as_tensor(cam.K), cam.width, cam.height,
                              sh_degree=gs.sh_degree, backend="torch")
    return img, alpha


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_transform_on_sh_equals_transform_of_the_render(degree):
    gs = random_gaussians(200, degree, seed=degree)
    # A mild map that keeps every SH colour positive, so the clamp at 0 never acts.
    t = ColorTransform(A=np.array([[0.9, 0.1, 0.0], [0.05, 0.8, 0.1], [0.0, 0.2, 0.7]]), b=np.array([0.1, -0.05, 0.2]))
    gt = apply_to_gaussians(gs, t)
    assert gt.means is gs.means and gt.quats is gs.quats  # geometry untouched
    A = torch.as_tensor(t.A)
    b = torch.as_tensor(t.b)
    for k, pos in enumerate(([0, -4, 0.5], [3, -3, -1], [-3.5, 1, 2])):  # several view directions
        cam = look_at(pos, [0, 0, 0], name=f"v{k}", size=(40, 32), f=40.0)
        img, alpha = render(gs, cam)
        img_t, alpha_t = render(gt, cam)
        assert alpha.max() > 0.5
        assert torch.equal(alpha, alpha_t)
        expected = img @ A.T + alpha * b  # blending is linear: the offset arrives weighted by coverage
        assert torch.allclose(img_t, expected, atol=1e-9), (img_t - expected).abs().max()


def test_foreground_pixels_unpremultiply_covered_pixels():
    img = np.array([[[0.2, 0.4, 0.1], [0.0, 0.0, 0.0]]])
    alpha = np.array([[[0.5], [0.1]]])
    px = foreground_pixels(img, alpha)
    assert np.allclose(px, [[0.4, 0.8, 0.2]])
