"""Presets choose the training resolution from a target long side; --downscale and --max-side override; the factor
stays a whole number so the images_N cache keeps the 3DGS tools' convention."""

from __future__ import annotations

import json

import pytest

from app.cli import main
from assets.demo.scene import make_demo_scene, write_demo_scene
from training.reconstruct.resolution import downscale_for_long_side, training_downscale
from training.reconstruct.trainer import ReconstructConfig


def test_presets_name_a_long_side():
    assert ReconstructConfig.from_preset("quick").max_side == 400
    assert ReconstructConfig.from_preset("standard").max_side == 1000
    assert ReconstructConfig.from_preset("paper").max_side is None
    assert ReconstructConfig.from_preset("paper").downscale == 1


@pytest.mark.parametrize("long_side, max_side, factor", [
    (1920, 400, 5),  # fox: 384 px instead of factor 8's 240
    (706, 400, 2),   # LLFF fern/flower after sfm
    (1000, 400, 3),
    (400, 400, 1), (401, 400, 2), (300, 400, 1),
    (1920, 1000, 2), (4032, 1000, 5),
])
def test_smallest_whole_factor_reaching_the_long_side(long_side, max_side, factor):
    n = downscale_for_long_side(long_side, max_side, downscale=8)
    assert n == factor and -(-long_side // n) <= max_side
    assert n == 1 or -(-long_side // (n - 1)) > max_side


def test_no_max_side_keeps_the_given_factor():
    assert downscale_for_long_side(1920, None, 8) == 8


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = make_demo_scene(num_views=9, width=96, height=72, num_points=200)
    return write_demo_scene(tmp_path_factory.mktemp("res") / "scene", d)


def test_scene_factor_from_headers(folder):
    assert training_downscale(folder, 40, 8) == 3  # 96 px -> 32 px
    assert training_downscale(folder, None, 2) == 2


@pytest.mark.slow
def test_cli_max_side_and_downscale(folder, tmp_path, capsys):
    rc = main(["reconstruct", str(folder), "-o", str(tmp_path / "a"), "--iters", "12", "--no-progress",
               "--max-side", "50"])
    err = capsys.readouterr().err
    assert rc == 0 and "training at 48x36 pixels (factor 2" in err and "estimated training time: about" in err
    report = json.loads((tmp_path / "a" / "report.json").read_text())
    cfg = report["settings"]["config"]
    assert (cfg["downscale"], cfg["max_side"]) == (2, 50) and report["settings"]["image_size"] == [48, 36]
    assert report["estimated_seconds"] > 0
    assert (tmp_path / "a" / "contact_sheet.png").is_file() and report["contact_sheet"] == "contact_sheet.png"
    names = sorted(p.name for p in (tmp_path / "a" / "renders").iterdir())
    assert len(names) == 2 * len(report["views"]) and any(n.endswith("_depth.png") for n in names)
    assert all({"psnr", "ssim", "lpips"} <= set(v) for v in report["views"])
    assert report["test_lpips"] == pytest.approx(sum(v["lpips"] for v in report["views"]) / len(report["views"]))

    assert main(["reconstruct", str(folder), "-o", str(tmp_path / "b"), "--downscale", "2", "--max-side", "50",
                 "--no-progress"]) == 2
    assert "not both" in capsys.readouterr().err


def test_output_under_a_file_is_one_line(folder, tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    rc = main(["reconstruct", str(folder), "-o", str(tmp_path / "file" / "out"), "--iters", "1", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "cannot create the output folder" in err[0] and "is a file" in err[0]
