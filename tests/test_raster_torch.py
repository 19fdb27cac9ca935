"""The PyTorch reference rasterizer against the float64 brute force, and its gradients against finite differences."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.raster_bruteforce import bruteforce_render, check_close
from tests.raster_scenes import fresh_seed, random_scene
from training.raster.rasterize import rasterize



@pytest.mark.parametrize("mode", ["RGB+D", "RGB+ED", "RGB", "D", "ED"])
def test_torch_matches_bruteforce(mode):
    seed = fresh_seed("torch-vs-brute")
    w, h = 61, 45
    scene = random_scene(300, w, h, seed, edge_cases=True, principal=(0.4, 0.6), log_scale_mean=-2.5)
    bg = torch.tensor([0.2, 0.5, 0.9])
    img, alpha, info = rasterize(*scene, w, h, background=bg, render_mode=mode, backend="torch")
    rgb_ref, d_ref, a_ref, slack = bruteforce_render(*scene, w, h, background=bg)
    assert info["backend"] == "torch"
    check_close(alpha.numpy(), a_ref, slack, 1e-5, "alpha")
    if mode.startswith("RGB"):
        check_close(img[..., :3].numpy(), rgb_ref, slack, 1e-5, "rgb")
    if "D" in mode:
        ref = d_ref / np.maximum(a_ref, 1e-10) if mode.endswith("ED") else d_ref
        scale = max(1.0, float(np.abs(ref).max()))
        if mode.endswith("ED"):
            slack = slack / np.maximum(a_ref[..., 0], 1e-10)
        check_close(img[..., -1:].numpy() / scale, ref / scale, slack, 1e-5, "depth", scale)


def test_torch_float64_matches_bruteforce_sh():
    seed = fresh_seed("torch64-sh")
    w, h = 40, 33
    scene = random_scene(200, w, h, seed, dtype=torch.float64, sh_degree=3, edge_cases=True)
    img, alpha, _ = rasterize(*scene, w, h, sh_degree=3, render_mode="RGB+D", backend="torch")
    rgb_ref, d_ref, a_ref, _ = bruteforce_render(*scene, w, h, sh_degree=3)
    np.testing.assert_allclose(img[..., :3].numpy(), rgb_ref, atol=1e-9)
    np.testing.assert_allclose(img[..., 3:].numpy(), d_ref, atol=1e-8)
    np.testing.assert_allclose(alpha.numpy(), a_ref, atol=1e-9)


@pytest.mark.parametrize("sh_degree,fast", [(None, False), (3, True)])
def test_torch_gradients_match_finite_differences(sh_degree, fast):
    seed = fresh_seed("torch-fd")
    w, h = 20, 17
    scene = random_scene(8, w, h, seed, dtype=torch.float64, sh_degree=sh_degree, log_scale_mean=-1.5)
    means, quats, scales, opac, colors, V, K = scene
    weights = torch.rand(h, w, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))
    bg = torch.tensor([0.3, 0.1, 0.7], dtype=torch.float64)

    def f(m, q, s, o, c, b):
        img, alpha, _ = rasterize(m, q, s, o, c, V, K, w, h, sh_degree=sh_degree, background=b,
                                  render_mode="RGB+D", backend="torch")
        return (img * weights).sum() + alpha.sum()

    inputs = [t.clone().requires_grad_(True) for t in (means, quats, scales, opac, colors, bg)]
    # fast_mode checks random directional derivatives (a few forwards) instead of every input element.
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4, fast_mode=fast)
