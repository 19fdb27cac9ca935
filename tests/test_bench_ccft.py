"""``splatstyler bench ccft`` runs end to end and its POT comparison is the real one."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest


@pytest.mark.slow
def test_bench_ccft_json_rows():
    pytest.importorskip("ot", reason="the bench compares with POT (pip install POT)")
    cmd = [sys.executable, "-m", "app.cli", "bench", "ccft", "--json", "--sizes", "96,128", "--repeat", "1",
           "--channels", "64", "--pot-max-entries", "10000"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    wall_ms = 1e3 * (time.perf_counter() - t0)
    assert proc.returncode == 0, proc.stderr
    rows = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    assert [(r["n"], r["m"]) for r in rows] == [(96, 96), (96, 128), (128, 96), (128, 128)]
    for r in rows:
        assert "error" not in r, r
        assert r["ms"] > 0 and r["peak_mb"] >= 0 and r["C"] == 64 and r["K"] == 16 and r["iters"] == 50
        # --repeat 1: the stages are those of the one timed call, so they fit inside its total
        stages = [r[f"{k}_ms"] for k in ("similarity_topk", "cost", "sinkhorn", "guide", "backward")]
        assert min(stages) >= 0 and r["sinkhorn_ms"] > 0 and sum(stages) <= r["ms"] * 1.001, r
    # every timed call happened inside the command: wall time measured around it bounds them all
    assert sum(r["ms"] + (r["pot_ms"] or 0) for r in rows) < wall_ms
    first = rows[0]
    assert first["pot_ms"] > 0 and first["max_abs_diff_vs_pot"] <= 1e-10 and first["pot_columns"] <= 96
    for r in rows[1:]:  # above --pot-max-entries: skipped with the reason, not run
        assert r["pot_ms"] is None and r["max_abs_diff_vs_pot"] is None and "pot-max-entries" in r["pot_skipped"]
