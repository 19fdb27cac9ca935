"""The report's worst-pair contact sheets: for one group and scene, the pair of neighbouring views that the
consistency measure finds least consistent, shown for every setting of the group side by side.

The pairs are those behind ``consistency_short_rmse`` (views next to each other on the cameras' nearest path, at
most the cell's ``--metric-pairs`` of them, evenly spaced: training/evaluate/measure.py). Each cell's saved model
is rendered again at those views (colours and expected depth, at the stylization size) and every pair gets its own
depth-warp RMSE (training/evaluate/consistency.py); the mean over a cell's pairs is its recorded
``consistency_short_rmse``. The worst pair is the one with the largest RMSE summed over the group's cells, so every
row shows the same two views. Columns: view A, view B, B warped into A (pixels the measure does not compare in
black), and |A - warped B| scaled by ``DIFF_GAIN`` (black where not compared).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

DIFF_GAIN = 4.0  # the differences the RMSE averages are a few hundredths: scaled to be seen


@dataclass
class CellViews:
    """What one cell's consistency measure looks at: its cameras at the stylization size, the pairs, and the
    render settings."""

    cameras: list
    pairs: list[tuple[int, int]]
    background: tuple
    backend: str
    device: Any


def cell_views(data: Path, flags: Sequence[str]) -> CellViews:
    """The cameras and short-range pairs of a cell run as `splatstyler stylize MODEL --data DATA --style PAINTING
    FLAGS` (the same preparation as the Stylizer's, without loading its network or the painting)."""
    from app.settings import parse_flags
    from app.settings import stylize as settings
    from training.evaluate.consistency import pairs_at_gap
    from training.evaluate.measure import SHORT_GAP
    from training.raster.rasterize import resolve_device
    from training.scene.loader import load_scene
    from training.stylize.config import render_camera
    from training.stylize.pipeline import choose_downscale
    from training.stylize.view_order import nearest_order

    args = parse_flags(settings.add_arguments, flags, "stylize flags")
    config = settings.config_from_args(args)
    scene = load_scene(data, downscale=choose_downscale(data, config.render_max_side), load_images=False)
    cameras = [render_camera(c, config.render_max_side) for c in scene.cameras]
    order = nearest_order(scene.cameras, scene.extent)  # measure_order's: the same pairs for every view order
    return CellViews(cameras, pairs_at_gap(order, SHORT_GAP, args.metric_pairs), tuple(config.background),
                     config.backend, resolve_device(config.device))


def render_pair_views(model: Path, views: CellViews) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """{camera index: (image, expected depth, alpha)} of the saved model at every camera some pair uses."""
    from training.evaluate.measure import render_with_depth
    from training.model.model_io import read_model

    used = sorted({i for pair in views.pairs for i in pair})
    images, depths, alphas = render_with_depth(read_model(model), [views.cameras[i] for i in used], views.background,
                                               views.backend, views.device)
    return {i: (im, d, a) for i, im, d, a in zip(used, images, depths, alphas)}


def pair_rmses(renders: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]], cameras: Sequence,
               pairs: Sequence[tuple[int, int]]) -> list[float | None]:
    """The depth-warp RMSE of each pair (target, source), None where too few pixels could be compared."""
    from training.evaluate.consistency import warp_consistency

    out = []
    for t, s in pairs:
        (it, dt, at), (is_, ds, as_) = renders[t], renders[s]
        out.append(warp_consistency(it, dt, at, cameras[t], is_, ds, as_, cameras[s])["rmse"])
    return out


def worst_pair(errors: Sequence[Sequence[float | None]]) -> int | None:
    """The index of the pair with the largest error summed over the rows (a pair some row could not compare is
    left out: its sum would leave that row out); None when no pair was compared in every row."""
    if not errors:
        return None
    sums = []
    for k in range(len(errors[0])):
        column = [row[k] for row in errors]
        sums.append(None if any(v is None for v in column) else float(sum(column)))
    scored = [(v, k) for k, v in enumerate(sums) if v is not None]
    return max(scored)[1] if scored else None


def pair_row(renders, cameras, pair: tuple[int, int]) -> list[np.ndarray]:
    """[view A, view B, B warped into A, |A - warped B| * DIFF_GAIN], the last two black where not compared."""
    from training.evaluate.consistency import backward_warp

    t, s = pair
    (it, dt, at), (is_, ds, as_) = renders[t], renders[s]
    warped, valid = backward_warp(dt, cameras[t], is_, ds, as_, cameras[s], target_alpha=at)
    target = np.asarray(it, dtype=np.float32)[..., :3]
    shown = np.where(valid[..., None], warped, 0.0)
    diff = np.where(valid[..., None], np.clip(np.abs(target - warped) * DIFF_GAIN, 0.0, 1.0), 0.0)
    return [target, np.asarray(is_, dtype=np.float32)[..., :3], shown, diff]


@dataclass
class WorstPairSheet:
    labels: list[str]  # one per row
    views: tuple[str, str]  # the two cameras' image names
    rmse: list[float]  # the pair's RMSE in each row
    cell_rmse: list[float]  # each row's mean over its pairs (its consistency_short_rmse, measured again)


def worst_pair_sheet(cells: Sequence[tuple[str, Path, Path, Path, Sequence[str]]], path: Path) -> WorstPairSheet | None:
    """Write the sheet for ``cells`` (label, stylized model, scene data, painting, stylize flags), rows in that
    order, to ``path``; None (nothing written) with fewer than two cells, cells whose views differ, or no pair
    compared in every cell."""
    from training.scene.image_grid import grid as layout
    from training.scene.image_io import write_image

    if len(cells) < 2:
        return None
    rows = []
    for label, model, data, _painting, flags in cells:
        views = cell_views(data, flags)
        renders = render_pair_views(model, views)
        rows.append((label, views, renders, pair_rmses(renders, views.cameras, views.pairs)))
    names = [[(v.cameras[t].name, v.cameras[s].name) for t, s in v.pairs] for _, v, _, _ in rows]
    if any(n != names[0] for n in names):
        return None  # not the same views (different scene data or --metric-pairs): no common pair to show
    k = worst_pair([errors for *_, errors in rows])
    if k is None:
        return None
    image_rows = [pair_row(renders, views.cameras, views.pairs[k]) for _, views, renders, _ in rows]
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, layout(image_rows), quality=90)
    return WorstPairSheet(labels=[label for label, *_ in rows], views=names[0][k],
                          rmse=[errors[k] for *_, errors in rows],
                          cell_rmse=[float(np.mean([e for e in errors if e is not None])) for *_, errors in rows])
