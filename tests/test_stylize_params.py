"""``StylizeConfig.params`` / ``splatstyler stylize --params``: colour-only stylization (the paper's method, default)
against optimising every Gaussian parameter (the paper's ablation).

Colour-only keeping the geometry bit-identical is tested in tests/test_stylize.py
(``test_geometry_bit_identical_and_colours_change``, ``test_cli_writes_ply_renders_and_report``); here: "all" moves
the geometry with gradients that reach it (also after colour-only renders filled the cpu rasterizer's frozen-geometry
cache), a selection keeps the others' geometry and colours bit-identical, ``keep()`` mid-run, the viewer's geometry
version, the CLI flag and refused values."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
import torch

from assets.demo.scene import make_demo_scene
from training.model.gaussian_init import gaussians_from_points
from training.scene.scene import Scene
from training.stylize import defaults as D
from training.stylize.optimizer import GEOMETRY
from training.stylize.trainer import FIXED_AT_START, StylizeConfig, Stylizer

BACKEND = "auto"  # the product path (numba on CPU)


@pytest.fixture(scope="module")
def tiny():
    """4 views of the demo scene at 64x48 and Gaussians (SH degree 1) from its surface points (as test_stylize),
    made anisotropic."""
    demo = make_demo_scene(num_views=4, width=64, height=48, num_points=1500, supersample=1)
    scene = Scene(cameras=demo.cameras, images=demo.images, points=demo.points, point_colors=demo.point_colors)
    g = gaussians_from_points(demo.points, demo.point_colors, sh_degree=1)
    g.opacity_logits = torch.full_like(g.opacity_logits, 2.0)  # cover the views (init opacity 0.1 leaves holes)
    gen = torch.Generator().manual_seed(0)
    g.shN = torch.randn(g.shN.shape, generator=gen) * 0.02
    # anisotropic and turned: the initial Gaussians are spheres, whose rotation gets no gradient at all
    g.log_scales = g.log_scales + 0.3 * torch.randn(g.log_scales.shape, generator=gen)
    g.quats = torch.nn.functional.normalize(torch.randn(g.quats.shape, generator=gen), dim=-1)
    return scene, g


def painting() -> np.ndarray:
    from assets.demo.painting import make_style_image

    return np.asarray(make_style_image(size=128, seed=0), dtype=np.float32)


def make(tiny, vgg, mask=None, **overrides) -> Stylizer:
    scene, g = tiny
    cfg = StylizeConfig(**{"preset": "quick", "max_side": 64, "backend": BACKEND, "device": "cpu", **overrides})
    return Stylizer(g, scene, painting(), cfg, vgg=vgg, mask=mask)


def snapshot_of(g):
    return {k: v.detach().clone() for k, v in g.parameters().items()}


def test_default_is_colour_and_params_is_fixed_at_start(tiny, vgg):
    assert StylizeConfig().params == "colour"
    assert "params" in FIXED_AT_START
    s = make(tiny, vgg, color_transfer=False, iters_per_view=1)
    with pytest.raises(ValueError, match="params"):
        s.update_config(params="all")  # it shapes the optimiser: refused while the run lasts
    s.step()
    assert all(not getattr(s.gaussians, k).requires_grad for k in GEOMETRY)
    assert [grp.get("name") for grp in s.optimizer.param_groups] == ["sh0"]  # DC only, the default
    every_band = make(tiny, vgg, color_transfer=False, iters_per_view=1, dc_only=False)
    every_band.step()
    assert [grp.get("name") for grp in every_band.optimizer.param_groups] == ["sh0", "shN"]
    given = s.input_gaussians()
    for name, value in tiny[1].parameters().items():
        assert torch.equal(getattr(given, name), value), name


def test_all_moves_the_geometry_and_the_loss_falls(tiny, vgg):
    _, g = tiny
    before = snapshot_of(g)
    # a small constant colour rate: the default 0.13 (with its decay) overshoots within 5 steps on one view
    s = make(tiny, vgg, params="all", color_transfer=False, iters_per_view=5, lr=0.02, lr_final=1.0)
    snaps = [s.snapshot()]
    for _ in range(5):  # all on the first view
        s.step()
        for name in GEOMETRY:  # the gradients reached every geometric parameter
            grad = getattr(s.gaussians, name).grad
            assert grad is not None and torch.isfinite(grad).all() and grad.abs().sum() > 0, name
        snaps.append(s.snapshot())
    losses = [h["loss"] for h in s.history]
    assert losses[-1] < losses[0], losses
    groups = {grp.get("name"): grp["lr"] for grp in s.optimizer.param_groups}
    assert groups["means"] == pytest.approx(D.MEANS_LR * tiny[0].extent)
    assert (groups["log_scales"], groups["quats"], groups["opacity_logits"]) == (
        D.SCALES_LR, D.QUATS_LR, D.OPACITY_LR)
    s.update_config(lr=0.05)  # the colour rate changes live; the geometry's rates stay
    s.step()
    groups = {grp.get("name"): grp["lr"] for grp in s.optimizer.param_groups}
    assert groups["sh0"] == 0.05 and groups["quats"] == D.QUATS_LR
    s.finish()
    out = s.stylized_gaussians()
    for name in GEOMETRY:
        assert not torch.equal(getattr(out, name), before[name]), name
    assert not torch.equal(out.sh0, before["sh0"])
    for name, value in before.items():  # the caller's model is untouched
        assert torch.equal(getattr(g, name), value), name
    given = s.input_gaussians()  # the "before" of a before/after comparison
    for name, value in before.items():
        assert torch.equal(getattr(given, name), value), name
    # the viewer re-uploads positions: the geometry version moves at every step, and the snapshot follows
    versions = [snap.geometry_version for snap in snaps]
    assert all(b > a for a, b in itertools.pairwise(versions)), versions
    assert not np.array_equal(snaps[0].means, snaps[-1].means)
    last = s.snapshot()
    assert np.array_equal(last.means, out.means.numpy())
    assert np.allclose(last.scales, out.scales.numpy()) and np.allclose(last.opacities, out.opacities.numpy())


def test_geometry_gradients_reach_the_leaves_after_colour_only_renders(tiny, vgg):
    """The cpu rasterizer reuses frozen geometry (no gradient, same bits, same camera) for colour-only steps. A
    colour run fills that cache for view 0; an "all" run on the same bits must not be served from it: the trainer's
    render gives every geometric parameter a gradient, equal bit for bit to one computed with the cache emptied.
    (That the cpu backend's geometry gradients match the torch reference: tests/test_raster_cpu.py.)"""
    from training.raster.rasterize import choose_backend

    s = make(tiny, vgg, params="all", color_transfer=False, iters_per_view=3)
    s._sync()  # the optimiser's leaves
    colour = make(tiny, vgg, color_transfer=False, iters_per_view=4, schedule="block")
    for _ in range(3):  # on the same first view: projection reused, then the pair weights recorded and replayed
        colour.step()
    cam = s.cameras[s.current_view.source_index]
    assert colour.current_view.camera is colour.cameras[s.current_view.source_index]
    weights = torch.rand(cam.height, cam.width, 3, generator=torch.Generator().manual_seed(1))

    def grads():
        for name in GEOMETRY:
            getattr(s.gaussians, name).grad = None
        image, _ = s.render(cam)
        (image * weights).sum().backward()
        return {name: getattr(s.gaussians, name).grad.clone() for name in GEOMETRY}

    cpu = choose_backend(BACKEND, s.device) == "cpu"
    if cpu:
        from training.raster.cpu import FROZEN

        entry = FROZEN.newest
        assert entry is not None and entry.records is not None  # the colour run's geometry, view and pairs are cached
        assert entry.params[:2] == (cam.width, cam.height)
        assert all(np.array_equal(a, b.detach().numpy()) for a, b in zip(
            entry.key_arrays, (s.gaussians.means, s.gaussians.quats, s.gaussians.scales, s.gaussians.opacities)))
    got = grads()
    for name in GEOMETRY:
        assert torch.isfinite(got[name]).all() and got[name].abs().sum() > 0, name
    if cpu:
        FROZEN.clear()
    fresh = grads()
    for name in GEOMETRY:
        assert torch.equal(got[name], fresh[name]), name


def test_selection_under_all_keeps_the_others_geometry_and_colours_bit_identical(tiny, vgg):
    _, g = tiny
    x = g.means[:, 0].numpy()
    mask = x < np.median(x)
    off = torch.from_numpy(~mask)
    s = make(tiny, vgg, mask=mask, params="all", iters_per_view=2)  # with the colour transfers
    for _ in range(3):
        s.step()
    mask2 = mask & (g.means[:, 1].numpy() < np.median(g.means[:, 1].numpy()))  # a smaller selection mid-run
    s.set_mask(mask2)
    moved = s.gaussians.detached()
    for _ in range(2):
        s.step()
    s.finish()
    out = s.stylized_gaussians()
    for name, value in g.parameters().items():
        assert torch.equal(getattr(out, name)[off], value[off]), name
    leavers = torch.from_numpy(mask & ~mask2)  # kept what they had when they left the selection
    for name in ("means", "log_scales", "quats", "opacity_logits"):
        assert torch.equal(getattr(out, name)[leavers], getattr(moved, name)[leavers]), name
    sel = torch.from_numpy(mask2)
    assert (out.means[sel] != g.means[sel]).any(1).float().mean() > 0.5  # the selection's geometry moved


def test_keep_mid_run_under_all(tiny, vgg):
    """Delete Gaussians between steps: the trained parameters are sliced, the optimiser restarts, the next steps
    (a virtual view among them, whose content is the input model's render) run and keep training the geometry."""
    s = make(tiny, vgg, params="all", color_transfer=False, iters_per_view=1, virtual_views=1, view_order="dataset")
    s.step()
    n = len(s.gaussians)
    keep = np.ones(n, dtype=bool)
    keep[::3] = False
    before = s.gaussians.detached()
    version = s.snapshot().geometry_version
    s.keep(keep)
    kept = torch.from_numpy(keep)
    assert len(s.gaussians) == int(keep.sum()) and s.optimizer is None
    for name in GEOMETRY:
        assert torch.equal(getattr(s.gaussians, name), getattr(before, name)[kept]), name
    assert all(len(t) == int(keep.sum()) for t in s.model.input_geometry.values())
    assert s.snapshot().geometry_version > version and len(s.snapshot()) == int(keep.sum())
    assert s.current_view.is_virtual
    r = s.step()
    assert np.isfinite(r["loss"]) and r["virtual"]
    s.step()
    for name in GEOMETRY:
        leaf = getattr(s.gaussians, name)
        assert leaf.requires_grad and leaf.grad.abs().sum() > 0, name
        assert not torch.equal(leaf.detach(), getattr(before, name)[kept]), name
    # the virtual view's content: the input model (geometry and colours) rendered, not the current model
    s.views.position = 1  # its content is kept from its step, or computed now: the same features either way
    content = s.content_features()
    with torch.no_grad():
        expected = s.features(s.render(s.trajectory[1].camera, sh=s.model.initial_sh, input_geometry=True)[0].clamp(0, 1))
        current_geometry = s.features(s.render(s.trajectory[1].camera, sh=s.model.initial_sh)[0].clamp(0, 1))
    assert torch.allclose(content, expected) and not torch.allclose(content, current_geometry)
    given = s.input_gaussians()
    for name, value in tiny[1].parameters().items():
        assert torch.equal(getattr(given, name), value[kept]), name


def test_invalid_params_refused_with_one_line(tiny, vgg, capsys):
    with pytest.raises(ValueError) as err:
        StylizeConfig(params="geometry").validate()
    message = str(err.value)
    assert "\n" not in message and "params" in message and "colour, all" in message and "'geometry'" in message
    with pytest.raises(ValueError, match="params must be one of colour, all"):
        make(tiny, vgg, params="positions")

    from app.cli import main

    with pytest.raises(SystemExit) as exit_info:  # argparse: usage, then one error line naming the choices
        main(["stylize", "m.ply", "--data", "d", "--style", "s.png", "-o", "out", "--params", "geometry"])
    assert exit_info.value.code == 2
    err_lines = capsys.readouterr().err.strip().splitlines()
    assert "--params" in err_lines[-1] and "'colour', 'all'" in err_lines[-1]


@pytest.mark.parametrize("flag,expected", [([], "colour"), (["--params", "all"], "all")])
def test_cli_flag_reaches_the_config(monkeypatch, capsys, flag, expected):
    """The parsed flag goes into the StylizeConfig the job gets (the job itself replaced: the real run is below)."""
    from app.cli import main
    from training.stylize import pipeline

    seen = {}

    def job(model, data, style, out, config, **kwargs):
        seen["config"] = config
        distance = {f"{k}_{when}": 1.0 for k in ("gram", "gram_normalised") for when in ("start", "end")}
        return {"num_views": 1, "iterations": 0, "style_distance": distance}

    monkeypatch.setattr(pipeline, "stylize_to_folder", job)
    assert main(["stylize", "m.ply", "--data", "d", "--style", "s.png", "-o", "out", *flag]) == 0
    assert seen["config"].params == expected


@pytest.mark.slow
def test_cli_params_all_reaches_the_config_and_the_ply(tmp_path, tiny, vgg):
    """A real tiny run (4 iterations at 64x48): report.json's config says "all" and the PLY's geometry moved."""
    from app.cli import main
    from assets.demo.scene import DemoScene, write_demo_scene
    from training.model.ply_io import read_ply, write_ply
    from training.scene.image_io import write_image

    scene, g = tiny
    data = write_demo_scene(tmp_path / "scene", DemoScene(scene.cameras, scene.images, scene.points,
                                                          scene.point_colors))
    write_ply(tmp_path / "model.ply", g)
    write_image(tmp_path / "style.png", painting())
    out = tmp_path / "out"
    assert main(["stylize", str(tmp_path / "model.ply"), "--data", str(data), "--style", str(tmp_path / "style.png"),
                 "-o", str(out), "--preset", "quick", "--max-side", "64", "--iters-per-view", "1",
                 "--backend", BACKEND, "--params", "all"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["config"]["params"] == "all" and report["iterations"] == 4
    result, original = read_ply(out / "point_cloud.ply"), read_ply(tmp_path / "model.ply")
    for name in GEOMETRY:
        assert not torch.equal(getattr(result, name), getattr(original, name)), name


def test_settings_that_are_not_numbers_of_their_kind_are_refused_in_one_line(capsys):
    """A float where a whole number goes and an infinite one are refused where the settings are validated (a
    project's JSON can hold 4.0 and Infinity; `--tau inf` parses as a float); each line names the setting."""
    for changes, words in (({"k": 4.0}, "k must be a whole number, got 4.0"),
                           ({"tau": float("inf")}, "tau must be a finite number, got inf"),
                           ({"lambda_content": float("nan")}, "lambda_content must be a finite number"),
                           ({"seed": True}, "seed must be a whole number"),
                           ({"color_transfer": "yes"}, "color_transfer must be true or false"),
                           ({"background": (0.0, 2.0, 0.0)}, "background must be 3 numbers in [0, 1]")):
        with pytest.raises(ValueError) as err:
            StylizeConfig(**changes).validate()
        assert words in str(err.value) and "\n" not in str(err.value)
    StylizeConfig(k=np.int64(4), tau=np.float32(0.5), lr=None).validate()  # numpy's numbers are numbers

    from app.cli import main

    assert main(["stylize", "m.ply", "--data", "d", "--style", "s.png", "-o", "out", "--tau", "inf"]) == 2
    assert capsys.readouterr().err == "splatstyler: error: --tau must be a finite number, got inf\n"
