"""The viewer (`splatstyler view --run reconstruct`, a real window on an X server) stopped at seeded random instants
of a live reconstruction: by SIGTERM (exit 143) and by Ctrl+Q typed through the X server (exit 0). Each stop ends
the process within STOP_S, with no traceback or stack dump, and what a step made is kept: a checkpoint that loads,
saved where the run stopped, beside the model. The instants are drawn from the test's seed (printed; the seed's
environment variable replays it): SIGTERM from the launch on (the interpreter starting, the window opening, the
scene loading, the steps), Ctrl+Q once the window is on the screen.

Slow: each instant is a viewer started afresh (about 10 s of imports and window on 2 cores) and run until it stops.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.system_deps import requires_program
from tests.test_viewer_x11 import x11_env
from tests.viewer_harness import ROOT, Xvfb, make_demo_scene, xvfb_missing

pytestmark = [pytest.mark.slow, pytest.mark.skipif(bool(xvfb_missing()), reason=xvfb_missing() or "ok")]

ITERS = 3000  # far more than any instant reaches: every stop lands in a running reconstruction
STOP_S = 60.0  # from the stop to the process's end, saves included, on a busy 2-core machine
DUMPS = ("Traceback", "Fatal Python error", "*** SIG", "Check failure")  # Python's, faulthandler's, glog's


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    return make_demo_scene(tmp_path_factory)


@pytest.fixture(scope="module")
def x_server():
    server = Xvfb((1280, 800)).start()
    yield server
    server.stop()


def _launch(scene_dir: Path, out: Path, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "app", "view", "--data", str(scene_dir), "-o", str(out),
                             "--run", "reconstruct", "--iters", str(ITERS), "--downscale", "4"],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _window(env: dict, proc: subprocess.Popen, seconds: float = 300.0) -> str:
    """The viewer's X window id, once it is mapped."""
    t0 = time.time()
    while time.time() - t0 < seconds:
        assert proc.poll() is None, proc.communicate()[0][-3000:]
        found = subprocess.run(["xdotool", "search", "--onlyvisible", "--name", "^splatstyler"], env=env,
                               capture_output=True, text=True, timeout=30).stdout.split()
        if found:
            return found[0]
        time.sleep(0.2)
    raise AssertionError("the viewer's window did not appear")


def _stopped(proc: subprocess.Popen, how: str) -> tuple[int, str, float]:
    t0 = time.time()
    try:
        output = proc.communicate(timeout=STOP_S)[0]
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError(f"{how}: the viewer did not end within {STOP_S:.0f} s:\n{proc.communicate()[0][-3000:]}")
    return proc.returncode, output, time.time() - t0


def _kept(out: Path, how: str) -> int | None:
    """The step of the reconstruction the stop kept (checked: it loads, it stopped before its end, its model is
    beside it; a stop after the trainer was built and before its first step keeps step 0), None where none."""
    from training.reconstruct.checkpoint import load_checkpoint

    folder = out / "reconstruction"
    if not (folder / "checkpoint.pt").exists():
        return None
    saved = load_checkpoint(folder / "checkpoint.pt")
    assert 0 <= saved["step"] < ITERS, (how, saved["step"])
    assert (folder / "point_cloud.ply").exists(), how
    return saved["step"]


@requires_program("xdotool", "xdotool")
def test_the_viewer_stops_at_random_instants_of_a_live_reconstruction(demo_scene, x_server, tmp_path):
    """Two SIGTERMs within 20 s of the launch (exit 143, a line saying so) and two Ctrl+Qs within 10 s of the
    window's appearance (exit 0): each viewer ends within STOP_S with no dump, any checkpoint it kept loads and
    stops before the run's end beside its model, and a Ctrl+Q kept at least one reconstruction step.
    Slow: four viewers started afresh on Xvfb (about 10 s of imports and window each on 2 cores), each run until
    its instant (up to 20 s from the launch, or 10 s after the window appears) and then its save (33 s in a
    clean-clone CI run on 2 cores)."""
    scene_dir, _, _ = demo_scene
    env = dict(os.environ, XDG_CONFIG_HOME=str(tmp_path / "config"), **x11_env(x_server))
    env.pop("SPLATSTYLER_VIEWER_PLATFORM", None)
    rng = random.Random(random.randrange(2 ** 31))  # from the test's seed (conftest)
    kept = []
    plan = [("SIGTERM", rng.uniform(0.15, 20.0)) for _ in range(2)] + [("Ctrl+Q", rng.uniform(0.0, 10.0))
                                                                         for _ in range(2)]
    for i, (how, delay) in enumerate(plan):
        out = tmp_path / f"out{i}"
        what = f"{how} at {delay:.2f} s"
        proc = _launch(scene_dir, out, env)
        try:
            if how == "SIGTERM":
                time.sleep(delay)
                assert proc.poll() is None, proc.communicate()[0][-3000:]
                proc.send_signal(signal.SIGTERM)
            else:  # the window must be there to take keys: the delay counts from its appearance
                window = _window(env, proc)
                time.sleep(delay)
                subprocess.run(["xdotool", "mousemove", "--window", window, "200", "200"], env=env, check=True,
                               timeout=30)
                # typed as a user types (XTEST, to the window under the pointer), not sent to the window (XSendEvent)
                subprocess.run(["xdotool", "key", "ctrl+q"], env=env, check=True, timeout=30)
            code, output, took = _stopped(proc, what)
        finally:
            if proc.poll() is None:
                proc.kill()
        assert code == (143 if how == "SIGTERM" else 0), f"{what}: exit {code}\n{output[-3000:]}"
        if how == "SIGTERM":
            # the window's "SIGTERM received: closing the window and saving", or, while it starts, the command's
            # "stopped by SIGTERM while the viewer was starting"
            assert any(line.startswith("splatstyler: ") and "SIGTERM" in line for line in output.splitlines()), \
                f"{what}\n{output[-3000:]}"
        assert not any(d in output for d in DUMPS), f"{what}\n{output[-3000:]}"
        kept.append(_kept(out, what))
        print(f"{what}: exit {code} in {took:.1f} s, reconstruction kept at step {kept[-1]}")
    assert any(step for step in kept[2:]), "no Ctrl+Q landed after a reconstruction step: nothing kept was checked"
