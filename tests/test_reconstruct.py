"""The Reconstructor on the demo scene at very low resolution: it learns, its config may change between steps,
NaNs are recovered from, checkpoints round-trip, and the shape/size regularizers do their job."""

import warnings

import pytest
import torch

from training.reconstruct.checkpoint import load_checkpoint, save_checkpoint
from assets.demo.scene import make_demo_scene
from training.reconstruct.densify import DensifyConfig
from training.reconstruct.metrics import constant_color_psnr
from training.model.ply_io import read_ply, write_ply
from training.reconstruct.trainer import ReconstructConfig, Reconstructor
from training.reconstruct.regularizers import scale_stats
from training.scene.scene import Scene


@pytest.fixture(scope="module")
def scene():
    d = make_demo_scene(num_views=16, width=64, height=48, num_points=1000)
    return Scene(d.cameras, d.images, points=d.points, point_colors=d.point_colors)


def test_defaults_are_the_papers_figures():
    """Hard-coded from the paper, not read from the code: a wrong constant there must fail here.

    Main paper, "Implementation Details": {lambda_s, beta1, beta2, lambda_shape, lambda_size} = {3.5, 0.1, 0.001,
    10, 1}, lambda_depth decays exponentially from 1 to 0.01. Supplementary, "Additional Implementation Details":
    reconstruction uses the original 3DGS's default settings (its 30k-iteration schedule: densification from
    iteration 500 to 15,000 every 100 with a gradient threshold of 0.0002, opacity reset every 3,000, one more SH
    degree every 1,000, D-SSIM weight 0.2)."""
    cfg = ReconstructConfig()
    assert (cfg.lambda_s, cfg.beta1, cfg.beta2, cfg.lambda_shape, cfg.lambda_size) == (3.5, 0.1, 0.001, 10, 1)
    assert (cfg.lambda_depth_start, cfg.lambda_depth_end) == (1.0, 0.01)
    paper = ReconstructConfig.from_preset("paper")
    assert (paper.iterations, paper.sh_interval, paper.lambda_dssim) == (30_000, 1000, 0.2)
    d = paper.densify
    assert (d.start, d.stop, d.interval, d.reset_every, d.grad_threshold) == (500, 15_000, 100, 3000, 0.0002)
    assert d.percent_dense == 0.01 and d.enabled and d.max_gaussians is None
    assert (paper.lr_means_init, paper.lr_means_final, paper.lr_sh0, paper.lr_scales, paper.lr_quats) == (
        1.6e-4, 1.6e-6, 0.0025, 0.005, 0.001)
    assert paper.lr_shN == pytest.approx(0.0025 / 20)
    # the presets shorten the schedule; the regularizers are the paper's in every one
    for name in ("quick", "standard"):
        short = ReconstructConfig.from_preset(name)
        assert short.iterations < 30_000
        assert (short.lambda_s, short.beta1, short.beta2, short.lambda_shape, short.lambda_size) == (
            3.5, 0.1, 0.001, 10, 1)


def test_with_iterations_stretches_the_schedule_and_leaves_the_preset_alone():
    quick = ReconstructConfig.from_preset("quick")
    half = quick.with_iterations(2500)
    d = half.densify
    assert (half.iterations, half.sh_interval, d.start, d.stop, d.interval, d.reset_every) == (
        2500, 250, 125, 1250, 84, 750)
    assert (quick.iterations, quick.densify.stop) == (5000, 2500)  # a copy, not an edit
    assert quick.with_iterations(5000) == quick


def _cfg(**kw):
    base = dict(iterations=300, sh_interval=100, device="cpu",
                densify=DensifyConfig(start=50, stop=250, interval=50, reset_every=0, max_gaussians=2000))
    base.update(kw)
    return ReconstructConfig(**base)


@pytest.mark.slow
def test_training_beats_initial_render_and_constant_colour(scene):
    r = Reconstructor(scene, _cfg())
    initial = r.evaluate(scene.test_indices)["psnr"]
    const = constant_color_psnr(scene, scene.train_indices, scene.test_indices)
    metrics = [r.step() for _ in range(300)]
    final = r.evaluate(scene.test_indices)["psnr"]
    assert not any(m["recovered"] for m in metrics)
    assert final > initial + 3.0, (initial, final)
    assert final > const + 2.0, (const, final)
    assert metrics[-1]["num_gaussians"] > 1000  # densification grew the model
    assert metrics[-1]["sh_degree"] == 3


def test_config_changes_between_steps(scene):
    r = Reconstructor(scene, _cfg(iterations=20))
    m = r.step()
    assert m["depth"] > 0 and m["size"] > 0  # the demo's SfM points give depth targets
    r.config.use_size = False
    r.config.use_depth = False
    m = r.step()
    assert m["size"] == 0 and m["depth"] == 0 and m["lambda_depth"] == 0
    r.config.use_size = True
    assert r.step()["size"] > 0


def test_nan_in_parameters_is_restored_with_a_warning(scene, tmp_path):
    r = Reconstructor(scene, _cfg(iterations=50, snapshot_every=5))
    for _ in range(10):
        r.step()
    good = r.gaussians.detached()  # the snapshot taken at step 10
    with torch.no_grad():
        r.gaussians.means[3] = float("nan")
        r.gaussians.sh0[7] = float("inf")
    with pytest.warns(RuntimeWarning, match="restored the model from step 10"):
        m = r.step()
    assert m["recovered"]
    torch.testing.assert_close(r.gaussians.means.detach(), good.means)
    for _ in range(5):
        assert not r.step()["recovered"]
    write_ply(tmp_path / "m.ply", r.export_gaussians())
    back = read_ply(tmp_path / "m.ply")
    assert all(torch.isfinite(t).all() for t in back.parameters().values())


def test_non_finite_loss_is_not_applied(scene):
    r = Reconstructor(scene, _cfg(iterations=50, snapshot_every=5))
    for _ in range(5):
        r.step()
    before = r.gaussians.detached()
    saved = r.images
    r.images = [torch.full_like(im, float("nan")) for im in saved]
    with pytest.warns(RuntimeWarning, match="loss is not finite"):
        assert r.step()["recovered"]
    r.images = saved
    torch.testing.assert_close(r.gaussians.means.detach(), before.means)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not r.step()["recovered"]


@pytest.mark.slow
def test_checkpoint_round_trip_continues_identically(scene, tmp_path):
    cfg = _cfg(iterations=60,
               densify=DensifyConfig(start=5, stop=50, interval=5, reset_every=0, max_gaussians=1500))
    a = Reconstructor(scene, cfg)
    for _ in range(12):
        a.step()
    save_checkpoint(tmp_path / "c.pt", a.state_dict())
    state = load_checkpoint(tmp_path / "c.pt")
    b = Reconstructor(scene, ReconstructConfig.from_dict(state["config"]))
    b.load_state_dict(state)
    assert b.step_count == 12 and len(b.gaussians) == len(a.gaussians)
    for _ in range(4):
        ma, mb = a.step(), b.step()
        assert ma["view"] == mb["view"]
    for k, v in a.gaussians.parameters().items():
        torch.testing.assert_close(b.gaussians.parameters()[k], v, atol=1e-5, rtol=1e-4)


def test_a_checkpoint_of_the_unfused_adam_resumes_on_the_fused_one(scene, tmp_path):
    """Checkpoints made before the trainer used the fused Adam carry fused=False in their param groups; loading
    one keeps the fast implementation, and the moments carry on (the same update as the unfused Adam's)."""
    cfg = _cfg(iterations=40, densify=DensifyConfig(start=5, stop=30, interval=5, reset_every=0, max_gaussians=1500))
    a = Reconstructor(scene, cfg)
    groups = [{"params": g["params"], "lr": g["lr"], "name": g["name"]} for g in a.optimizer.param_groups]
    a.optimizer = torch.optim.Adam(groups, lr=0.0, eps=1e-15, fused=False)  # as they were
    for _ in range(8):
        a.step()
    save_checkpoint(tmp_path / "c.pt", a.state_dict())
    state = load_checkpoint(tmp_path / "c.pt")
    assert not any(g["fused"] for g in state["optimizer"]["param_groups"])
    b = Reconstructor(scene, ReconstructConfig.from_dict(state["config"]))
    b.load_state_dict(state)
    assert all(g["fused"] for g in b.optimizer.param_groups)
    for _ in range(3):
        ma, mb = a.step(), b.step()
        assert ma["view"] == mb["view"] and not mb["recovered"]
    for k, v in a.gaussians.parameters().items():
        torch.testing.assert_close(b.gaussians.parameters()[k], v, atol=1e-5, rtol=1e-4)


@pytest.mark.slow
def test_shape_and_size_regularizers_bound_the_scales(scene):
    """Start from deliberately needle-like, oversized Gaussians: with the regularizers the 95th percentiles of
    S_max/S_min and S_max fall towards lambda_s and beta1; without them they stay far off."""
    def run(on: bool):
        r = Reconstructor(scene, _cfg(iterations=100, use_shape=on, use_size=on, use_depth=False,
                                      densify=DensifyConfig(enabled=False)))
        with torch.no_grad():
            gen = torch.Generator().manual_seed(0)
            r.gaussians.log_scales[:, 0] += torch.rand(len(r.gaussians), generator=gen) * 2.5
        for _ in range(100):
            r.step()
        return scale_stats(r.gaussians.scales.detach() / r.extent)

    off, on = run(False), run(True)
    assert off["aniso_p95"] > 8.0 and on["aniso_p95"] < 0.6 * off["aniso_p95"], (off, on)
    assert on["smax_p95"] < off["smax_p95"], (off, on)
