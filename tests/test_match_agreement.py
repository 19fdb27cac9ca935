"""Match agreement (training/evaluate/match_agreement.py): corresponding feature cells of two views, found by the
depth warp of the consistency metric, compared by the style feature each is assigned; on a plane where the right
correspondence is known, then on a stylizer's renders."""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_eval_metrics import plane_views
from training.evaluate.match_agreement import match_agreement, pair_agreement


def test_cells_correspond_along_the_known_disparity_of_a_plane():
    """64x48 views of the plane z = 4, the source 10 px to the right: feature cells are 8 px, so target cell column
    j (centre 8j + 4) lands at 8j - 6, in source column j - 1; column 0 falls off the source's left edge."""
    (ct, _, dt, at), (cs, _, ds, as_) = plane_views()
    labels = np.arange(6 * 8).reshape(6, 8)  # a different style feature on every cell of the target
    shifted = np.zeros_like(labels)
    shifted[:, :-1] = labels[:, 1:]  # the source's cell j sees what the target's cell j + 1 sees
    assert pair_agreement(labels, dt, at, ct, shifted, ds, as_, cs) == (6 * 7, 6 * 7)
    # the same labels without the shift: every corresponding cell disagrees
    assert pair_agreement(labels, dt, at, ct, labels, ds, as_, cs) == (0, 6 * 7)
    # a nearer surface over the source's left 20 columns hides the plane there: target columns < 30 (cells 0-3,
    # whose centres 4, 12, 20, 28 land at -6 .. 18) are not compared
    near = ds.copy()
    near[:, :20] = 2.0
    assert pair_agreement(labels, dt, at, ct, shifted, near, as_, cs) == (6 * 4, 6 * 4)
    # uncovered target pixels are not compared either
    half = at.copy()
    half[:24] = 0.0
    assert pair_agreement(labels, dt, half, ct, shifted, ds, as_, cs) == (3 * 7, 3 * 7)


def test_match_agreement_of_a_stylizer(vgg, painting):
    """On renders of a model: a view paired with itself agrees everywhere it is covered (the plan's assignment is
    a function of the features), and neighbouring views agree on a share in [0, 1]."""
    import torch

    from assets.demo.scene import make_demo_scene
    from training.evaluate.measure import render_with_depth
    from training.model.gaussian_init import gaussians_from_points
    from training.scene.scene import Scene
    from training.stylize.trainer import StylizeConfig, Stylizer

    demo = make_demo_scene(num_views=4, width=96, height=72, num_points=3000, supersample=1)
    scene = Scene(cameras=demo.cameras, images=demo.images, points=demo.points, point_colors=demo.point_colors)
    g = gaussians_from_points(demo.points, demo.point_colors, sh_degree=0)
    g.opacity_logits = torch.full_like(g.opacity_logits, 3.0)
    s = Stylizer(g, scene, painting, StylizeConfig(preset="quick", max_side=96, device="cpu"), vgg=vgg)
    images, depths, alphas = render_with_depth(s.gaussians, s.cameras)
    cfg = s.config
    args = (s.features, s.style_features, cfg.k, cfg.epsilon, cfg.tau, cfg.sinkhorn_iters)
    itself = match_agreement(images, depths, alphas, s.cameras, [1, 1], *args)
    assert itself["match_agreement"] == 1.0 and itself["match_agreement_cells"] > 40
    near = match_agreement(images, depths, alphas, s.cameras, [0, 1, 2, 3], *args)
    assert 0.0 <= near["match_agreement"] < 1.0 and near["match_agreement_cells"] > 0


@pytest.fixture(scope="module")
def painting():
    from assets.demo.painting import make_style_image

    return np.asarray(make_style_image(size=128, seed=0), dtype=np.float32)


FOX = __import__("pathlib").Path(__file__).resolve().parents[2] / "shared" / "data" / "scenes" / "fox"
STARRY = FOX.parents[1] / "styles" / "starry_night.jpg"


@pytest.mark.slow
@pytest.mark.skipif(not FOX.is_dir(), reason="needs ../shared/data/scenes/fox")
def test_guidance_raises_the_match_agreement_between_neighbouring_views(vgg):
    """The paper's claim for cross-view guidance, on a real scene: 16 neighbouring fox cameras at 1/16 size, a short
    reconstruction, then the interleaved schedule (a new view every step) stylized twice from the same model with
    the same seed, guided (lambda_guide 1) and not (0). The guided plans assign the cells two consecutive views both
    see to the same style feature more often. The painting at twice the render's size: at these 1/16-size renders
    the painting at the render's size (the default) gives so few painting features that two views agree by chance
    (unguided 0.219-0.237, 3 reconstruction seeds) and guidance adds only +0.007 to +0.017; at twice the size,
    guided 0.156-0.189, unguided 0.090-0.103, differences +0.066 to +0.086 (same seeds). The margin asked for is
    0.02."""
    from dataclasses import replace

    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
    from training.scene.loader import load_scene
    from training.scene.scene import Scene
    from training.stylize.style_image import load_style_image
    from training.stylize.trainer import StylizeConfig, Stylizer
    from training.stylize.view_order import nearest_order

    full = load_scene(FOX, downscale=16)
    pick = sorted(nearest_order(full.cameras, full.extent)[:16])
    scene = Scene(cameras=[full.cameras[i] for i in pick], images=[full.images[i] for i in pick],
                  points=full.points, point_colors=full.point_colors)
    cfg = ReconstructConfig.from_preset("quick", depth="none", random_init_points=3000, seed=0)
    cfg = replace(cfg, iterations=150, densify=replace(cfg.densify, start=40, interval=40, stop=140))
    rec = Reconstructor(scene, cfg)
    for _ in range(cfg.iterations):
        rec.step()
    model = rec.gaussians.detached()
    style = load_style_image(STARRY)
    agreement = {}
    for guide in (1.0, 0.0):
        s = Stylizer(model, scene, style, StylizeConfig(preset="quick", device="cpu", lambda_guide=guide,
                                                        iters_per_view=2, seed=0, style_scale=2.0), vgg=vgg)
        assert s.config.schedule == "interleaved"
        s.run()
        agreement[guide] = s.agreement.mean()
        print(f"lambda_guide {guide:g}: step match agreement {agreement[guide]:.4f}")
    assert agreement[1.0] > agreement[0.0] + 0.02
