"""Where the structure budget's drift and the report's structure distance part: for each finished stylization cell
of a `splatstyler eval` output, the report's figure against cheaper measures of the same kind, on the renders of
the report's style views.

    python scripts/structure_measures.py EVAL_OUT SETTING OUT.csv [SCENE_PATTERN]

Columns: ``report`` (the report's structure distance recomputed: relu3_1 and relu4_1 of the full-size renders at
1024 sampled positions), ``in_run_drift_end`` (the budget's drift at the run's end, from report.json), and the
budget's own form of the measure (every position, relu3_1 and/or relu4_1, the renders halved as the run halves
them) on the finished model (``half_r3_all`` ...) and on the finished model before the final colour transfer
(``pre_ct_half_r3``: the saved model mapped back by the inverse of the recorded map, against the input after the
pre colour transfer, as the run compares them). ``pre_ct_half_r3 / in_run_drift_end`` is what the views and the
averaging change, ``half_r3_all / pre_ct_half_r3`` what the final colour transfer changes, ``report /
half_r3_all`` what the report's layers, size and sampling change.
"""

from __future__ import annotations

import csv
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from app.evaluate.grid import job_dir
from app.evaluate.remeasure import prepared_stylizer
from training.evaluate.content_metrics import self_distance, structure_distance
from training.evaluate.measure import STYLE_VIEWS, render_all, style_view_indices
from training.evaluate.vgg_taps import VGGTaps
from training.model.model_io import read_model
from training.stylize.color_transfer import ColorTransform, apply_to_gaussians


def drift(a: torch.Tensor, b: torch.Tensor) -> float:
    """The budget's form: every position, cosine self-distance with each column divided by its mean."""
    fa, fb = a[0].flatten(1).t().double(), b[0].flatten(1).t().double()
    return float((self_distance(fa) - self_distance(fb)).abs().mean())


def halved(image: np.ndarray) -> torch.Tensor:
    x = torch.as_tensor(image[..., :3]).permute(2, 0, 1)[None].float()
    return F.interpolate(x, scale_factor=0.5, mode="bilinear", antialias=True)


def measure_cell(out: Path, folder: Path, taps: VGGTaps) -> dict:
    spec = json.loads((folder / "job.json").read_text())["spec"]
    report = json.loads((folder / "report.json").read_text())
    recon = job_dir(out, spec["recon_job"]) / "point_cloud.ply"
    data = Path(spec["data"]) if spec.get("data") else job_dir(out, f"sfm/{spec['scene']}")
    st, _ = prepared_stylizer(recon, data, Path(spec["painting_path"]), spec["flags"])
    cameras = [st.cameras[i] for i in style_view_indices(len(st.cameras), STYLE_VIEWS)]
    args = (st.config.background, st.config.backend, st.device, "RGB")
    original, stylized = read_model(recon).to(st.device), read_model(folder / "point_cloud.ply").to(st.device)
    post = report["color_transfer"]["post"]
    inverse = np.linalg.inv(np.array(post["A"]))
    before_ct = apply_to_gaussians(stylized, ColorTransform(inverse, -inverse @ np.array(post["b"])))
    content = st.model.gaussians  # the input after the pre colour transfer
    renders = {name: [img for img, _ in render_all(g, g.sh, cameras, *args)]
               for name, g in (("original", original), ("stylized", stylized), ("before_ct", before_ct),
                               ("content", content))}
    v = {k: [] for k in ("report", "full_r3_all", "full_r34_all", "half_r3_all", "half_r4_all", "half_r34_all",
                         "pre_ct_report", "pre_ct_half_r3")}
    for i in range(len(cameras)):
        s, o = taps(renders["stylized"][i][..., :3]), taps(renders["original"][i][..., :3])
        v["report"].append(structure_distance(s, o))
        v["full_r3_all"].append(drift(s["relu3"], o["relu3"]))
        v["full_r34_all"].append((v["full_r3_all"][-1] + drift(s["relu4"], o["relu4"])) / 2)
        hs, ho = taps(halved(renders["stylized"][i])), taps(halved(renders["original"][i]))
        v["half_r3_all"].append(drift(hs["relu3"], ho["relu3"]))
        v["half_r4_all"].append(drift(hs["relu4"], ho["relu4"]))
        v["half_r34_all"].append((v["half_r3_all"][-1] + v["half_r4_all"][-1]) / 2)
        b, c = renders["before_ct"][i][..., :3], renders["content"][i][..., :3]
        v["pre_ct_report"].append(structure_distance(taps(b), taps(c)))
        v["pre_ct_half_r3"].append(drift(taps(halved(b))["relu3"], taps(halved(c))["relu3"]))
    return {"scene": spec["scene"], "painting": spec["painting"], "views": len(cameras),
            "report_structure": report["metrics"]["structure_distance"],
            "in_run_drift_end": (report.get("structure_budget") or {}).get("drift_end"),
            **{k: round(float(np.mean(x)), 5) for k, x in v.items()}}


def main() -> int:
    out, setting, dest = Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3])
    scenes = sys.argv[4] if len(sys.argv) > 4 else "*"
    taps, rows = VGGTaps(), []
    for job in sorted((out / "cell").glob(f"{scenes}/{setting}/*/seed0/job.json")):
        if not (job.parent / "report.json").is_file():
            continue
        t0 = time.time()
        rows.append(measure_cell(out, job.parent, taps))
        print(rows[-1], f"{time.time() - t0:.0f} s", flush=True)
        with open(dest, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
