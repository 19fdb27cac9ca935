"""Spatial style control: a stylization restricted to a selection leaves every other Gaussian's colour bit-identical
(through the steps, both colour transfers, a mask change and a PLY round trip) and moves the selected ones toward
the painting; two regions stylized one after another with two paintings from the CLI."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from assets.demo.scene import make_demo_scene
from training.core.errors import InputError
from training.model.gaussian_init import gaussians_from_points
from training.model.selection import box_mask
from training.scene.scene import Scene
from training.stylize.style_distance import gram_distance
from training.stylize.trainer import StylizeConfig, Stylizer

BACKEND = "auto"


@pytest.fixture(scope="module")
def tiny():
    demo = make_demo_scene(num_views=4, width=64, height=48, num_points=1500, supersample=1)
    scene = Scene(cameras=demo.cameras, images=demo.images, points=demo.points, point_colors=demo.point_colors)
    g = gaussians_from_points(demo.points, demo.point_colors, sh_degree=1)
    g.opacity_logits = torch.full_like(g.opacity_logits, 2.0)
    g.shN = torch.randn(g.shN.shape, generator=torch.Generator().manual_seed(0)) * 0.02
    return scene, g


def painting(seed: int = 0) -> np.ndarray:
    from assets.demo.painting import make_style_image

    return np.asarray(make_style_image(size=128, seed=seed), dtype=np.float32)


def half_mask(g) -> np.ndarray:
    """The Gaussians left of the median x: about half, a region that shows in every view."""
    x = g.means[:, 0].numpy()
    return x < np.median(x)


def make(tiny, vgg, mask, style=None, **overrides) -> Stylizer:
    scene, g = tiny
    cfg = StylizeConfig(**{"preset": "quick", "max_side": 64, "backend": BACKEND, "device": "cpu", **overrides})
    return Stylizer(g, scene, painting() if style is None else style, cfg, vgg=vgg, mask=mask)


def test_unselected_colours_bit_identical_through_steps_transfers_and_ply(tiny, vgg, tmp_path):
    from training.model.ply_io import read_ply, write_ply

    _, g = tiny
    mask = half_mask(g)
    s = make(tiny, vgg, mask, iters_per_view=2)
    pre = s.gaussians.sh.detach().clone()
    off = torch.from_numpy(~mask)
    assert torch.equal(pre[off], g.sh[off])  # the pre colour transfer skipped them
    assert not torch.equal(pre[~off], g.sh[~off])  # ... and moved the selection
    for _ in range(4):
        s.step()
    s.finish()
    out = s.stylized_gaussians()
    assert torch.equal(out.sh0[off], g.sh0[off]) and torch.equal(out.shN[off], g.shN[off])
    changed = (out.sh0[~off] != g.sh0[~off]).flatten(1).any(1)
    assert changed.float().mean() > 0.9  # the selected ones were stylized
    write_ply(tmp_path / "m.ply", out)
    back = read_ply(tmp_path / "m.ply")
    assert torch.equal(back.sh0[off], g.sh0[off]) and torch.equal(back.shN[off], g.shN[off])


def test_set_mask_between_steps_freezes_the_leavers_and_bumps_the_version(tiny, vgg):
    _, g = tiny
    mask = half_mask(g)
    s = make(tiny, vgg, mask, iters_per_view=1, color_transfer=False)
    s.step()
    s.step()
    snap = s.snapshot()
    now = s.gaussians.sh.detach().clone()
    s.set_mask(~mask)  # the other half from now on: the first half keeps what it has
    assert s.snapshot().version > snap.version
    assert np.array_equal(s.mask, ~mask)
    for _ in range(3):  # Adam momentum of the first half would move it without the copy-back
        s.step()
    sel = torch.from_numpy(mask)
    assert torch.equal(s.gaussians.sh[sel], now[sel])
    assert not torch.equal(s.gaussians.sh[~sel], now[~sel])
    with pytest.raises(ValueError, match="Gaussians"):
        s.set_mask(np.ones(3, dtype=bool))
    s.set_mask(None)
    assert s.mask is None


def test_bad_masks_are_refused(tiny, vgg):
    _, g = tiny
    with pytest.raises(InputError, match="selects no Gaussians"):
        make(tiny, vgg, np.zeros(len(g), dtype=bool))
    with pytest.raises(InputError, match="shape"):
        make(tiny, vgg, np.ones(len(g) + 1, dtype=bool))
    with pytest.raises(InputError, match="boolean"):
        make(tiny, vgg, np.ones(len(g), dtype=np.int64))


def render_subset(s: Stylizer, sel: torch.Tensor, sh: torch.Tensor, cam) -> torch.Tensor:
    """The selected Gaussians alone, with colours ``sh``, at ``cam``."""
    from training.raster.rasterize import rasterize

    g = s.gaussians
    img, _, _ = rasterize(g.means[sel], g.quats[sel], s.model.scales[sel], s.model.opacities[sel], sh[sel],
                          torch.as_tensor(cam.world_to_camera, dtype=torch.float32),
                          torch.as_tensor(cam.K, dtype=torch.float32), cam.width, cam.height,
                          sh_degree=g.sh_degree, background=torch.zeros(3), backend=BACKEND)
    return img.clamp(0, 1)


def test_selected_region_moves_toward_the_painting(tiny, vgg):
    """Gram distance to the painting of renders of the selected Gaussians alone goes down (no colour transfer, so
    only the style loss can have moved them; the content and TV terms off, as they hold the colours back)."""
    _, g = tiny
    mask = half_mask(g)
    s = make(tiny, vgg, mask, iters_per_view=6, color_transfer=False, lr=0.05, lambda_content=0.0, lambda_tv=0.0,
             lr_final=1.0)
    sel = torch.from_numpy(mask)
    before = s.gaussians.sh.detach().clone()

    def distance(sh):
        with torch.no_grad():
            return np.mean([gram_distance(s.features(render_subset(s, sel, sh, c)), s.style_features(c))
                            for c in s.cameras])

    start = distance(before)
    s.run()
    end = distance(s.gaussians.sh.detach())
    print(f"selected-region Gram distance {start:.4g} -> {end:.4g}")
    assert end < 0.9 * start
    assert torch.equal(s.gaussians.sh[~sel], before[~sel])


def test_cli_two_regions_two_paintings(tmp_path, tiny, vgg, capsys):
    """Region A with painting 1, then region B of that output with painting 2: A keeps the first stylization
    bit for bit, B gets the second, the rest stays as reconstructed."""
    from app.cli import main
    from assets.demo.scene import DemoScene, write_demo_scene
    from training.model.ply_io import read_ply, write_ply
    from training.model.selection import save_mask
    from training.scene.image_io import write_image

    scene, g = tiny
    data = write_demo_scene(tmp_path / "scene", DemoScene(scene.cameras, scene.images, scene.points,
                                                          scene.point_colors))
    write_ply(tmp_path / "model.ply", g)
    for i in (1, 2):
        write_image(tmp_path / f"style{i}.png", painting(seed=i))
    means = g.means.numpy()
    lo, hi = means.min(0), means.max(0)
    mid = 0.5 * (lo + hi)
    box_a = ",".join(f"{v:.6g}" for v in (*(lo - 1), mid[0], hi[1] + 1, hi[2] + 1))  # x below the middle
    mask_b = box_mask(means, (mid[0], lo[1] - 1, lo[2] - 1), (hi[0] + 1, mid[1], hi[2] + 1))  # right and low
    a = box_mask(means, lo - 1, (mid[0], hi[1] + 1, hi[2] + 1))
    mask_b &= ~a
    save_mask(tmp_path / "b.npy", mask_b)
    common = ["--data", str(data), "--preset", "quick", "--max-side", "64", "--iters-per-view", "1",
              "--backend", BACKEND]
    assert main(["stylize", str(tmp_path / "model.ply"), "--style", str(tmp_path / "style1.png"),
                 "-o", str(tmp_path / "A"), f"--box={box_a}", *common]) == 0
    assert "selected" in capsys.readouterr().out
    assert main(["stylize", str(tmp_path / "A" / "point_cloud.ply"), "--style", str(tmp_path / "style2.png"),
                 "-o", str(tmp_path / "B"), "--mask", str(tmp_path / "b.npy"), *common]) == 0
    first, second = read_ply(tmp_path / "A" / "point_cloud.ply"), read_ply(tmp_path / "B" / "point_cloud.ply")
    original = read_ply(tmp_path / "model.ply")
    ta, tb = torch.from_numpy(a), torch.from_numpy(mask_b)
    rest = ~(ta | tb)
    assert torch.equal(second.sh[ta], first.sh[ta])
    assert torch.equal(second.sh[rest], original.sh[rest])
    assert not torch.equal(first.sh[ta], original.sh[ta])
    assert not torch.equal(second.sh[tb], first.sh[tb])

    # a mask for another model: one line naming the file
    np.save(tmp_path / "short.npy", np.ones(5, dtype=bool))
    capsys.readouterr()
    assert main(["stylize", str(tmp_path / "model.ply"), "--style", str(tmp_path / "style1.png"),
                 "-o", str(tmp_path / "C"), "--mask", str(tmp_path / "short.npy"), *common]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "short.npy" in err[0]
