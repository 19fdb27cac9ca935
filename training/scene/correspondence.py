"""Which pixel of one view shows the same surface point as a pixel of another: the depth warp shared by the
consistency metric (training/evaluate/consistency.py), the match agreement (training/evaluate/match_agreement.py)
and the stylizer's per-step agreement (training/stylize/plan_readouts.py).

A target pixel centre p = (x + 0.5, y + 0.5) at the target's rendered expected depth z_t(p) is unprojected,
X = C2W_t (z_t(p) K_t^-1 [p, 1]), and projected into the source, q = K_s X_s / z_s with X_s = W2C_s X. It is what
the source shows there when q lies inside the source image with z_s > 0, the source's alpha sampled at q is at least
``MIN_ALPHA``, and |z_s - D_s(q)| <= ``DEPTH_TOLERANCE`` z_s (not hidden behind a nearer surface; a bilinear sample
across a depth edge mixes the two depths and fails the test too).

Feature cells (``cell_correspondence``): a (h, w) grid over an (H, W) render, cell (i, j) covering rows
[iH/h, (i+1)H/h) and columns [jW/w, (j+1)W/w); its centre is carried with the depth and alpha sampled there and lands
in the source cell that contains it.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

DEPTH_TOLERANCE = 0.03  # relative: |z_projected - z_source| <= 3 % of z_projected
MIN_ALPHA = 0.5  # pixels of the target and the source with less coverage than this are not compared
MIN_CELLS = 8  # a pair of views with fewer corresponding feature cells gives no agreement


def warp_points(xs: torch.Tensor, ys: torch.Tensor, zt: torch.Tensor, target_camera,
                source_camera) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Target pixel coordinates (xs, ys) (pixel centres at +0.5) at camera depths ``zt`` -> their pixel coordinates
    (u, v) in the source view and their depth z there; float64 tensors of the inputs' shape. The cameras are
    training/scene/camera.py's, which unproject and project."""
    def plain(t):
        return t.detach().cpu().numpy()

    ps = source_camera.camera_points(target_camera.unproject(plain(xs), plain(ys), plain(zt)))
    uv, _ = source_camera.pixels(ps, near=1e-9)

    def back(a):
        return torch.from_numpy(np.ascontiguousarray(a)).reshape(xs.shape)

    return back(uv[:, 0]), back(uv[:, 1]), back(ps[:, 2])


def sample_bilinear(image: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """(H, W, C) float64 sampled bilinearly at pixel coordinates (u, v) (centres at +0.5; border-clamped) ->
    (*u.shape, C)."""
    Hs, Ws = image.shape[:2]
    # pixel coordinates -> grid_sample's [-1, 1] with align_corners=False
    grid = torch.stack([2 * u / Ws - 1, 2 * v / Hs - 1], dim=-1).reshape(1, -1, 1, 2)
    out = F.grid_sample(image.permute(2, 0, 1)[None], grid, mode="bilinear", padding_mode="border",
                        align_corners=False)[0, :, :, 0]
    return out.t().reshape(*u.shape, image.shape[2])


def seen_by_source(u, v, z, source_alpha, source_depth, width: int, height: int, min_alpha: float = MIN_ALPHA,
                   depth_tolerance: float = DEPTH_TOLERANCE) -> torch.Tensor:
    """Where a warped point is what the source view shows: in front of it, inside its image, on its covered
    pixels, and at the depth it renders there (``source_alpha``/``source_depth`` sampled at (u, v))."""
    inside = (z > 1e-9) & (u >= 0) & (u <= width) & (v >= 0) & (v <= height)
    return inside & (source_alpha >= min_alpha) & ((z - source_depth).abs() <= depth_tolerance * z)


def _plane(x) -> torch.Tensor:
    """(H, W) or (H, W, 1) array or tensor -> (H, W) float64 tensor on the CPU."""
    x = x.detach().cpu() if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    x = x.to(torch.float64)
    return x[..., 0] if x.dim() == 3 else x


def cell_correspondence(target_depth, target_alpha, target_camera, target_cells: tuple[int, int], source_depth,
                        source_alpha, source_camera, source_cells: tuple[int, int], min_alpha: float = MIN_ALPHA,
                        depth_tolerance: float = DEPTH_TOLERANCE) -> tuple[torch.Tensor, torch.Tensor]:
    """For each cell of the target's (h, w) grid, the flat index of the source cell (hs, ws grid) its centre lands
    in, and whether it is a correspondence (covered in the target, seen by the source). Depths and alphas are the
    renders' (H, W[, 1]); returns (h, w) int64 and (h, w) bool tensors."""
    zt, at = _plane(target_depth), _plane(target_alpha)
    H, W = zt.shape
    h, w = target_cells
    ys, xs = torch.meshgrid((torch.arange(h, dtype=torch.float64) + 0.5) * H / h,
                            (torch.arange(w, dtype=torch.float64) + 0.5) * W / w, indexing="ij")
    z_c, a_c = sample_bilinear(torch.stack([zt, at], dim=-1), xs, ys).unbind(-1)
    u, v, z = warp_points(xs, ys, z_c, target_camera, source_camera)
    source = torch.stack([_plane(source_alpha), _plane(source_depth)], dim=-1)
    Hs, Ws = source.shape[:2]
    s_alpha, s_depth = sample_bilinear(source, u, v).unbind(-1)
    valid = seen_by_source(u, v, z, s_alpha, s_depth, Ws, Hs, min_alpha, depth_tolerance)
    valid &= (a_c >= min_alpha) & (z_c > 0)
    hs, ws = source_cells
    ci = (v * hs / Hs).floor().long().clamp(0, hs - 1)
    cj = (u * ws / Ws).floor().long().clamp(0, ws - 1)
    return ci * ws + cj, valid


def label_agreement(target_labels, source_labels, landing: torch.Tensor, valid: torch.Tensor) -> tuple[int, int]:
    """(agreeing cells, corresponding cells): how many valid target cells carry the same label as the source cell
    they land in (``cell_correspondence``); labels (h, w) and (hs, ws) integer arrays or tensors."""
    t = torch.as_tensor(np.asarray(target_labels) if not isinstance(target_labels, torch.Tensor) else target_labels)
    s = torch.as_tensor(np.asarray(source_labels) if not isinstance(source_labels, torch.Tensor) else source_labels)
    same = (s.cpu().reshape(-1)[landing] == t.cpu()) & valid
    return int(same.sum()), int(valid.sum())
