"""One ``read_model`` for every model file: the bytes decide the format (the name only for .splat, which has no
header), every format reads back what we write, a damaged file of any format is one line naming it (exit 2), and
nothing outside training/model reads model files another way."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
import torch

from app.cli import main
from training.core.errors import InputError
from training.model.export import write_export
from training.model.gaussians import Gaussians
from training.model.model_io import model_format, read_model

ROOT = Path(__file__).resolve().parents[1]
FILES = {"ply": "m.ply", "compressed-ply": "m.compressed.ply", "splat": "m.splat", "spz": "m.spz", "glb": "m.glb"}


def model(n=300, degree=3, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g) * 2, log_scales=torch.randn(n, 3, generator=g) * 0.5 - 4,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g),
                     sh0=torch.randn(n, 1, 3, generator=g) * 0.5,
                     shN=(torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g) * 0.2).clamp(-0.9, 0.9),
                     sh_degree=degree)


def written(tmp_path: Path, fmt: str, g: Gaussians, version: int | None = None) -> Path:
    path = tmp_path / (FILES[fmt] if version != 3 else "m3.spz")
    write_export(path, g, fmt, spz_version=version)
    return path


@pytest.mark.parametrize("fmt", list(FILES))
def test_every_format_reads_back_whatever_its_name(tmp_path, fmt):
    g = model()
    path = written(tmp_path, fmt, g)
    back = read_model(path)
    assert model_format(path) == fmt and len(back) == len(g)
    assert back.sh_degree == (0 if fmt == "splat" else 3)
    if fmt != "splat":  # .splat has no header: its name is all there is
        renamed = path.rename(tmp_path / "model.bin")
        assert model_format(renamed) == fmt
        again = read_model(renamed)
        for name, t in back.parameters().items():
            assert torch.equal(getattr(again, name), t), name
    if fmt in ("ply", "glb"):  # float32 formats: the model itself (glb: exp/sigmoid and back)
        assert torch.equal(back.means, g.means) and torch.equal(back.shN, g.shN)
        assert torch.allclose(back.log_scales, g.log_scales, atol=1e-5)
    # order-free comparison (.splat sorts by importance, compressed PLY by Morton code)
    near = torch.cdist(back.means.double(), g.means.double()).min(dim=1).values
    assert near.max() < 0.01


def test_the_bytes_decide_not_the_name(tmp_path):
    g = model()
    spz = written(tmp_path, "spz", g)
    fake = tmp_path / "looks_like.glb"
    fake.write_bytes(spz.read_bytes())
    assert model_format(fake) == "spz" and len(read_model(fake)) == len(g)
    compressed = written(tmp_path, "compressed-ply", g)
    plain = tmp_path / "plain.ply"
    plain.write_bytes(compressed.read_bytes())
    assert model_format(plain) == "compressed-ply" and len(read_model(plain)) == len(g)
    assert model_format(ROOT / "pyproject.toml") is None


def _truncate(data: bytes) -> bytes:
    return data[: len(data) * 2 // 3 - 5]


def _damage_middle(data: bytes) -> bytes:
    b = bytearray(data)
    b[40:120] = b"\xff" * 80
    return bytes(b)


def _text(data: bytes) -> bytes:
    return b"hello world"


def _json(data: bytes) -> bytes:
    return b"{}"


# (format, spz version, damage, a word the line must hold)
DAMAGES = [("ply", None, _truncate, "truncated"), ("compressed-ply", None, _truncate, "truncated"),
           ("splat", None, _truncate, "not a multiple of 32"), ("spz", 4, _truncate, "truncated or damaged"),
           ("spz", 3, _truncate, "truncated or damaged"), ("glb", None, _truncate, "truncated or damaged"),
           ("spz", 4, _damage_middle, "SPZ"), ("spz", 3, _damage_middle, "not a readable SPZ"),
           ("glb", None, _damage_middle, "JSON"), ("compressed-ply", None, _damage_middle, "PLY"),
           ("spz", 4, _text, "not an SPZ file"), ("glb", None, _json, "not a binary glTF")]


@pytest.mark.parametrize("fmt,version,damage,word", DAMAGES,
                         ids=[f"{f}{v or ''}-{d.__name__.strip('_')}" for f, v, d, _ in DAMAGES])
def test_a_damaged_file_is_one_line_and_exit_2(tmp_path, capsys, fmt, version, damage, word):
    path = written(tmp_path, fmt, model(), version)
    path.write_bytes(damage(path.read_bytes()))
    for argv in (["info", path], ["export", path, "-o", tmp_path / "o.ply"], ["render", path, "--orbit",
                                                                              "1", "-o", tmp_path / "o.png"]):
        assert main([str(a) for a in argv]) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"splatstyler: error: {path}: "), lines
        assert word in lines[0], lines[0]
    assert not (tmp_path / "o.ply").exists() and not (tmp_path / "o.png").exists()


def test_non_finite_values_are_refused_where_the_model_enters(tmp_path):
    g = model()
    path = written(tmp_path, "glb", g)
    data = bytearray(path.read_bytes())
    json_len = int.from_bytes(data[12:16], "little")
    start = 20 + json_len + 8  # the first value of POSITION
    data[start: start + 4] = np.float32(np.inf).tobytes()
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="1 of 300 Gaussians have NaN or infinite POSITION"):
        read_model(path)


def test_nothing_reads_a_model_file_but_read_model():
    """Outside training/model (where the readers live) no module imports a format's reader."""
    readers = {"read_ply", "read_splat", "read_compressed_ply", "read_spz", "read_glb"}
    offenders = []
    for top in ("app", "training", "renderer_gl"):
        for path in (ROOT / top).rglob("*.py"):
            if path.is_relative_to(ROOT / "training" / "model"):
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and any(a.name in readers for a in node.names):
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert offenders == []


def test_a_log_scale_float32_cannot_square_is_refused_and_one_it_can_exports_and_reads_back(tmp_path):
    """A finite log-scale of 100 (a scale of 2.7e43, infinite in float32) is refused where the model enters; before,
    it was read, and its .splat and .glb exports held an infinite scale our own readers then refused. At the bound,
    every format writes a file that reads back."""
    from training.model.model_io import MAX_LOG_SCALE

    g = model()
    g.log_scales[0, 1] = 100.0
    with pytest.raises(InputError, match=r"1 of 300 Gaussians have a log-scale above 44.36 \(up to 100\)"):
        read_model(written(tmp_path, "ply", g))
    g.log_scales[0, 1] = MAX_LOG_SCALE - 0.01
    source = read_model(written(tmp_path, "ply", g))
    for fmt in ("splat", "glb"):  # the formats that store the scale itself, not its log
        back = read_model(written(tmp_path, fmt, source))
        assert torch.isfinite(back.log_scales).all() and float(back.log_scales.max()) > 40, fmt
