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


@pytest.mark.slow
def test_sigterm_closes_the_viewer_saving_the_running_reconstruction(tmp_path):
    """What timeout, systemd, Docker and SLURM send: the window closes as the close button does, the
    reconstruction's checkpoint and model are saved, exit status 143, and no stack dump (pycolmap's glog handler,
    installed when the COLMAP scene is read, must not take SIGTERM)."""
    import os
    import signal
    import time

    from assets.demo.assets import demo_assets
    from training.reconstruct.checkpoint import load_checkpoint

    scene = demo_assets().scene_dir
    env = dict(os.environ, XDG_CONFIG_HOME=str(tmp_path / "config"))
    env.pop("DISPLAY", None)
    proc = subprocess.Popen([sys.executable, "-m", "app", "view", "--data", str(scene), "--run", "reconstruct",
                             "--iters", "3000", "-o", str(tmp_path / "out")], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(30)  # the scene loads and the trainer steps
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, (out, err)
    assert "SIGTERM received" in out and "stack trace" not in err and "Traceback" not in err, (out, err)
    state = load_checkpoint(tmp_path / "out" / "reconstruction" / "checkpoint.pt")
    assert 0 < state["step"] < 3000
    assert (tmp_path / "out" / "reconstruction" / "point_cloud.ply").is_file()


def _photos(folder, n: int = 3):
    """``n`` small photos of random texture (the argument checks read the folder, no SfM runs)."""
    import numpy as np

    from training.scene.image_io import write_image

    rng = np.random.default_rng(0)
    for i in range(n):
        write_image(folder / f"p{i}.png", rng.random((24, 32, 3)))
    return folder


def test_view_of_a_folder_of_photos_checks_what_the_photos_pipeline_needs(tmp_path):
    photos = _photos(tmp_path / "photos")
    proc = view(str(photos), "--run", "reconstruct")
    assert proc.returncode == 2 and "--run is for a model or --data: a folder of photos starts at once" in proc.stderr
    proc = view(str(photos), "--style", str(tmp_path / "missing.jpg"))
    assert proc.returncode == 2 and "missing.jpg" in proc.stderr
    proc = view(str(_photos(tmp_path / "one", 1)))
    assert proc.returncode == 2 and "needs at least 2 photos, found 1" in proc.stderr
    proc = view("--data", str(photos))
    assert proc.returncode == 2 and f"`splatstyler view {photos}` makes a scene of them" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.slow
def test_sigterm_while_the_photos_are_registered_leaves_no_scene_folder_and_says_so(tmp_path):
    """`splatstyler view PHOTOS`: SIGTERM during structure from motion closes the window, leaves no scene folder
    (nor the hidden one it is built in), prints one line saying so, and exits 143."""
    import os
    import signal
    import time

    from tests.test_sfm import FERN
    from training.scene.image_io import read_image, resize_image, write_image

    if not FERN.is_dir():
        pytest.skip("shared llff_fern photos not available (../shared)")
    photos = tmp_path / "photos"
    for p in sorted(FERN.iterdir()):
        img = read_image(p)
        write_image(photos / p.name, resize_image(img, 480, round(img.shape[0] * 480 / img.shape[1])))
    env = dict(os.environ, XDG_CONFIG_HOME=str(tmp_path / "config"))
    env.pop("DISPLAY", None)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "app", "view", str(photos), "-o", str(out)], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.time()
        while not (out / ".scene.sfm-partial" / ".work" / "photos").is_dir():  # SfM is under way
            assert proc.poll() is None and time.time() - t0 < 120, proc.communicate()
            time.sleep(0.1)
        time.sleep(2.0)  # into the features
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, (stdout, stderr)
    assert f"structure from motion stopped: nothing written ({out / 'scene'} appears only once complete)" \
        in stdout.splitlines(), (stdout, stderr)
    assert "Traceback" not in stderr and "stack trace" not in stderr, stderr
    assert sorted(p.name for p in out.iterdir()) == []
