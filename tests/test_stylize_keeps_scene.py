"""The stylization keeps the scene (issue 37): on the real fox at the quick preset's defaults, the stylized renders
keep the photo render's structure and still move toward the painting.

A short reconstruction of 16 neighbouring fox cameras at 1/8 size, then the quick stylization with every default
(CCFT, the content weight in its relative unit, the stroke size, the learning-rate decay) after The Starry Night,
measured on 4 views by the report's own measures (training/evaluate/measure.py): the structure distance to the
unstylized render (self-similarity of VGG features: what resembles what across the image) and the SWD ratio to the
painting (below 1: closer to it than the colour-transferred start). The settings of before issue 37 (ARF's content
unit at the paper's 0.005, the painting as large as the render, a constant rate) paint the fox out here: the second
test keeps the floor honest by running them.
"""

from __future__ import annotations

from pathlib import Path

import pytest

FOX = Path(__file__).resolve().parents[2] / "shared" / "data" / "scenes" / "fox"
STARRY = FOX.parents[1] / "styles" / "starry_night.jpg"
# Measured on this model, 16 iterations a view (256 in all): structure distance / SWD ratio with the defaults
# 0.0958 / 0.928; with the settings before issue 37 (OLD_SETTINGS) 0.1286 / 0.829. The model is a short
# reconstruction, blurrier than a user's, and the style moves less on it than on the quick reconstruction of the
# acceptance run (0.0791 / 0.798, docs/stylization.md).
MAX_STRUCTURE = 0.11
MAX_SWD_RATIO = 0.96
ITERS_PER_VIEW = 16
OLD_SETTINGS = dict(content_norm="mse", lambda_content=0.005, content_source="photo", style_scale=1.0, dc_only=False,
                    lr=0.02, lr_final=1.0, lambda_tv=0.0, k=16)


@pytest.fixture(scope="module")
def fox_model():
    from dataclasses import replace

    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
    from training.scene.loader import load_scene
    from training.scene.scene import Scene
    from training.stylize.view_order import nearest_order

    full = load_scene(FOX, downscale=8)
    pick = sorted(nearest_order(full.cameras, full.extent)[:16])
    scene = Scene(cameras=[full.cameras[i] for i in pick], images=[full.images[i] for i in pick],
                  points=full.points, point_colors=full.point_colors)
    cfg = ReconstructConfig.from_preset("quick", depth="none", random_init_points=6000, seed=0)
    cfg = replace(cfg, iterations=400, densify=replace(cfg.densify, start=60, interval=60, stop=340))
    rec = Reconstructor(scene, cfg)
    for _ in range(cfg.iterations):
        rec.step()
    return rec.gaussians.detached(), scene


def stylize_fox(fox_model, vgg, **settings) -> dict:
    """The quick stylization of the fox model with ``settings`` over the defaults, then its style and content
    measures (the report's)."""
    from training.evaluate.measure import measure_style_and_content
    from training.stylize.style_image import load_style_image
    from training.stylize.trainer import StylizeConfig, Stylizer

    model, scene = fox_model
    cfg = StylizeConfig(**{"preset": "quick", "device": "cpu", "iters_per_view": ITERS_PER_VIEW, **settings})
    stylizer = Stylizer(model, scene, load_style_image(STARRY), cfg, vgg=vgg)
    stylizer.run()
    stylizer.finish()
    metrics = measure_style_and_content(stylizer, style_views=4)
    print(f"{settings or 'defaults'}: structure distance {metrics['structure_distance']:.4f}, SWD ratio "
          f"{metrics['swd_ratio_pre_ct']:.3f}, {stylizer.iteration} iterations")
    return metrics


@pytest.mark.slow
@pytest.mark.skipif(not FOX.is_dir(), reason="needs ../shared/data/scenes/fox")
def test_the_fox_stays_the_fox_and_is_painted(fox_model, vgg):
    metrics = stylize_fox(fox_model, vgg)
    assert metrics["structure_distance"] <= MAX_STRUCTURE, "the painting replaced the scene"
    assert metrics["swd_ratio_pre_ct"] <= MAX_SWD_RATIO, "the renders did not move toward the painting"


@pytest.mark.slow
@pytest.mark.skipif(not FOX.is_dir(), reason="needs ../shared/data/scenes/fox")
def test_the_settings_before_issue_37_fail_the_floor(fox_model, vgg):
    metrics = stylize_fox(fox_model, vgg, **OLD_SETTINGS)
    assert metrics["structure_distance"] > MAX_STRUCTURE
