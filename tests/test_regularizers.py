"""The paper's shape, size and depth terms on hand-made inputs: values and gradients."""

import math

import torch

from training.reconstruct.regularizers import depth_loss, depth_weight, scale_stats, shape_loss, size_loss


def test_shape_loss_values_and_gradient():
    s = torch.tensor([[1.0, 1.0, 1.0],      # isotropic: 0
                      [0.7, 0.1, 0.2],      # 0.7 - 3.5 * 0.1 = 0.35
                      [0.3, 0.1, 0.1]],     # 0.3 - 0.35 < 0: 0
                     requires_grad=True)
    loss = shape_loss(s, 3.5)
    assert abs(float(loss.detach()) - 0.35 / 3) < 1e-7
    loss.backward()
    expected = torch.zeros(3, 3)
    expected[1, 0] = 1 / 3
    expected[1, 1] = -3.5 / 3
    torch.testing.assert_close(s.grad, expected)


def test_size_loss_values_and_gradient():
    s = torch.tensor([[0.3, 0.01, 0.01],    # too big: 0.3 - 0.1 = 0.2
                      [0.05, 0.02, 0.01],   # inside the bounds: 0
                      [0.0005, 1e-4, 1e-4]],  # too small: 0.001 - 0.0005 = 0.0005
                     requires_grad=True)
    loss = size_loss(s, 0.1, 0.001)
    assert abs(float(loss.detach()) - (0.2 + 0.0005) / 3) < 1e-7
    loss.backward()
    expected = torch.zeros(3, 3)
    expected[0, 0] = 1 / 3
    expected[2, 0] = -1 / 3
    torch.testing.assert_close(s.grad, expected)


def test_empty_model_gives_zero():
    s = torch.zeros(0, 3, requires_grad=True)
    assert float(shape_loss(s).detach()) == 0.0 and float(size_loss(s).detach()) == 0.0


def test_depth_loss_only_where_valid():
    target = torch.tensor([[1.0, 2.0], [3.0, 4.0]])
    valid = torch.tensor([[True, False], [True, False]])
    rendered = torch.tensor([[1.5, 100.0], [2.0, -7.0]], requires_grad=True)
    loss = depth_loss(rendered[..., None], target, valid)
    assert abs(float(loss.detach()) - (0.5 + 1.0) / 2) < 1e-7
    loss.backward()
    torch.testing.assert_close(rendered.grad, torch.tensor([[0.5, 0.0], [-0.5, 0.0]]))
    assert float(depth_loss(rendered, target, torch.zeros(2, 2, dtype=torch.bool)).detach()) == 0.0


def test_depth_weight_decays_exponentially_from_1_to_001():
    assert abs(depth_weight(0, 1000) - 1.0) < 1e-12
    assert abs(depth_weight(1000, 1000) - 0.01) < 1e-12
    assert abs(depth_weight(500, 1000) - 0.1) < 1e-12  # geometric midpoint
    assert abs(depth_weight(250, 1000) - math.sqrt(0.1)) < 1e-12


def test_scale_stats_percentiles():
    s = torch.ones(100, 3)
    s[:, 0] = torch.arange(1, 101, dtype=torch.float32)
    st = scale_stats(s)
    assert abs(st["aniso_p95"] - 95.05) < 1e-6 and abs(st["smax_p95"] - 95.05) < 1e-6
