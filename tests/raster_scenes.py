"""Random Gaussian scenes for the rasterizer tests, seeded from the test's own seed (tests/conftest.py: fixed per
test unless SPLATSTYLER_TEST_SEED asks for a random run), the scene's seed printed."""

from __future__ import annotations

import torch


def fresh_seed(label: str) -> int:
    # Drawn from torch's global generator, which conftest seeds per test: reproducible by default, new scenes
    # in a SPLATSTYLER_TEST_SEED=random run.
    seed = int(torch.randint(0, 2**31 - 1, (1,)))
    print(f"[{label}] seed={seed}")  # pytest shows it for failing tests; rerun with this seed to reproduce
    return seed


def random_scene(n, width, height, seed, dtype=torch.float32, sh_degree=None, edge_cases=False,
                 fx_scale=0.9, fy_ratio=1.1, principal=(0.5, 0.5), log_scale_mean=-3.0):
    """Gaussians in front of an identity-ish camera. Returns (means, quats, scales, opacities, colors, viewmat, K).

    edge_cases mixes in Gaussians behind the camera, straddling and at the near plane, far off-screen, partly
    off-screen, with zero and huge scales, and fully opaque ones.
    """
    g = torch.Generator().manual_seed(seed)
    d = torch.float64
    means = (torch.rand(n, 3, generator=g, dtype=d) - 0.5) * torch.tensor([4.0, 3.0, 4.0], dtype=d)
    means[:, 2] += 5.0
    quats = torch.randn(n, 4, generator=g, dtype=d)
    scales = torch.exp(torch.randn(n, 3, generator=g, dtype=d) * 0.5 + log_scale_mean)
    opacities = torch.rand(n, generator=g, dtype=d) * 0.9 + 0.05
    if sh_degree is None:
        colors = torch.rand(n, 3, generator=g, dtype=d)
    else:
        colors = torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g, dtype=d) * 0.3
    if edge_cases and n >= 16:
        k = n // 16
        sl = [slice(i * k, (i + 1) * k) for i in range(8)]
        means[sl[0], 2] = -means[sl[0], 2]  # behind the camera
        means[sl[1], 2] = 0.01  # at the near plane
        means[sl[2], 2] = torch.rand(k, generator=g, dtype=d) * 0.05  # straddling the near plane
        means[sl[3], 0] = means[sl[3], 2] * (torch.rand(k, generator=g, dtype=d) * 2 + 1.0)  # off-screen right
        means[sl[4], 1] = -means[sl[4], 2] * 0.6  # partly off-screen top
        scales[sl[5], 0] = 0.0  # degenerate (flat) Gaussians
        scales[sl[6]] = scales[sl[6]] * 40  # huge (faint, so they do not hide everything else)
        opacities[sl[6]] = 0.02
        opacities[sl[7]] = 0.999  # opaque: exercises the alpha clamp and early termination
    f = fx_scale * width
    K = torch.tensor([[f, 0, principal[0] * width], [0, f * fy_ratio, principal[1] * height], [0, 0, 1]], dtype=d)
    # A slightly rotated and shifted camera so the world-to-camera transform is exercised.
    a = 0.1
    R = torch.tensor([[1, 0, 0], [0, torch.cos(torch.tensor(a)), -torch.sin(torch.tensor(a))],
                      [0, torch.sin(torch.tensor(a)), torch.cos(torch.tensor(a))]], dtype=d)
    V = torch.eye(4, dtype=d)
    V[:3, :3] = R
    V[:3, 3] = torch.tensor([0.1, -0.05, 0.2], dtype=d)
    # Keep means in camera frame as generated: world = R^T (p - t).
    means = (means - V[:3, 3]) @ R
    return [x.to(dtype) for x in (means, quats, scales, opacities, colors, V, K)]
