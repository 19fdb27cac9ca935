"""CUDA rasterizer: gsplat's ``rasterization`` behind our single-camera, render-mode conventions.

gsplat takes batched cameras (C, 4, 4) world-to-camera in the OpenCV convention and (C, 3, 3) intrinsics with
pixel centres at +0.5, like ours; we pass one camera and take element 0. We ask it for raw colour and/or depth
("RGB", "D", "RGB+D") without background and let ``rasterize()`` add the background and divide by alpha for
"ED", so every backend composes its outputs the same way. ``packed=False`` gives per-Gaussian means2d (C, N, 2);
a hook copies its gradient into the (N, 2) leaf returned in info, which is what our contract promises.

Known differences from the reference semantics: gsplat clamps alpha at 0.999 where the graphdeco kernels and
our backends use 0.99 (identical while opacity <= 0.99), and computes the projection in float32.
"""

from __future__ import annotations

import torch


def render_features_cuda(
    means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor, colors: torch.Tensor,
    viewmat: torch.Tensor, K: torch.Tensor, width: int, height: int, sh_degree: int | None, use_rgb: bool,
    use_depth: bool, near_plane: float, far_plane: float, eps2d: float, tile_size: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The cuda backend of ``training.raster.rasterize.rasterize``; same return values as the cpu backend."""
    from gsplat import rasterization

    mode = "RGB+D" if (use_rgb and use_depth) else ("RGB" if use_rgb else "D")
    render, alphas, meta = rasterization(
        means, quats, scales, opacities, colors, viewmat[None], K[None], width, height,
        near_plane=near_plane, far_plane=far_plane, eps2d=eps2d, sh_degree=sh_degree, packed=False,
        tile_size=tile_size, render_mode=mode, rasterize_mode="classic",
    )
    feats = render[0]
    if mode == "D":
        feats = feats[..., -1:]
    trans = 1.0 - alphas[0]

    m2 = meta["means2d"]
    leaf = m2.detach()[0].clone()
    if m2.requires_grad:
        leaf.requires_grad_(True)

        def copy_grad(grad: torch.Tensor) -> None:
            g = grad[0].detach()
            leaf.grad = g.clone() if leaf.grad is None else leaf.grad + g

        m2.register_hook(copy_grad)
    radii = meta["radii"][0]
    if radii.dim() == 2:  # gsplat >= 1.5 gives per-axis radii
        radii = radii.max(dim=-1).values
    return feats, trans, leaf, radii.to(torch.int32), meta["depths"][0].detach()
