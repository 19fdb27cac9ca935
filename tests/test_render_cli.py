"""``splatstyler render``: headless images of a model file from a dataset camera or an orbit (EGL)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from renderer_gl import look_at
from tests.gl_scenes import separated_grid

ROOT = Path(__file__).resolve().parents[1]


def write_model(path: Path, rng, rgb=None) -> dict:
    import torch

    from training.model.gaussians import Gaussians
    from training.model.ply_io import write_ply

    means, scales, quats, opac, sh = separated_grid(rng, sh_degree=1, scale=(0.05, 0.1))
    if rgb is not None:
        sh[:] = 0.0
        sh[:, 0] = (np.asarray(rgb, np.float32) - 0.5) / 0.28209479177387814
    t = torch.as_tensor
    g = Gaussians(means=t(means), log_scales=t(np.log(scales)), quats=t(quats),
                  opacity_logits=t(np.log(opac / (1 - opac))), sh0=t(sh[:, :1]).contiguous(),
                  shN=t(sh[:, 1:]).contiguous(), sh_degree=1)
    write_ply(path, g)
    return dict(means=means, opac=opac)


def write_scene(folder: Path, width=80, height=60) -> list[np.ndarray]:
    """A transforms.json scene of two cameras looking at the origin from z < 0; returns their world-to-camera."""
    from training.scene.image_io import write_image

    folder.mkdir(parents=True)
    frames, w2cs = [], []
    for i, eye in enumerate([(0.0, 0.0, -4.0), (1.0, 0.0, -3.8)]):
        w2c = look_at(eye, (0, 0, 0))
        w2cs.append(w2c)
        c2w_gl = np.linalg.inv(w2c) @ np.diag([1.0, -1.0, -1.0, 1.0])
        write_image(folder / f"{i}.png", np.full((height, width, 3), 0.5, np.float32))
        frames.append({"file_path": f"{i}.png", "transform_matrix": c2w_gl.tolist()})
    meta = {"fl_x": 90.0, "fl_y": 90.0, "cx": width / 2, "cy": height / 2, "w": width, "h": height,
            "frames": frames}
    (folder / "transforms.json").write_text(json.dumps(meta))
    return w2cs


def splatstyler(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "app", *args], capture_output=True, text=True, cwd=ROOT,
                          timeout=300)


def test_render_a_dataset_camera_to_png_and_depth_exr(tmp_path):
    from training.scene.image_io import read_image

    rng = np.random.default_rng(0)
    model = write_model(tmp_path / "m.ply", rng, rgb=(1.0, 0.0, 0.0))
    w2cs = write_scene(tmp_path / "data")
    out = splatstyler("render", str(tmp_path / "m.ply"), "--data", str(tmp_path / "data"), "--camera", "0",
                      "-o", str(tmp_path / "c0.png"))
    assert out.returncode == 0, out.stderr
    img = read_image(tmp_path / "c0.png")
    assert img.shape == (60, 80, 3)
    red = (img[..., 0] > 0.5) & (img[..., 1] < 0.1)
    assert 20 < red.sum() < img.shape[0] * img.shape[1] // 2  # the splats, on black
    out = splatstyler("render", str(tmp_path / "m.ply"), "--data", str(tmp_path / "data"), "--camera", "0.png",
                      "--size", "160x120", "--mode", "depth", "-o", str(tmp_path / "d.exr"))
    assert out.returncode == 0, out.stderr
    import OpenImageIO as oiio  # read_image clips to [0, 1]; depth needs the raw floats

    inp = oiio.ImageInput.open(str(tmp_path / "d.exr"))
    depth = np.asarray(inp.read_image(0, 0, 0, 1, "float")).reshape(inp.spec().height, inp.spec().width)
    inp.close()
    assert depth.shape == (120, 160)
    z = model["means"] @ w2cs[0][:3, :3].T + w2cs[0][:3, 3]
    seen = depth[depth > 0]
    assert seen.size > 50
    assert z[:, 2].min() - 0.3 < seen.min() and seen.max() < z[:, 2].max() + 0.3


def test_render_an_orbit_and_a_split_view(tmp_path):
    from training.scene.image_io import read_image

    rng = np.random.default_rng(1)
    write_model(tmp_path / "a.ply", rng, rgb=(1.0, 0.0, 0.0))
    write_model(tmp_path / "b.ply", np.random.default_rng(1), rgb=(0.0, 0.0, 1.0))
    out = splatstyler("render", str(tmp_path / "a.ply"), "--orbit", "3", "--size", "96x64", "--split",
                      str(tmp_path / "b.ply"), "--background", "1,1,1", "-o", str(tmp_path / "orbit"))
    assert out.returncode == 0, out.stderr
    files = sorted((tmp_path / "orbit").glob("*.png"))
    assert [f.name for f in files] == ["color_0000.png", "color_0001.png", "color_0002.png"]
    for f in files:
        img = read_image(f)
        assert img.shape == (64, 96, 3)
        left, right = img[:, :44], img[:, 52:]
        assert ((left[..., 0] > 0.8) & (left[..., 2] < 0.5)).sum() > 10  # model a (red) left of the divider
        assert ((right[..., 2] > 0.8) & (right[..., 0] < 0.5)).sum() > 10  # model b (blue) right of it
        assert not ((left[..., 2] > 0.8) & (left[..., 0] < 0.5)).any()


@pytest.mark.parametrize("args, message", [
    (["--camera", "0"], "--camera needs --data"),
    (["--orbit", "2", "--size", "big"], "--size must look like"),
    (["--orbit", "2", "--background", "red"], "--background"),
    (["--orbit", "2", "--mode", "points", "--format", "exr"], "EXR holds float data"),
])
def test_bad_input_is_one_line(tmp_path, args, message):
    write_model(tmp_path / "m.ply", np.random.default_rng(2))
    out = splatstyler("render", str(tmp_path / "m.ply"), *args, "-o", str(tmp_path / "out"))
    assert out.returncode == 2, out.stderr
    assert message in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr


def test_a_missing_model_is_one_line(tmp_path):
    out = splatstyler("render", str(tmp_path / "none.ply"), "--orbit", "1", "-o", str(tmp_path / "o"))
    assert out.returncode == 2 and "does not exist" in out.stderr
