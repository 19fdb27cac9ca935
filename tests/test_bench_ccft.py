"""``splatstyler bench ccft`` runs end to end and its POT comparison is the real one."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


@pytest.mark.slow
def test_bench_ccft_json_rows():
    cmd = [sys.executable, "-m", "app.cli", "bench", "ccft", "--json", "--sizes", "96,128", "--repeat", "1",
           "--channels", "64", "--pot-max-entries", "10000"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    rows = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    assert [(r["n"], r["m"]) for r in rows] == [(96, 96), (96, 128), (128, 96), (128, 128)]
    for r in rows:
        assert "error" not in r, r
        assert r["ms"] > 0 and r["peak_mb"] >= 0 and r["C"] == 64 and r["K"] == 16 and r["iters"] == 50
    first = rows[0]
    assert first["pot_ms"] > 0 and first["max_abs_diff_vs_pot"] <= 1e-10 and first["pot_columns"] <= 96
    for r in rows[1:]:  # above --pot-max-entries: skipped with the reason, not run
        assert r["pot_ms"] is None and r["max_abs_diff_vs_pot"] is None and "pot-max-entries" in r["pot_skipped"]
