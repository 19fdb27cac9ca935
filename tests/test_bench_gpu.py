"""``splatstyler bench gpu``: its one-line refusal without CUDA, and its report written from a real (tiny) run of
the same steps on the CPU."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from app.bench import gpu
from app.cli import main as cli

STYLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "styles" / "starry_night.jpg"


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_without_cuda_it_says_so_in_one_line_and_exits_2(tmp_path, capsys):
    out = tmp_path / "out"
    rc = cli(["bench", "gpu", "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and "CUDA" in err[0] and "Traceback" not in err[0], err
    assert not out.exists()  # nothing started, nothing written


@pytest.mark.slow
def test_report_from_a_real_cpu_run_of_every_step(tmp_path):
    """Every step through the code bench gpu runs, on the CPU at toy sizes (10 s on 2 quiet cores, 40 s under load)."""
    from assets.demo.scene import make_demo_scene, write_demo_scene

    scene = tmp_path / "scene"
    scene = write_demo_scene(scene, make_demo_scene(num_views=8, width=64, height=48, num_points=300))
    style = STYLE if STYLE.is_file() else None  # None: the demo's generated painting (generated once, cached)
    results = gpu.collect(tmp_path / "run", list(gpu.STEPS), [3000], "96x64", 1, data=scene, style=style,
                          backend="cpu", recon_extra=["--iters", "40", "--downscale", "1", "--depth", "none"],
                          stylize_extra=["--iters-per-view", "1", "--no-metrics"])
    steps = {s["step"]: s for s in results["steps"]}
    assert list(steps) == list(gpu.STEPS)
    assert steps["parity"]["status"] == ("ok" if torch.cuda.is_available() else "skipped")
    assert steps["parity"]["skipped"] >= 1 or steps["parity"]["passed"] >= 1
    raster = steps["raster"]
    assert raster["status"] == "ok" and raster["rows"][0]["backend"] == "cpu" and raster["rows"][0]["fwd_ms"] > 0
    viewer = steps["viewer"]["rows"][0]
    assert viewer["n"] == 3000 and viewer["frame_f2_ms"] > 0
    # the chooser's pick: on a CUDA machine it may be the cuda path (it was, on an H100)
    assert viewer["display_path"].startswith("gl-") or (torch.cuda.is_available() and viewer["display_path"] == "cuda")
    rec = steps["reconstruct"]
    assert rec["status"] == "ok", rec
    assert rec["iterations"] == 40 and rec["minutes"] > 0 and rec["test_psnr"] > 5 and rec["peak_gpu_gib"] is None
    sty = steps["stylize"]
    assert sty["status"] in ("ok", "failed")  # failed only where no VGG weights can be had: its error says so
    if sty["status"] == "failed":
        assert "VGG" in sty["error"] or "vgg" in sty["error"], sty
    else:
        assert sty["iterations"] >= 1 and sty["it_per_s"] > 0

    json_path, md_path = gpu.write_report(results, tmp_path / "report")
    assert json.loads(json_path.read_text())["steps"][2]["rows"][0]["frame_f2_ms"] == viewer["frame_f2_ms"]
    md = md_path.read_text()
    assert "## Rasterizer (ms)" in md and "## Viewer (ms a frame)" in md and "## Pipeline" in md
    assert f"| cpu | 3000 | 96x64 | {gpu._fmt(raster['rows'][0]['fwd_ms'])} |" in md
    assert f"| reconstruct | ok | {gpu._fmt(rec['minutes'])} |" in md
    assert "8.35 min (RTX 4090)" in md and viewer["display_path"] in md
    assert [r["step"] for r in gpu.pipeline_rows(results)] == list(gpu.STEPS)
