"""The .splat format: byte layout decoded by hand, importance order, read-back, broken files."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from training.core.errors import InputError
from training.model.gaussians import Gaussians

# The degree-0 real spherical harmonic, 1 / (2 sqrt(pi)), computed here: the test must not share the writer's
# constant, or a wrong one there would go unnoticed.
SH_C0 = 0.5 / math.sqrt(math.pi)
from training.model.splat_io import read_splat, write_splat


def model(n=64, degree=2, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(
        means=torch.randn(n, 3, generator=g),
        log_scales=torch.randn(n, 3, generator=g) - 2,
        quats=torch.randn(n, 4, generator=g) * 3,
        opacity_logits=torch.randn(n, generator=g) * 2,
        sh0=torch.randn(n, 1, 3, generator=g),  # some colours fall outside [0, 1]: clipping is exercised
        shN=torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g),
        sh_degree=degree,
    )


def test_byte_layout_and_order(tmp_path):
    g = model()
    path = tmp_path / "m.splat"
    write_splat(path, g)
    raw = path.read_bytes()
    n = len(g)
    assert len(raw) == 32 * n
    pos = np.frombuffer(raw, np.uint8).reshape(n, 32)
    position = pos[:, 0:12].copy().view("<f4")
    scale = pos[:, 12:24].copy().view("<f4")
    rgba = pos[:, 24:28]
    rot = pos[:, 28:32]

    # Identify each record's source Gaussian by its position (float32, exact).
    src = np.array([int(np.nonzero((g.means.numpy() == p).all(axis=1))[0][0]) for p in position])
    assert sorted(src.tolist()) == list(range(n))

    p64 = {k: v.double().numpy()[src] for k, v in g.parameters().items()}
    np.testing.assert_allclose(scale, np.exp(p64["log_scales"]), rtol=1e-6)
    alpha = 1 / (1 + np.exp(-p64["opacity_logits"]))
    rgb = 0.5 + SH_C0 * p64["sh0"][:, 0]
    expect_rgba = np.floor(np.clip(np.concatenate([rgb, alpha[:, None]], 1) * 255, 0, 255))
    np.testing.assert_array_equal(rgba, expect_rgba)
    assert (rgba == 255).any() and (rgba == 0).any()
    q = p64["quats"] / np.linalg.norm(p64["quats"], axis=1, keepdims=True)
    expect_rot = np.floor(np.clip(q * 128 + 128, 0, 255))
    np.testing.assert_array_equal(rot, expect_rot)

    importance = np.exp(p64["log_scales"].sum(1)) * alpha
    assert (np.diff(importance) <= 0).all()
    assert importance[0] == pytest.approx(
        (torch.exp(g.log_scales.double().sum(1)) * torch.sigmoid(g.opacity_logits.double())).max().item())


def test_read_back(tmp_path):
    g = model(n=100, seed=1)
    path = tmp_path / "m.splat"
    write_splat(path, g)
    back = read_splat(path)
    assert len(back) == 100 and back.sh_degree == 0
    importance = torch.exp(g.log_scales.double().sum(1)) * torch.sigmoid(g.opacity_logits.double())
    order = np.argsort(-importance.numpy(), kind="stable")
    np.testing.assert_array_equal(back.means.numpy(), g.means.numpy()[order])
    np.testing.assert_allclose(back.scales.numpy(), g.scales.numpy()[order], rtol=1e-5)
    rgb = (0.5 + SH_C0 * g.sh0[:, 0]).clamp(0, 1).numpy()[order]
    np.testing.assert_allclose((0.5 + SH_C0 * back.sh0[:, 0]).numpy(), rgb, atol=1.01 / 255)
    np.testing.assert_allclose(back.opacities.numpy(), torch.sigmoid(g.opacity_logits).numpy()[order],
                               atol=1.01 / 255)
    cos = (back.rotations * g.rotations[order]).sum(1).abs()
    assert cos.min() > 0.98


def test_bad_splat_files(tmp_path):
    path = tmp_path / "m.splat"
    write_splat(path, model(n=4))
    data = path.read_bytes()
    path.write_bytes(data[:-5])
    with pytest.raises(InputError, match="not a multiple of 32"):
        read_splat(path)
    path.write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        read_splat(path)
    arr = np.frombuffer(data, np.uint8).copy()
    arr[12:16] = np.frombuffer(np.float32(np.nan).tobytes(), np.uint8)
    path.write_bytes(arr.tobytes())
    with pytest.raises(InputError, match="1 of 4 splats have NaN or infinite scale"):
        read_splat(path)


def test_non_finite_model_is_not_exported(tmp_path):
    g = model(n=5)
    g.opacity_logits[2] = float("inf")
    with pytest.raises(ValueError, match="non-finite opacity_logits"):
        write_splat(tmp_path / "x.splat", g)
    assert not any(tmp_path.iterdir())
