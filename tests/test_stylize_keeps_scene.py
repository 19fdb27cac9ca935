"""Every painting paints and the scene stays (issues 37 and 48): on the real fox at the quick preset's defaults, the
stylized renders keep the unstylized render's structure and move toward the painting, for three paintings unlike
each other (strokes, a figure's swirls, cubist planes); and it is the content term that keeps the scene.

A short reconstruction of 16 neighbouring fox cameras at 1/8 size, then the quick stylization, measured on 4 views
by the report's own measures (training/evaluate/measure.py): the structure distance to the unstylized render
(self-similarity of VGG features: what resembles what across the image) and the SWD ratio to the painting (below 1:
closer to it than the colour-transferred start). The model is a short reconstruction, blurrier than a user's, so the
figures differ from the grid's (docs/stylization.md, "Every painting").
"""

from __future__ import annotations

from pathlib import Path

import pytest

FOX = Path(__file__).resolve().parents[2] / "shared" / "data" / "scenes" / "fox"
STYLES = FOX.parents[1] / "styles"
PAINTINGS = ("starry_night", "the_scream", "udnie")
# Measured on this model, 16 iterations a view (256 in all), structure distance / SWD ratio:
# - the defaults: starry_night 0.1007 / 0.867, the_scream 0.1037 / 0.859, udnie 0.0714 / 0.845;
# - the content term off (lambda_content 0), The Starry Night: 0.1262 / 0.762;
# - the defaults before issue 48 (a constant content weight, the painting at twice the render's size, TV 40, no
#   feature statistics), which left most paintings a tint: starry_night 0.0956 / 0.941, the_scream 0.1045 / 0.909,
#   udnie 0.0623 / 0.954. The SWD ceiling sits between the two sets of runs.
MAX_STRUCTURE = 0.115
MAX_SWD_RATIO = 0.89
ITERS_PER_VIEW = 16


def small_fox_model():
    """(model, scene): 400 reconstruction steps on 16 neighbouring fox cameras at 1/8 size."""
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


@pytest.fixture(scope="module")
def fox_model():
    """The module's (model, scene), made once for its four tests (small_fox_model).
    Slow: loading the 67 fox photos at 1/8 size and 400 reconstruction steps on 16 of them on the CPU, densification
    included; the first painting's setup pays it (43.66 s of setup in a clean-clone CI run on 2 cores)."""
    return small_fox_model()


def stylize_fox(fox_model, vgg, painting: str, **settings) -> dict:
    """The quick stylization of the fox model after ``painting`` with ``settings`` over the defaults, then its
    style and content measures (the report's)."""
    from training.evaluate.measure import measure_style_and_content
    from training.stylize.style_image import load_style_image
    from training.stylize.trainer import StylizeConfig, Stylizer

    model, scene = fox_model
    cfg = StylizeConfig(**{"preset": "quick", "device": "cpu", "iters_per_view": ITERS_PER_VIEW, **settings})
    stylizer = Stylizer(model, scene, load_style_image(STYLES / f"{painting}.jpg"), cfg, vgg=vgg)
    stylizer.run()
    stylizer.finish()
    metrics = measure_style_and_content(stylizer, style_views=4)
    print(f"{painting} {settings or 'defaults'}: structure distance {metrics['structure_distance']:.4f}, SWD ratio "
          f"{metrics['swd_ratio_pre_ct']:.3f}, {stylizer.iteration} iterations")
    return metrics


@pytest.mark.slow
@pytest.mark.skipif(not FOX.is_dir(), reason="needs ../shared/data/scenes/fox")
@pytest.mark.parametrize("painting", PAINTINGS)
def test_the_fox_stays_the_fox_and_is_painted(fox_model, vgg, painting):
    """The quick stylization of the fox model after the painting keeps the scene (structure distance to the
    unstylized render at most MAX_STRUCTURE) and moves toward the painting (SWD ratio to the colour-transferred start
    at most MAX_SWD_RATIO).
    Slow: 256 quick-preset CCFT steps (16 a view over 16 views; VGG-16 forward and backward on the CPU at the fox's
    1/8 size), the post colour transfer's renders of every view, and the report's style and content measures on 4
    views (47.2 s starry_night, 44.8 s the_scream, 53.5 s udnie in a clean-clone CI run on 2 cores; the 43.66 s of
    setup before the first are the fox_model fixture's)."""
    metrics = stylize_fox(fox_model, vgg, painting)
    assert metrics["structure_distance"] <= MAX_STRUCTURE, "the painting replaced the scene"
    assert metrics["swd_ratio_pre_ct"] <= MAX_SWD_RATIO, "the renders did not move toward the painting"


@pytest.mark.slow
@pytest.mark.skipif(not FOX.is_dir(), reason="needs ../shared/data/scenes/fox")
def test_without_the_content_term_the_painting_replaces_the_scene(fox_model, vgg):
    """The same run with the content weight at 0 (the budget then has nothing to steer): only the content term
    stands between the painting and the scene's structure.
    Slow: the same 256 quick-preset CCFT steps on the CPU with The Starry Night, its post colour transfer and the
    report's measures on 4 views (40 s in a clean-clone CI run on 2 cores)."""
    metrics = stylize_fox(fox_model, vgg, PAINTINGS[0], lambda_content=0.0)
    assert metrics["structure_distance"] > MAX_STRUCTURE
