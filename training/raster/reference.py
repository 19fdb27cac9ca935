"""Plain PyTorch tile rasterizer: the reference the fast backends are tested against, and the last-resort fallback.

Semantics (shared by every backend, as in the graphdeco / gsplat CUDA kernels):
- camera space p = R m + t (OpenCV: z forward); Gaussians with z < near or z > far are culled;
- EWA: Sigma2d = J W Sigma W^T J^T + eps2d * I, with x/z and y/z clamped to 1.3x the field of view for J only;
- pixel (x, y) samples at (x + 0.5, y + 0.5); alpha = min(0.99, o * exp(-0.5 d^T Sigma2d^-1 d)), skipped when
  below 1/255; a Gaussian's screen box is the ellipse where alpha reaches 1/255, so nothing outside it counts;
- per pixel, Gaussians in increasing z, front to back; a Gaussian that would bring the transmittance T to
  1e-4 or below is not composited and ends the pixel; colour = sum c_i a_i T_i + T_final * background.
The numbers are defined once in training/raster/constants.py.

Autograd does the backward. Per 16x16 tile the (pixels x Gaussians) alpha matrix is built at once and the
transmittance is an exclusive cumulative product, so memory grows with the number of tile-Gaussian pairs.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from training.model.rotation import quat_to_rotmat
from training.model.sh import sh_to_rgb
from training.raster.constants import ALPHA_MAX, ALPHA_MIN, FOV_CLAMP_MARGIN, T_MIN


@dataclass
class Projected:
    """Per-Gaussian screen-space quantities. Shapes: N Gaussians."""

    means2d: torch.Tensor  # (N, 2) pixels
    conics: torch.Tensor  # (N, 3) upper triangle (a, b, c) of the inverse 2D covariance
    depths: torch.Tensor  # (N,) camera z
    radii: torch.Tensor  # (N, 2) int32 half-extent of the screen box in x and y; 0 = culled
    valid: torch.Tensor  # (N,) bool


def project_gaussians(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    eps2d: float,
) -> Projected:
    """EWA projection of N Gaussians (differentiable w.r.t. means, quats, scales).

    means (N,3), quats (N,4) wxyz, scales (N,3), opacities (N,), viewmat (4,4), K (3,3). Computed in float64
    and returned in the input dtype: for thin Gaussians close to the camera, det(Sigma2d) = ac - b^2 cancels
    catastrophically in float32 (errors of several percent in alpha over the whole image), and this O(N) step
    costs little next to compositing.
    """
    out_dtype = means.dtype
    means, quats, scales, viewmat, K = (x.to(torch.float64) for x in (means, quats, scales, viewmat, K))
    R = viewmat[:3, :3]
    t = viewmat[:3, 3]
    pc = means @ R.T + t
    x, y, z = pc.unbind(-1)
    in_depth = (z >= near_plane) & (z <= far_plane)
    # Culled rows still flow through autograd (multiplied by zero); keep them finite so no NaN leaks.
    zs = torch.where(in_depth, z, torch.ones_like(z))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]

    rot = quat_to_rotmat(quats)
    M = rot * scales.unsqueeze(-2)  # R S
    cov_w = M @ M.transpose(-1, -2)
    cov_c = R @ cov_w @ R.T

    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    lim_xp = (width - cx) / fx + FOV_CLAMP_MARGIN * tan_fovx
    lim_xn = cx / fx + FOV_CLAMP_MARGIN * tan_fovx
    lim_yp = (height - cy) / fy + FOV_CLAMP_MARGIN * tan_fovy
    lim_yn = cy / fy + FOV_CLAMP_MARGIN * tan_fovy
    tx = zs * torch.minimum(torch.maximum(x / zs, -lim_xn), lim_xp)
    ty = zs * torch.minimum(torch.maximum(y / zs, -lim_yn), lim_yp)
    zero = torch.zeros_like(zs)
    J = torch.stack(
        [fx / zs, zero, -fx * tx / (zs * zs), zero, fy / zs, -fy * ty / (zs * zs)], dim=-1
    ).reshape(-1, 2, 3)
    cov2 = J @ cov_c @ J.transpose(-1, -2)
    a = cov2[:, 0, 0] + eps2d
    b = cov2[:, 0, 1]
    c = cov2[:, 1, 1] + eps2d
    det = a * c - b * b
    ok_det = det > 0
    dets = torch.where(ok_det, det, torch.ones_like(det))
    conics = torch.stack([c / dets, -b / dets, a / dets], dim=-1)
    means2d = torch.stack([fx * x / zs + cx, fy * y / zs + cy], dim=-1)

    with torch.no_grad():
        op = opacities.detach()
        ok_op = op >= ALPHA_MIN
        # Box of the ellipse where o * exp(-q/2) = 1/255: half-width extend * sqrt(Sigma_xx), exact per axis.
        extend = torch.sqrt(2.0 * torch.log(op.clamp_min(ALPHA_MIN) / ALPHA_MIN))
        rx = torch.ceil(extend * torch.sqrt(a.detach().clamp_min(0)))
        ry = torch.ceil(extend * torch.sqrt(c.detach().clamp_min(0)))
        m2 = means2d.detach()
        on_screen = (m2[:, 0] + rx > 0) & (m2[:, 0] - rx < width) & (m2[:, 1] + ry > 0) & (m2[:, 1] - ry < height)
        valid = in_depth & ok_det & ok_op & (rx > 0) & (ry > 0) & on_screen
        valid &= torch.isfinite(m2).all(dim=-1) & torch.isfinite(conics.detach()).all(dim=-1)
        radii = torch.stack([rx, ry], dim=-1).nan_to_num(0).clamp(0, 2**30).to(torch.int32)
        radii[~valid] = 0
    return Projected(means2d=means2d.to(out_dtype), conics=conics.to(out_dtype), depths=z.to(out_dtype),
                     radii=radii, valid=valid)


def tile_pairs(
    means2d: torch.Tensor, radii: torch.Tensor, depths: torch.Tensor, valid: torch.Tensor,
    width: int, height: int, tile_size: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Tile-Gaussian intersections sorted by (tile, depth, index).

    Returns gauss_ids (P,) int64 and tile_offsets (tiles_y * tiles_x + 1,) int64: tile t owns
    gauss_ids[tile_offsets[t]:tile_offsets[t + 1]] in front-to-back order.
    """
    tiles_x = (width + tile_size - 1) // tile_size
    tiles_y = (height + tile_size - 1) // tile_size
    idx = torch.nonzero(valid).squeeze(1)
    m = means2d.detach()[idx].double()
    r = radii[idx].double()
    x0 = torch.floor((m[:, 0] - r[:, 0]) / tile_size).clamp(0, tiles_x).long()
    x1 = torch.ceil((m[:, 0] + r[:, 0]) / tile_size).clamp(0, tiles_x).long()
    y0 = torch.floor((m[:, 1] - r[:, 1]) / tile_size).clamp(0, tiles_y).long()
    y1 = torch.ceil((m[:, 1] + r[:, 1]) / tile_size).clamp(0, tiles_y).long()
    nx, ny = x1 - x0, y1 - y0
    counts = nx * ny
    keep = counts > 0
    idx, x0, y0, nx, counts = idx[keep], x0[keep], y0[keep], nx[keep], counts[keep]
    dev = means2d.device
    owner = torch.repeat_interleave(torch.arange(idx.numel(), device=dev), counts)
    start = torch.cumsum(counts, 0) - counts
    local = torch.arange(owner.numel(), device=dev) - start[owner]
    tile = (y0[owner] + local // nx[owner]) * tiles_x + x0[owner] + local % nx[owner]
    # Depth rank (stable, ties by index) makes the (tile, rank) key an exact integer.
    order = torch.sort(depths.detach()[idx], stable=True).indices
    rank = torch.empty_like(order)
    rank[order] = torch.arange(order.numel(), device=dev)
    key = tile * max(idx.numel(), 1) + rank[owner]
    sort = torch.sort(key).indices
    gauss_ids = idx[owner[sort]]
    per_tile = torch.bincount(tile, minlength=tiles_x * tiles_y)
    offsets = torch.zeros(tiles_x * tiles_y + 1, dtype=torch.long, device=dev)
    offsets[1:] = torch.cumsum(per_tile, 0)
    return gauss_ids, offsets


def composite_tiles(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    features: torch.Tensor,
    gauss_ids: torch.Tensor,
    offsets: torch.Tensor,
    width: int,
    height: int,
    tile_size: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Front-to-back compositing per tile.

    features (N, C). Returns (H, W, C) sum of f_i a_i T_i, and (H, W, 1) final transmittance.
    """
    tiles_x = (width + tile_size - 1) // tile_size
    tiles_y = (height + tile_size - 1) // tile_size
    C = features.shape[1]
    dtype = means2d.dtype
    dev = means2d.device
    ar = torch.arange(tile_size, dtype=dtype, device=dev) + 0.5
    py, px = torch.meshgrid(ar, ar, indexing="ij")
    px, py = px.reshape(-1), py.reshape(-1)
    n_pix = tile_size * tile_size
    empty_f = torch.zeros(n_pix, C, dtype=dtype, device=dev)
    empty_t = torch.ones(n_pix, 1, dtype=dtype, device=dev)
    bounds = offsets.tolist()
    outs_f, outs_t = [], []
    for ty in range(tiles_y):
        for tx in range(tiles_x):
            t = ty * tiles_x + tx
            s, e = bounds[t], bounds[t + 1]
            if s == e:
                outs_f.append(empty_f)
                outs_t.append(empty_t)
                continue
            ids = gauss_ids[s:e]
            m = means2d[ids]
            con = conics[ids]
            dx = m[None, :, 0] - (px[:, None] + tx * tile_size)  # (P, K)
            dy = m[None, :, 1] - (py[:, None] + ty * tile_size)
            power = -0.5 * (con[None, :, 0] * dx * dx + con[None, :, 2] * dy * dy) - con[None, :, 1] * dx * dy
            alpha = torch.clamp_max(opacities[ids][None, :] * torch.exp(power), ALPHA_MAX)
            with torch.no_grad():
                skip = (power > 0) | (alpha < ALPHA_MIN)
            alpha = torch.where(skip, torch.zeros_like(alpha), alpha)
            one_minus = 1.0 - alpha
            with torch.no_grad():
                # T after each Gaussian is non-increasing, so "still above T_MIN" is a prefix: exactly the
                # Gaussians the sequential loop composites before it stops.
                include = torch.cumprod(one_minus, dim=1) > T_MIN
            one_minus = torch.where(include, one_minus, torch.ones_like(one_minus))
            trans = torch.cumprod(one_minus, dim=1)  # T after each
            t_before = torch.cat([torch.ones_like(trans[:, :1]), trans[:, :-1]], dim=1)
            w = torch.where(include, alpha * t_before, torch.zeros_like(alpha))
            outs_f.append(w @ features[ids])
            outs_t.append(trans[:, -1:])

    def assemble(tiles: list[torch.Tensor], c: int) -> torch.Tensor:
        img = torch.stack(tiles).reshape(tiles_y, tiles_x, tile_size, tile_size, c)
        img = img.permute(0, 2, 1, 3, 4).reshape(tiles_y * tile_size, tiles_x * tile_size, c)
        return img[:height, :width]

    return assemble(outs_f, C), assemble(outs_t, 1)


def render_features(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    sh_degree: int | None,
    use_rgb: bool,
    use_depth: bool,
    near_plane: float,
    far_plane: float,
    eps2d: float,
    tile_size: int,
) -> tuple[torch.Tensor, torch.Tensor, Projected, torch.Tensor]:
    """Project, evaluate colours and composite [rgb][depth] channels.

    Returns features image (H, W, C) without background, final transmittance (H, W, 1), the projection, and an
    (N, 2) tensor equal to the pixel-space means whose ``.grad`` receives the screen-space gradient.
    """
    proj = project_gaussians(means, quats, scales, opacities, viewmat, K, width, height, near_plane, far_plane, eps2d)
    means2d_out = proj.means2d.detach().clone()
    if torch.is_grad_enabled() and proj.means2d.requires_grad:
        # A leaf holding the same values: adding (leaf - leaf.detach()) changes nothing in the forward pass but
        # routes dL/d(means2d) into leaf.grad, the screen-space gradient densification reads.
        means2d_out.requires_grad_(True)
        proj.means2d = proj.means2d + (means2d_out - means2d_out.detach())
    feats = []
    if use_rgb:
        if sh_degree is None:
            feats.append(colors)
        else:
            campos = -viewmat[:3, :3].T @ viewmat[:3, 3]
            feats.append(sh_to_rgb(sh_degree, colors, means, campos))
    if use_depth:
        feats.append(proj.depths.unsqueeze(-1))
    features = torch.cat(feats, dim=-1)
    gauss_ids, offsets = tile_pairs(proj.means2d, proj.radii, proj.depths, proj.valid, width, height, tile_size)
    img, trans = composite_tiles(
        proj.means2d, proj.conics, opacities, features, gauss_ids, offsets, width, height, tile_size
    )
    return img, trans, proj, means2d_out

