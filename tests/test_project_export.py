"""``splatstyler export --project P -o OUT``: a project baked with no display is what applying its edits by hand gives;
style strength 0 and 1 give the original and the stylized colours bit for bit; a missing or changed model is one
line naming it (exit 2)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch

from training.scene.pose import quat_to_matrix
from app.cli import main
from app.project import FileRef, ModelEntry, Project, save_project
from training.model.colour_edit import ColourAdjustment, ColourEdits, adjust_sh, blend_style
from training.model.gaussians import Gaussians
from training.model.model_io import read_model
from training.model.ply_io import read_ply, write_ply
from training.model.rotation import quat_to_rotmat
from training.model.sh import sh_basis
from training.model.splat_io import read_splat
from training.model.transform import transform_gaussians

N = 300


def photo_and_stylized(tmp_path) -> tuple[Gaussians, Gaussians]:
    """A model and a 'stylized' one: the same Gaussians with other colours, as a colour-only stylization gives."""
    g = torch.Generator().manual_seed(0)
    photo = Gaussians(means=torch.randn(N, 3, generator=g), log_scales=torch.randn(N, 3, generator=g) - 3,
                      quats=torch.randn(N, 4, generator=g), opacity_logits=torch.randn(N, generator=g),
                      sh0=torch.randn(N, 1, 3, generator=g), shN=torch.randn(N, 15, 3, generator=g) * 0.2,
                      sh_degree=3)
    params = photo.parameters()
    params["sh0"] = torch.randn(N, 1, 3, generator=g)
    params["shN"] = torch.randn(N, 15, 3, generator=g) * 0.2
    stylized = Gaussians(**params, sh_degree=3)
    write_ply(tmp_path / "photo.ply", photo)
    write_ply(tmp_path / "stylized.ply", stylized)
    return read_ply(tmp_path / "photo.ply"), read_ply(tmp_path / "stylized.ply")


def similarity(scale, q, t) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = scale * quat_to_matrix(np.array(q, float))
    m[:3, 3] = t
    return m


def project(tmp_path, strength=0.4, transform=None, world=None, colour=True) -> tuple[Project, dict]:
    rng = np.random.default_rng(1)
    kept = np.flatnonzero(rng.random(N) > 0.25)  # a deletion of about a quarter
    region = rng.random(N) > 0.5
    strong = rng.random(N) > 0.8
    adjust = ColourAdjustment(brightness=0.05, contrast=0.1, saturation=-0.3, hue=20, temperature=0.5)
    edits = ColourEdits([(region, adjust)] if colour else [], strength=strength,
                        strength_regions=[(strong, 1.0)] if colour else [])
    transform = np.eye(4) if transform is None else transform
    world = np.eye(4) if world is None else world
    entry = ModelEntry(FileRef(tmp_path / "stylized.ply"), "scene", FileRef(tmp_path / "photo.ply"), kept,
                       np.zeros(len(kept), bool), np.zeros(len(kept), bool), transform, edits)
    p = Project([entry], world=world)
    path = save_project(tmp_path / "p.splatproj", p)
    return p, {"path": path, "kept": kept, "region": region, "strong": strong, "adjust": adjust}


def export(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_deletion_transform_colour_and_strength_are_baked_as_by_hand(tmp_path, capsys):
    photo, stylized = photo_and_stylized(tmp_path)
    transform = similarity(1.5, (0.8, 0.2, -0.4, 0.3), (0.5, -1.0, 2.0))
    world = similarity(2.0, (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # up axis flipped, scene doubled
    _, h = project(tmp_path, transform=transform, world=world)
    out = tmp_path / "out.ply"
    code, stdout, err = export(capsys, "export", "--project", h["path"], "-o", out)
    assert code == 0, err
    assert f"{len(h['kept'])} Gaussians" in stdout
    got = read_ply(out)

    # by hand, with the library's steps: the wiring (order, rows, regions, matrices) bit for bit
    s = np.where(h["strong"], 1.0, 0.4)
    sh = adjust_sh(blend_style(photo.sh, stylized.sh, s), [(h["region"], h["adjust"])])
    params = stylized.parameters()
    params["sh0"], params["shN"] = sh[:, :1].contiguous(), sh[:, 1:].contiguous()
    rows = torch.as_tensor(h["kept"])
    by_hand = transform_gaussians(Gaussians(**params, sh_degree=3).subset(rows), world @ transform)
    for k in ("means", "log_scales", "quats", "opacity_logits", "sh0", "shN"):
        assert torch.equal(getattr(got, k), getattr(by_hand, k)), k

    # by hand from the definitions, in float64: the same model within float32 rounding
    a = world[:3, :3] @ transform[:3, :3]
    t = world[:3, :3] @ transform[:3, 3] + world[:3, 3]
    keep = h["kept"]
    assert np.allclose(got.means.numpy(), stylized.means.double().numpy()[keep] @ a.T + t, atol=1e-5)
    cov = lambda g: (quat_to_rotmat(g.quats.double()) @ torch.diag_embed(g.scales.double() ** 2)  # noqa: E731
                     @ quat_to_rotmat(g.quats.double()).mT)
    assert torch.allclose(cov(got), torch.from_numpy(a) @ cov(stylized)[keep] @ torch.from_numpy(a.T), atol=1e-8,
                          rtol=1e-4)
    dirs = torch.nn.functional.normalize(torch.randn(32, 3, generator=torch.Generator().manual_seed(3),
                                                     dtype=torch.float64), dim=-1)
    r = torch.from_numpy(a / np.cbrt(np.linalg.det(a)))

    def colours(g_sh, d):  # unclamped rendered colour of each Gaussian along each direction
        return torch.einsum("dk,nkc->ndc", sh_basis(3, d), g_sh.double()) + 0.5

    w = torch.from_numpy(s)[:, None, None]
    blended = colours(photo.sh, dirs) + w * (colours(stylized.sh, dirs) - colours(photo.sh, dirs))
    m, o = h["adjust"].affine()
    expected = torch.where(torch.from_numpy(h["region"])[:, None, None], blended @ torch.from_numpy(m).T
                           + torch.from_numpy(o), blended)[keep]
    # the exported Gaussian seen along R d shows what the edited one showed along d
    assert torch.allclose(colours(got.sh, dirs @ r.T), expected, atol=2e-5)


@pytest.mark.parametrize("strength, which", [(0.0, "photo"), (1.0, "stylized")])
def test_style_strength_0_and_1_export_the_original_and_stylized_colours_bit_for_bit(tmp_path, capsys, strength,
                                                                                   which):
    photo, stylized = photo_and_stylized(tmp_path)
    shift = np.eye(4)
    shift[:3, 3] = [1.0, 2.0, 3.0]
    _, h = project(tmp_path, strength=strength, transform=shift, colour=False)
    out = tmp_path / "out.ply"
    code, _, err = export(capsys, "export", "--project", h["path"], "-o", out)
    assert code == 0, err
    got, want = read_ply(out), {"photo": photo, "stylized": stylized}[which]
    rows = torch.as_tensor(h["kept"])
    assert torch.equal(got.sh0, want.sh0[rows]) and torch.equal(got.shN, want.shN[rows])
    assert not torch.equal(got.sh0, {"photo": stylized, "stylized": photo}[which].sh0[rows])
    assert torch.allclose(got.means, stylized.means[rows] + torch.tensor([1.0, 2.0, 3.0]))


def test_other_formats_and_hidden_gaussians(tmp_path, capsys):
    photo_and_stylized(tmp_path)
    p, h = project(tmp_path)
    p.models[0].hidden[:10] = True
    path = save_project(tmp_path / "hidden.splatproj", p)
    code, _, err = export(capsys, "export", "--project", path, "-o", tmp_path / "o.splat", "--without-hidden")
    assert code == 0, err
    assert len(read_splat(tmp_path / "o.splat")) == len(h["kept"]) - 10
    code, _, err = export(capsys, "export", "--project", path, "-o", tmp_path / "o.compressed.ply")
    assert code == 0, err
    for name, extra in (("o.spz", ["--spz-version", "3"]), ("o.glb", [])):
        code, _, err = export(capsys, "export", "--project", path, "-o", tmp_path / name, "--without-hidden", *extra)
        assert code == 0, err
        assert len(read_model(tmp_path / name)) == len(h["kept"]) - 10
    assert (tmp_path / "o.spz").read_bytes()[:2] == b"\x1f\x8b"  # version 3: gzip
    code, _, err = export(capsys, "export", tmp_path / "photo.ply", "--project", path, "-o", tmp_path / "x.ply")
    assert code == 2 and "give a model file IN or --project P" in err


@pytest.mark.parametrize("damage", ["moved", "changed"])
def test_a_project_whose_model_moved_or_changed_fails_in_one_line(tmp_path, capsys, damage):
    photo_and_stylized(tmp_path)
    _, h = project(tmp_path)
    if damage == "moved":
        shutil.move(tmp_path / "stylized.ply", tmp_path / "elsewhere.ply")
    else:
        write_ply(tmp_path / "stylized.ply", read_ply(tmp_path / "photo.ply"))
    out = tmp_path / "out.ply"
    code, _, err = export(capsys, "export", "--project", h["path"], "-o", out)
    assert code == 2 and not out.exists()
    assert len(err.strip().splitlines()) == 1 and str(tmp_path / "stylized.ply") in err
    assert ("not found" if damage == "moved" else "changed since the project was saved") in err


def test_two_models_export_as_one_file_with_their_transforms(tmp_path, capsys):
    photo, stylized = photo_and_stylized(tmp_path)
    g = torch.Generator().manual_seed(5)
    second = Gaussians(torch.randn(50, 3, generator=g), torch.randn(50, 3, generator=g) - 3,
                       torch.randn(50, 4, generator=g), torch.randn(50, generator=g), torch.randn(50, 1, 3, generator=g),
                       torch.randn(50, 3, 3, generator=g), 1)
    write_ply(tmp_path / "second.ply", second)
    second = read_ply(tmp_path / "second.ply")
    move = similarity(0.5, (0.6, 0.0, 0.8, 0.0), (10.0, 0.0, 0.0))
    p = Project([ModelEntry(FileRef(tmp_path / "photo.ply"), "a"),
                 ModelEntry(FileRef(tmp_path / "second.ply"), "b", transform=move)])
    path = save_project(tmp_path / "two.splatproj", p)
    code, stdout, err = export(capsys, "export", "--project", path, "-o", tmp_path / "union.ply")
    assert code == 0, err
    assert f"{N + 50} Gaussians" in stdout
    got = read_ply(tmp_path / "union.ply")
    assert len(got) == N + 50 and got.sh_degree == 3
    assert torch.equal(got.means[:N], photo.means) and torch.equal(got.shN[:N], photo.shN)
    moved = transform_gaussians(second, move)
    assert torch.equal(got.means[N:], moved.means) and torch.equal(got.shN[N:, :3], moved.shN)
    assert not got.shN[N:, 3:].any()  # the degree-1 model's missing bands are zero


def damaged_project(tmp_path, damage: str):
    """A project of one model whose "selected" array member is damaged as ``damage`` says."""
    import io
    import json
    import zipfile

    photo_and_stylized(tmp_path)
    manifest = {"version": 1, "models": [{"path": "photo.ply", "selected": "arrays/s.npy"}]}
    path = tmp_path / f"{damage}.splatproj"
    if damage == "bomb":  # 200 MB of a valid bool array that deflates to about 200 kB
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("project.json", json.dumps(manifest))
            with z.open("arrays/s.npy", "w", force_zip64=True) as f:
                rows = 200_000_000
                np.lib.format.write_array_header_1_0(f, {"descr": "|b1", "fortran_order": False,
                                                         "shape": (rows,)})
                block = bytes(1 << 24)
                for _ in range(rows // len(block)):
                    f.write(block)
                f.write(bytes(rows % len(block)))
        return path
    if damage == "empty":
        member = b""
    elif damage == "zip inside":
        buf = io.BytesIO()
        np.savez(buf, s=np.zeros(N, bool))
        member = buf.getvalue()
    else:
        buf = io.BytesIO()
        np.save(buf, np.zeros(N, bool))
        member = buf.getvalue()
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        z.writestr("project.json", json.dumps(manifest))
        z.writestr("arrays/s.npy", member)
    if damage == "crc":  # one byte of the stored array flipped: the zip's checksum no longer matches
        data = bytearray(path.read_bytes())
        at = data.index(member) + len(member) - 1
        data[at] ^= 0xFF
        path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("damage", ["empty", "zip inside", "crc", "bomb"])
def test_a_damaged_array_member_is_one_line_and_is_not_read_whole(tmp_path, capsys, damage):
    """An empty .npy, a member that is itself a zip, a checksum error and a zip bomb (200 MB that deflate to
    200 kB) are each one line naming the project (exit 2), and the bomb is refused before it is inflated."""
    import tracemalloc

    path = damaged_project(tmp_path, damage)
    out = tmp_path / "out.ply"
    tracemalloc.start()
    try:
        code, _, err = export(capsys, "export", "--project", path, "-o", out)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert code == 2 and not out.exists(), err
    assert err.startswith(f"splatstyler: error: {path}: ") and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    assert peak < 50e6, f"{peak / 1e6:.0f} MB held while reading the project"
