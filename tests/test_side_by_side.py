"""scripts/side_by_side.py: the figure it reads from a command's JSON, the ratio it prints, and a real run of two
commits of a small repository, each in its own checkout."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "side_by_side.py"


def _module():
    spec = importlib.util.spec_from_file_location("side_by_side", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


sbs = _module()

BENCH_LINES = """bench ccft: 100%|##########| 2/2
{"n": 1024, "m": 1024, "ms": 12.5, "parts": {"sinkhorn_ms": 4.0}}
{"n": 4096, "m": 1024, "ms": 40.0, "parts": {"sinkhorn_ms": 9.0}}
not json {"n": 1}
"""


def test_figure_is_the_key_of_the_selected_row():
    assert sbs.figure_from(BENCH_LINES, "ms", {"n": "4096"}) == 40.0
    assert sbs.figure_from(BENCH_LINES, "parts.sinkhorn_ms", {"n": "1024", "m": "1024"}) == 4.0
    # a whole JSON document (a file such as bench_gpu.json) is one row
    assert sbs.figure_from('{\n  "step": {"cpu_ms": 144.1}\n}', "step.cpu_ms", {}) == 144.1


@pytest.mark.parametrize("key, where, says", [
    ("ms", {}, "pick one with --where"),           # two rows have it: the figure would be a guess
    ("ms", {"n": "8"}, "no JSON row with"),
    ("seconds", {"n": "1024"}, "no key 'seconds'"),
    ("parts", {"n": "1024"}, "not a number"),
])
def test_figure_errors_say_what_is_missing(key, where, says):
    with pytest.raises(sbs.FigureError, match=says):
        sbs.figure_from(BENCH_LINES, key, where)


def test_ratio_is_median_of_b_over_median_of_a():
    s = sbs.summarize([10.0, 30.0, 12.0], [5.0, 6.0, 100.0])
    assert s["median_a"] == 12.0 and s["median_b"] == 6.0 and s["b_over_a"] == 0.5
    assert s["round_ratios"] == [0.5, 0.2, 100.0 / 12.0]
    with pytest.raises(ValueError):
        sbs.summarize([1.0], [1.0, 2.0])
    text = sbs.table(("old", "new"), [10.0, 30.0, 12.0], [5.0, 6.0, 100.0], "ms")
    assert "| median | 12 | 6 | **0.500** |" in text and "A / B = 2.000" in text


def test_two_commits_each_in_its_own_checkout(tmp_path):
    """A repository whose bench prints a different time at each commit: the table shows each commit's figure,
    alternating, and the ratio; each run's PYTHONPATH is its own checkout; the checkouts are gone afterwards."""
    repo = tmp_path / "repo"
    repo.mkdir()

    def git(*args):
        return subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                              check=True, capture_output=True, text=True).stdout.strip()

    git("init", "-q")
    bench = ("import json, os, sys\n"
             "assert os.environ['PYTHONPATH'] == os.getcwd(), (os.environ['PYTHONPATH'], os.getcwd())\n"
             "print('warming up', file=sys.stderr)\n"
             "print(json.dumps({'n': 1, 'ms': MS}))\n"
             "print(json.dumps({'n': 2, 'ms': 1000}))\n")
    for ms in (40, 10):
        (repo / "bench.py").write_text(bench.replace("MS", str(ms)))
        git("add", "bench.py")
        git("commit", "-q", "-m", f"{ms} ms")
    proc = subprocess.run([sys.executable, str(SCRIPT), "HEAD~1", "HEAD", "--rounds", "2", "--warmup", "0",
                           "--key", "ms", "--where", "n=1", "--", "python", "bench.py"],
                          cwd=repo, capture_output=True, text=True, timeout=120, env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    order = [line.split(":")[0] for line in out.splitlines() if line.startswith("round ")]
    assert order == ["round 1 A", "round 1 B", "round 2 A", "round 2 B"]
    assert "| 1 | 40 | 10 | 0.250 |" in out and "| median | 40 | 10 | **0.250** |" in out
    assert "A / B = 4.000" in out
    assert git("worktree", "list").count("\n") == 0  # only the repository itself is left


def test_failed_command_stops_with_its_error(tmp_path):
    repo = tmp_path / "repo"
    repo.mkdir()
    run = dict(check=True, capture_output=True)
    subprocess.run(["git", "-C", str(repo), "init", "-q"], **run)
    subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q",
                    "--allow-empty", "-m", "empty"], **run)
    proc = subprocess.run([sys.executable, str(SCRIPT), "HEAD", "HEAD", "--", "python", "-c",
                           "import sys; sys.exit('no such scene: fox')"],
                          cwd=repo, capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "failed" in proc.stderr and "no such scene: fox" in proc.stderr
