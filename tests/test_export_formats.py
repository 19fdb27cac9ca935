"""Export options: sizes known before writing, SH bands, selections, and the compressed PLY checked by decoding it
with plyfile and a decoder written here from PlayCanvas's published layout (not our encoder's code)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from plyfile import PlyData

from app.cli import main
from training.model.export import export_size, format_for_path, write_export
from training.model.gaussians import Gaussians
from training.model.ply_io import read_ply, write_ply
from training.model.splat_io import read_splat

SH_C0 = 0.28209479177387814


def model(n=1000, degree=3, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g) * 2, log_scales=torch.randn(n, 3, generator=g) - 3,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g) * 2,
                     sh0=torch.randn(n, 1, 3, generator=g), shN=torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g),
                     sh_degree=degree)


# ------------------------------------------------------------------ an independent decoder of compressed.ply
def unorm(v, bits):
    return (v & ((1 << bits) - 1)) / ((1 << bits) - 1)


def lerp(lo, hi, t):
    return lo * (1 - t) + hi * t


def decode_compressed(path):
    """(means, log_scales, quats wxyz, opacities, rgb, f_rest (N, M) or None) from a compressed PLY."""
    ply = PlyData.read(str(path))
    names = [e.name for e in ply.elements]
    assert names[:2] == ["chunk", "vertex"] and len(names) in (2, 3)
    ch, v = ply["chunk"].data, ply["vertex"].data
    assert all(ch.dtype[p] == np.dtype("<f4") for p in ch.dtype.names) and len(ch.dtype.names) == 18
    assert list(v.dtype.names) == ["packed_position", "packed_rotation", "packed_scale", "packed_color"]
    assert all(v.dtype[p] == np.dtype("<u4") for p in v.dtype.names)
    n = len(v)
    assert len(ch) == (n + 255) // 256
    c = np.arange(n) // 256

    def bounds(prefix_lo, prefix_hi, axes):
        return [(ch[f"{prefix_lo}{a}"][c].astype(np.float64), ch[f"{prefix_hi}{a}"][c].astype(np.float64))
                for a in axes]

    def unpack_11_10_11(word, bnds):
        parts = (unorm(word >> 21, 11), unorm(word >> 11, 10), unorm(word, 11))
        return np.stack([lerp(lo, hi, t) for (lo, hi), t in zip(bnds, parts)], axis=1)

    pos = unpack_11_10_11(v["packed_position"].astype(np.int64), bounds("min_", "max_", "xyz"))
    scl = unpack_11_10_11(v["packed_scale"].astype(np.int64), bounds("min_scale_", "max_scale_", "xyz"))
    col = v["packed_color"].astype(np.int64)
    rgb = np.stack([lerp(lo, hi, unorm(col >> s, 8)) for (lo, hi), s in zip(bounds("min_", "max_", "rgb"),
                                                                              (24, 16, 8))], axis=1)
    opacity = unorm(col, 8)
    rot = v["packed_rotation"].astype(np.int64)
    three = np.stack([(unorm(rot >> s, 10) - 0.5) / (np.sqrt(2) * 0.5) for s in (20, 10, 0)], axis=1)
    largest = rot >> 30
    q = np.zeros((n, 4))
    for i in range(n):
        rest = [j for j in range(4) if j != largest[i]]
        q[i, rest] = three[i]
        q[i, largest[i]] = np.sqrt(max(0.0, 1 - (three[i] ** 2).sum()))
    f_rest = None
    if "sh" in names:
        sh = ply["sh"].data
        assert len(sh) == n and all(sh.dtype[p] == np.dtype("u1") for p in sh.dtype.names)
        raw = np.stack([sh[f"f_rest_{i}"] for i in range(len(sh.dtype.names))], axis=1).astype(np.float64)
        f_rest = ((raw + 0.5) / 256 - 0.5) * 8  # bin centres
    return pos, scl, q, opacity, rgb, f_rest


@pytest.mark.parametrize("n,bands", [(1000, 3), (300, 1), (256, 0), (1, 2)])
def test_compressed_ply_decodes_to_the_model_within_quantisation(tmp_path, n, bands):
    g = model(n=n)
    path = tmp_path / "m.compressed.ply"
    result = write_export(path, g, sh_bands=bands)
    assert result.format == "compressed-ply" and path.stat().st_size == export_size("compressed-ply", bands, n)
    order = result.order
    assert sorted(order.tolist()) == list(range(n))
    pos, scl, q, opacity, rgb, f_rest = decode_compressed(path)
    a = {k: t.double().numpy()[order] for k, t in g.parameters().items()}

    ch = PlyData.read(str(path))["chunk"].data
    c = np.arange(n) // 256
    span = np.stack([ch[f"max_{x}"] - ch[f"min_{x}"] for x in "xyz"], axis=1)[c]
    step = span / np.array([2047, 1023, 2047])
    assert np.all(np.abs(pos - a["means"]) <= step / 2 + 1e-5)
    sspan = np.stack([ch[f"max_scale_{x}"] - ch[f"min_scale_{x}"] for x in "xyz"], axis=1)[c]
    assert np.all(np.abs(scl - a["log_scales"]) <= sspan / np.array([2047, 1023, 2047]) / 2 + 1e-5)
    want_rgb = a["sh0"][:, 0] * SH_C0 + 0.5
    cspan = np.stack([ch[f"max_{x}"] - ch[f"min_{x}"] for x in "rgb"], axis=1)[c]
    assert np.all(np.abs(rgb - want_rgb) <= cspan / 255 / 2 + 1e-5)
    assert np.all(np.abs(opacity - 1 / (1 + np.exp(-a["opacity_logits"]))) <= 0.5 / 255 + 1e-9)
    unit = a["quats"] / np.linalg.norm(a["quats"], axis=1, keepdims=True)
    err = np.minimum(np.abs(q - unit).max(1), np.abs(q + unit).max(1))  # q and -q are one rotation
    assert err.max() < 3e-3
    if bands == 0:
        assert f_rest is None
    else:
        k = (bands + 1) ** 2 - 1
        want = a["shN"][:, :k, :].transpose(0, 2, 1).reshape(n, 3 * k)  # channel-major, as a standard PLY
        inside = np.abs(want) < 3.9
        assert np.all(np.abs(f_rest - want)[inside] <= 8 / 256 / 2 + 1e-9)
        assert np.all(np.sign(f_rest[~inside]) == np.sign(want[~inside]))
    if n >= 1000:  # Morton order keeps chunks compact: each chunk's box is a fraction of the model's
        whole = np.prod(g.means.numpy().max(0) - g.means.numpy().min(0))
        assert np.prod(span[:256 * (n // 256)], axis=1).max() < 0.5 * whole


@pytest.mark.parametrize("fmt", ["ply", "compressed-ply", "splat", "glb"])
@pytest.mark.parametrize("bands", [0, 1, 2, 3])
@pytest.mark.parametrize("n", [1, 255, 257, 1000])
def test_export_size_is_the_written_size(tmp_path, fmt, bands, n):
    if fmt == "splat" and bands:
        with pytest.raises(ValueError, match="SH bands"):
            export_size(fmt, bands, n)
        return
    g = model(n=n)
    for pad in (True, False):
        path = tmp_path / f"m.{'splat' if fmt == 'splat' else 'glb' if fmt == 'glb' else 'ply'}"
        write_export(path, g, fmt, bands, pad_sh=pad)
        assert path.stat().st_size == export_size(fmt, bands, n, pad_sh=pad), pad


@pytest.mark.parametrize("bands", [0, 3])
def test_compressed_ply_reads_back_as_the_independent_decoder_decodes_it(tmp_path, bands):
    from training.model.model_io import read_model

    g = model(n=700, degree=3)
    write_export(tmp_path / "m.compressed.ply", g, sh_bands=bands)
    pos, scl, q, opacity, rgb, f_rest = decode_compressed(tmp_path / "m.compressed.ply")
    back = read_model(tmp_path / "m.compressed.ply")
    assert back.sh_degree == bands and len(back) == 700
    assert np.allclose(back.means.double().numpy(), pos, atol=1e-5)
    assert np.allclose(back.log_scales.double().numpy(), scl, atol=1e-5)
    assert np.allclose(torch.sigmoid(back.opacity_logits.double()).numpy(), opacity.clip(0.5 / 255, 1 - 0.5 / 255),
                       atol=1e-6)
    assert np.allclose(back.sh0[:, 0].double().numpy() * SH_C0 + 0.5, rgb, atol=1e-6)
    assert np.allclose(torch.nn.functional.normalize(back.quats.double(), dim=1).numpy(), q, atol=1e-6)
    if bands:
        assert np.allclose(back.shN.double().numpy().transpose(0, 2, 1).reshape(700, -1), f_rest, atol=1e-6)


def test_compact_ply_reads_back_with_its_bands_and_is_smaller(tmp_path):
    g = model(n=200, degree=3)
    write_export(tmp_path / "c.ply", g, sh_bands=1, pad_sh=False)
    write_export(tmp_path / "p.ply", g, sh_bands=1)
    c, p = read_ply(tmp_path / "c.ply"), read_ply(tmp_path / "p.ply")
    assert c.sh_degree == p.sh_degree == 1
    assert torch.equal(c.shN, g.shN[:, :3]) and torch.equal(p.shN, c.shN) and torch.equal(c.sh0, g.sh0)
    assert len(PlyData.read(str(tmp_path / "c.ply"))["vertex"].data.dtype.names) == 62 - 45 + 9
    assert (tmp_path / "c.ply").stat().st_size < (tmp_path / "p.ply").stat().st_size


def test_selection_export_holds_exactly_the_selected(tmp_path):
    g = model(n=500)
    mask = g.means[:, 0].numpy() > 0.3
    write_export(tmp_path / "s.ply", g, mask=mask)
    back = read_ply(tmp_path / "s.ply")
    for name, t in g.subset(torch.from_numpy(mask)).parameters().items():
        assert torch.equal(getattr(back, name), t), name
    with pytest.raises(ValueError, match="empty"):
        write_export(tmp_path / "e.ply", g, mask=np.zeros(500, dtype=bool))
    assert not (tmp_path / "e.ply").exists()


def test_format_from_name():
    assert format_for_path("a/scene.compressed.ply") == "compressed-ply"
    assert format_for_path("scene.PLY") == "ply" and format_for_path("x.splat") == "splat"
    assert format_for_path("x.spz") == "spz" and format_for_path("x.GLB") == "glb"
    assert format_for_path("x.ksplat") is None and format_for_path("x.gltf") is None


def test_cli_dry_run_box_and_formats(tmp_path, capsys):
    g = model(n=600, degree=2)
    src = tmp_path / "m.ply"
    write_ply(src, g)
    out = tmp_path / "cut.compressed.ply"
    assert main(["export", str(src), "-o", str(out), "--box=-1,-1,-1,1,1,1", "--sh-bands", "1", "--dry-run"]) == 0
    text = capsys.readouterr().out
    inside = ((g.means.abs() <= 1).all(1)).sum().item()
    assert f"{inside} of 600 Gaussians" in text and str(export_size("compressed-ply", 1, inside)) in text
    assert not out.exists()
    assert main(["export", str(src), "-o", str(out), "--box=-1,-1,-1,1,1,1", "--sh-bands", "1"]) == 0
    assert out.stat().st_size == export_size("compressed-ply", 1, inside)
    assert len(decode_compressed(out)[0]) == inside
    assert main(["export", str(src), "-o", str(tmp_path / "rest.splat"), "--box=-1,-1,-1,1,1,1", "--invert"]) == 0
    assert len(read_splat(tmp_path / "rest.splat")) == 600 - inside
    capsys.readouterr()
    assert main(["export", str(src), "-o", str(tmp_path / "x.splat"), "--sh-bands", "2"]) == 2
    assert "splat" in capsys.readouterr().err
    np.save(tmp_path / "bad.npy", np.ones(7, dtype=bool))
    assert main(["export", str(src), "-o", str(tmp_path / "y.ply"), "--mask", str(tmp_path / "bad.npy")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.npy" in err[0] and "600" in err[0]
    assert main(["export", str(src), "-o", str(tmp_path / "z.ply"), "--box=9,9,9,10,10,10"]) == 2
    assert "none of" in capsys.readouterr().err and not (tmp_path / "z.ply").exists()
