"""The per-layer style distances behind the flower finding (docs/evaluation.md, "The flower"), on a scene's photos:
original, after the pooled pre colour transfer, stylized in 2D (training/evaluate/baseline_2d, CCFT) with the post
colour transfer, and the last two low-passed to the loss's scale (2x area down, bilinear up). Prints each layer's
Gram and SWD distance to the painting and the ratios to the colour-transferred start.

    PYTHONPATH=. python scripts/style_layers_on_photos.py ../shared/data/scenes/llff_flower/images \\
        ../shared/data/styles/the_scream.jpg [--iters 60] [--views 3] [--every 6]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

import training  # noqa: F401  (sets OMP_WAIT_POLICY before torch's threads start)
from training.scene.image_io import read_image
from training.evaluate.baseline_2d import stylize_images_independently
from training.evaluate.measure import _ratio_to_start
from training.evaluate.style_metrics import painting_for, style_distances, taps_stats
from training.evaluate.vgg_taps import LAYERS, VGGTaps
from training.reconstruct.lpips import LPIPS
from training.stylize.color_transfer import apply_to_image, fit_color_transfer
from training.stylize.style_image import load_style_image


def resized(image: np.ndarray, long_side: int) -> np.ndarray:
    t = torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)).permute(2, 0, 1)[None]
    s = long_side / max(t.shape[-2:])
    size = (round(t.shape[-2] * s), round(t.shape[-1] * s))
    return F.interpolate(t, size=size, mode="area")[0].permute(1, 2, 0).numpy()


def lowpass(image: np.ndarray) -> np.ndarray:
    t = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)[None]
    down = F.interpolate(t, size=(t.shape[-2] // 2, t.shape[-1] // 2), mode="area")
    return F.interpolate(down, size=t.shape[-2:], mode="bilinear", align_corners=False)[0].permute(1, 2, 0).numpy()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("photos", type=Path)
    p.add_argument("painting", type=Path)
    p.add_argument("--iters", type=int, default=60)
    p.add_argument("--views", type=int, default=3)
    p.add_argument("--every", type=int, default=6)
    p.add_argument("--long-side", type=int, default=256)
    args = p.parse_args()
    files = sorted(f for f in args.photos.iterdir() if f.is_file())[::args.every][:args.views]
    photos = [resized(np.clip(read_image(f)[..., :3], 0, 1), args.long_side) for f in files]
    painting = load_style_image(args.painting)
    taps = VGGTaps(LPIPS().weights)
    h, w = photos[0].shape[:2]
    reference = taps_stats(taps(painting_for(painting, w, h)))
    pre_ct = fit_color_transfer(photos, painting.reshape(-1, 3))
    start = [np.clip(apply_to_image(i, pre_ct), 0, 1) for i in photos]
    styl = stylize_images_independently(photos, painting, iters=args.iters)
    post_ct = fit_color_transfer(styl, painting.reshape(-1, 3))
    styl = [np.clip(apply_to_image(i, post_ct), 0, 1) for i in styl]

    def distances(images):
        per_view = [style_distances(taps(np.ascontiguousarray(i, dtype=np.float32)), reference) for i in images]
        return {k: float(np.mean([d[k] for d in per_view])) for k in per_view[0]}

    rows = {"original": distances(photos), "pre colour transfer": distances(start),
            "stylized + post CT": distances(styl), "pre CT, low-passed": distances([lowpass(i) for i in start]),
            "stylized, low-passed": distances([lowpass(i) for i in styl])}
    for kind in ("gram", "swd"):
        print(f"{kind}: " + " ".join(f"{layer:>9s}" for layer in LAYERS))
        for name, d in rows.items():
            print(f"  {name:22s}" + " ".join(f"{d[f'{kind}_{layer}']:9.4g}" for layer in LAYERS))
        for name, num, den in (("stylized / start", "stylized + post CT", "pre colour transfer"),
                               ("low-passed", "stylized, low-passed", "pre CT, low-passed")):
            r = [rows[num][f"{kind}_{layer}"] / rows[den][f"{kind}_{layer}"] for layer in LAYERS]
            print(f"  {name:22s}" + " ".join(f"{v:9.3f}" for v in r) + f"   mean of ratios {np.mean(r):.3f}")
        print(f"  ratio of shares (METRICS_VERSION 3): "
              f"{_ratio_to_start(rows['stylized + post CT'], rows['pre colour transfer'], rows['original'], kind):.3f}")


if __name__ == "__main__":
    main()
