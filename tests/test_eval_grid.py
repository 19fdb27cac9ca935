"""`splatstyler eval`: the grid file, a real (tiny) grid through the console command with a local pool and on a
local Ray instance, resuming, and one failing cell that does not stop the grid."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from app.evaluate.grid import job_dir, load_grid
from training.core.errors import InputError

TINY = """
title = "tiny"
seeds = [0]
[reconstruct]
iters = 100
downscale = 4
[stylize]
preset = "quick"
max_side = 64
iters_per_view = 1
min_total_iters = 3
[scenes.demo]
data = "{scene}"
[paintings]
strokes = "{style}"
[settings.ccft]
[settings.nnfm]
loss = "nnfm"
{extra}
[groups.loss]
title = "Loss"
settings = ["ccft", "nnfm"]
metrics = ["utilisation", "swd_ratio_pre_ct", "consistency_short_rmse"]
expect = [["ccft", ">", "nnfm", "utilisation"]]
"""


@pytest.fixture(scope="module")
def demo():
    from assets.demo.assets import demo_assets

    return demo_assets()


def write_grid(folder: Path, demo, extra: str = "") -> Path:
    path = folder / "grid.toml"
    path.write_text(TINY.format(scene=demo.scene_dir, style=demo.style_image, extra=extra))
    return path


def stop_cell_after_its_first_step(folder: Path) -> int:
    """Leave ``folder`` as a grid stopped in that cell leaves it: its stylization run again from the cell's own
    settings (job.json) and stopped (as SIGTERM does) after the first step, so only its checkpoint is there."""
    from app.settings import parse_flags
    from app.settings import stylize as settings
    from training.core import stop
    from training.core.messages import Stepped
    from training.stylize.checkpoint import CHECKPOINT_NAME
    from training.stylize.pipeline import stylize_to_folder

    spec = json.loads((folder / "job.json").read_text())["spec"]
    model = job_dir(folder.parents[4], spec["recon_job"]) / "point_cloud.ply"
    (folder / "report.json").unlink()
    options = settings.stylize_options(parse_flags(settings.add_arguments, spec["flags"], "stylize flags"), model)
    try:
        with pytest.raises(stop.StopRequested, match=r"at iteration \d+;") as stopped:
            stylize_to_folder(model, Path(spec["data"]), Path(spec["painting_path"]), folder, overwrite=True,
                              listener=lambda event: isinstance(event, Stepped) and stop.request(), **options)
    finally:
        stop.reset()
    assert (folder / CHECKPOINT_NAME).is_file()
    return int(str(stopped.value).split("at iteration ")[1].split(";")[0])


def run_eval(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "app", "eval", *argv], capture_output=True, text=True, timeout=1500)


@pytest.mark.parametrize("body, problem", [
    ("[scenes.a]\ndata = 'x'\n", "no such file or folder"),
    ("colour = 1\n", "unknown key 'colour'"),
    ("seeds = []\n", "seeds must be a non-empty list"),
    ("[scenes.a]\n", "needs exactly one of data"),
])
def test_bad_grid_files_name_the_problem(tmp_path, body, problem):
    path = tmp_path / "g.toml"
    path.write_text(body)
    with pytest.raises(InputError, match=problem):
        load_grid(path)


def test_grid_expands_cells_and_shares_reconstructions(tmp_path, demo):
    grid = load_grid(write_grid(tmp_path, demo, extra='[settings.vanilla]\nreconstruction = "plain"\n'
                                                  '[reconstructions.plain]\nno_shape = true\n'))
    cells = grid.cells
    assert [c.spec["setting"] for c in cells] == ["ccft", "nnfm", "vanilla"]
    recons = [j for j in grid.jobs if j.kind == "reconstruct"]
    assert len(recons) == 2  # ccft and nnfm share one; the variant has its own
    assert cells[0].deps == cells[1].deps != cells[2].deps
    assert "--no-shape" in recons[1].spec["flags"] and "--no-shape" not in recons[0].spec["flags"]
    assert cells[1].spec["flags"][-4:] == ["--loss", "nnfm", "--seed", "0"]


def test_undefined_names_are_refused(tmp_path, demo):
    with pytest.raises(InputError, match="reconstruction 'nope' is not defined"):
        load_grid(write_grid(tmp_path, demo, extra='[settings.x]\nreconstruction = "nope"\n'))
    path = write_grid(tmp_path, demo)
    path.write_text(path.read_text().replace('settings = ["ccft", "nnfm"]', 'settings = ["ccft", "gram"]'))
    with pytest.raises(InputError, match="'gram' is not in"):
        load_grid(path)


@pytest.mark.slow
def test_grid_runs_resumes_and_records_a_failed_cell(tmp_path, demo):
    """The tiny grid with a cell whose tau is -1, on 2 workers: that cell fails with the stylize command's one-line
    error and the grid exits 1, the ccft and nnfm cells finish with every metric in cells.csv, and RESULTS.md counts
    2 of 3 cells finished, checks the paper's ccft > nnfm and names the failed cell, beside a plot and a contact
    sheet. Run again after the nnfm cell's record is removed and its stylization stopped after its first step, only
    the two jobs not done run, the finished ccft cell is left untouched, the nnfm cell continues from its checkpoint,
    and the new record carries the package's version.
    Slow: two `splatstyler eval` runs, each a process with spawned workers importing torch: a 100-step
    reconstruction of the demo scene at 1/4 size, three quick stylizations at 64 px (ccft and nnfm, then nnfm
    again) each measured for the report (training/evaluate/measure.py), and the report twice, its worst-pair sheet
    rendered again from the saved models (85 s in a clean-clone CI run on 2 cores)."""
    grid = write_grid(tmp_path, demo, extra="[settings.broken]\ntau = -1\n")
    out = tmp_path / "out"
    proc = run_eval(str(grid), "-o", str(out), "--workers", "2", "--threads", "1")
    # the broken cell fails with the stylize command's own one-line message; the others finish
    assert proc.returncode == 1, proc.stdout[-3000:] + proc.stderr[-3000:]
    broken = json.loads((out / "jobs" / "cell" / "demo" / "broken" / "strokes" / "seed0.json").read_text())
    assert broken["status"] == "failed" and "tau" in broken["error"] and "\n" not in broken["error"]
    with open(out / "report" / "results" / "cells.csv") as f:
        rows = list(csv.DictReader(f))
    assert sorted(r["setting"] for r in rows) == ["ccft", "nnfm"]
    for row in rows:
        for key in ("utilisation", "swd_ratio_pre_ct", "consistency_short_rmse", "structure_distance",
                    "recon_test_psnr"):
            assert row[key] != "" and float(row[key]) == float(row[key]), (row["setting"], key)
    md = (out / "report" / "RESULTS.md").read_text()
    assert "2 of 3 cells finished, 1 failed" in md
    assert "paper: ccft > nnfm on `utilisation`: ours agrees on" in md
    assert (out / "report" / "results" / "plots" / "loss.png").stat().st_size > 1000
    assert (out / "report" / "results" / "sheets" / "loss_demo.jpg").is_file()
    assert "cell/demo/broken/strokes/seed0" in md

    # a second run resumes: the finished cells are kept untouched, only the failed one runs again, and the nnfm
    # cell, stopped after its first step, continues from its checkpoint
    ok_report = out / "cell" / "demo" / "ccft" / "strokes" / "seed0" / "report.json"
    before = ok_report.stat().st_mtime_ns
    (out / "jobs" / "cell" / "demo" / "nnfm" / "strokes" / "seed0.json").unlink()
    kept_at = stop_cell_after_its_first_step(out / "cell" / "demo" / "nnfm" / "strokes" / "seed0")
    proc = run_eval(str(grid), "-o", str(out), "--workers", "1", "--resume")  # --resume: the same, said
    assert "2 jobs to run (2 already done)" in proc.stdout, proc.stdout
    assert ok_report.stat().st_mtime_ns == before
    nnfm = json.loads((out / "jobs" / "cell" / "demo" / "nnfm" / "strokes" / "seed0.json").read_text())
    assert nnfm["status"] == "ok"
    resumed = json.loads((out / "cell" / "demo" / "nnfm" / "strokes" / "seed0" / "report.json").read_text())
    assert 1 <= kept_at == resumed["resumed_at_iteration"] < resumed["iterations"]
    from importlib.metadata import version

    assert nnfm["splatstyler_version"] == version("splatstyler")


@pytest.mark.slow
def test_grid_runs_on_a_local_ray_instance(tmp_path, demo):
    """`splatstyler eval --ray local` runs the tiny grid as tasks on a local Ray instance: exit 0, the console says
    "on Ray (local)", both cells are recorded ok with a utilisation above 0, and RESULTS.md is written.
    Slow: a local Ray instance started (its own processes, and workers that import torch), the grid's 100-step
    reconstruction of the demo scene at 1/4 size and its two quick stylizations at 64 px, each measured for the
    report, and the report (89 s in a clean-clone CI run on 2 cores)."""
    pytest.importorskip("ray")
    grid = write_grid(tmp_path, demo)
    out = tmp_path / "ray_out"
    # a local Ray instance with the machine's CPUs (2 in CI), one task per job
    proc = run_eval(str(grid), "-o", str(out), "--ray", "local", "--threads", "1")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "on Ray (local)" in proc.stdout
    for setting in ("ccft", "nnfm"):
        rec = json.loads((out / "jobs" / "cell" / "demo" / setting / "strokes" / "seed0.json").read_text())
        assert rec["status"] == "ok" and rec["metrics"]["utilisation"] > 0
    assert (out / "report" / "RESULTS.md").is_file()


def test_a_record_made_with_other_settings_is_not_done(tmp_path, demo):
    from app.evaluate.runner import is_done

    grid = load_grid(write_grid(tmp_path, demo))
    job = grid.cells[1]
    from training.evaluate.measure import METRICS_VERSION

    record = {"status": "ok", "job": {"id": job.id, "spec": dict(job.spec)}, "metrics_version": METRICS_VERSION}
    assert is_done(record, job)
    path = tmp_path / "grid.toml"
    path.write_text(path.read_text().replace('loss = "nnfm"', 'loss = "nnfm"\ntau = 0.1'))
    changed = load_grid(path)
    assert not is_done(record, changed.cells[1])  # the grid file changed this cell: it runs again
    assert not is_done({**record, "status": "failed"}, job)


@pytest.mark.slow
def test_a_grid_killed_with_sigkill_resumes_losing_only_the_running_job(tmp_path, demo):
    """SIGKILL to the whole grid (parent and workers: no handler runs) once the reconstruction is recorded: the run
    after it keeps that job, runs the rest, and finishes.
    Slow: two `splatstyler eval` runs on one worker: the first through the 100-step reconstruction of the demo scene
    until its record appears, then killed; the second through both quick stylizations at 64 px, one after the
    other, each measured for the report, and the report (80 s in a clean-clone CI run on 2 cores)."""
    import os
    import signal
    import time

    grid = write_grid(tmp_path, demo)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "app", "eval", str(grid), "-o", str(out), "--workers", "1",
                             "--threads", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        t0 = time.time()
        while time.time() - t0 < 600 and proc.poll() is None:
            done = [p for p in (out / "jobs").rglob("*.json")
                    if json.loads(p.read_text()).get("status") == "ok"] if (out / "jobs").is_dir() else []
            if done:
                break
            time.sleep(0.5)
        assert proc.poll() is None, "the grid ended before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    kept = {p: p.read_text() for p in done}
    assert len(kept) == 1
    again = run_eval(str(grid), "-o", str(out), "--workers", "1", "--threads", "1")
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert "(1 already done)" in again.stdout, again.stdout
    for path, text in kept.items():
        assert path.read_text() == text  # the recorded job was not run again
    for setting in ("ccft", "nnfm"):
        rec = json.loads((out / "jobs" / "cell" / "demo" / setting / "strokes" / "seed0.json").read_text())
        assert rec["status"] == "ok"


def test_time_left_goes_by_the_recorded_jobs_most_like_each_one_left():
    from app.evaluate.grid import Job
    from app.evaluate.runner import time_left

    def cell(scene, setting, seed):
        return Job(f"cell/{scene}/{setting}/{seed}", "cell", {"scene": scene, "setting": setting})

    jobs = {j.id: j for j in (
        Job("reconstruct/fern", "reconstruct", {"scene": "fern"}), cell("fox", "sh", 0), cell("fox", "sh", 1),
        cell("fern", "sh", 0), cell("fern", "all", 0), cell("fern", "all", 1), cell("fern", "dc", 0),
        cell("flower", "sh", 0), Job("sfm/flower", "sfm", {"scene": "flower"}))}
    results = {"reconstruct/fern": {"status": "ok", "seconds": 300.0},
               "cell/fox/sh/0": {"status": "ok", "seconds": 300.0}, "cell/fox/sh/1": {"status": "ok", "seconds": 320.0},
               "cell/fern/sh/0": {"status": "ok", "seconds": 250.0}, "cell/fern/all/0": {"status": "ok", "seconds": 600.0},
               "cell/flower/sh/0": {"status": "failed", "error": "x", "seconds": 5.0}}
    # a fern "all" cell at fern's "all" cells; a fern "dc" cell at fern's cells; a flower cell (none finished) at
    # every finished cell; shared by two workers
    left = time_left(results, jobs, [jobs["cell/fern/all/1"], jobs["cell/fern/dc/0"], jobs["cell/flower/sh/0"]],
                     capacity=2)
    assert left == pytest.approx((600.0 + (250.0 + 600.0) / 2 + (300.0 + 320.0 + 250.0 + 600.0) / 4) / 2)
    assert time_left(results, jobs, [jobs["sfm/flower"]], capacity=1) is None  # no SfM finished to go by
    assert time_left(results, jobs, [], capacity=1) == 0.0
