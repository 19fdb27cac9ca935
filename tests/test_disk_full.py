"""A filesystem that fills up while a checkpoint, a model, a render or an export is written: one line naming the
output and "no space left", the previous file under that name unchanged, and no partial file left behind. Runs on
a small tmpfs (CI runs as root and can mount one); skips with the reason where mounting is not permitted."""

from __future__ import annotations

import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest
import torch

from training.core.errors import InputError

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def small_disk(tmp_path):
    mount = tmp_path / f"disk_{uuid.uuid4().hex[:6]}"
    mount.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mount)], capture_output=True,
                          text=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({proc.stderr.strip() or 'mount failed'}): needs root")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)  # lazy: a writer's handle may linger


def model(n: int):
    from training.model.gaussians import Gaussians

    g = torch.Generator().manual_seed(0)
    return Gaussians(means=torch.randn(n, 3, generator=g), log_scales=torch.randn(n, 3, generator=g) - 3,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g),
                     sh0=torch.randn(n, 1, 3, generator=g), shN=torch.randn(n, 15, 3, generator=g), sh_degree=3)


def assert_one_line_and_nothing_partial(exc: InputError, target: Path, before: bytes | None) -> None:
    assert "\n" not in str(exc) and str(target) in str(exc) and "no space left" in str(exc)
    if before is None:
        assert not target.exists()
    else:
        assert target.read_bytes() == before  # the previous file, whole
    assert not [p for p in target.parent.iterdir() if p.name.startswith(f".{target.name}.")]  # no temporary


def test_checkpoint_model_and_render_on_a_full_disk(small_disk):
    from training.model.ply_io import write_ply
    from training.reconstruct.checkpoint import load_checkpoint, save_checkpoint
    from training.scene.image_io import write_image

    ckpt = small_disk / "checkpoint.pt"
    save_checkpoint(ckpt, {"step": 1, "weights": torch.zeros(1000)})  # a small one fits
    before = ckpt.read_bytes()
    with pytest.raises(InputError) as info:
        save_checkpoint(ckpt, {"step": 2, "weights": torch.zeros(2_000_000)})  # 8 MB into 1 MB
    assert_one_line_and_nothing_partial(info.value, ckpt, before)
    assert load_checkpoint(ckpt)["step"] == 1

    ply = small_disk / "point_cloud.ply"
    with pytest.raises(InputError) as info:
        write_ply(ply, model(20_000))  # about 5 MB
    assert_one_line_and_nothing_partial(info.value, ply, None)

    png = small_disk / "render.png"
    with pytest.raises(InputError) as info:
        write_image(png, np.random.default_rng(0).random((1200, 1200, 3), dtype=np.float32))  # noise: incompressible
    assert_one_line_and_nothing_partial(info.value, png, None)


def test_export_cli_on_a_full_disk_is_one_line_and_exit_2(small_disk, tmp_path):
    from training.model.ply_io import write_ply

    src = tmp_path / "model.ply"
    write_ply(src, model(20_000))
    target = small_disk / "scene.ply"
    proc = subprocess.run([sys.executable, "-m", "app", "export", str(src), "-o", str(target)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "no space left" in lines[0] and str(target) in lines[0], proc.stderr
    assert not target.exists() and not list(small_disk.iterdir())
