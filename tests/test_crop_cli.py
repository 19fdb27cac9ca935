"""``splatstyler crop``: exactly the Gaussians inside (or outside) the box or sphere, bit for bit; one-line errors."""

from __future__ import annotations

import numpy as np
import torch

from app.cli import main
from training.model.gaussians import Gaussians
from training.model.ply_io import read_ply, write_ply
from training.model.selection import box_mask, sphere_mask


def model(n=400, degree=2, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g), log_scales=torch.randn(n, 3, generator=g) - 3,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g),
                     sh0=torch.randn(n, 1, 3, generator=g), shN=torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g),
                     sh_degree=degree)


def test_crop_box_keeps_exactly_the_inside_and_invert_the_rest(tmp_path, capsys):
    g = model()
    src = tmp_path / "m.ply"
    write_ply(src, g)
    inside = ((g.means >= torch.tensor([-0.5, -1.0, -2.0])) & (g.means <= torch.tensor([1.0, 0.5, 2.0]))).all(1)
    assert 0 < int(inside.sum()) < len(g)
    # corners given in the "wrong" order span the same box
    assert main(["crop", str(src), "--box=1,0.5,2,-0.5,-1,-2", "-o", str(tmp_path / "in.ply")]) == 0
    assert f"kept {int(inside.sum())} of 400" in capsys.readouterr().out
    assert main(["crop", str(src), "--box=-0.5,-1,-2,1,0.5,2", "--invert", "-o", str(tmp_path / "out.ply")]) == 0
    a, b = read_ply(tmp_path / "in.ply"), read_ply(tmp_path / "out.ply")
    for name, t in g.subset(inside).parameters().items():
        assert torch.equal(getattr(a, name), t), name
    for name, t in g.subset(~inside).parameters().items():
        assert torch.equal(getattr(b, name), t), name
    assert a.sh_degree == 2


def test_crop_sphere_and_helpers(tmp_path, capsys):
    g = model()
    src = tmp_path / "m.ply"
    write_ply(src, g)
    assert main(["crop", str(src), "--sphere", "0,0,0,1", "-o", str(tmp_path / "s.ply")]) == 0
    expect = g.means.norm(dim=1) <= 1
    assert len(read_ply(tmp_path / "s.ply")) == int(expect.sum())
    means = g.means.numpy()
    assert np.array_equal(sphere_mask(means, (0, 0, 0), 1.0), expect.numpy())
    assert np.array_equal(box_mask(means, (0, 0, 0), (1, 1, 1), invert=True), ~box_mask(g.means, (1, 1, 1), (0, 0, 0)))


def test_crop_errors_are_one_line(tmp_path, capsys):
    g = model()
    src = tmp_path / "m.ply"
    write_ply(src, g)
    cases = [(["--box", "1,2,3"], "--box takes 6"), (["--box=9,9,9,10,10,10"], "none of its 400"),
             (["--sphere", "0,0,0,-1"], "radius")]
    for extra, words in cases:
        capsys.readouterr()
        assert main(["crop", str(src), *extra, "-o", str(tmp_path / "x.ply")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err
    assert main(["crop", str(src), "--box", "0,0,0,1,1,1", "-o", str(tmp_path / "x.obj")]) == 2
    assert not (tmp_path / "x.ply").exists()


def test_negative_coordinates_after_a_space_are_the_options_value(tmp_path, capsys):
    """The README's form, --box X0,... with a space, where X0 is negative: argparse alone takes '-0.5,...' for an
    option ("expected one argument"); every comma-list option accepts it."""
    g = model()
    src = tmp_path / "m.ply"
    write_ply(src, g)
    assert main(["crop", str(src), "--box", "-0.5,-1,-2,1,0.5,2", "-o", str(tmp_path / "in.ply")]) == 0
    inside = ((g.means >= torch.tensor([-0.5, -1.0, -2.0])) & (g.means <= torch.tensor([1.0, 0.5, 2.0]))).all(1)
    assert f"kept {int(inside.sum())} of 400" in capsys.readouterr().out
    assert main(["crop", str(src), "--sphere", "-0.2,0.1,-0.3,1.5", "-o", str(tmp_path / "s.ply")]) == 0
    centre = torch.tensor([-0.2, 0.1, -0.3])
    kept = int(((g.means - centre).norm(dim=1) <= 1.5).sum())
    assert f"kept {kept} of 400" in capsys.readouterr().out
