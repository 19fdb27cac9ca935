"""Style losses on real VGG features of a real painting and a real photo: capacity control and the baselines."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

import training.stylize.vgg_weights as vw
from training.stylize.style_losses import CCFTStyleLoss, GramStyleLoss, NNFMStyleLoss, make_style_loss
from training.stylize.vgg_features import VGGFeatures

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def _load_rgb(path: Path, long_side: int) -> torch.Tensor:
    from training.scene.image_io import read_image

    img = torch.from_numpy(read_image(path)).permute(2, 0, 1)[None]
    h, w = img.shape[2:]
    s = long_side / max(h, w)
    return F.interpolate(img, size=(round(h * s), round(w * s)), mode="bilinear", antialias=True,
                         align_corners=False)


@pytest.fixture(scope="module")
def feats():
    """VGG features (1, 768, h, w) of a fox photo, the next fox photo and The Starry Night, downsized."""
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} (the shared real data) is absent")
    weights = vw._from_converted_cache() or vw.resolve_vgg_weights()
    vgg = VGGFeatures(weights)
    with torch.no_grad():
        photo = vgg(_load_rgb(SHARED / "data/scenes/fox/images/0001.jpg", 192))
        photo2 = vgg(_load_rgb(SHARED / "data/scenes/fox/images/0003.jpg", 192))
        style = vgg(_load_rgb(SHARED / "data/styles/starry_night.jpg", 192))
    return photo, photo2, style


def test_utilisation_and_entropy_rise_strictly_with_tau(feats):
    photo, _, style = feats
    stats = []
    for tau in (0.01, 0.1, 1.0):
        _, s = make_style_loss("ccft", tau=tau)(photo, style)
        stats.append(s)
    util = [s["utilisation"] for s in stats]
    ent = [s["column_entropy"] for s in stats]
    assert util[0] < util[1] < util[2], util
    assert ent[0] < ent[1] < ent[2], ent
    assert util[2] - util[0] > 0.2  # a real effect, not rounding
    # the support does not depend on tau: the same reachable set each time
    assert len({s["reachable_fraction"] for s in stats}) == 1


def test_ccft_uses_more_distinct_style_features_than_nnfm(feats):
    photo, _, style = feats
    m = style.shape[2] * style.shape[3]
    ccft = CCFTStyleLoss()  # default tau = 0.5
    _, sc = ccft(photo, style)
    _, sn = NNFMStyleLoss()(photo, style)
    used_ccft = sc["utilisation"] * sc["reachable_fraction"] * m  # style features given at least half a fair share
    assert used_ccft > 1.5 * sn["distinct_count"], (used_ccft, sn["distinct_count"])
    assert sc["column_entropy"] > sn["column_entropy"] + 0.5


def test_nnfm_is_the_mean_nearest_cosine_distance(feats):
    photo, _, style = feats
    X = photo[0].flatten(1).t().double().requires_grad_(True)
    Y = style[0].flatten(1).t().double()
    nnfm = NNFMStyleLoss(chunk_elements=100 * style.shape[2] * style.shape[3] + 7)  # several chunks, a ragged one
    loss, stats = nnfm(X.t().reshape(photo.shape), Y.t().reshape(style.shape))
    D = 1 - F.normalize(X, dim=1) @ F.normalize(Y, dim=1).t()
    ref = D.min(dim=1).values.mean()
    torch.testing.assert_close(loss, ref, rtol=1e-12, atol=1e-12)
    assert stats["distinct_count"] == len(torch.unique(D.argmin(dim=1)))
    # the gradient pulls each rendered feature toward its nearest style feature only
    (g,) = torch.autograd.grad(loss, X)
    (g_ref,) = torch.autograd.grad(ref, X)
    torch.testing.assert_close(g, g_ref, rtol=1e-9, atol=1e-12)


def test_gram_loss_matches_definition_and_sees_only_feature_statistics(feats):
    photo, _, style = feats
    loss, stats = GramStyleLoss()(photo, style)
    Fr = photo[0].flatten(1).double()
    Fs = style[0].flatten(1).double()
    ref = ((Fr @ Fr.t() / Fr.shape[1] - Fs @ Fs.t() / Fs.shape[1]) ** 2).mean()
    assert abs(float(loss) - float(ref)) <= 1e-4 * float(ref)
    assert stats["loss"] == pytest.approx(float(loss))
    assert float(GramStyleLoss()(style, style)[0]) == 0.0
    # Another image with the painting's feature statistics: its pixels shuffled and tiled 2 x 2. Its Gram matrix
    # (normalised by the pixel count) is the painting's, so the loss must vanish to rounding; a loss that looked at
    # positions, or normalised by anything but the pixel count, would not.
    g = torch.Generator().manual_seed(0)
    c, h, w = style.shape[1:]
    shuffled = style.flatten(2)[:, :, torch.randperm(h * w, generator=g)].reshape(1, c, h, w)
    same_stats = shuffled.repeat(1, 1, 2, 2)
    assert float(GramStyleLoss()(same_stats, style)[0]) <= 1e-6 * float(ref)
    # The gradient reaches the render's features only, and it is that of the definition.
    X = photo.double().requires_grad_(True)
    S = style.double().requires_grad_(True)
    (gx, gs) = torch.autograd.grad(GramStyleLoss()(X, S)[0], (X, S), allow_unused=True)
    Xf = X[0].flatten(1)
    (gx_ref,) = torch.autograd.grad(((Xf @ Xf.t() / Xf.shape[1] - Fs @ Fs.t() / Fs.shape[1]) ** 2).mean(), X)
    assert gs is None or not gs.any()
    torch.testing.assert_close(gx, gx_ref, rtol=1e-9, atol=1e-15)


def test_ccft_interface_keeps_the_guide_between_views(feats):
    photo, photo2, style = feats
    loss_fn = make_style_loss("ccft", tau=0.5, k=16)
    assert loss_fn.guide is None
    x = photo.clone().requires_grad_(True)
    loss, stats = loss_fn(x, style)
    loss.backward()
    assert x.grad is not None and torch.isfinite(x.grad).all() and float(x.grad.abs().sum()) > 0
    guide = loss_fn.guide
    assert guide is not None and guide.shape == (style.shape[2] * style.shape[3], 768)
    # the next view is matched under the previous view's guide: the support differs from an unguided one
    _, _ = loss_fn(photo2, style)
    guided = loss_fn.last_result.plan.indices
    loss_fn.reset_guide()
    assert loss_fn.guide is None
    loss_fn.lambda_guide = 0.0
    _, _ = loss_fn(photo2, style)
    plain = loss_fn.last_result.plan.indices
    assert (guided.sort(dim=1).values != plain.sort(dim=1).values).any(dim=1).float().mean() > 0.05
    # parameters are live attributes
    loss_fn.tau = 0.01
    _, low = loss_fn(photo, style)
    assert low["utilisation"] < stats["utilisation"]
    # a style image at another resolution: the stale guide is dropped instead of failing
    loss_fn.lambda_guide = 1.0
    small_style = F.avg_pool2d(style, 2)
    _, s = loss_fn(photo, small_style)
    assert loss_fn.guide.shape[0] == small_style.shape[2] * small_style.shape[3]


def test_make_style_loss_names():
    assert isinstance(make_style_loss("NNFM"), NNFMStyleLoss)
    assert isinstance(make_style_loss("gram"), GramStyleLoss)
    assert make_style_loss("ccft", epsilon=0.01).epsilon == 0.01
    with pytest.raises(ValueError, match="unknown style loss"):
        make_style_loss("adain")
    with pytest.raises(TypeError):
        make_style_loss("ccft", temperature=1.0)
