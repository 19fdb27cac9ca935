"""``splatstyler info PATH [--json]``: what a scene folder or a Gaussian model file holds.

A scene (a COLMAP folder, a folder with transforms.json, or the json file itself) is read through the scene loader
without decoding its images: cameras, image sizes, train/test split, SfM points, normalisation. A model file (any of
training/model/formats.py, read by training/model/model_io.py) is read fully (and so validated): Gaussian count,
SH degree, bounds, opacity and scale statistics.

``--json`` prints one object. Its keys always include ``kind`` ("scene", or the model's format name), ``path``,
``num_cameras``, ``num_points``, ``num_gaussians`` and ``sh_degree``; those that do not apply to the kind are
null.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from app.render_inputs import detect_kind
from training.model.formats import SUFFIX_LIST


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "info",
        help=f"summarise a scene folder or a Gaussian model file ({SUFFIX_LIST})",
        description=f"Summarise a scene (COLMAP folder, transforms.json folder or file) or a Gaussian model file "
                    f"({SUFFIX_LIST}). Reading it also validates it: a broken file gives a one-line error.",
    )
    parser.add_argument("path", type=Path, help="scene folder, transforms.json, or model file")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    parser.add_argument("--downscale", type=int, default=1, metavar="N",
                        help="scenes: report image sizes and intrinsics as loaded with --downscale N (default 1)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from training.core.errors import InputError

    if args.downscale < 1:
        raise InputError(None, f"--downscale must be 1 or more, got {args.downscale}")
    kind = detect_kind(args.path)
    if kind == "scene":
        summary = scene_summary(args.path, args.downscale)
    else:
        summary = gaussians_file_summary(args.path, kind)
    if args.json:
        print(json.dumps(summary))
    else:
        print(format_summary(summary))
    return 0


def _stats(values, names=("min", "mean", "median", "max")) -> dict[str, float]:
    import numpy as np

    v = np.asarray(values, dtype=np.float64).ravel()
    funcs = {"min": np.min, "mean": np.mean, "median": np.median, "max": np.max}
    return {k: float(funcs[k](v)) for k in names}


def gaussians_file_summary(path: Path, kind: str) -> dict:
    """Summary of a Gaussian model file of format ``kind``."""
    import torch

    from training.model.model_io import read_model

    g = read_model(path)
    with torch.no_grad():
        means = g.means.double().numpy()
        scales = g.scales.double().numpy()
        opac = g.opacities.double().numpy()
    return {
        "kind": kind,
        "path": str(path),
        "file_bytes": path.stat().st_size,
        "num_cameras": None,
        "num_points": None,
        "num_gaussians": len(g),
        "sh_degree": g.sh_degree,
        "bounds_min": means.min(axis=0).tolist(),
        "bounds_max": means.max(axis=0).tolist(),
        "opacity": _stats(opac),
        "scale": _stats(scales),
        "scale_max_axis": _stats(scales.max(axis=1)),
    }


def scene_summary(path: Path, downscale: int = 1) -> dict:
    """Summary of a scene as the loader sees it (images not decoded)."""
    import numpy as np

    from training.scene.loader import load_scene

    scene = load_scene(path, downscale=downscale, load_images=False)
    sizes: dict[tuple[int, int], int] = {}
    for cam in scene.cameras:
        sizes[(cam.width, cam.height)] = sizes.get((cam.width, cam.height), 0) + 1
    focal = np.array([[c.fx, c.fy] for c in scene.cameras], dtype=np.float64).reshape(-1, 2)
    summary = {
        "kind": "scene",
        "path": str(path),
        "source": str(scene.source) if scene.source is not None else None,
        "num_cameras": len(scene.cameras),
        "num_points": scene.num_points,
        "num_gaussians": None,
        "sh_degree": None,
        "downscale": downscale,
        "image_sizes": [{"width": w, "height": h, "count": n} for (w, h), n in sorted(sizes.items())],
        "focal_px": {"min": float(focal.min()), "max": float(focal.max())} if len(focal) else None,
        "num_train": len(scene.train_indices),
        "num_test": len(scene.test_indices),
        "test_indices": list(scene.test_indices),
        "center": np.asarray(scene.center, dtype=np.float64).tolist(),
        "extent": float(scene.extent),
        "has_point_colors": scene.point_colors is not None,
        "points_bounds_min": None,
        "points_bounds_max": None,
    }
    if scene.num_points:
        pts = np.asarray(scene.points, dtype=np.float64)
        summary["points_bounds_min"] = pts.min(axis=0).tolist()
        summary["points_bounds_max"] = pts.max(axis=0).tolist()
    return summary


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "(" + ", ".join(_fmt(x) for x in v) + ")"
    if isinstance(v, dict):
        return "  ".join(f"{k} {_fmt(x)}" for k, x in v.items())
    return str(v)


def format_summary(s: dict) -> str:
    """Human-readable lines for a summary dict (text output of ``info``)."""
    lines = [f"{s['path']}: {s['kind']}"]
    if s["kind"] == "scene":
        lines.append(f"  cameras       {s['num_cameras']}  (train {s['num_train']}, test {s['num_test']}: "
                     f"every 8th view held out)")
        for size in s["image_sizes"]:
            lines.append(f"  image size    {size['width']} x {size['height']}  ({size['count']} views"
                         + (f", downscale {s['downscale']})" if s["downscale"] != 1 else ")"))
        if s["focal_px"]:
            lines.append(f"  focal (px)    {_fmt(s['focal_px'])}")
        lines.append(f"  SfM points    {s['num_points']}" + ("" if s["has_point_colors"] or not s["num_points"]
                                                            else " (no colours)"))
        if s["points_bounds_min"] is not None:
            lines.append(f"  point bounds  {_fmt(s['points_bounds_min'])} .. {_fmt(s['points_bounds_max'])}")
        lines.append(f"  centre        {_fmt(s['center'])}")
        lines.append(f"  extent        {_fmt(s['extent'])}  (radius enclosing the cameras x 1.1)")
        if s.get("source"):
            lines.append(f"  loaded from   {s['source']}")
    else:
        lines.append(f"  Gaussians     {s['num_gaussians']}")
        lines.append(f"  SH degree     {s['sh_degree']}")
        lines.append(f"  file size     {s['file_bytes'] / 1e6:.3g} MB")
        lines.append(f"  bounds        {_fmt(s['bounds_min'])} .. {_fmt(s['bounds_max'])}")
        lines.append(f"  opacity       {_fmt(s['opacity'])}")
        lines.append(f"  scale (std)   {_fmt(s['scale'])}")
    return "\n".join(lines)
