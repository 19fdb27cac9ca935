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
    # the phases apart (SSIM and each regularizer apart from the loss), summing to the step with "other"
    from training.reconstruct.trainer import PHASES

    assert {"ssim", "shape", "size", "depth", "checks"} <= set(PHASES)
    assert min(rows[0][f"ms_{k}"] for k in ("ssim", "shape", "size", "depth", "checks")) > 0
    assert sum(rows[0][f"ms_{k}"] for k in (*PHASES, "other")) == pytest.approx(rows[0]["ms_total"])
    # and the cpu rasterizer's own stages, its backward's inside the step's backward
    raster = {k[len("ms_raster_"):]: v for k, v in rows[0].items() if k.startswith("ms_raster_")}
    assert {"project", "sort", "sh", "composite", "composite_bwd", "project_sh_bwd"} <= set(raster)
    assert raster["composite_bwd"] + raster["project_sh_bwd"] <= rows[0]["ms_backward"]


@pytest.mark.slow
def test_bench_reconstruct_from_a_checkpoint(demo_folder, tmp_path, capsys):
    """--checkpoint times the steps that follow a run's checkpoint: its model, optimiser and schedule position."""
    out = tmp_path / "run"
    rc, _ = _run([demo_folder, "-o", out, "--iters", "20", "--max-gaussians", "700"], capsys)
    assert rc == 0
    n = json.loads((out / "report.json").read_text())["num_gaussians"]
    rc = main(["bench", "reconstruct", "--scene", str(demo_folder), "--checkpoint", str(out / "checkpoint.pt"),
               "--iters", "3", "--warmup", "1", "--backends", "cpu", "--json"])
    assert rc == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    assert rows[0]["steps"] == "22-24" and rows[0]["size"] == "64x48"
    assert rows[0]["gaussians_end"] == n  # densification stopped before step 20 of 20: the model as saved
    rc = main(["bench", "reconstruct", "--checkpoint", str(out / "checkpoint.pt"), "--iters", "1"])
    assert rc == 2 and "--scene" in capsys.readouterr().err


def test_eval_every_scores_the_test_views_into_the_report(demo_folder, tmp_path, capsys):
    """--eval-every N: the test views' PSNR every N iterations (and at the end), kept in report.json; the last point
    is the report's own test PSNR."""
    out = tmp_path / "curve"
    rc, _ = _run([demo_folder, "-o", out, "--iters", "12", "--eval-every", "5"], capsys)
    assert rc == 0
    report = json.loads((out / "report.json").read_text())
    assert [p["iteration"] for p in report["test_curve"]] == [5, 10, 12]
    assert report["test_curve"][-1]["psnr"] == pytest.approx(report["test_psnr"])
    assert 0 < report["test_curve_seconds"] < report["seconds"]
    rc, cap = _run([demo_folder, "-o", tmp_path / "bad", "--iters", "2", "--eval-every", "-1"], capsys)
    assert rc == 2 and "--eval-every" in cap.err and not (tmp_path / "bad").exists()


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
                    "--backend", "torch", "--eval-every", "1"], capsys)
    assert rc == 0 and "at iteration 8" in cap.err, cap.err
    report = json.loads((out / "report.json").read_text())
    config = report["settings"]["config"]
    assert config["iterations"] == 10 and config["backend"] == "torch" and config["densify"]["max_gaussians"] == 500
    # the scoring may change on a resume (--eval-every 1: the resumed iterations 9 and 10 scored)
    assert config["eval_every"] == 1 and [p["iteration"] for p in report["test_curve"]][-2:] == [9, 10]


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


def test_stop_when_flat_ends_the_run_and_keeps_the_best_model(demo_folder, tmp_path, capsys, monkeypatch):
    """--stop-when-flat N: once densification has stopped (step 30 of 60 here), the run ends when the test views'
    PSNR has not risen by 0.05 dB for N iterations, and the best-scoring model is the one written, saying so."""
    from training.reconstruct.trainer import Reconstructor

    real = Reconstructor.evaluate
    kept = {}

    def evaluate(self, indices):
        result = real(self, indices)
        step = self.step_count
        if not kept.get("final"):  # the scores during the run: rising to step 40, then falling
            result["psnr"] = 20.0 + 0.1 * min(step, 40) - 0.2 * max(0, step - 40)
            if step == 40:
                kept["params"] = {k: v.detach().clone() for k, v in self.gaussians.parameters().items()}
        return result

    monkeypatch.setattr(Reconstructor, "evaluate", evaluate)
    out = tmp_path / "flat"
    rc, cap = _run([demo_folder, "-o", out, "--iters", "60", "--eval-every", "5", "--stop-when-flat", "10"],
                   capsys)
    assert rc == 0, cap.err
    report = json.loads((out / "report.json").read_text())
    assert report["iterations"] == 50 and [p["iteration"] for p in report["test_curve"]][-1] == 50
    assert report["early_stop"]["stopped_at"] == 50 and report["early_stop"]["best_iteration"] == 40
    assert report["early_stop"]["kept"] == "best"
    assert "stopped at iteration 50 of 60" in cap.err and "kept the model of iteration 40" in cap.err
    written = read_ply(out / "point_cloud.ply")
    for name, value in kept["params"].items():
        torch.testing.assert_close(getattr(written, name), value, rtol=1e-6, atol=1e-6)
    rc, cap = _run([demo_folder, "-o", tmp_path / "bad", "--iters", "2", "--stop-when-flat", "-1"], capsys)
    assert rc == 2 and "--stop-when-flat" in cap.err
