"""The one axis conversion (training/model/axes.py): its SH parity table against the SH basis, every convention's
turn and its inverse, what a turned Gaussian is (centre, covariance, colour seen from each direction, all from the
definitions, mirrors and the z-up family included), and a render of a turned model seen by the turned camera equal
to the original's render."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from training.evaluate.measure import render_with_depth
from training.model.axes import AXES, axes_matrix, convert_axes, sh_signs
from training.model.gaussians import Gaussians
from training.model.rotation import quat_to_rotmat
from training.model.sh import sh_basis, sh_to_rgb
from training.scene.scene import Camera


def model(n=60, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g) * 0.6, log_scales=torch.randn(n, 3, generator=g) * 0.4 - 2.2,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g) + 1,
                     sh0=torch.randn(n, 1, 3, generator=g) * 0.6, shN=torch.randn(n, 15, 3, generator=g) * 0.3,
                     sh_degree=3)


@pytest.mark.parametrize("signs", list(itertools.product((1.0, -1.0), repeat=3)))
def test_sh_signs_are_the_basis_parities(signs):
    d = torch.nn.functional.normalize(torch.randn(50, 3, dtype=torch.float64), dim=1)
    ratio = sh_basis(3, d * torch.tensor(signs, dtype=torch.float64))[:, 1:] / sh_basis(3, d)[:, 1:]
    assert torch.allclose(ratio, torch.from_numpy(sh_signs(signs, 15)).expand_as(ratio))


def test_axes_matrices_name_what_they_say():
    # RDF -> RUB is the half turn about x; -> LUF about z; to the z-up RFU: y' = forward = z, z' = up = -y
    assert np.array_equal(axes_matrix("RDF", "RUB"), np.diag([1.0, -1.0, -1.0]))
    assert np.array_equal(axes_matrix("RDF", "LUF"), np.diag([-1.0, -1.0, 1.0]))
    assert np.array_equal(axes_matrix("RDF", "RFU") @ [1.0, 2.0, 3.0], [1.0, 3.0, -2.0])
    for a, b in itertools.product(AXES, repeat=2):
        assert np.array_equal(axes_matrix(b, a) @ axes_matrix(a, b), np.eye(3))


def covariances(g: Gaussians) -> torch.Tensor:
    r = quat_to_rotmat(torch.nn.functional.normalize(g.quats.double(), dim=1))
    return r @ torch.diag_embed(torch.exp(2 * g.log_scales.double())) @ r.transpose(1, 2)


@pytest.mark.parametrize("target", ["RUB", "LUF", "RDB", "LDF", "RFU", "LBD", "RBU"])
def test_a_turned_gaussian_is_the_same_gaussian_in_the_other_axes(target):
    g = model()
    m = torch.from_numpy(axes_matrix("RDF", target))
    t = convert_axes(g, "RDF", target)
    assert torch.allclose(t.means.double(), g.means.double() @ m.T, atol=1e-6)
    assert torch.allclose(covariances(t), m @ covariances(g) @ m.T, atol=1e-6)
    assert torch.equal(t.log_scales, g.log_scales) and torch.equal(t.sh0, g.sh0)
    # the colour seen along d before is the colour seen along M d after
    d = torch.nn.functional.normalize(torch.randn(len(g), 3, dtype=torch.float64), dim=1)
    before = sh_to_rgb(3, g.sh.double(), -d, torch.zeros(3, dtype=torch.float64))
    after = sh_to_rgb(3, t.sh.double(), -(d @ m.T), torch.zeros(3, dtype=torch.float64))
    assert torch.allclose(before, after, atol=1e-5)
    back = convert_axes(t, target, "RDF")
    assert torch.allclose(covariances(back), covariances(g), atol=1e-6)
    assert torch.allclose(back.means, g.means, atol=1e-6) and torch.allclose(back.shN, g.shN, atol=1e-5)


def test_the_same_axes_return_the_model_and_in_place_changes_it():
    g = model()
    assert convert_axes(g, "RDF", "rdf") is g
    means = g.means.clone()
    t = convert_axes(g, "RDF", "RUB")
    assert torch.equal(g.means, means) and not torch.equal(t.means, means)
    assert convert_axes(g, "RDF", "RUB", in_place=True) is g and torch.equal(g.means, t.means)
    with pytest.raises(ValueError, match="unknown axes"):
        convert_axes(g, "RDF", "XYZ")


@pytest.mark.parametrize("target", ["RUB", "LUF", "RFU"])
def test_turned_model_seen_by_the_turned_camera_renders_the_same(target):
    g = model()
    f = np.eye(4)
    f[:3, :3] = axes_matrix("RDF", target)
    w2c = np.eye(4)
    w2c[:3, 3] = (0.2, -0.1, 3.0)  # looking down +z at the model, off its axis so that the SH matter
    a = Camera("a", 96, 72, 80.0, 80.0, 48.0, 36.0, w2c)
    b = Camera("b", 96, 72, 80.0, 80.0, 48.0, 36.0, w2c @ f.T)  # x_cam = W x = W F^T (F x)
    before = render_with_depth(g, [a])[0][0]
    after = render_with_depth(convert_axes(g, "RDF", target), [b])[0][0]
    assert before.std() > 0.05  # the model is in view
    assert np.abs(before - after).max() < 1e-4
    # a turn that forgot the SH (or the rotations) shows: the check can fail
    wrong = convert_axes(g, "RDF", target)
    wrong = Gaussians(**{**wrong.parameters(), "shN": g.shN}, sh_degree=3)
    assert np.abs(render_with_depth(wrong, [b])[0][0] - before).max() > 1e-2
