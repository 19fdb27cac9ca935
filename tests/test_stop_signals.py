"""SIGTERM, as timeout, systemd, Docker, SLURM and Ray send it, stops a long command the way Ctrl-C does: the work so
far is saved, one line says so, the exit status is 143, and pycolmap's glog handler (installed when pycolmap is
first imported) never turns it into a stack dump."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time

import pytest

from tests.viewer_harness import ROOT


def test_sigterm_after_pycolmap_is_imported_reaches_python():
    code = ("import os, signal, sys\n"
            "from app import stop_signals\n"
            "stop_signals.install()\n"
            "import pycolmap\n"  # a second import changes nothing: the handler stays ours
            "try:\n"
            "    os.kill(os.getpid(), signal.SIGTERM)\n"
            "    import time; time.sleep(5)\n"
            "except KeyboardInterrupt:\n"
            "    sys.exit(stop_signals.exit_code())\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 143, proc.stderr
    assert "stack trace" not in proc.stderr


@pytest.mark.slow
def test_sigterm_stops_a_reconstruction_with_a_checkpoint_and_exit_143(tmp_path):
    from assets.demo.assets import demo_assets
    from training.reconstruct.checkpoint import load_checkpoint

    out = tmp_path / "recon"
    proc = subprocess.Popen([sys.executable, "-m", "app", "reconstruct", str(demo_assets().scene_dir), "-o",
                             str(out), "--iters", "3000", "--no-progress"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ))
    try:
        t0 = time.time()
        while time.time() - t0 < 120:  # until the trainer is stepping (its time estimate is printed then)
            time.sleep(1)
            if proc.poll() is not None:
                break
            if (out / "checkpoint.pt").exists() or time.time() - t0 > 25:
                break
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err
    assert "stopped by SIGTERM at iteration" in err and "checkpoint saved" in err, err
    assert "stack trace" not in err and "Traceback" not in err, err
    state = load_checkpoint(out / "checkpoint.pt")
    assert 0 < state["step"] < 3000


@pytest.mark.slow
def test_sigterm_stops_the_headless_demo_with_its_reconstruction_checkpointed(tmp_path):
    """The demo in a container stopped by `docker stop`: the reconstruction under way keeps its checkpoint, one line
    says so, exit 143, no stack dump."""
    from training.reconstruct.checkpoint import load_checkpoint

    out = tmp_path / "demo"
    log = tmp_path / "stderr.txt"
    with open(log, "w") as err_file:  # a file, not a pipe: the progress bar would fill a pipe nobody reads yet
        proc = subprocess.Popen([sys.executable, "-m", "app", "demo", "--headless", "-o", str(out), "--recon-iters",
                                 "3000"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err_file,
                                env=dict(os.environ))
    ckpt = out / "reconstruction" / "checkpoint.pt"

    def steps_done() -> int:  # from the reconstruction's progress bar, "| 37/3000 ["
        found = re.findall(r"\| (\d+)/3000 \[", log.read_text())
        return int(found[-1]) if found else 0

    try:
        t0 = time.time()
        while time.time() - t0 < 300 and proc.poll() is None and steps_done() < 20:
            time.sleep(0.3)  # until the reconstruction is stepping, long before its first periodic checkpoint
        assert proc.poll() is None and steps_done() >= 20 and not ckpt.exists(), log.read_text()[-2000:]
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = log.read_text()
    assert proc.returncode == 143, err[-2000:]
    assert "stopped by SIGTERM" in err and "checkpoint saved" in err, err[-2000:]
    assert "stack trace" not in err and "Traceback" not in err, err[-2000:]
    assert 20 <= load_checkpoint(ckpt)["step"] < 3000
