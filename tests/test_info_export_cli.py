"""``splatstyler info`` and ``splatstyler export`` as a user runs them, and their one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from app.cli import main
from training.model.gaussians import Gaussians
from training.model.ply_io import read_ply, write_ply
from training.model.splat_io import read_splat, splat_records

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
FOX = SHARED / "data" / "scenes" / "fox"
REPO = Path(__file__).resolve().parents[1]


def model(n=300, degree=3, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g) * 2, log_scales=torch.randn(n, 3, generator=g) - 3,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g),
                     sh0=torch.randn(n, 1, 3, generator=g), shN=torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g),
                     sh_degree=degree)


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_info_json_on_ply(tmp_path, capsys):
    g = model(degree=2)
    path = tmp_path / "m.ply"
    write_ply(path, g)
    code, out, err = run_cli(capsys, "info", path, "--json")
    assert code == 0 and err == ""
    s = json.loads(out)
    assert s["kind"] == "ply" and s["num_gaussians"] == 300 and s["sh_degree"] == 2
    assert s["num_cameras"] is None and s["num_points"] is None
    np.testing.assert_allclose(s["bounds_min"], g.means.min(0).values.numpy(), rtol=1e-6)
    np.testing.assert_allclose(s["bounds_max"], g.means.max(0).values.numpy(), rtol=1e-6)
    assert s["opacity"]["max"] == pytest.approx(torch.sigmoid(g.opacity_logits).max().item(), rel=1e-6)
    assert s["scale"]["min"] == pytest.approx(g.scales.min().item(), rel=1e-6)
    assert s["file_bytes"] == path.stat().st_size

    code, out, _ = run_cli(capsys, "info", path)
    assert code == 0 and "Gaussians     300" in out and "SH degree     2" in out


def test_info_json_on_splat(tmp_path, capsys):
    path = tmp_path / "m.splat"
    code, _, _ = run_cli(capsys, "export", _ply(tmp_path), "-o", path)
    assert code == 0
    code, out, _ = run_cli(capsys, "info", path, "--json")
    s = json.loads(out)
    assert code == 0 and s["kind"] == "splat" and s["num_gaussians"] == 300 and s["sh_degree"] == 0


def _ply(tmp_path, degree=3) -> Path:
    path = tmp_path / "in.ply"
    write_ply(path, model(degree=degree))
    return path


def test_info_json_on_fox_scene(capsys):
    if not FOX.exists():
        pytest.skip(f"shared data not found at {FOX}")
    code, out, err = run_cli(capsys, "info", FOX, "--json")
    assert code == 0, err
    s = json.loads(out)
    assert s["kind"] == "scene"
    assert s["num_cameras"] == 67 and s["num_train"] + s["num_test"] == 67
    assert s["test_indices"] == list(range(0, 67, 8))
    assert s["num_points"] == 0  # transforms.json carries no SfM points
    assert s["num_gaussians"] is None and s["sh_degree"] is None
    assert sum(size["count"] for size in s["image_sizes"]) == 67
    assert s["extent"] > 0
    code, out2, _ = run_cli(capsys, "info", FOX, "--json", "--downscale", "2")
    s2 = json.loads(out2)
    assert s2["focal_px"]["max"] == pytest.approx(s["focal_px"]["max"] / 2, rel=0.01)


def test_export_ply_to_splat_matches_the_library(tmp_path, capsys):
    src = _ply(tmp_path)
    out = tmp_path / "out.splat"
    code, stdout, _ = run_cli(capsys, "export", src, "-o", out)
    assert code == 0 and "300 Gaussians" in stdout
    assert out.read_bytes() == splat_records(read_ply(src)).tobytes()
    assert len(read_splat(out)) == 300


def test_export_ply_lowers_sh_degree(tmp_path, capsys):
    src = _ply(tmp_path)
    out = tmp_path / "deg1.ply"
    code, _, _ = run_cli(capsys, "export", src, "-o", out, "--sh-degree", "1")
    assert code == 0
    a, b = read_ply(src), read_ply(out)
    assert b.sh_degree == 1
    assert torch.equal(b.shN, a.shN[:, :3])
    assert torch.equal(b.means, a.means) and torch.equal(b.sh0, a.sh0)


def test_export_errors(tmp_path, capsys):
    src = _ply(tmp_path, degree=1)
    code, out, err = run_cli(capsys, "export", src, "-o", tmp_path / "x.obj")
    assert code == 2 and "x.obj: unknown output format" in err
    code, out, err = run_cli(capsys, "export", src, "-o", tmp_path / "y.ply", "--sh-degree", "3")
    assert code == 2 and "holds SH degree 1" in err
    assert not (tmp_path / "y.ply").exists()


@pytest.mark.parametrize("damage", ["truncate", "nan", "not_ply", "missing"])
def test_bad_ply_is_one_line_exit_2(tmp_path, capsys, damage):
    path = _ply(tmp_path)
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        path.write_bytes(bytes(data[: len(data) // 2]))
        word = "truncated"
    elif damage == "nan":
        header_end = data.index(b"end_header\n") + len(b"end_header\n")
        data[header_end: header_end + 4] = np.float32(np.nan).tobytes()  # x of the first Gaussian
        path.write_bytes(bytes(data))
        word = "NaN"
    elif damage == "not_ply":
        path.write_bytes(b"solid cube\nfacet normal 0 0 1\n")
        word = "not a PLY"
    else:
        header = data[: data.index(b"end_header\n") + 11].decode().replace("property float opacity\n", "")
        path.write_bytes(header.encode())  # header without opacity and without data
        word = "missing attribute"
    for argv in (["info", path], ["export", path, "-o", tmp_path / "o.splat"]):
        code, out, err = run_cli(capsys, *argv)
        assert code == 2
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"splatstyler: error: {path}: "), err
        assert word in lines[0]
    assert not (tmp_path / "o.splat").exists()


def test_console_command_exit_code_and_no_traceback(tmp_path):
    bad = _ply(tmp_path)
    data = bad.read_bytes()
    bad.write_bytes(data[: data.index(b"end_header\n") + 11] + data[-1000:])
    proc = subprocess.run([sys.executable, "-m", "app", "info", str(bad)], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip() == f"splatstyler: error: {bad}: PLY file is truncated: header declares 300 vertices " \
                                  "(74400 bytes), the file holds 1000 bytes (~4 vertices)"


def test_info_json_on_colmap_scene_with_points(tmp_path, capsys):
    from tests.test_gaussian_init import ring_scene
    from training.scene.colmap_io import write_colmap_model
    from training.model.gaussian_init import gaussians_from_points
    from training.scene.image_io import write_image
    from training.scene.loader import load_scene

    scene = ring_scene(10)
    rng = np.random.default_rng(0)
    for cam in scene.cameras:
        cam.name += ".png"
        write_image(tmp_path / "images" / cam.name, rng.uniform(size=(cam.height, cam.width, 3)).astype(np.float32))
    pts = rng.normal(size=(80, 3)).astype(np.float32)
    write_colmap_model(tmp_path / "sparse" / "0", scene.cameras, pts, rng.uniform(size=(80, 3)).astype(np.float32))

    code, out, err = run_cli(capsys, "info", tmp_path, "--json")
    assert code == 0, err
    s = json.loads(out)
    assert s["kind"] == "scene" and s["num_cameras"] == 10 and s["num_points"] == 80
    assert s["has_point_colors"] and s["num_train"] == 8 and s["test_indices"] == [0, 8]
    assert s["image_sizes"] == [{"width": 64, "height": 48, "count": 10}]
    np.testing.assert_allclose(s["points_bounds_min"], pts.min(0), rtol=1e-6)
    assert s["extent"] == pytest.approx(scene.extent, rel=1e-6)

    # The loaded points initialise one Gaussian each.
    loaded = load_scene(tmp_path, load_images=False)
    g = gaussians_from_points(loaded.points, loaded.point_colors, source=loaded.source)
    assert len(g) == 80 and torch.isfinite(g.log_scales).all()


def test_a_reader_that_leaves_the_pipe_gets_no_error_line(tmp_path):
    """`splatstyler info DATA | head -1`: the reader leaves early; like any Unix tool, no error and no traceback."""
    import subprocess
    import sys

    from assets.demo.assets import demo_assets

    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, "-m", "app", "info", str(demo_assets().scene_dir)], cwd=root,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()  # the reader is gone before the first line is written
    err = proc.stderr.read()
    proc.wait(timeout=120)
    assert err == "" and proc.returncode == 141, (proc.returncode, err)
