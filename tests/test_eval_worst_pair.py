"""The eval report's worst-pair contact sheets (app/evaluate/worst_pair.py) and reusing an earlier run's cells.csv
(`splatstyler eval --cells-from`): a tiny real grid on the demo scene through the console command."""

from __future__ import annotations

import csv
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.evaluate.worst_pair import worst_pair

GRID = """
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
metric_pairs = 5
[scenes.demo]
data = "{scene}"
[paintings]
strokes = "{style}"
[settings.ccft]
[settings.dc]
dc_only = true
[groups.what]
title = "What"
settings = ["dc", "ccft"]
metrics = ["consistency_short_rmse"]
"""


def run_eval(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "app", "eval", *argv], capture_output=True, text=True, timeout=1500)


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    """(grid file, output folder) of the tiny grid (settings dc and ccft on the demo scene) run once through
    `splatstyler eval` with one worker, for the module's tests.
    Slow: a `splatstyler eval` process and its spawned worker, each importing torch: a 100-step reconstruction of
    the demo scene at 1/4 size, two quick stylizations at 64 px one after the other, each measured for the report
    (training/evaluate/measure.py), and the report, its worst-pair sheet rendered again from the saved models
    (53.77 s of setup in a clean-clone CI run on 2 cores)."""
    from assets.demo.assets import demo_assets

    demo = demo_assets()
    folder = tmp_path_factory.mktemp("worst_pair")
    grid = folder / "grid.toml"
    grid.write_text(GRID.format(scene=demo.scene_dir, style=demo.style_image))
    out = folder / "out"
    proc = run_eval(str(grid), "-o", str(out), "--workers", "1", "--threads", "2")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return grid, out


def test_worst_pair_is_the_largest_sum_over_rows_and_skips_uncompared_pairs():
    assert worst_pair([[0.1, 0.3, 0.2], [0.2, 0.1, 0.25]]) == 2  # 0.45 beats 0.4 and 0.3
    assert worst_pair([[0.1, 0.9, 0.2], [0.2, None, 0.1]]) == 2  # pair 1 not compared in row 2
    assert worst_pair([[None], [0.1]]) is None


@pytest.mark.slow
def test_report_draws_the_worst_pair_the_measure_saw(evaluated):
    """The report's worst-pair sheet is written and linked from RESULTS.md; its caption names the rows in the
    group's order (dc, ccft), each with its pair's RMSE above 0 and the mean over its pairs, measured again from the
    saved model, equal to the cell's recorded consistency_short_rmse (within 2 %); the sheet is wider than tall.
    Slow: its setup, the module's `evaluated` fixture, runs the whole tiny grid through `splatstyler eval` (see
    there); the test itself only reads what that wrote (53.77 s of setup in a clean-clone CI run on 2 cores)."""
    grid, out = evaluated
    md = (out / "report" / "RESULTS.md").read_text()
    sheet = out / "report" / "results" / "sheets" / "what_demo_worst_pair.jpg"
    assert sheet.stat().st_size > 1000
    assert "(results/sheets/what_demo_worst_pair.jpg)" in md
    caption = next(line for line in md.splitlines() if "least consistent pair" in line)
    with open(out / "report" / "results" / "cells.csv") as f:
        recorded = {r["setting"]: float(r["consistency_short_rmse"]) for r in csv.DictReader(f)}
    # rows in the group's order; the mean over each row's pairs, measured again from the saved model, is the
    # cell's recorded consistency_short_rmse: the sheet looks at the measure's own pairs and renders
    rows = re.findall(r"(\w+) \(pair ([0-9.]+), mean over its pairs ([0-9.]+)\)", caption)
    assert [r[0] for r in rows] == ["dc", "ccft"]
    for setting, pair, mean in rows:
        assert float(mean) == pytest.approx(recorded[setting], rel=0.02, abs=2e-4), setting
        assert float(pair) > 0

    from training.scene.image_io import read_image

    image = read_image(sheet)
    # two rows of four 64 px views with 4 px gaps
    assert image.shape[0] < image.shape[1] and image.shape[1] >= 4 * 40


@pytest.mark.slow
def test_planted_blotch_makes_its_pairs_the_worst(evaluated):
    from app.evaluate.worst_pair import cell_views, pair_rmses, render_pair_views
    from app.evaluate.grid import load_grid, job_dir

    grid_path, out = evaluated
    grid = load_grid(grid_path)
    job = next(j for j in grid.cells if j.spec["setting"] == "ccft")
    views = cell_views(Path(job.spec["data"]), job.spec["flags"])
    renders = render_pair_views(job_dir(out, job) / "point_cloud.ply", views)
    before = pair_rmses(renders, views.cameras, views.pairs)
    # paint a bright square onto one view: the pairs that hold it must become the least consistent
    victim = views.pairs[len(views.pairs) // 2][1]
    image, depth, alpha = renders[victim]
    image = image.copy()
    h, w = image.shape[:2]
    image[h // 4:3 * h // 4, w // 4:3 * w // 4] = [1.0, 0.0, 1.0]
    renders[victim] = (image, depth, alpha)
    after = pair_rmses(renders, views.cameras, views.pairs)
    k = worst_pair([after])
    assert victim in views.pairs[k]
    assert after[k] > 2 * max(v for v in before if v is not None)
    untouched = [i for i, p in enumerate(views.pairs) if victim not in p]
    assert untouched and all(np.isclose(after[i], before[i]) for i in untouched)


@pytest.mark.slow
def test_cells_from_an_earlier_csv_fill_the_tables(evaluated, tmp_path):
    grid, out = evaluated
    earlier = out / "report" / "results" / "cells.csv"
    # a fresh output folder that ran nothing: every cell comes from the earlier run's CSV
    proc = run_eval(str(grid), "-o", str(tmp_path / "fresh"), "--report-only", "--cells-from", str(earlier))
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    md = (tmp_path / "fresh" / "report" / "RESULTS.md").read_text()
    assert "2 of 2 cells finished (2 of them, on demo, measured by an earlier run" in md
    assert f"--cells-from {earlier}" in md
    assert "least consistent pair" not in md  # no models here to draw from
    with open(earlier) as f:
        old = {r["setting"]: r for r in csv.DictReader(f)}
    with open(tmp_path / "fresh" / "report" / "results" / "cells.csv") as f:
        new = {r["setting"]: r for r in csv.DictReader(f)}
    assert new.keys() == old.keys()
    for setting in old:
        assert float(new[setting]["consistency_short_rmse"]) == float(old[setting]["consistency_short_rmse"])

    # a row naming a cell the grid does not have is refused with one line, before anything runs
    bad = tmp_path / "bad.csv"
    bad.write_text(earlier.read_text().replace(",dc,", ",dc_only,", 1))
    proc = run_eval(str(grid), "-o", str(tmp_path / "bad_out"), "--cells-from", str(bad))
    assert proc.returncode != 0
    assert "cell/demo/dc_only/strokes/seed0 is not a cell of grid.toml" in proc.stderr
    assert not (tmp_path / "bad_out").exists()
