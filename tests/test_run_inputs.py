"""Runs that know their inputs (issue 30): a checkpoint, report or grid record holds the fingerprint of what it was
made from, and a resume or a skip checks it; a stylization keeps what it made when interrupted and resumes; SfM
output is whole or absent; grid names are checked."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from app.cli import main

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
FOX = SHARED / "data" / "scenes" / "fox"
FERN = SHARED / "data" / "scenes" / "llff_fern" / "images"


def fox_subset(folder: Path, frames: int) -> Path:
    """The first ``frames`` frames of the fox: its transforms.json cut short, the photos where they are."""
    folder.mkdir(parents=True)
    (folder / "images").symlink_to(FOX / "images")
    doc = json.loads((FOX / "transforms.json").read_text())
    doc["frames"] = doc["frames"][:frames]
    (folder / "transforms.json").write_text(json.dumps(doc))
    return folder


def tiny_inputs(root: Path, views: int = 5, seed: int = 0) -> dict[str, Path]:
    """A demo scene of ``views`` views at 64x48, a model made from its surface points, a painting."""
    from assets.demo.painting import make_style_image
    from assets.demo.scene import make_demo_scene, write_demo_scene
    from training.model.gaussian_init import gaussians_from_points
    from training.model.ply_io import write_ply
    from training.scene.image_io import write_image

    d = make_demo_scene(num_views=views, width=64, height=48, num_points=1500, supersample=1, seed=seed)
    write_demo_scene(root / "scene", d)
    g = gaussians_from_points(d.points, d.point_colors, sh_degree=1)
    g.opacity_logits = torch.full_like(g.opacity_logits, 2.0)  # cover the views (init opacity 0.1 leaves holes)
    write_ply(root / "model.ply", g)
    write_image(root / "style.png", np.asarray(make_style_image(size=128, seed=0), dtype=np.float32))
    return {"model": root / "model.ply", "data": root / "scene", "style": root / "style.png"}


def stylize_args(inputs: dict[str, Path], out: Path, *extra: str) -> list[str]:
    return ["stylize", str(inputs["model"]), "--data", str(inputs["data"]), "--style", str(inputs["style"]),
            "-o", str(out), "--preset", "quick", "--max-side", "64", "--iters-per-view", "2", "--device", "cpu",
            *extra]


# ---------------------------------------------------------------------------------------------- reconstruct


@pytest.mark.slow
@pytest.mark.skipif(not FOX.is_dir(), reason="shared fox scene not available (../shared)")
def test_reconstruct_resume_checks_the_data_of_its_checkpoint(tmp_path, capsys, monkeypatch):
    """A fox checkpoint resumed against 2 of the fox's frames: one line naming what differs and how to start
    afresh, exit 2, the checkpoint untouched; against the fox itself it resumes; --force starts afresh on the
    subset; a checkpoint from before fingerprints resumes with one line saying it could not be checked. (Each run
    is stopped by a Ctrl-C after its next step, which saves a checkpoint: the evaluation at the end is not what
    is tested here.)"""
    from training.reconstruct.checkpoint import load_checkpoint, save_checkpoint
    from training.reconstruct.trainer import Reconstructor

    real_step = Reconstructor.step

    def step(self):
        if getattr(self, "_test_stepped", False):
            raise KeyboardInterrupt
        self._test_stepped = True
        return real_step(self)

    monkeypatch.setattr(Reconstructor, "step", step)
    out = tmp_path / "out"
    ckpt = out / "checkpoint.pt"

    def reconstruct(data: Path, *extra: str) -> tuple[int, str]:
        rc = main(["reconstruct", str(data), "-o", str(out), "--iters", "50", "--downscale", "8",
                   "--checkpoint-every", "0", "--no-progress", "--depth", "none", *extra])
        return rc, capsys.readouterr().err

    assert reconstruct(FOX)[0] == 130 and load_checkpoint(ckpt)["step"] == 1
    before = ckpt.read_bytes()
    subset = fox_subset(tmp_path / "fox2", 2)

    rc, err = reconstruct(subset, "--resume")
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, lines
    assert str(ckpt) in lines[0] and "2 cameras now, 67 then" in lines[0] and "--force" in lines[0], lines[0]
    assert ckpt.read_bytes() == before

    rc, err = reconstruct(FOX, "--resume")
    assert rc == 130 and f"resuming from {ckpt} at iteration 1" in err and "could not be checked" not in err
    assert load_checkpoint(ckpt)["step"] == 2

    state = load_checkpoint(ckpt)
    del state["fingerprint"]  # as a checkpoint of an older version
    save_checkpoint(ckpt, state)
    rc, err = reconstruct(FOX, "--resume")
    assert rc == 130 and "at iteration 2" in err
    assert sum("could not be checked" in line for line in err.splitlines()) == 1
    assert load_checkpoint(ckpt)["fingerprint"]["dataset"]["cameras"] == 67

    rc, err = reconstruct(subset, "--resume", "--force")
    assert rc == 130 and "starting afresh" in err and "resuming" not in err
    state = load_checkpoint(ckpt)
    assert state["step"] == 1 and state["fingerprint"]["dataset"]["cameras"] == 2


def test_fingerprint_names_what_differs():
    from training.scene.fingerprint import InputsChanged, check_same_inputs, difference, make_fingerprint

    a = make_fingerprint(dataset={"cameras": 3, "names": "x", "sizes": "s", "camera_parameters": "p",
                                  "points": 10}, painting="aa" * 32, settings={"seed": 0, "background": (0, 0, 0)})
    assert difference(a, json.loads(json.dumps(a))) is None  # a tuple read back from JSON as a list is the same
    b = {**a, "dataset": {**a["dataset"], "camera_parameters": "q"}}
    assert difference(a, b) == "the dataset differs (other camera poses or intrinsics)"
    assert difference(a, {**a, "settings": {"seed": 1, "background": [0, 0, 0]}}) == \
        "the settings differ (seed 1 now, 0 then)"
    assert "painting file differs" in difference(a, {**a, "painting": "bb" * 32})
    assert difference({"version": 1}, a) is None  # parts a record lacks cannot be compared
    with pytest.raises(InputsChanged) as info:
        check_same_inputs(a, b, "/o/checkpoint.pt")
    assert "\n" not in str(info.value) and str(info.value).startswith("/o/checkpoint.pt: made from other inputs")
    assert check_same_inputs(None, a, "/o/x.pt").startswith("/o/x.pt: records no fingerprint")


# ---------------------------------------------------------------------------------------------- stylize


@pytest.mark.slow
def test_sigterm_after_the_iterations_keeps_the_model_and_resume_finishes_without_iterating(tmp_path):
    """SIGTERM once the stylization is over (during the metrics and renders): exit 143, a model that loads, and
    --resume writes the report without running an iteration again."""
    from training.model.ply_io import read_ply

    inputs = tiny_inputs(tmp_path)
    out = tmp_path / "out"
    args = [sys.executable, "-m", "app", *stylize_args(inputs, out, "--metric-pairs", "2")]
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.time()
        while proc.poll() is None and not (out / "point_cloud.ply").exists() and time.time() - t0 < 300:
            time.sleep(0.005)
        assert proc.poll() is None, "the stylization ended before it could be stopped"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err
    assert not (out / "report.json").exists()  # stopped before the end: the metrics and renders were cut short
    model = out / "point_cloud.ply"
    saved = model.read_bytes()
    assert len(read_ply(model)) == len(read_ply(inputs["model"]))

    again = subprocess.run(args + ["--resume"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert "at iteration 10, stylization finished" in again.stdout
    report = json.loads((out / "report.json").read_text())
    assert report["iterations"] == 10 and len(report["losses"]["history"]) == 10
    assert report["resumed_at_iteration"] == 10 and report["metrics"] is not None
    assert model.read_bytes() == saved  # the model of the first run, not stylized further
    assert len(list((out / "renders").glob("*.png"))) == 5
    assert not (out / "stylize_checkpoint.pt").exists()  # the run is whole


@pytest.mark.slow
def test_interrupt_mid_stylization_then_resume_matches_an_uninterrupted_run(tmp_path, capsys, monkeypatch, vgg):
    """Ctrl-C at the 4th of 10 iterations: exit 130, a model that loads and a checkpoint; a run without --resume
    is refused (it would replace the checkpoint); --resume goes on from there (optimiser moments and CCFT guide
    included) to the model an uninterrupted run makes. Another painting, or another fixed setting, is refused with
    one line."""
    from training.model.ply_io import read_ply
    from training.stylize.trainer import Stylizer

    monkeypatch.setattr("training.stylize.vgg_features.load_vgg16_features", lambda *a, **k: vgg)
    inputs = tiny_inputs(tmp_path)
    whole = tmp_path / "whole"
    assert main(stylize_args(inputs, whole, "--no-metrics")) == 0

    out = tmp_path / "out"
    real_step = Stylizer.step

    def step(self):
        if self.iteration == 4:
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(Stylizer, "step", step)
    assert main(stylize_args(inputs, out, "--no-metrics")) == 130
    assert "splatstyler: stopped by SIGINT at iteration 4; the model so far is in" in capsys.readouterr().err
    assert len(read_ply(out / "point_cloud.ply")) == len(read_ply(inputs["model"]))
    assert (out / "stylize_checkpoint.pt").is_file() and not (out / "report.json").exists()
    monkeypatch.setattr(Stylizer, "step", real_step)

    from training.scene.image_io import write_image

    before = (out / "stylize_checkpoint.pt").read_bytes()  # a run without --resume would replace it: refused
    assert main(stylize_args(inputs, out, "--no-metrics")) == 2
    assert capsys.readouterr().err == (f"splatstyler: error: {out / 'stylize_checkpoint.pt'}: holds an interrupted "
                                       "stylization's checkpoint: continue it with --resume, or start afresh with "
                                       "--overwrite (which replaces it)\n")
    assert (out / "stylize_checkpoint.pt").read_bytes() == before

    other = tmp_path / "other.png"
    write_image(other, np.full((80, 80, 3), 0.5, dtype=np.float32))
    for changed in (stylize_args({**inputs, "style": other}, out, "--no-metrics", "--resume"),
                    stylize_args(inputs, out, "--no-metrics", "--resume", "--view-order", "random")):
        assert main(changed) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "stylize_checkpoint.pt" in err[0] and "--force" in err[0], err
        assert ("painting file differs" in err[0]) != ("view_order 'random' now, 'nearest' then" in err[0])

    assert main(stylize_args(inputs, out, "--no-metrics", "--resume")) == 0
    assert "resuming from" in capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    assert report["iterations"] == 10 and report["resumed_at_iteration"] == 4
    expected = json.loads((whole / "report.json").read_text())["losses"]["history"]
    np.testing.assert_allclose([h["loss"] for h in report["losses"]["history"]], [h["loss"] for h in expected],
                               rtol=1e-4)
    got, want = read_ply(out / "point_cloud.ply"), read_ply(whole / "point_cloud.ply")
    torch.testing.assert_close(got.sh0, want.sh0, atol=1e-5, rtol=0)
    torch.testing.assert_close(got.shN, want.shN, atol=1e-5, rtol=0)


# ---------------------------------------------------------------------------------------------- sfm


def fern_photos(folder: Path, count: int = 8, width: int = 320) -> Path:
    from training.scene.image_io import read_image, resize_image, write_image

    for p in sorted(FERN.iterdir())[::20 // count][:count]:
        img = read_image(p)
        h, w = img.shape[:2]
        write_image(folder / p.name, resize_image(img, width, round(h * width / w)))
    return folder


@pytest.mark.slow
@pytest.mark.skipif(not FERN.is_dir(), reason="shared llff_fern photos not available (../shared)")
def test_sfm_killed_mid_run_leaves_nothing_and_the_same_command_succeeds(tmp_path):
    from training.scene.loader import load_scene

    photos = fern_photos(tmp_path / "photos")
    data = tmp_path / "data"
    args = [sys.executable, "-m", "app", "sfm", str(photos), "-o", str(data), "--max-features", "1024"]
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        for line in proc.stdout:  # killed as the matching starts (8 small photos match in well under a second)
            if line.startswith("[3/5]"):
                break
        assert proc.poll() is None, "sfm ended before it could be killed"
        proc.kill()
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert not data.exists()  # whole or absent
    again = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-2000:]
    assert len(load_scene(data, load_images=False).cameras) >= 6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "photos"]  # the killed run's remains are gone
    report = json.loads((data / "sfm_report.json").read_text())
    assert report["fingerprint"]["photos"]["photos"] == 8


def test_sfm_interrupted_while_moving_into_place_leaves_nothing(tmp_path, monkeypatch):
    """Ctrl-C at the last moment, while the finished scene is being put in place: no folder that passes for a
    scene or refuses the rerun. (pycolmap's own stages are stood in for: this is about the files.)"""
    import training.scene.sfm as sfm
    from training.scene.image_io import write_image

    photos = tmp_path / "photos"
    for i in range(3):
        write_image(photos / f"{i}.png", np.full((16, 16, 3), 0.1 * i, dtype=np.float32))
    real_replace = os.replace
    calls = []

    def replace(src, dst):
        calls.append(dst)
        if Path(dst) in (tmp_path / "data", tmp_path / "data" / "sparse" / "0"):  # the model, into place
            raise KeyboardInterrupt
        return real_replace(src, dst)

    class Model:  # what _map_with_retries hands back: 3 of 3 photos, 500 points
        def num_reg_images(self):
            return 3

        def num_points3D(self):
            return 500

        def reg_image_ids(self):
            return [0, 1, 2]

        def image(self, i):
            return type("Image", (), {"name": f"{i}.png"})

        def write_binary(self, path):
            Path(path, "cameras.bin").write_bytes(b"")

    def undistort(out, model, images, output_type, cancellation_token):
        (Path(out) / "images").mkdir(parents=True)
        (Path(out) / "sparse").mkdir()

    import pycolmap

    monkeypatch.setattr(sfm, "_extract_features", lambda db, *a, **k: Path(db).write_bytes(b""))
    monkeypatch.setattr(sfm, "_match_pairs", lambda *a: None)
    monkeypatch.setattr(pycolmap, "undistort_images", undistort)
    monkeypatch.setattr(sfm, "photos_without_overlap", lambda db, names: [])
    monkeypatch.setattr(sfm, "_map_with_retries", lambda *a: (Model(), "mapping settings that worked: test"))
    monkeypatch.setattr(sfm, "quality_summary", lambda rec, n: {"registered": 3, "photos": n, "points": 500})
    monkeypatch.setattr(sfm.os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        sfm.run_sfm(photos, tmp_path / "data", log=lambda s: None, progress=False)
    assert calls, "the run did not get as far as putting its scene in place"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]
    monkeypatch.setattr(sfm.os, "replace", real_replace)
    result = sfm.run_sfm(photos, tmp_path / "data", log=lambda s: None, progress=False)
    assert result.num_registered == 3 and sfm.sfm_complete(tmp_path / "data")


# ---------------------------------------------------------------------------------------------- eval grid

GRID = """
seeds = [0]
[reconstruct]
iters = 10
downscale = 1
[stylize]
preset = "quick"
max_side = 64
iters_per_view = 1
no_metrics = true
[scenes.a]
data = "{a}"
[scenes.b]
data = "{b}"
[paintings]
p = "{style}"
[settings.ccft]
"""


@pytest.mark.slow
def test_grid_whose_scene_data_changes_redoes_that_scene_and_keeps_the_rest(tmp_path):
    a = tiny_inputs(tmp_path / "a", views=5)
    b = tiny_inputs(tmp_path / "b", views=5, seed=1)
    c = tiny_inputs(tmp_path / "c", views=6, seed=2)
    grid = tmp_path / "grid.toml"
    grid.write_text(GRID.format(a=a["data"], b=b["data"], style=a["style"]))
    out = tmp_path / "out"
    run = [sys.executable, "-m", "app", "eval", str(grid), "-o", str(out), "--workers", "1", "--threads", "1"]
    first = subprocess.run(run, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    kept = {p: p.stat().st_mtime_ns for p in (out / "reconstruct").rglob("report.json") if "/b-" in str(p)}
    kept.update({p: p.stat().st_mtime_ns for p in (out / "cell" / "b").rglob("report.json")})
    assert len(kept) == 2

    grid.write_text(GRID.format(a=c["data"], b=b["data"], style=a["style"]))
    second = subprocess.run(run, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert second.returncode == 0, second.stdout[-3000:] + second.stderr[-3000:]
    assert "2 jobs to run (2 already done)" in second.stdout, second.stdout
    said = [line for line in second.stdout.splitlines() if "runs again" in line]
    assert any(line.startswith("eval: reconstruct/a-") and f"data is {c['data']} now" in line for line in said), \
        second.stdout
    assert any(line.startswith("eval: cell/a/ccft/p/seed0 runs again") for line in said), second.stdout
    for path, mtime in kept.items():
        assert path.stat().st_mtime_ns == mtime, path  # scene b: nothing redone
    recon_a = next((out / "reconstruct").glob("a-*"))
    assert json.loads((recon_a / "report.json").read_text())["fingerprint"]["dataset"]["cameras"] == 6
    cell_a = json.loads((out / "cell" / "a" / "ccft" / "p" / "seed0" / "report.json").read_text())
    assert cell_a["num_views"] == 6


def test_a_record_of_other_inputs_is_not_done_and_nor_are_its_dependants(tmp_path):
    """Same grid file, same paths, but the scene's cameras changed in place: its jobs run again, and say why."""
    from app.evaluate.grid import load_grid, with_inputs
    from app.evaluate.runner import _to_run
    from training.evaluate.measure import METRICS_VERSION

    a = tiny_inputs(tmp_path / "a", views=5)
    b = tiny_inputs(tmp_path / "b", views=5, seed=1)
    grid = tmp_path / "grid.toml"
    grid.write_text(GRID.format(a=a["data"], b=b["data"], style=a["style"]))
    jobs = with_inputs(load_grid(grid))
    records = {j.id: {"status": "ok", "job": {"id": j.id, "spec": j.spec, "inputs": j.inputs},
                      "metrics_version": METRICS_VERSION} for j in jobs}
    lines: list[str] = []
    assert _to_run(jobs, records, lines.append) == [] and lines == []

    from training.scene.colmap_io import write_colmap_model
    from training.scene.loader import load_scene

    scene = load_scene(a["data"], load_images=False)
    for cam in scene.cameras:  # every camera 1 cm to the side, in place: the grid file is unchanged
        cam.world_to_camera[0, 3] += 0.01
    write_colmap_model(a["data"] / "sparse" / "0", scene.cameras, points=scene.points,
                       point_colors=scene.point_colors)
    changed = with_inputs(load_grid(grid))
    todo = _to_run(changed, records, lines.append)
    assert sorted(j.id for j in todo) == sorted(j.id for j in jobs if j.spec["scene"] == "a")
    assert any("reconstruct/a-" in line and "camera poses or intrinsics" in line for line in lines), lines

    old = {jid: {**r, "job": {"id": jid, "spec": r["job"]["spec"]}} for jid, r in records.items()}
    lines.clear()
    assert _to_run(changed, old, lines.append) == []  # records of an older version: kept, with one line
    assert len(lines) == 1 and "could not be checked" in lines[0]


def test_group_named_outside_out_is_refused_and_nothing_is_written(tmp_path, capsys):
    (tmp_path / "scene").mkdir()
    (tmp_path / "style.png").write_bytes(b"")  # the grid is refused before anything is read
    grid = tmp_path / "grid.toml"
    grid.write_text(GRID.format(a=tmp_path / "scene", b=tmp_path / "scene", style=tmp_path / "style.png")
                    + '[groups."../x"]\nsettings = ["ccft"]\nmetrics = ["utilisation"]\n')
    before = sorted(tmp_path.rglob("*"))
    rc = main(["eval", str(grid), "-o", str(tmp_path / "out"), "--report-only"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, lines
    assert "group name '../x'" in lines[0] and str(grid) in lines[0]
    assert sorted(tmp_path.rglob("*")) == before
