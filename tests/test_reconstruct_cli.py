"""``splatstyler reconstruct`` end to end on tiny demo scenes written to disk as COLMAP folders."""

import json
import time

import numpy as np
import pytest
import torch

from app.cli import main
from assets.demo.scene import make_demo_scene, write_demo_scene
from training.model.ply_io import read_ply

REPORT_KEYS = {"train_psnr", "test_psnr", "test_ssim", "num_gaussians", "aniso_p95", "smax_p95", "seconds",
               "settings"}


@pytest.fixture(scope="module")
def demo_folder(tmp_path_factory):
    d = make_demo_scene(num_views=10, width=64, height=48, num_points=400)
    return write_demo_scene(tmp_path_factory.mktemp("demo") / "scene", d)


@pytest.fixture(scope="module")
def no_points_folder(tmp_path_factory):
    from training.scene.colmap_io import write_colmap_model
    from training.scene.image_io import write_image

    d = make_demo_scene(num_views=9, width=48, height=36, num_points=10)
    folder = tmp_path_factory.mktemp("nopts") / "scene"
    for cam, im in zip(d.cameras, d.images):
        write_image(folder / "images" / cam.name, im)
    (folder / "sparse" / "0").mkdir(parents=True)
    write_colmap_model(folder / "sparse" / "0", d.cameras, points=None)
    return folder


def _run(args, capsys):
    rc = main(["reconstruct", *map(str, args), "--no-progress", "--downscale", "1"])
    return rc, capsys.readouterr()


def test_help_says_a_finished_run_keeps_its_checkpoint_and_why(capsys):
    """A finished run keeps OUT/checkpoint.pt (about three times the PLY on disk, the model with Adam's moments):
    --help says so, what it is for and that it may be deleted (the test below extends a finished run from it)."""
    with pytest.raises(SystemExit):
        main(["reconstruct", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "The checkpoint is kept when the run finishes" in text
    assert "--resume --iters N trains on from it" in text and "delete it once the model is final" in text


@pytest.mark.slow
def test_cli_writes_ply_report_and_resumes(demo_folder, tmp_path, capsys):
    out = tmp_path / "out"
    t0 = time.perf_counter()
    rc, _ = _run([demo_folder, "-o", out, "--iters", "30", "--checkpoint-every", "15"], capsys)
    wall = time.perf_counter() - t0
    assert rc == 0
    report = json.loads((out / "report.json").read_text())
    assert REPORT_KEYS <= set(report)
    assert 0 < report["seconds"] <= wall
    assert report["iterations"] == 30 and report["settings"]["depth_used"] == "sfm"
    assert report["settings"]["init"] == "sfm" and report["settings"]["config"]["preset"] == "quick"
    g = read_ply(out / "point_cloud.ply")
    assert len(g) == report["num_gaussians"]
    assert all(torch.isfinite(t).all() for t in g.parameters().values())
    assert 1.0 <= report["aniso_p95"] and 0.0 < report["smax_p95"]
    assert np.isfinite(report["test_psnr"]) and np.isfinite(report["constant_color_psnr"])

    rc, cap = _run([demo_folder, "-o", out, "--resume", "--iters", "36"], capsys)
    assert rc == 0 and "at iteration 30" in cap.err
    report2 = json.loads((out / "report.json").read_text())
    assert report2["iterations"] == 36
    assert report2["seconds"] >= report["seconds"]
    assert report2["seconds"] > report["seconds"]  # the resumed run's time adds to the first run's


def test_ctrl_c_saves_a_checkpoint_and_exits_130(demo_folder, tmp_path, capsys, monkeypatch):
    from training.reconstruct.checkpoint import load_checkpoint
    from training.reconstruct.trainer import Reconstructor

    real_step = Reconstructor.step

    def step(self):
        if self.step_count == 7:
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(Reconstructor, "step", step)
    out = tmp_path / "out"
    rc, cap = _run([demo_folder, "-o", out, "--iters", "30", "--checkpoint-every", "0"], capsys)
    assert rc == 130 and "--resume" in cap.err
    assert load_checkpoint(out / "checkpoint.pt")["step"] == 7
    assert not (out / "point_cloud.ply").exists()


def test_scene_without_points_and_sfm_depth_falls_back(no_points_folder, tmp_path, capsys):
    out = tmp_path / "out"
    with pytest.warns(UserWarning, match="no SfM points"):
        rc, _ = _run([no_points_folder, "-o", out, "--iters", "10", "--depth", "sfm"], capsys)
    assert rc == 0
    report = json.loads((out / "report.json").read_text())
    assert report["settings"]["depth_used"] == "none" and report["settings"]["init"] == "random"


def test_bad_inputs_are_one_line_errors(tmp_path, capsys, no_points_folder):
    rc, cap = _run([tmp_path / "missing", "-o", tmp_path / "o"], capsys)
    assert rc == 2 and cap.err.count("\n") == 1 and "splatstyler: error:" in cap.err
    rc, cap = _run([no_points_folder, "-o", tmp_path / "o2", "--resume"], capsys)
    assert rc == 2 and "checkpoint" in cap.err and cap.err.count("\n") == 1
    rc, cap = _run([no_points_folder, "-o", tmp_path / "o3", "--depth", "mono"], capsys)
    assert rc == 2 and "SfM points" in cap.err and cap.err.count("\n") == 1
    assert not (tmp_path / "o3" / "point_cloud.ply").exists()
    for flag, value, rule in (("--densify-grad", "0", "positive"), ("--prune-screen", "-0.1", "at least 0")):
        rc, cap = _run([no_points_folder, "-o", tmp_path / "o4", flag, value], capsys)
        assert rc == 2 and cap.err.count("\n") == 1 and flag in cap.err and rule in cap.err
        assert not (tmp_path / "o4").exists()


def test_bench_reconstruct_reports_phases(demo_folder, capsys):
    t0 = time.perf_counter()
    rc = main(["bench", "reconstruct", "--scene", str(demo_folder), "--downscale", "1", "--iters", "3",
               "--warmup", "1", "--backends", "cpu", "--json"])
    wall_ms = 1e3 * (time.perf_counter() - t0)
    assert rc == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    assert len(rows) == 1 and rows[0]["backend"] == "cpu" and rows[0]["size"] == "64x48"
    phases = [rows[0][f"ms_{k}"] for k in ("rasterize", "loss", "backward", "optimizer", "densify")]
    assert all(p >= 0 for p in phases) and rows[0]["it_per_s"] > 0
    assert sum(phases) <= rows[0]["ms_total"] * 1.001
    # every timed iteration does render, compute a loss and step back through it
    assert min(rows[0][f"ms_{k}"] for k in ("rasterize", "loss", "backward")) > 0
    assert rows[0]["it_per_s"] == pytest.approx(1e3 / rows[0]["ms_total"])
    assert 3 * rows[0]["ms_total"] < wall_ms  # the 3 timed iterations ran inside the call


def test_resume_refuses_settings_that_differ_from_the_checkpoint(demo_folder, tmp_path, capsys):
    """--resume trains on with the checkpoint's settings: a flag that would change them is one line naming it and
    the checkpoint's value (exit 2, nothing touched), not silently dropped; the same value, --iters and --backend
    are taken."""
    out = tmp_path / "out"
    rc, _ = _run([demo_folder, "-o", out, "--iters", "8", "--max-gaussians", "500", "--seed", "2"], capsys)
    assert rc == 0
    before = (out / "checkpoint.pt").read_bytes()
    rc, cap = _run([demo_folder, "-o", out, "--resume", "--iters", "10", "--max-gaussians", "900", "--seed", "2",
                    "--no-shape", "--preset", "paper"], capsys)
    assert rc == 2 and cap.err.count("\n") == 1 and "Traceback" not in cap.err, cap.err
    assert cap.err.startswith(f"splatstyler: error: {out / 'checkpoint.pt'}: --resume continues")
    for named in ("--max-gaussians 900 (it has densify.max_gaussians 500)", "--no-shape (it has use_shape True)",
                  "--preset paper (it has quick)", "--overwrite"):
        assert named in cap.err, cap.err
    assert "--seed" not in cap.err and "--iters" not in cap.err  # the checkpoint's own value; a longer run
    assert (out / "checkpoint.pt").read_bytes() == before
    rc, cap = _run([demo_folder, "-o", out, "--resume", "--iters", "10", "--max-gaussians", "500", "--seed", "2",
                    "--backend", "torch"], capsys)
    assert rc == 0 and "at iteration 8" in cap.err, cap.err
    config = json.loads((out / "report.json").read_text())["settings"]["config"]
    assert config["iterations"] == 10 and config["backend"] == "torch" and config["densify"]["max_gaussians"] == 500


def test_a_fresh_run_does_not_replace_an_interrupted_runs_checkpoint(demo_folder, tmp_path, capsys, monkeypatch):
    """A run without --resume in an OUT whose checkpoint is an interrupted run's is refused in one line (exit 2,
    the checkpoint as it was) unless --overwrite; a finished run's checkpoint is replaced as its model is."""
    from training.reconstruct.trainer import Reconstructor

    real_step = Reconstructor.step

    def step(self):
        if self.step_count == 5:
            raise KeyboardInterrupt
        return real_step(self)

    out = tmp_path / "out"
    with monkeypatch.context() as m:
        m.setattr(Reconstructor, "step", step)
        rc, _ = _run([demo_folder, "-o", out, "--iters", "12", "--checkpoint-every", "0"], capsys)
    assert rc == 130
    before = (out / "checkpoint.pt").read_bytes()
    rc, cap = _run([demo_folder, "-o", out, "--iters", "12"], capsys)
    assert rc == 2 and cap.err.count("\n") == 1, cap.err
    assert cap.err == (f"splatstyler: error: {out / 'checkpoint.pt'}: holds an interrupted run's checkpoint "
                       "(iteration 5 of 12): continue it with --resume, or start afresh with --overwrite (which "
                       "replaces it)\n")
    assert (out / "checkpoint.pt").read_bytes() == before and not (out / "point_cloud.ply").exists()
    rc, cap = _run([demo_folder, "-o", out, "--iters", "6", "--overwrite"], capsys)
    assert rc == 0 and "resuming" not in cap.err
    rc, _ = _run([demo_folder, "-o", out, "--iters", "4"], capsys)  # over a finished run: its files are replaced
    assert rc == 0 and json.loads((out / "report.json").read_text())["iterations"] == 4
