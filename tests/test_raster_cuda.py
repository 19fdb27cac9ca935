"""Parity of the cuda (gsplat) backend with the PyTorch reference on the same GPU. Skipped without CUDA+gsplat."""

from __future__ import annotations

import pytest
import torch

from tests.raster_scenes import fresh_seed, random_scene
from training.raster.rasterize import rasterize

gsplat = pytest.importorskip("gsplat", reason="the cuda backend needs gsplat")
pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="the cuda backend needs a CUDA GPU")

INPUTS = ["means", "quats", "scales", "opacities", "colors"]


def _run(backend, scene, w, h, sh_degree, weights, mode):
    ins = [t.clone().cuda().requires_grad_(True) for t in scene[:5]]
    rest = [t.cuda() for t in scene[5:]]
    bg = torch.tensor([0.1, 0.2, 0.3], device="cuda")
    img, alpha, info = rasterize(*ins, *rest, w, h, sh_degree=sh_degree, background=bg, render_mode=mode,
                                 backend=backend)
    ((img * weights[..., : img.shape[-1]]).sum() + alpha.sum()).backward()
    grads = {n: t.grad for n, t in zip(INPUTS, ins)}
    grads["means2d"] = info["means2d"].grad
    return img.detach(), alpha.detach(), info, grads


@pytest.mark.parametrize("sh_degree,mode", [(3, "RGB+D"), (None, "RGB"), (1, "RGB+ED")])
def test_cuda_matches_torch_reference(sh_degree, mode):
    seed = fresh_seed("cuda-vs-torch")
    w, h = 97, 70
    # opacities stay below 0.95: gsplat clamps alpha at 0.999 where the reference clamps at 0.99
    scene = random_scene(3000, w, h, seed, sh_degree=sh_degree, log_scale_mean=-3.3, principal=(0.45, 0.55))
    weights = torch.rand(h, w, 4, device="cuda")
    img_c, a_c, info_c, g_c = _run("cuda", scene, w, h, sh_degree, weights, mode)
    img_t, a_t, info_t, g_t = _run("torch", scene, w, h, sh_degree, weights, mode)
    assert info_c["backend"] == "cuda"
    assert (a_c - a_t).abs().max() <= 1e-4
    assert (img_c[..., :3] - img_t[..., :3]).abs().max() <= 1e-4
    if "D" in mode:
        assert ((img_c[..., -1] - img_t[..., -1]).abs() / img_t[..., -1].abs().clamp_min(1)).max() <= 1e-4
    assert torch.equal(info_c["radii"] > 0, info_t["radii"] > 0)
    for name in INPUTS + ["means2d"]:
        rel = float((g_c[name] - g_t[name]).norm() / g_t[name].norm())
        print(f"{name}: relative error {rel:.3g}")
        assert rel <= 1e-3, f"{name}: relative error {rel:.3g}"
