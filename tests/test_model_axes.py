"""The one axis conversion (RDF <-> RUB, training/model/axes.py): its SH sign table against the SH basis, its own
inverse, and a render of a turned model seen by the turned camera equal to the original's render."""

from __future__ import annotations

import numpy as np
import torch

from training.evaluate.measure import render_with_depth
from training.model.axes import SH_REST_SIGNS, rdf_rub
from training.model.gaussians import Gaussians
from training.model.sh import sh_basis
from training.scene.scene import Camera

F = np.diag([1.0, -1.0, -1.0, 1.0])  # the half turn about x, as a 4x4


def model(n=60, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g) * 0.6, log_scales=torch.randn(n, 3, generator=g) * 0.4 - 2.2,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g) + 1,
                     sh0=torch.randn(n, 1, 3, generator=g) * 0.6, shN=torch.randn(n, 15, 3, generator=g) * 0.3,
                     sh_degree=3)


def test_sh_signs_are_the_basis_parities():
    d = torch.nn.functional.normalize(torch.randn(50, 3, dtype=torch.float64), dim=1)
    ratio = sh_basis(3, d * torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))[:, 1:] / sh_basis(3, d)[:, 1:]
    assert torch.allclose(ratio, torch.tensor(SH_REST_SIGNS, dtype=torch.float64).expand_as(ratio))


def test_the_turn_is_its_own_inverse():
    g = model()
    back = rdf_rub(rdf_rub(g))
    for name, t in g.parameters().items():
        assert torch.equal(getattr(back, name), t), name


def test_turned_model_seen_by_the_turned_camera_renders_the_same():
    g = model()
    w2c = np.eye(4)
    w2c[:3, 3] = (0.2, -0.1, 3.0)  # looking down +z at the model, off its axis so that the SH matter
    a = Camera("a", 96, 72, 80.0, 80.0, 48.0, 36.0, w2c)
    b = Camera("b", 96, 72, 80.0, 80.0, 48.0, 36.0, w2c @ F)  # x_cam = W x = W F (F x)
    before = render_with_depth(g, [a])[0][0]
    after = render_with_depth(rdf_rub(g), [b])[0][0]
    assert before.std() > 0.05  # the model is in view
    assert np.abs(before - after).max() < 1e-4
    # a turn that forgot the SH (or the rotations) shows: the check can fail
    wrong = rdf_rub(g)
    wrong = Gaussians(**{**wrong.parameters(), "shN": g.shN}, sh_degree=3)
    assert np.abs(render_with_depth(wrong, [b])[0][0] - before).max() > 1e-2
