"""``splatstyler view``: what the command line names is checked before a window opens (one line, exit 2)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.viewer_harness import ROOT


def view(*args: str, env=None) -> subprocess.CompletedProcess:
    import os

    env = dict(os.environ, **(env or {}))
    env.pop("DISPLAY", None)
    return subprocess.run([sys.executable, "-m", "app", "view", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=120, env=env)


@pytest.mark.parametrize("args, words", [
    (("/nonexistent/model.ply",), "/nonexistent/model.ply: does not exist"),
    (("--data", "/nonexistent/scene"), "/nonexistent/scene"),
    (("--style", "/nonexistent/painting.jpg"), "/nonexistent/painting.jpg"),
    (("--run", "reconstruct"), "--run reconstruct needs --data"),
])
def test_view_checks_its_arguments_before_a_window_opens(args, words):
    proc = view(*args)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


def test_view_of_a_text_file_is_not_a_model(tmp_path):
    bad = tmp_path / "model.txt"
    bad.write_text("hello")
    proc = view(str(bad))
    assert proc.returncode == 2 and "is not a Gaussian model file" in proc.stderr
