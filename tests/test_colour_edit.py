"""Colour adjustments and style strength on SH coefficients (training/model/colour_edit.py): checked against the
same map applied to rendered colours (the CPU rasterizer's images, and SH evaluation along many directions)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.raster_scenes import random_scene
from training.model.colour_edit import (ColourAdjustment, ColourEdits, adjust_sh, blend_style,
                                        strength_per_gaussian)
from training.model.sh import sh_basis
from training.model.sh_constants import SH_C0
from training.raster.rasterize import rasterize

ADJUST = ColourAdjustment(brightness=0.05, contrast=0.2, saturation=0.25, hue=25.0, temperature=-0.3)


def psnr(a, b) -> float:
    mse = float(((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2).mean())
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def random_sh(n=400, degree=3, seed=0, rest_scale=0.1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    sh = torch.randn(n, (degree + 1) ** 2, 3, generator=g) * rest_scale
    sh[:, 0] = (torch.rand(n, 3, generator=g) * 0.5 + 0.25 - 0.5) / SH_C0  # base colours in [0.25, 0.75]
    return sh


def evaluate(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Unclamped colours (N, D, 3) of every Gaussian along every direction (D, 3), float64."""
    degree = int(round(sh.shape[1] ** 0.5)) - 1
    basis = sh_basis(degree, dirs.double())  # (D, K)
    return torch.einsum("dk,nkc->ndc", basis, sh.double()) + 0.5


def test_identity_parameters_are_exact_no_ops():
    sh = random_sh()
    assert adjust_sh(sh, [(None, ColourAdjustment())]) is sh
    assert adjust_sh(sh, []) is sh
    assert ColourEdits().apply(sh) is sh
    assert ColourEdits([(None, ColourAdjustment())], strength=1.0).apply(sh) is sh
    m, o = ColourAdjustment().affine()
    assert np.allclose(m, np.eye(3), atol=1e-15) and not o.any()


def test_adjustment_matches_the_map_on_rendered_images_of_a_dc_only_model():
    """A view-independent model: render, adjust its SH, render again; the map applied to the first image (the
    offset weighted by alpha, since it is added to every splat's colour) gives the second."""
    means, quats, scales, opac, colors, viewmat, K = random_scene(300, 96, 72, seed=3, sh_degree=0, log_scale_mean=-2.2)
    colors = random_sh(300, degree=0, seed=4)
    before, alpha, _ = rasterize(means, quats, scales, opac, colors, viewmat, K, 96, 72, sh_degree=0, backend="cpu")
    adjusted = adjust_sh(colors, [(None, ADJUST)])
    assert (ADJUST.on_colours(SH_C0 * colors[:, 0].numpy() + 0.5) > 0).all()  # no clamp in play
    after, _, _ = rasterize(means, quats, scales, opac, adjusted, viewmat, K, 96, 72, sh_degree=0, backend="cpu")
    m, o = ADJUST.affine()
    reference = before.numpy().astype(np.float64) @ m.T + alpha.numpy() * o
    assert alpha.numpy().mean() > 0.3  # the scene covers the image
    assert np.abs(after.numpy() - reference).max() < 1e-4
    assert psnr(after.numpy(), reference) > 80
    assert psnr(after.numpy(), before.numpy()) < 30  # the adjustment changed the picture


def test_higher_bands_follow_the_map_along_every_direction():
    sh = random_sh(200, degree=3, seed=1).double()
    g = torch.Generator().manual_seed(2)
    dirs = torch.nn.functional.normalize(torch.randn(64, 3, generator=g, dtype=torch.float64), dim=-1)
    out = adjust_sh(sh, [(None, ADJUST)])
    expected = ADJUST.on_colours(evaluate(sh, dirs).numpy())
    assert np.abs(evaluate(out, dirs).numpy() - expected).max() < 1e-12


def test_each_parameter_does_what_its_name_says():
    grey, red = np.array([0.4, 0.4, 0.4]), np.array([0.8, 0.3, 0.2])
    luma = np.array([0.2126, 0.7152, 0.0722])
    assert np.allclose(ColourAdjustment(brightness=0.1).on_colours(red), red + 0.1)
    assert np.allclose(ColourAdjustment(contrast=1.0).on_colours(red), 2 * (red - 0.5) + 0.5)
    for hue in (30.0, -120.0):  # hue and saturation keep greys grey
        assert np.allclose(ColourAdjustment(hue=hue, saturation=0.7).on_colours(grey), grey)
    desat = ColourAdjustment(saturation=-1.0).on_colours(red)
    assert np.allclose(desat, red @ luma) and np.isclose(desat @ luma, red @ luma)
    assert np.allclose(ColourAdjustment(hue=120.0).on_colours(np.array([1.0, 0, 0])), [0, 1, 0], atol=1e-12)
    warm = ColourAdjustment(temperature=1.0).on_colours(grey)
    assert warm[0] > grey[0] and warm[2] < grey[2] and warm[1] == grey[1]
    with pytest.raises(ValueError, match="saturation must be in"):
        ColourAdjustment(saturation=-2.0).validate()
    with pytest.raises(ValueError, match="hue must be a finite number"):
        ColourAdjustment(hue=float("nan")).validate()


def test_regions_leave_other_rows_bit_exact_and_compose_in_order():
    sh = random_sh(300, seed=5)
    region = torch.rand(300, generator=torch.Generator().manual_seed(6)).numpy() < 0.3
    second = ColourAdjustment(saturation=-0.5)
    out = adjust_sh(sh, [(region, ADJUST), (None, second)])
    alone = adjust_sh(sh, [(region, ADJUST)])
    assert torch.equal(alone[~region], sh[~region])
    assert not torch.equal(alone[region], sh[region])
    # composition: the second map after the first, on rendered colours
    dirs = torch.nn.functional.normalize(torch.randn(16, 3, generator=torch.Generator().manual_seed(7)), dim=-1)
    colours = evaluate(sh, dirs).numpy()
    expected = second.on_colours(np.where(region[:, None, None], ADJUST.on_colours(colours), colours))
    assert np.abs(evaluate(out, dirs).numpy() - expected).max() < 1e-5  # float32 coefficients
    numpy_out = adjust_sh(sh.numpy(), [(region, ADJUST), (None, second)])
    assert isinstance(numpy_out, np.ndarray) and np.array_equal(numpy_out, out.numpy())
    with pytest.raises(ValueError, match="region must be an"):
        adjust_sh(sh, [(region[:10], ADJUST)])


def test_style_strength_ends_are_bit_exact():
    original, stylized = random_sh(500, seed=8), random_sh(500, seed=9)
    assert torch.equal(blend_style(original, stylized, 0.0), original)
    assert torch.equal(blend_style(original, stylized, 1.0), stylized)
    s = np.array([0.0, 1.0, 0.25] * 166 + [0.0, 1.0])
    out = blend_style(original, stylized, s)
    assert torch.equal(out[s == 0], original[s == 0]) and torch.equal(out[s == 1], stylized[s == 1])
    mid = s == 0.25
    assert torch.allclose(out[mid], original[mid] + 0.25 * (stylized[mid] - original[mid]), atol=1e-6)
    # per region, later regions over earlier ones; the blend is linear in rendered colour too
    region = np.zeros(500, bool)
    region[:100] = True
    per = strength_per_gaussian(500, 0.0, [(region, 0.5)])
    assert per[:100].tolist() == [0.5] * 100 and not per[100:].any()
    edits = ColourEdits(strength=0.0, strength_regions=[(region, 0.5)])
    out = edits.apply(stylized, original_sh=original)
    assert torch.equal(out[100:], original[100:])
    dirs = torch.nn.functional.normalize(torch.randn(8, 3, generator=torch.Generator().manual_seed(10)), dim=-1)
    expected = 0.5 * (evaluate(original[:100], dirs) + evaluate(stylized[:100], dirs))
    assert torch.allclose(evaluate(out[:100], dirs), expected, atol=1e-6)
    with pytest.raises(ValueError, match="needs the original"):
        edits.apply(stylized)
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        strength_per_gaussian(5, 1.5)


def test_apply_on_the_rows_an_editor_kept():
    """The viewer's model is the file's rows ``index`` (after deletions): regions over file rows pick theirs."""
    original, stylized = random_sh(400, seed=11), random_sh(400, seed=12)
    region = np.arange(400) % 3 == 0
    edits = ColourEdits([(region, ADJUST)], strength=0.3)
    rows = np.flatnonzero(np.arange(400) % 5 != 0)
    shown = edits.apply(stylized[rows], original_sh=original[rows], rows=rows)
    whole = edits.apply(stylized, original_sh=original)
    assert torch.equal(shown, whole[rows])


def test_bench_edits_reports_every_operation(capsys):
    import json

    from app.cli import main

    assert main(["bench", "edits", "--sizes", "2000", "--repeat", "1", "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(rows) == 6 and all(r["gaussians"] == 2000 and r["seconds"] > 0 and r["ratio"] > 0 for r in rows)
    assert rows[-1]["operation"].startswith("open project") and rows[-1]["file_bytes"] > 0
