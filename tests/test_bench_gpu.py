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
    """Every step through the code bench gpu runs, on the CPU at toy sizes (10 s on 2 quiet cores, 40 s under load).
    Slow: all six steps for real: the parity step's pytest in a subprocess (its start and collection; the CUDA
    cases skip), the CPU rasterizer's bench, the viewer benches (every accumulation format and display path on
    llvmpipe), a 40-step reconstruction with its report and a stylization with VGG-16 loaded, one step a view over
    8 views (58 s in a clean-clone CI run on 2 cores)."""
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
    assert viewer["display_path"].startswith("gl-") or (torch.cuda.is_available()
                                                        and viewer["display_path"].startswith("cuda/"))
    if not torch.cuda.is_available():
        assert viewer["cuda_breakdown_skipped"] == "torch sees no CUDA device"
        assert steps["display"]["rows"][0]["cuda_breakdown_skipped"] == "torch sees no CUDA device"
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


def test_frame_breakdown_of_the_cuda_path_and_its_table():
    """The CUDA display path's frame breakdown, run on CPU tensors (the torch backend: the same code), and the table
    bench gpu writes of it; interop cannot run without CUDA, and the table says why."""
    from app.bench.cuda_frame import STAGES, frame_breakdown
    from app.viewer.camera import ViewerCamera
    from renderer_gl import create_context
    from tests.test_display_path import snapshot

    ctx = create_context("egl")
    cam = ViewerCamera.looking_at((0.4, -0.3, -4.0), (0.0, 0.0, 0.0), up=(0.0, -1.0, 0.0), fov_y_degrees=40.0)
    bd = frame_breakdown(ctx, snapshot(n=2000), cam.camera(64, 48), repeat=2, backend="torch")
    ctx.release()
    assert bd["cuda_pinned_frame_ms"] > 0 and all(bd[f"cuda_pinned_{s}_ms"] > 0 for s in STAGES)
    assert bd["cuda_pinned_stages_ms"] == pytest.approx(sum(bd[f"cuda_pinned_{s}_ms"] for s in STAGES))
    assert "cuda_interop_frame_ms" not in bd and bd["cuda_interop_skipped"].startswith("InteropError: ")
    row = {"n": 2000, "width": 64, "height": 48, **bd}
    md = "\n".join(gpu.breakdown_markdown({"display": {"command": "splatstyler bench viewer --cuda-only",
                                                         "rows": [row, {"n": 10, "cuda_breakdown_skipped": "why"}]}}))
    assert "## Where a frame of the CUDA display path goes (ms)" in md
    cells = [gpu._fmt(bd[f"cuda_pinned_{s}_ms"]) for s in STAGES]
    assert f"| 2000 | 64x48 | pinned | {' | '.join(cells)} | {gpu._fmt(bd['cuda_pinned_stages_ms'])} |" in md
    assert f"- 2000 splats, interop: not measured: {bd['cuda_interop_skipped']}" in md
    assert "- 10 splats: not measured: why" in md
