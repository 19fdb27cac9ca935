"""The grid's colour-shift measure (training/evaluate/colour_shift.py): exact on known changes, and on a real
stylization it tells a DC-only run (the bands above 0 untouched without colour transfer) from a colour run."""

from __future__ import annotations

import pytest
import torch

from training.evaluate.colour_shift import colour_shift
from training.model.gaussians import Gaussians


def model(n=50, degree=2, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g), log_scales=torch.randn(n, 3, generator=g) - 3,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g),
                     sh0=torch.randn(n, 1, 3, generator=g), shN=torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g),
                     sh_degree=degree)


def test_shift_is_the_mean_absolute_change_per_coefficient():
    a = model()
    b = a.subset(torch.arange(len(a)))
    b.sh0 = a.sh0 + 0.25
    b.shN = a.shN.clone()
    b.shN[:10] -= 0.5  # 10 of 50 rows, every coefficient above band 0
    out = colour_shift(a, b)
    assert out["dc_shift"] == pytest.approx(0.25)
    assert out["shn_shift"] == pytest.approx(0.5 * 10 / 50)
    assert out["shn_size"] == pytest.approx(float(a.shN.abs().mean()))
    assert colour_shift(a, a.subset(torch.arange(10))) == {}  # rows do not pair
    assert colour_shift(model(degree=0), model(degree=0)) == {"dc_shift": 0.0}


@pytest.mark.slow
def test_a_dc_only_stylization_leaves_the_view_dependent_bands_alone():
    from assets.demo.assets import demo_assets
    from training.model.gaussian_init import gaussians_from_points
    from training.scene.loader import load_scene
    from training.stylize.style_image import load_style_image
    from training.stylize.trainer import StylizeConfig, Stylizer

    assets = demo_assets()
    scene = load_scene(assets.scene_dir)
    start = gaussians_from_points(scene.points, scene.point_colors, sh_degree=1)
    start.shN = 0.05 * torch.randn(start.shN.shape, generator=torch.Generator().manual_seed(0))
    shifts = {}
    for dc_only in (True, False):
        trainer = Stylizer(start, scene, load_style_image(assets.style_image),
                           StylizeConfig(preset="quick", max_side=48, iters_per_view=1, color_transfer=False,
                                         dc_only=dc_only))
        for _ in range(4):
            trainer.step()
        shifts[dc_only] = colour_shift(start, trainer.stylized_gaussians())
    assert shifts[True]["dc_shift"] > 0 and shifts[True]["shn_shift"] == 0.0
    assert shifts[False]["dc_shift"] > 0 and shifts[False]["shn_shift"] > 0
