"""``splatstyler video`` with no display: MP4 frames decode (imageio) to the expected count and size, PNG folders,
before/after split, the dataset path, cancel; and the acceptance case on a fox reconstruction (slow)."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from app.cli import main

FOX = Path(__file__).resolve().parents[2] / "shared" / "data" / "scenes" / "fox"


def decode(path: Path) -> list[np.ndarray]:
    import imageio

    with imageio.get_reader(str(path)) as r:
        return [np.asarray(f) for f in r]


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """A small demo-scene model (SH degree 0) and its COLMAP folder."""
    from assets.demo.scene import write_demo_scene, make_demo_scene
    from training.model.gaussian_init import gaussians_from_points
    from training.model.ply_io import write_ply

    folder = tmp_path_factory.mktemp("video")
    scene = make_demo_scene(num_views=4, width=64, height=48, num_points=1500, supersample=1)
    g = gaussians_from_points(scene.points, scene.point_colors, sh_degree=0)
    g.opacity_logits = torch.full_like(g.opacity_logits, 2.0)
    write_ply(folder / "model.ply", g)
    other = g.detached()
    other.sh0 = torch.zeros_like(other.sh0) + 1.5  # a bright "stylized" twin for the split video
    write_ply(folder / "bright.ply", other)
    return folder, write_demo_scene(folder / "scene", scene)


def gl_or_skip():
    from renderer_gl import create_context

    try:
        create_context("auto").release()
    except RuntimeError as exc:
        pytest.skip(f"no headless OpenGL: {exc}")


def test_orbit_mp4_png_and_split(demo, tmp_path, capsys):
    gl_or_skip()
    folder, data = demo
    out = tmp_path / "orbit.mp4"
    assert main(["video", str(folder / "model.ply"), "--orbit", "--data", str(data), "--size", "96x64",
                 "--seconds", "1", "--fps", "12", "-o", str(out), "--save-path", str(tmp_path / "p.json")]) == 0
    frames = decode(out)
    assert len(frames) == 12 and frames[0].shape == (64, 96, 3)
    assert frames[0].mean() > 5 and not np.array_equal(frames[0], frames[6])  # the model shows, the camera moves
    assert "ms per frame" in capsys.readouterr().out
    # the saved path replays the same video as PNG frames
    pngs = tmp_path / "frames"
    (pngs).mkdir()
    (pngs / "frame_00099.png").write_bytes(b"from a longer run")
    assert main(["video", str(folder / "model.ply"), "--path", str(tmp_path / "p.json"), "-o", str(pngs)]) == 0
    names = sorted(p.name for p in pngs.iterdir())
    assert names == [f"frame_{i:05d}.png" for i in range(12)]
    from training.scene.image_io import read_image

    first = read_image(pngs / "frame_00000.png")
    assert first.shape[:2] == (64, 96) and np.abs(first[..., :3] * 255 - frames[0]).mean() < 8  # H.264 is lossy
    # before/after: the bright twin on the right half only
    assert main(["video", str(folder / "model.ply"), "--path", str(tmp_path / "p.json"), "--split-with",
                 str(folder / "model.ply"), "-o", str(tmp_path / "same.mp4")]) == 0
    assert main(["video", str(folder / "bright.ply"), "--path", str(tmp_path / "p.json"), "--split-with",
                 str(folder / "model.ply"), "-o", str(tmp_path / "split.mp4")]) == 0
    same, split = decode(tmp_path / "same.mp4")[0].astype(float), decode(tmp_path / "split.mp4")[0].astype(float)
    left, right = slice(0, 40), slice(56, 96)
    assert np.abs(split[:, left] - same[:, left]).mean() < 4
    assert split[:, right].mean() > same[:, right].mean() + 10


def test_dataset_path_and_errors(demo, tmp_path, capsys):
    gl_or_skip()
    folder, data = demo
    assert main(["video", str(folder / "model.ply"), "--dataset", "--data", str(data), "--fps", "8",
                 "-o", str(tmp_path / "d.mp4")]) == 0
    frames = decode(tmp_path / "d.mp4")
    assert len(frames) == 6 and frames[0].shape == (48, 64, 3)  # 3 segments of 0.25 s at 8 fps, camera size
    cases = [(["--dataset"], "--dataset needs --data"), (["--orbit", "--size", "63x48"], "even sides"),
             (["--orbit", "--fps", "0"], "--fps"), (["--orbit", "-o", str(tmp_path / "x.gif")], "unknown video")]
    for extra, words in cases:
        capsys.readouterr()
        argv = ["video", str(folder / "model.ply"), *extra]
        if "-o" not in extra:
            argv += ["-o", str(tmp_path / "e.mp4")]
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err
    assert not (tmp_path / "e.mp4").exists()


def test_cancel_leaves_no_mp4_and_keeps_finished_pngs(demo, tmp_path):
    gl_or_skip()
    from app.camera_path import orbit_path
    from app.render_inputs import load_model_arrays
    from app.video_output import write_path_video
    from renderer_gl import SplatRenderer, create_context
    from training.core.messages import Cancelled

    folder, _ = demo
    arrays = load_model_arrays(folder / "model.ply")
    cams = orbit_path(arrays[0].mean(0), 3.0, up=(0, -1, 0), width=64, height=48, seconds=1, fps=10).cameras()
    ctx = create_context("auto")
    r = SplatRenderer(ctx, sort_tolerance_deg=0.0)
    r.set_splats(*arrays[:5], arrays[5])
    try:
        for out in (tmp_path / "c.mp4", tmp_path / "pngs"):
            calls = []
            with pytest.raises(Cancelled):
                write_path_video(r, cams, out, 64, 48, 10, cancel=lambda: calls.append(1) or len(calls) > 3)
        assert not (tmp_path / "c.mp4").exists() and not list(tmp_path.glob(".c.mp4*"))
        assert sorted(p.name for p in (tmp_path / "pngs").iterdir()) == [f"frame_{i:05d}.png" for i in range(3)]
    finally:
        r.release()
        ctx.release()


@pytest.mark.slow
@pytest.mark.skipif(not FOX.is_dir(), reason="needs ../shared/data/scenes/fox")
def test_fox_orbit_video_3s_640x360(tmp_path, capsys):
    """The acceptance case: a 3-second 640x360 orbit of a fox reconstruction (made here cheaply, as the renderer's
    fox test does: no reconstruction is stored), headless; its frames decode to 90 of 640x360."""
    gl_or_skip()
    from training.model.ply_io import write_ply
    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
    from training.scene.loader import load_scene

    scene = load_scene(FOX, downscale=16)
    cfg = ReconstructConfig.from_preset("quick", depth="none", random_init_points=4000, seed=0)
    cfg = replace(cfg, iterations=120, densify=replace(cfg.densify, start=40, interval=40, stop=110))
    rec = Reconstructor(scene, cfg)
    for _ in range(cfg.iterations):
        rec.step()
    write_ply(tmp_path / "fox.ply", rec.gaussians.detached().to("cpu"))
    out = tmp_path / "fox.mp4"
    t0 = time.perf_counter()
    assert main(["video", str(tmp_path / "fox.ply"), "--orbit", "--data", str(FOX), "--downscale", "16",
                 "--size", "640x360", "--seconds", "3", "--fps", "30", "-o", str(out)]) == 0
    seconds = time.perf_counter() - t0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    frames = decode(out)
    print(f"{line}; {len(rec.gaussians)} Gaussians; command {seconds:.1f} s")
    assert len(frames) == 90 and all(f.shape == (360, 640, 3) for f in frames)
    assert np.mean([f.mean() for f in frames]) > 5  # the fox is in view, not a black video


@pytest.mark.slow
def test_sigterm_stops_a_video_leaving_no_mp4(demo, tmp_path):
    """`timeout`, Docker and SLURM stop a long render with SIGTERM: one line, exit 143, and no MP4, whole or half,
    left where the user looks for it (nor its temporary file)."""
    gl_or_skip()
    import os
    import signal
    import subprocess
    import sys

    folder, _ = demo
    out = tmp_path / "long.mp4"
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, "-m", "app", "video", str(folder / "model.ply"), "--orbit", "--seconds",
                             "600", "--fps", "30", "--size", "64x48", "-o", str(out)], cwd=root,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ))
    try:
        t0 = time.time()
        while time.time() - t0 < 120 and proc.poll() is None and not list(tmp_path.glob(".long.mp4*")):
            time.sleep(0.2)  # until frames are being encoded into the temporary file
        assert proc.poll() is None and list(tmp_path.glob(".long.mp4*")), proc.communicate()
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err
    lines = [line for line in err.splitlines() if "SIGTERM" in line]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert not out.exists() and list(tmp_path.iterdir()) == [], list(tmp_path.iterdir())
