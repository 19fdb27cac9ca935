"""Multi-view consistency of stylized renders by depth warping (a MEt3R stand-in; docs/evaluation.md).

For a pair of views (target t, source s) of the same model, the source render is warped into the target view with
the target's rendered expected depth and the known cameras (a backward warp): every target pixel centre
p = (x + 0.5, y + 0.5) with target alpha >= ``min_alpha`` is unprojected at its expected depth z_t(p),
X = C2W_t (z_t(p) K_t^-1 [p, 1]), projected into the source, q = K_s X_s / z_s with X_s = W2C_s X, and the source
image, alpha and expected depth are sampled bilinearly at q. The pixel is valid when

- q lies inside the source image and z_s > 0,
- the sampled source alpha is >= ``min_alpha``,
- |z_s - D_s(q)| <= ``depth_tolerance`` * z_s (``DEPTH_TOLERANCE`` = 3 %): the point is what the source sees, not
  something hidden behind a nearer surface (a bilinear sample across a depth edge mixes the two depths and fails
  the test too, so silhouettes drop out).

Over the valid pixels V: RMSE = sqrt(mean_{p in V, c} (I_t(p)_c - I_s(q)_c)^2) with RGB in [0, 1]; LPIPS-VGG as the
mean over V of LPIPS's spatial map (each layer's lin output upsampled bilinearly to the image size and summed over
the five layers, as the ``lpips`` package's ``spatial=True``), computed between the target image and the warped
source whose invalid pixels are filled with the target's own (so they add no difference of their own; the
receptive field still lets a few pixels near the mask edge feel them); valid fraction = |V| / (target pixels with
alpha >= min_alpha).

A perfectly view-consistent model (colours fixed on the surface, view-independent) scores RMSE about 0 wherever the
expected depth is the surface's; what remains comes from view-dependent colour (SH degree > 0), the expected
depth of semi-transparent Gaussians and resampling (bilinear interpolation of the source).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from training.core import stop
from training.scene.correspondence import (DEPTH_TOLERANCE, MIN_ALPHA, sample_bilinear, seen_by_source,  # noqa: F401
                                           warp_points)
MIN_VALID_PIXELS = 16  # a pair with fewer valid pixels gives no RMSE/LPIPS (its valid fraction still counts)


def _t(x, device=None) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x) if not isinstance(x, torch.Tensor) else x, device=device)


def _hw(x: torch.Tensor, channels: int) -> torch.Tensor:
    """(H, W) or (H, W, C) -> float64 (H, W, channels)."""
    x = x.double()
    if x.dim() == 2:
        x = x[..., None]
    return x[..., :channels]


def backward_warp(target_depth, target_camera, source_image, source_depth, source_alpha, source_camera,
                  target_alpha=None, min_alpha: float = MIN_ALPHA,
                  depth_tolerance: float = DEPTH_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """The source image seen from the target view and the valid mask: (H_t, W_t, 3) float32, (H_t, W_t) bool.

    Depths are the renders' expected camera z ("RGB+ED"); images (H, W, 3) in [0, 1]; alphas (H, W[, 1])."""
    zt = _hw(_t(target_depth), 1)[..., 0]
    H, W = zt.shape
    if (target_camera.height, target_camera.width) != (H, W):
        raise ValueError(f"target depth is {W}x{H}, its camera {target_camera.width}x{target_camera.height}")
    src = _hw(_t(source_image), 3)
    Hs, Ws = src.shape[:2]
    if (source_camera.height, source_camera.width) != (Hs, Ws):
        raise ValueError(f"source image is {Ws}x{Hs}, its camera {source_camera.width}x{source_camera.height}")
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float64) + 0.5, torch.arange(W, dtype=torch.float64) + 0.5,
                            indexing="ij")
    u, v, z = warp_points(xs, ys, zt, target_camera, source_camera)
    stack = torch.cat([src, _hw(_t(source_alpha), 1), _hw(_t(source_depth), 1)], dim=-1)
    sampled = sample_bilinear(stack, u, v)
    warped, s_alpha, s_depth = sampled[..., :3], sampled[..., 3], sampled[..., 4]
    valid = seen_by_source(u, v, z, s_alpha, s_depth, Ws, Hs, min_alpha, depth_tolerance) & (zt > 0)
    if target_alpha is not None:
        valid &= _hw(_t(target_alpha), 1)[..., 0] >= min_alpha
    return warped.float().numpy(), valid.numpy()


def lpips_map(lpips, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(H, W) spatial LPIPS-VGG between two (H, W, 3) images in [0, 1]: each layer's lin output upsampled
    (bilinear, align_corners=False) to (H, W) and summed over the layers, as the ``lpips`` package's
    ``spatial=True``; its spatial mean is ``lpips(a, b)``'s value up to the upsampling. ``lpips``: a
    ``training.reconstruct.lpips.LPIPS`` (its ``features`` and lin weights are used)."""
    from training.reconstruct.lpips import SCALE, SHIFT

    x = torch.stack([_t(a).float()[..., :3], _t(b).float()[..., :3]]).permute(0, 3, 1, 2)
    H, W = x.shape[-2:]
    x = ((2 * x - 1) - SHIFT.view(1, 3, 1, 1)) / SCALE.view(1, 3, 1, 1)
    total = torch.zeros(H, W)
    with torch.no_grad():
        for k, f in enumerate(lpips.features(x)):
            f = f / (f.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            d = F.conv2d((f[:1] - f[1:]) ** 2, lpips.weights[f"lin{k}.weight"].to(f))
            total += F.interpolate(d, size=(H, W), mode="bilinear", align_corners=False)[0, 0]
    return total


def warp_consistency(target_image, target_depth, target_alpha, target_camera, source_image, source_depth,
                     source_alpha, source_camera, lpips=None, min_alpha: float = MIN_ALPHA,
                     depth_tolerance: float = DEPTH_TOLERANCE) -> dict:
    """One pair: {"rmse", "lpips" (None without ``lpips``), "valid_fraction", "valid_pixels"}; rmse and lpips are
    None when fewer than ``MIN_VALID_PIXELS`` pixels are valid. See the module docstring."""
    warped, valid = backward_warp(target_depth, target_camera, source_image, source_depth, source_alpha,
                                  source_camera, target_alpha, min_alpha, depth_tolerance)
    target = np.asarray(target_image, dtype=np.float32)[..., :3]
    covered = int((np.asarray(target_alpha, dtype=np.float32).reshape(valid.shape) >= min_alpha).sum())
    n = int(valid.sum())
    out = {"rmse": None, "lpips": None, "valid_fraction": n / covered if covered else 0.0, "valid_pixels": n}
    if n < MIN_VALID_PIXELS:
        return out
    diff = (target - warped)[valid].astype(np.float64)
    out["rmse"] = float(np.sqrt((diff ** 2).mean()))
    if lpips is not None:
        filled = np.where(valid[..., None], warped, target)
        spatial = lpips_map(lpips, torch.from_numpy(target), torch.from_numpy(filled))
        out["lpips"] = float(spatial[torch.from_numpy(valid)].double().mean())
    return out


def pairs_at_gap(order: Sequence[int], gap: int, max_pairs: int | None = None) -> list[tuple[int, int]]:
    """(order[i], order[i + gap]) for every i, or ``max_pairs`` of them evenly spaced along the trajectory."""
    pairs = [(int(order[i]), int(order[i + gap])) for i in range(len(order) - gap)]
    if max_pairs is not None and len(pairs) > max_pairs:
        pairs = [pairs[int(i)] for i in np.linspace(0, len(pairs) - 1, max_pairs).round()]
    return pairs


def consistency_metrics(images, depths, alphas, cameras, order, gap: int, lpips=None, max_pairs: int | None = None,
                        lpips_pairs: int | None = None, min_alpha: float = MIN_ALPHA,
                        depth_tolerance: float = DEPTH_TOLERANCE) -> dict | None:
    """Mean over the pairs (target order[i], source order[i + gap]) of ``warp_consistency``:
    {"rmse", "lpips", "valid_fraction", "pairs"}. rmse and lpips average the pairs that had enough valid pixels
    (None when none had; lpips None without ``lpips``), valid_fraction averages every pair. None when the trajectory
    has no pair ``gap`` apart. images/depths/alphas: lists indexed like ``cameras``. ``max_pairs``: at most that many
    pairs, evenly spaced along the trajectory (None: all); ``lpips_pairs``: LPIPS (a VGG-16 pass over both images
    of a pair, most of the cost) only on that many of them, evenly spaced (None: on every pair)."""
    if gap < 1:
        raise ValueError(f"gap must be at least 1, got {gap}")
    pairs = pairs_at_gap(order, gap, max_pairs)
    if not pairs:
        return None
    with_lpips = set(range(len(pairs)))
    if lpips_pairs is not None and len(pairs) > lpips_pairs:
        with_lpips = {int(i) for i in np.linspace(0, len(pairs) - 1, lpips_pairs).round()}
    results = []
    for k, (t, s) in enumerate(pairs):
        stop.check()
        results.append(warp_consistency(images[t], depths[t], alphas[t], cameras[t], images[s], depths[s], alphas[s],
                                        cameras[s], lpips if k in with_lpips else None, min_alpha, depth_tolerance))

    def mean(key):
        values = [r[key] for r in results if r[key] is not None]
        return float(np.mean(values)) if values else None

    return {"rmse": mean("rmse"), "lpips": mean("lpips"), "valid_fraction": mean("valid_fraction"),
            "pairs": len(pairs)}
