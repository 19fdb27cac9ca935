"""``splatstyler bench formats`` on a small model: a row per format with the written file's bytes, PLY's ratio 1,
and with --data a PSNR that is infinite for the lossless formats and finite for the quantised ones."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from app.cli import main
from app.bench.formats import random_model
from training.model.ply_io import write_ply

FOX = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "scenes" / "fox" / "transforms.json"


def test_bench_formats_rows(tmp_path, capsys):
    write_ply(tmp_path / "m.ply", random_model(400, 2))
    assert main(["bench", "formats", "--model", str(tmp_path / "m.ply"), "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["format"] for r in rows] == ["ply", "compressed-ply", "splat", "spz v4", "spz v3", "glb"]
    by = {r["format"]: r for r in rows}
    assert by["ply"]["size_vs_ply"] == 1 and by["ply"]["bytes"] == (tmp_path / "m.ply").stat().st_size
    assert by["splat"]["bytes"] == 400 * 32 and by["splat"]["sh_bands"] == 0
    assert by["spz v4"]["bytes"] < by["compressed-ply"]["bytes"] < by["ply"]["bytes"]
    assert all(r["gaussians"] == 400 and r["write_s"] > 0 and r["read_s"] > 0 for r in rows)


def test_bench_formats_psnr_on_a_scene(tmp_path, capsys):
    if not FOX.exists():
        pytest.skip(f"shared data not found at {FOX}")
    write_ply(tmp_path / "m.ply", random_model(300, 1))
    assert main(["bench", "formats", "--model", str(tmp_path / "m.ply"), "--data", str(FOX), "--views", "2",
                 "--max-side", "48", "--json"]) == 0
    rows = {r["format"]: r for r in map(json.loads, capsys.readouterr().out.splitlines())}
    assert rows["ply"]["psnr_db"] == float("inf")
    assert 20 < rows["spz v4"]["psnr_db"] < float("inf")
