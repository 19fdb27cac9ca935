"""The numba cpu rasterizer: forward against the float64 brute force, gradients against autograd through the
PyTorch reference, edge cases, and the backend choice."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.raster_bruteforce import bruteforce_render, check_close
from tests.raster_scenes import fresh_seed, random_scene
from training.raster.rasterize import choose_backend, rasterize

INPUTS = ["means", "quats", "scales", "opacities", "colors"]


@pytest.mark.parametrize(
    "size,fx_scale,fy_ratio,principal,sh_degree,mode,tile_size",
    [
        ((61, 45), 0.9, 1.1, (0.4, 0.6), None, "RGB+D", 16),  # odd size, fx != fy, off-centre principal point
        ((64, 48), 1.2, 1.0, (0.5, 0.5), 3, "RGB+ED", 16),
        ((33, 70), 0.7, 0.8, (0.7, 0.3), 1, "RGB", 8),
        ((47, 29), 1.0, 1.0, (0.5, 0.5), None, "D", 16),
        ((40, 40), 1.0, 1.0, (0.2, 0.9), 2, "ED", 16),
        ((1, 1), 1.0, 1.0, (0.5, 0.5), None, "RGB+D", 16),  # a single pixel
    ],
)
def test_cpu_forward_matches_bruteforce(size, fx_scale, fy_ratio, principal, sh_degree, mode, tile_size):
    seed = fresh_seed("cpu-vs-brute")
    w, h = size
    n = 400 if w * h > 1 else 50
    scene = random_scene(n, w, h, seed, edge_cases=True, sh_degree=sh_degree, fx_scale=fx_scale,
                         fy_ratio=fy_ratio, principal=principal, log_scale_mean=-2.5)
    bg = torch.tensor([0.25, 0.5, 0.75])
    img, alpha, info = rasterize(*scene, w, h, sh_degree=sh_degree, background=bg, render_mode=mode, backend="cpu",
                                 tile_size=tile_size)
    rgb_ref, d_ref, a_ref, near = bruteforce_render(*scene, w, h, sh_degree=sh_degree, background=bg)
    assert info["backend"] == "cpu"
    assert img.dtype == torch.float32 and alpha.shape == (h, w, 1)
    assert img.shape == (h, w, {"RGB": 3, "D": 1, "ED": 1, "RGB+D": 4, "RGB+ED": 4}[mode])
    check_close(alpha.numpy(), a_ref, near, 1e-5, "alpha")
    if mode.startswith("RGB"):
        check_close(img[..., :3].numpy(), rgb_ref, near, 1e-5, "rgb")
    if "D" in mode:
        ref = d_ref / np.maximum(a_ref, 1e-10) if mode.endswith("ED") else d_ref
        depth_scale = max(1.0, float(scene[0][:, 2].abs().max()) + 1.0)  # depths are ~5, not ~1: relative
        if mode.endswith("ED"):  # dividing by alpha also divides the slack
            near = near / np.maximum(a_ref[..., 0], 1e-10)
        check_close(img[..., -1:].numpy() / depth_scale, ref / depth_scale, near, 1e-5, "depth", depth_scale)
    # culled Gaussians: behind the camera or in front of the near plane get radius 0
    z = info["depths"]
    assert (info["radii"][z < 0.01] == 0).all()
    assert (info["radii"] > 0).any()


def _grads(backend, scene, w, h, sh_degree, weights, bg):
    ins = [t.clone().requires_grad_(True) for t in scene[:5]]
    img, alpha, info = rasterize(*ins, *scene[5:], w, h, sh_degree=sh_degree, background=bg,
                                 render_mode="RGB+D", backend=backend)
    loss = (img * weights).sum() + (alpha[..., 0] * weights[..., 0]).sum()
    loss.backward()
    out = {name: t.grad for name, t in zip(INPUTS, ins)}
    out["means2d"] = info["means2d"].grad
    return out, info


@pytest.mark.parametrize("sh_degree", [3, None])
def test_cpu_gradients_match_torch_reference(sh_degree):
    seed = fresh_seed("cpu-grad")
    w, h = 96, 72
    scene = random_scene(5000, w, h, seed, sh_degree=sh_degree, edge_cases=True, log_scale_mean=-3.3)
    weights = torch.rand(h, w, 4, generator=torch.Generator().manual_seed(seed))
    bg = torch.tensor([0.1, 0.2, 0.3])
    got, info_cpu = _grads("cpu", scene, w, h, sh_degree, weights, bg)
    ref, info_ref = _grads("torch", scene, w, h, sh_degree, weights, bg)
    for name in INPUTS + ["means2d"]:
        g, r = got[name], ref[name]
        assert g is not None and g.shape == r.shape, name
        assert torch.isfinite(g).all(), name
        rel = float((g - r).norm() / r.norm())
        print(f"{name}: relative error {rel:.3g}")
        assert r.norm() > 0, name
        assert rel <= 1e-4, f"{name}: relative error {rel:.3g}"
    assert torch.equal(info_cpu["radii"] > 0, info_ref["radii"] > 0)
    vis = info_ref["radii"] > 0
    assert torch.allclose(info_cpu["means2d"][vis], info_ref["means2d"][vis], atol=1e-3)
    assert torch.allclose(info_cpu["depths"], info_ref["depths"], rtol=1e-6)
    assert (info_cpu["radii"] - info_ref["radii"]).abs().max() <= 1


def test_cpu_float64_inputs_give_float64_gradients():
    seed = fresh_seed("cpu-f64")
    scene = random_scene(200, 32, 24, seed, dtype=torch.float64)
    ins = [t.clone().requires_grad_(True) for t in scene[:5]]
    img, alpha, _ = rasterize(*ins, *scene[5:], 32, 24, backend="cpu")
    img.sum().backward()
    assert all(t.grad.dtype == torch.float64 and torch.isfinite(t.grad).all() for t in ins)


def test_empty_scene_renders_background():
    bg = torch.tensor([0.3, 0.6, 0.9])
    z = torch.zeros(0, 3, requires_grad=True)
    q = torch.zeros(0, 4, requires_grad=True)
    o = torch.zeros(0, requires_grad=True)
    for backend in ("cpu", "torch"):
        img, alpha, info = rasterize(z, q, z, o, z, torch.eye(4), torch.eye(3) * 10, 17, 9, background=bg,
                                     render_mode="RGB+ED", backend=backend)
        assert img.shape == (9, 17, 4)
        assert torch.allclose(img[..., :3], bg.expand(9, 17, 3))
        assert (alpha == 0).all() and (img[..., 3] == 0).all()
        img.sum().backward()
        assert info["means2d"].shape == (0, 2)


def test_all_gaussians_culled_have_zero_gradients():
    seed = fresh_seed("cpu-culled")
    means, quats, scales, opac, colors, V, K = random_scene(100, 20, 20, seed)
    means = means.clone()
    means[:, 2] = -5.0  # behind a camera that looks along +z (V is close to identity)
    ins = [t.clone().requires_grad_(True) for t in (means, quats, scales, opac, colors)]
    img, alpha, info = rasterize(*ins, V, K, 20, 20, backend="cpu")
    (img.sum() + alpha.sum()).backward()
    assert (alpha == 0).all() and (info["radii"] == 0).all()
    assert all((t.grad == 0).all() for t in ins)


def test_zero_and_huge_scales_stay_finite():
    seed = fresh_seed("cpu-scales")
    means, quats, scales, opac, colors, V, K = random_scene(50, 30, 20, seed)
    scales = scales.clone()
    scales[:10] = 0.0
    scales[10:12] = 1e4
    scales[12:14] = 1e-12
    ins = [t.clone().requires_grad_(True) for t in (means, quats, scales, opac, colors)]
    img, alpha, info = rasterize(*ins, V, K, 30, 20, render_mode="RGB+ED", backend="cpu")
    rgb_ref, d_ref, a_ref, near = bruteforce_render(means, quats, scales, opac, colors, V, K, 30, 20)
    check_close(alpha.detach().numpy(), a_ref, near, 1e-5, "alpha")
    (img.sum() + alpha.sum()).backward()
    assert torch.isfinite(img).all() and all(torch.isfinite(t.grad).all() for t in ins)


def test_backend_choice(monkeypatch):
    cpu = torch.device("cpu")
    monkeypatch.delenv("SPLATSTYLER_RASTER_BACKEND", raising=False)
    assert choose_backend("auto", cpu) == "cpu"
    assert choose_backend("torch", cpu) == "torch"
    monkeypatch.setenv("SPLATSTYLER_RASTER_BACKEND", "torch")
    assert choose_backend("auto", cpu) == "torch"
    assert choose_backend("cpu", cpu) == "cpu"  # an explicit argument wins over the environment
    with pytest.raises(ValueError):
        choose_backend("opengl", cpu)
    with pytest.raises(ValueError):
        rasterize(torch.zeros(2, 3), torch.zeros(2, 4), torch.zeros(2, 3), torch.zeros(2), torch.zeros(3, 3),
                  torch.eye(4), torch.eye(3), 8, 8)


def test_depth_order_is_a_stable_argsort():
    from training.raster.cpu_sort import depth_order

    seed = fresh_seed("depth-order")
    rng = np.random.default_rng(seed)
    for n in (0, 1, 7, 5000):
        d = (rng.standard_normal(n) * 3).astype(np.float32)
        d[: n // 3] = np.round(d[: n // 3])  # many ties, including -0.0 and 0.0
        visible = np.flatnonzero(rng.random(n) > 0.2)
        assert np.array_equal(depth_order(d, visible), visible[np.argsort(d[visible], kind="stable")])


@pytest.mark.parametrize("mode", ["ED", "D", "RGB+ED"])
def test_cpu_depth_mode_gradients_match_torch_reference(mode):
    seed = fresh_seed("cpu-grad-depth")
    w, h = 48, 36
    scene = random_scene(1000, w, h, seed, sh_degree=1, log_scale_mean=-3.0)
    weights = torch.rand(h, w, 4, generator=torch.Generator().manual_seed(seed))
    grads = {}
    for backend in ("cpu", "torch"):
        ins = [t.clone().requires_grad_(True) for t in scene[:5]]
        img, alpha, info = rasterize(*ins, *scene[5:], w, h, sh_degree=1, render_mode=mode, backend=backend)
        ((img * weights[..., : img.shape[-1]]).sum() + alpha.sum()).backward()
        grads[backend] = [t.grad for t in ins[:4]] + [info["means2d"].grad]
        if mode in ("D", "ED"):
            assert ins[4].grad is None or (ins[4].grad == 0).all()  # colours do not enter a depth-only render
    for name, g, r in zip(["means", "quats", "scales", "opacities", "means2d"], grads["cpu"], grads["torch"]):
        rel = float((g - r).norm() / r.norm())
        assert rel <= 1e-4, f"{mode} {name}: relative error {rel:.3g}"


def _cpu_grads(scene, w, h, sh_degree, mode, weights, trained):
    """Gradients of one weighted loss with only the inputs named in ``trained`` requiring grad."""
    ins = [t.clone().requires_grad_(name in trained) for name, t in zip(INPUTS, scene[:5])]
    img, alpha, info = rasterize(*ins, *scene[5:], w, h, sh_degree=sh_degree, background=torch.tensor([0.1, 0.2, 0.3]),
                                 render_mode=mode, backend="cpu")
    ((img * weights[..., : img.shape[-1]]).sum() + (alpha[..., 0] * weights[..., 0]).sum()).backward()
    out = {name: t.grad for name, t in zip(INPUTS, ins)}
    out["means2d"] = info["means2d"].grad
    return out


@pytest.mark.parametrize("sh_degree,mode", [(3, "RGB"), (None, "RGB+D"), (0, "RGB+ED")])
def test_colour_only_backward_equals_full_backward(sh_degree, mode):
    seed = fresh_seed("cpu-colour-only")
    w, h = 64, 48
    scene = random_scene(2000, w, h, seed, sh_degree=sh_degree, edge_cases=True, log_scale_mean=-3.0)
    weights = torch.rand(h, w, 4, generator=torch.Generator().manual_seed(seed))
    full = _cpu_grads(scene, w, h, sh_degree, mode, weights, INPUTS)
    colour = _cpu_grads(scene, w, h, sh_degree, mode, weights, ["colors"])
    assert full["colors"].abs().sum() > 0
    # The colour-only kernels repeat the full backward's float operations for the colour terms: bit-identical.
    assert torch.equal(colour["colors"], full["colors"])
    for name in ["means", "quats", "scales", "opacities", "means2d"]:
        assert colour[name] is None, name


@pytest.mark.parametrize("trained", [["means"], ["quats", "colors"], ["opacities"], ["scales", "opacities"]])
def test_partial_backward_keeps_the_gradients_it_computes(trained):
    """Whatever subset requires grad, the gradients computed equal the full backward's (the SH view-direction
    term of the means included), and the others stay None."""
    seed = fresh_seed("cpu-partial")
    w, h = 48, 40
    scene = random_scene(1500, w, h, seed, sh_degree=3, edge_cases=True, log_scale_mean=-3.0)
    weights = torch.rand(h, w, 4, generator=torch.Generator().manual_seed(seed))
    full = _cpu_grads(scene, w, h, 3, "RGB+D", weights, INPUTS)
    part = _cpu_grads(scene, w, h, 3, "RGB+D", weights, trained)
    for name in INPUTS:
        if name in trained:
            assert torch.equal(part[name], full[name]), name
        else:
            assert part[name] is None, name
    assert torch.equal(part["means2d"], full["means2d"])  # some geometry is trained: the screen-space gradient too


def _colour_step(scene, w, h, sh_degree, mode, colors, weights):
    c = colors.clone().requires_grad_(True)
    img, alpha, _ = rasterize(*scene[:4], c, *scene[5:], w, h, sh_degree=sh_degree, render_mode=mode, backend="cpu")
    ((img * weights[..., : img.shape[-1]]).sum() + alpha.sum()).backward()
    return img.detach(), alpha.detach(), c.grad


@pytest.mark.parametrize("sh_degree,mode", [(3, "RGB"), (None, "RGB+D")])
def test_frozen_geometry_replay_is_bit_identical(sh_degree, mode):
    """Colour-only steps on one view reuse the projection, then replay the recorded pairs: every step's
    image, alpha and colour gradient equal an uncached render's bit for bit."""
    from training.raster.cpu import FROZEN

    seed = fresh_seed("cpu-replay")
    w, h = 64, 48
    scene = random_scene(2000, w, h, seed, sh_degree=sh_degree, edge_cases=True, log_scale_mean=-3.0)
    weights = torch.rand(h, w, 4, generator=torch.Generator().manual_seed(seed))
    FROZEN.clear()
    cached = [_colour_step(scene, w, h, sh_degree, mode, scene[4] * (1 + 0.1 * i), weights) for i in range(4)]
    entry = FROZEN.newest
    assert entry is not None and entry.records is not None  # the later steps replayed
    for i, got in enumerate(cached):
        FROZEN.clear()
        ref = _colour_step(scene, w, h, sh_degree, mode, scene[4] * (1 + 0.1 * i), weights)
        for a, b in zip(got, ref):
            assert torch.equal(a, b), i


def test_frozen_geometry_is_kept_for_every_view_of_a_cycle():
    """An interleaved stylization renders view 0, 1, 2, 0, 1, 2, ...: each camera keeps its own entry (one copy of
    the geometry), records on its first visit and replays from its second, bit-identical to uncached renders. Past
    the cache's budget the first views stay served and the others are computed each time, still exactly."""
    from training.raster.cpu import FROZEN

    seed = fresh_seed("cpu-replay-cycle")
    w, h = 48, 40
    scene = random_scene(1500, w, h, seed, sh_degree=3, log_scale_mean=-3.0)
    weights = torch.rand(h, w, 4, generator=torch.Generator().manual_seed(seed))
    views = []
    for k in range(3):  # the same camera turned a little about its y axis
        a = 0.05 * k
        turn = torch.tensor([[np.cos(a), 0, np.sin(a), 0], [0, 1, 0, 0], [-np.sin(a), 0, np.cos(a), 0], [0, 0, 0, 1]],
                            dtype=scene[5].dtype)
        views.append((*scene[:5], turn @ scene[5], scene[6]))
    budget = FROZEN.max_bytes
    try:
        for max_bytes, kept in ((budget, 3), (1, 1)):
            FROZEN.clear()
            FROZEN.max_bytes = max_bytes
            cached = [_colour_step(views[i % 3], w, h, 3, "RGB", scene[4] * (1 + 0.1 * i), weights) for i in range(9)]
            assert len(FROZEN) == kept
            entries = FROZEN.entries()
            assert all(e.records is not None for e in entries) == (kept == 3)
            assert all(e.key_arrays[0] is entries[0].key_arrays[0] for e in entries)  # one geometry copy
            for i, got in enumerate(cached):
                FROZEN.clear()
                ref = _colour_step(views[i % 3], w, h, 3, "RGB", scene[4] * (1 + 0.1 * i), weights)
                for a, b in zip(got, ref):
                    assert torch.equal(a, b), (max_bytes, i)
    finally:
        FROZEN.max_bytes = budget
        FROZEN.clear()


def test_frozen_geometry_changed_in_place_is_not_reused():
    from training.raster.cpu import FROZEN

    seed = fresh_seed("cpu-replay-stale")
    w, h = 48, 40
    scene = random_scene(1000, w, h, seed, log_scale_mean=-3.0)
    weights = torch.rand(h, w, 4, generator=torch.Generator().manual_seed(seed))
    FROZEN.clear()
    for _ in range(3):  # recorded and replayed
        _colour_step(scene, w, h, None, "RGB", scene[4], weights)
    with torch.no_grad():
        scene[0][::7] += 0.05  # the same tensor, moved in place: must not be served the old projection
        scene[3][::5] *= 0.5
    got = _colour_step(scene, w, h, None, "RGB", scene[4], weights)
    FROZEN.clear()
    ref = _colour_step(scene, w, h, None, "RGB", scene[4], weights)
    for a, b in zip(got, ref):
        assert torch.equal(a, b)


def test_auto_device_follows_an_explicit_backend():
    """`reconstruct --backend cpu` on a CUDA machine must keep the model on the CPU: the cpu rasterizer takes CPU
    tensors (bench gpu's CPU run failed on the H100 with 'the cpu rasterizer needs CPU tensors, got cuda:0')."""
    import torch

    from training.raster.rasterize import resolve_device

    assert resolve_device("auto", "cpu") == torch.device("cpu")
    assert resolve_device("auto", "cuda") == torch.device("cuda")
    assert resolve_device("cpu", "auto") == torch.device("cpu")
    if not torch.cuda.is_available():
        assert resolve_device("auto") == torch.device("cpu")
