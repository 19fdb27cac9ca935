"""Density control: clone / split / prune counts, the children's parameters, and Adam moments kept in step."""

import torch

from training.reconstruct.densify import PARAM_NAMES, DensifyConfig, DensifyStrategy
from training.model.gaussians import Gaussians

W = H = 100
HIGH = 0.001 / (0.5 * W)  # a pixel-space gradient whose NDC-scaled norm (0.001) exceeds the 0.0002 threshold
LOW = 0.0001 / (0.5 * W)


def _model(scales, opacities):
    n = len(scales)
    g = Gaussians(
        means=torch.arange(n * 3, dtype=torch.float32).reshape(n, 3),
        log_scales=torch.log(torch.tensor(scales, dtype=torch.float32)),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n),
        opacity_logits=torch.logit(torch.tensor(opacities, dtype=torch.float32)),
        sh0=torch.arange(n * 3, dtype=torch.float32).reshape(n, 1, 3),
        shN=torch.zeros(n, 15, 3),
        sh_degree=3,
    )
    for t in g.parameters().values():
        t.requires_grad_(True)
    opt = torch.optim.Adam([{"params": [p], "lr": 1e-3, "name": k} for k, p in g.parameters().items()], eps=1e-15)
    # one real step so every parameter has Adam moments, distinct per row
    loss = sum((p * torch.arange(1, p.numel() + 1, dtype=torch.float32).reshape(p.shape)).sum()
               for p in g.parameters().values())
    loss.backward()
    opt.step()
    opt.zero_grad()
    return g, opt


def _info(grads, radii):
    m2d = torch.zeros(len(grads), 2, requires_grad=True)
    m2d.grad = torch.tensor([[g, 0.0] for g in grads])
    return {"means2d": m2d, "radii": torch.tensor(radii, dtype=torch.int32)}


def _check_optimizer(g, opt):
    params = g.parameters()
    for group in opt.param_groups:
        p = group["params"][0]
        assert p is params[group["name"]] and p.requires_grad and p.is_leaf
        st = opt.state[p]
        assert st["exp_avg"].shape == p.shape and st["exp_avg_sq"].shape == p.shape


def test_clone_split_prune_counts_and_optimizer_state():
    #        clone   split   keep    prune (transparent)
    scales = [[0.005] * 3, [0.05, 0.03, 0.02], [0.005] * 3, [0.005] * 3]
    g, opt = _model(scales, [0.5, 0.5, 0.5, 0.001])
    before = {k: opt.state[p]["exp_avg"].clone() for k, p in g.parameters().items()}
    orig = g.detached()
    strat = DensifyStrategy(extent=1.0, num_gaussians=4)
    cfg = DensifyConfig(start=0, stop=100, interval=1, reset_every=0)
    out = strat.step_post_backward(cfg, 1, g, opt, _info([HIGH, HIGH, LOW, LOW], [5, 5, 5, 5]), W, H,
                                   torch.Generator().manual_seed(0))
    assert (out["cloned"], out["split"], out["pruned"]) == (1, 1, 1)
    assert len(g) == 4 + 1 + 2 - 1 - 1
    _check_optimizer(g, opt)
    # survivors in order: original 0, original 2, the clone of 0, the two halves of 1
    torch.testing.assert_close(g.means[:2], orig.means[[0, 2]])
    torch.testing.assert_close(g.means[2], orig.means[0])
    torch.testing.assert_close(g.sh0[3:], orig.sh0[[1, 1]])
    torch.testing.assert_close(g.scales[3:], orig.scales[[1, 1]] / 1.6)
    assert ((g.means[3:] - orig.means[1]).abs() < 5 * 0.05).all()
    assert not torch.equal(g.means[3], g.means[4])
    for k in PARAM_NAMES:
        m = opt.state[g.parameters()[k]]["exp_avg"]
        torch.testing.assert_close(m[:2], before[k][[0, 2]])  # survivors keep their moments
        assert (m[2:] == 0).all()  # new Gaussians start from zero moments
    assert strat.grad_accum.shape == (5,) and (strat.count == 0).all()


def test_gradient_is_averaged_over_the_views_that_saw_it():
    g, opt = _model([[0.005] * 3] * 2, [0.5, 0.5])
    strat = DensifyStrategy(extent=1.0, num_gaussians=2)
    cfg = DensifyConfig(start=0, stop=100, interval=3, reset_every=0)
    # Gaussian 0: seen 3 times, once with a high gradient -> mean below threshold; Gaussian 1: seen once, high
    mid = 0.0005 / (0.5 * W)  # above the threshold in one view, below it averaged over three
    for step, (grads, radii) in enumerate([([mid, 0.0], [3, 0]), ([0.0, 0.0], [3, 0]),
                                          ([0.0, HIGH], [3, 4])], start=1):
        out = strat.step_post_backward(cfg, step, g, opt, _info(grads, radii), W, H)
    assert out["cloned"] == 1 and len(g) == 3
    _check_optimizer(g, opt)


def test_prune_huge_only_after_first_reset_and_opacity_reset():
    #         fine          huge in world (> 0.1 extent)   huge on screen
    scales = [[0.01] * 3, [0.5, 0.5, 0.5], [0.01] * 3]
    g, opt = _model(scales, [0.5, 0.5, 0.5])
    first_mean = g.means[0].detach().clone()
    strat = DensifyStrategy(extent=1.0, num_gaussians=3)
    cfg = DensifyConfig(start=0, stop=100, interval=5, reset_every=10)
    info = _info([0.0, 0.0, 0.0], [3, 3, 50])
    out = strat.step_post_backward(cfg, 5, g, opt, info, W, H)  # before the first reset: nothing huge pruned
    assert out["pruned"] == 0 and len(g) == 3
    out = strat.step_post_backward(cfg, 10, g, opt, info, W, H)  # the reset itself
    assert out["reset"] and len(g) == 3
    assert (g.opacities <= 0.01 + 1e-6).all()
    assert (opt.state[g.opacity_logits]["exp_avg"] == 0).all()
    assert (opt.state[g.means]["exp_avg"] != 0).any()  # other moments untouched
    # reset made them transparent-ish, 0.01 > 0.005: only the huge ones go
    out = strat.step_post_backward(cfg, 15, g, opt, _info([0.0, 0.0, 0.0], [3, 3, 50]), W, H)
    assert out["pruned"] == 2 and len(g) == 1
    torch.testing.assert_close(g.means[0].detach(), first_mean)
    _check_optimizer(g, opt)


def _screen_pruned(radius_px: int, size: int, prune_screen: float = 0.15) -> int:
    """How many of one Gaussian (after the first opacity reset) go for its screen radius at a size x size image."""
    g, opt = _model([[0.01] * 3], [0.5])
    strat = DensifyStrategy(extent=1.0, num_gaussians=1)
    cfg = DensifyConfig(start=0, stop=100, interval=5, reset_every=2, reset_opacity=0.5,
                        prune_screen=prune_screen)
    info = _info([0.0], [radius_px])
    for step in range(1, 6):
        out = strat.step_post_backward(cfg, step, g, opt, info, size, size)
    return out["pruned"]


def test_screen_size_pruning_is_a_fraction_of_the_image():
    # the same Gaussian seen at 4x the resolution covers 4x the pixels: the decision must not change
    assert _screen_pruned(20, 100) == 1 and _screen_pruned(80, 400) == 1  # 0.2 of the long side
    assert _screen_pruned(10, 100) == 0 and _screen_pruned(40, 400) == 0  # 0.1
    assert _screen_pruned(30, 400) == 0  # 3DGS's fixed 20 px would prune this one
    assert _screen_pruned(80, 400, prune_screen=0.0) == 0  # 0 switches the rule off


def test_max_gaussians_keeps_the_largest_gradients():
    g, opt = _model([[0.005] * 3] * 4, [0.5] * 4)
    strat = DensifyStrategy(extent=1.0, num_gaussians=4)
    cfg = DensifyConfig(start=0, stop=100, interval=1, reset_every=0, max_gaussians=6)
    out = strat.step_post_backward(cfg, 1, g, opt, _info([HIGH, 3 * HIGH, 2 * HIGH, HIGH], [5] * 4), W, H)
    assert out["cloned"] == 2 and len(g) == 6
    torch.testing.assert_close(g.means[4:], g.means[[1, 2]])


def test_nothing_happens_outside_the_window():
    g, opt = _model([[0.005] * 3] * 2, [0.5, 0.001])
    strat = DensifyStrategy(extent=1.0, num_gaussians=2)
    cfg = DensifyConfig(start=10, stop=20, interval=5, reset_every=0)
    for step in (5, 10, 20, 25):  # 5, 10: not after start; 20, 25: not before stop
        out = strat.step_post_backward(cfg, step, g, opt, _info([HIGH, HIGH], [5, 5]), W, H)
        assert (out["cloned"], out["split"], out["pruned"]) == (0, 0, 0)
    assert len(g) == 2


def test_a_checkpoint_with_pixel_radii_does_not_prune_everything_on_resume():
    strat = DensifyStrategy(extent=1.0, num_gaussians=2)
    old = {"grad_accum": torch.zeros(2), "count": torch.zeros(2), "max_radii": torch.tensor([12.0, 3.0]),
           "extent": 1.0}  # as written before the radii became fractions of the long side
    strat.load_state_dict(old)
    assert (strat.max_radii == 0).all()
    strat.max_radii = torch.tensor([0.2, 0.01])
    again = DensifyStrategy(extent=1.0, num_gaussians=2)
    again.load_state_dict(strat.state_dict())
    torch.testing.assert_close(again.max_radii, torch.tensor([0.2, 0.01]))
