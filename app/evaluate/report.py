"""The grid's report: a CSV of every cell and metric, a markdown page with one table per group (mean and spread
across seeds), the paper's expected directions checked per scene, plots (matplotlib) and contact sheets (the same
views of every setting side by side).

Layout under ``folder`` (OUT/report by default): RESULTS.md, and results/cells.csv, results/plots/*.png,
results/sheets/*.jpg (evenly spaced views, and the worst pair of neighbouring views: app/evaluate/worst_pair.py),
linked relatively, so the folder can be copied as is (docs/ holds one such copy).
"""

from __future__ import annotations

import csv
import datetime
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from app.evaluate.grid import Grid, Group, job_dir
from training.core.atomic_write import atomic_open, atomic_path

SHEET_CELL = 256  # the quick preset renders at 256 px: shown as rendered
ID_COLUMNS = ("scene", "setting", "painting", "seed", "reconstruction", "method")


def cell_rows(grid: Grid, results: dict[str, dict[str, Any]],
              earlier: dict[str, dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """One row per finished cell: its ids and every metric; a cell with no finished result here takes its row from
    ``earlier`` (read_cells_csv), if there."""
    rows = []
    for job in grid.cells:
        r = results.get(job.id)
        if not r or r.get("status") != "ok":
            if earlier and job.id in earlier:
                rows.append(dict(earlier[job.id]))
            continue
        row = {k: job.spec[k] for k in ID_COLUMNS}
        row.update({k: v for k, v in (r.get("metrics") or {}).items() if isinstance(v, (int, float)) or v is None})
        rows.append(row)
    return rows


def read_cells_csv(path: Path, grid: Grid) -> dict[str, dict[str, Any]]:
    """The rows of an earlier report's cells.csv, by the id of the grid cell each one is: {job id: row}. Every row
    must name a cell of ``grid`` with the same reconstruction and method; numbers are parsed, empty fields are None.
    The file carries no settings or metrics version of its own: it must come from a run of this grid file at this
    METRICS_VERSION (the caller's word)."""
    from training.core.errors import InputError

    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as f:
            table = list(csv.DictReader(f))
    except FileNotFoundError:
        raise InputError(path, "no such cells.csv") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError(path, f"not a readable cells.csv: {exc}") from None
    by_id = {j.id: j for j in grid.cells}
    rows: dict[str, dict[str, Any]] = {}
    for line, raw in enumerate(table, start=2):
        if any(raw.get(k) in (None, "") for k in ID_COLUMNS):
            raise InputError(path, f"line {line}: needs the columns {', '.join(ID_COLUMNS)}")
        jid = f"cell/{raw['scene']}/{raw['setting']}/{raw['painting']}/seed{raw['seed']}"
        job = by_id.get(jid)
        if job is None:
            raise InputError(path, f"line {line}: {jid} is not a cell of {grid.path.name}")
        for key in ("reconstruction", "method"):
            if raw[key] != str(job.spec[key]):
                raise InputError(path, f"line {line}: {jid} has {key} {raw[key]!r}, the grid's is {job.spec[key]!r}")
        if jid in rows:
            raise InputError(path, f"line {line}: {jid} is in the file twice")
        row: dict[str, Any] = {k: job.spec[k] for k in ID_COLUMNS}
        for key, value in raw.items():
            if key in ID_COLUMNS or key is None:
                continue
            try:
                row[key] = None if value in ("", None) else float(value)
            except ValueError:
                raise InputError(path, f"line {line}: {key} = {value!r} is not a number") from None
        rows[jid] = row
    return rows


def write_csv(rows: list[dict[str, Any]], path: Path) -> None:
    columns = list(ID_COLUMNS)
    for row in rows:
        columns += [k for k in row if k not in columns]
    with atomic_open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns)
        w.writeheader()
        for row in rows:
            w.writerow({k: _csv_value(row.get(k)) for k in columns})


def _csv_value(v: Any) -> Any:
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    return "" if v is None else v


def _values(rows: list[dict], metric: str) -> list[float]:
    out = []
    for r in rows:
        v = r.get(metric)
        if isinstance(v, (int, float)) and math.isfinite(float(v)):
            out.append(float(v))
    return out


def _fmt(x: float) -> str:
    if x == 0:
        return "0"
    a = abs(x)
    return f"{x:.3g}" if 1e-3 <= a < 1e4 else f"{x:.2e}"


def mean_sd(values: list[float]) -> str:
    """"mean ± sd" (sample sd over the seeds and paintings pooled in the cell), or the value alone for one."""
    if not values:
        return "-"
    if len(values) == 1:
        return _fmt(values[0])
    return f"{_fmt(float(np.mean(values)))} ± {_fmt(float(np.std(values, ddof=1)))}"


def _group_rows(group: Group, rows: list[dict], by_painting: bool = False) -> dict[tuple, list[dict]]:
    """The group's cells by (scene, setting), or by (scene, setting, painting)."""
    out: dict[tuple, list[dict]] = defaultdict(list)
    for r in rows:
        if r["setting"] in group.settings and (group.paintings is None or r["painting"] in group.paintings):
            key = (r["scene"], r["setting"]) + ((r["painting"],) if by_painting else ())
            out[key].append(r)
    return out


def check_expectations(group: Group, rows: list[dict], scenes: list[str]) -> list[str]:
    """For each expected direction, on how many scenes the means agree (seeds and paintings pooled), and on how
    many of those the gap is clear: more than twice the larger of the two standard deviations across seeds (with
    one cell a side there is no spread to compare, and the gap is not called clear); and per scene, in how many
    cells of the same seed and painting (the same reconstruction) the direction holds."""
    cells = _group_rows(group, rows)
    lines = []
    for a, op, b, metric in group.expect:
        agree, clear, compared, detail = 0, 0, 0, []
        for scene in scenes:
            va, vb = _values(cells.get((scene, a), []), metric), _values(cells.get((scene, b), []), metric)
            if not va or not vb:
                continue
            ma, mb = float(np.mean(va)), float(np.mean(vb))
            ok = ma < mb if op == "<" else ma > mb
            spread = max(np.std(va, ddof=1) if len(va) > 1 else np.inf, np.std(vb, ddof=1) if len(vb) > 1 else np.inf)
            is_clear = ok and abs(ma - mb) > 2 * spread
            compared += 1
            agree += ok
            clear += is_clear
            note = "" if not ok else (", clear" if is_clear else
                                      ", within the spread" if np.isfinite(spread) else ", one cell: no spread")
            # the same seed and painting on both sides share the reconstruction: compare them pair by pair too
            pa = {(r["painting"], r["seed"]): r.get(metric) for r in cells.get((scene, a), [])}
            pb = {(r["painting"], r["seed"]): r.get(metric) for r in cells.get((scene, b), [])}
            paired = [(pa[k], pb[k]) for k in pa if k in pb and pa[k] is not None and pb[k] is not None]
            holds = sum(1 for x, y in paired if (x < y if op == "<" else x > y))
            detail.append(f"{scene} {_fmt(ma)} vs {_fmt(mb)}{note if ok else ' (not)'}, "
                          f"{holds}/{len(paired)} paired")
        if compared:
            lines.append(f"- paper: {a} {op} {b} on `{metric}`: ours agrees on {agree} of {compared} scenes, "
                         f"clearly (by more than twice the seed spread) on {clear} ({'; '.join(detail)})")
        else:
            lines.append(f"- paper: {a} {op} {b} on `{metric}`: no finished cells to compare")
    return lines


def plot_group(group: Group, rows: list[dict], scenes: list[str], path: Path) -> bool:
    """Bars per scene and setting, one panel per metric, error bars = sd across seeds (and paintings)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = _group_rows(group, rows)
    metrics = [m for m in group.metrics if any(_values(v, m) for v in cells.values())]
    if not metrics:
        return False
    fig, axes = plt.subplots(1, len(metrics), figsize=(3.2 * len(metrics) + 0.8, 3.0), squeeze=False)
    width = 0.8 / max(1, len(group.settings))
    for ax, metric in zip(axes[0], metrics):
        for k, setting in enumerate(group.settings):
            means, sds = [], []
            for scene in scenes:
                v = _values(cells.get((scene, setting), []), metric)
                means.append(np.mean(v) if v else np.nan)
                sds.append(np.std(v, ddof=1) if len(v) > 1 else 0.0)
            x = np.arange(len(scenes)) + (k - (len(group.settings) - 1) / 2) * width
            ax.bar(x, means, width, yerr=sds, capsize=2, label=setting)
        ax.set_xticks(np.arange(len(scenes)), scenes)
        ax.set_title(metric, fontsize=9)
        ax.tick_params(labelsize=8)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(group.title, fontsize=10)
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=90, format="png")
    finally:
        plt.close(fig)
    return True


def contact_sheet(grid: Grid, out: Path, group: Group, scene: str, results: dict, path: Path) -> list[str] | None:
    """Rows: the group's settings (and paintings), first seed; columns: the same evenly spaced views; the painting
    closes each row. Returns the row labels, or None when no cell of the scene has renders."""
    from training.scene.image_grid import grid as layout, shrink_to
    from training.scene.image_io import read_image, write_image

    paintings = group.paintings or list(grid.paintings)
    seed = grid.seeds[0]
    rows, labels = [], []
    for setting in group.settings:
        for painting in paintings:
            jid = f"cell/{scene}/{setting}/{painting}/seed{seed}"
            r = results.get(jid)
            if not r or r.get("status") != "ok" or not r.get("renders"):
                continue
            renders = r["renders"]
            n = len(renders)
            picks = sorted({round(k * (n - 1) / max(1, grid.sheet_views - 1)) for k in range(min(grid.sheet_views, n))})
            folder = job_dir(out, jid) / "renders"
            row = [shrink_to(read_image(folder / renders[i]), SHEET_CELL) for i in picks]
            row.append(shrink_to(read_image(grid.paintings[painting]), SHEET_CELL))
            rows.append(row)
            labels.append(f"{setting} / {painting}" if len(paintings) > 1 else setting)
    if not rows or (len(rows) == 1 and len(group.settings) > 1):
        return None  # nothing to compare side by side on this scene
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, layout(rows), quality=85)
    return labels


def worst_pair_section(grid: Grid, out: Path, group: Group, scene: str, results: dict, path: Path) -> list[str]:
    """The markdown for the group's worst-pair sheet on ``scene`` (app/evaluate/worst_pair.py), first seed; [] when
    fewer than two of its cells have a saved model here."""
    from app.evaluate.jobs import data_path
    from app.evaluate.worst_pair import DIFF_GAIN, worst_pair_sheet
    from training.core.errors import InputError

    by_id = {j.id: j for j in grid.cells}
    paintings = group.paintings or list(grid.paintings)
    seed = grid.seeds[0]
    cells = []
    for setting in group.settings:
        for painting in paintings:
            jid = f"cell/{scene}/{setting}/{painting}/seed{seed}"
            r, job = results.get(jid), by_id.get(jid)
            model = job_dir(out, jid) / "point_cloud.ply"
            if job is None or not r or r.get("status") != "ok" or job.spec["method"] != "stylize" \
                    or not model.is_file():
                continue  # not run here, or a 2D cell (no model to render)
            label = f"{setting} / {painting}" if len(paintings) > 1 else setting
            cells.append((label, model, data_path(out, job.spec), Path(job.spec["painting_path"]),
                          job.spec["flags"]))
    if len(cells) < 2:
        return []
    try:
        sheet = worst_pair_sheet(cells, path)
    except (InputError, OSError, ValueError) as exc:  # the scene data moved since the grid ran: no sheet
        return [f"{scene}: the worst pair could not be drawn ({str(exc).splitlines()[0][:200]}).", ""]
    if sheet is None:
        return []
    rows = ", ".join(f"{label} (pair {sheet.rmse[i]:.4f}, mean over its pairs {sheet.cell_rmse[i]:.4f})"
                     for i, label in enumerate(sheet.labels))
    return [f"{scene}, seed {seed}: the least consistent pair of neighbouring views (largest depth-warp RMSE summed "
            f"over the rows), A = `{sheet.views[0]}`, B = `{sheet.views[1]}`; rows: {rows}; columns: A, B, B warped "
            f"into A (black: not compared), |A - warped B| x{DIFF_GAIN:g}.", "",
            f"![{group.title}: {scene}, worst pair](results/sheets/{path.name})", ""]


def _reused_note(reused: list) -> str:
    if not reused:
        return ""
    scenes = sorted({j.spec["scene"] for j in reused})
    return (f" ({len(reused)} of them, on {', '.join(scenes)}, measured by an earlier run of the same grid and "
            f"taken from its cells.csv: no contact sheets or reconstruction times for those)")


def write_report(grid: Grid, out: Path, results: dict[str, dict[str, Any]], folder: Path | None = None,
                 command: str = "", earlier: dict[str, dict[str, Any]] | None = None) -> Path:
    """Write RESULTS.md, the CSV, the plots and the contact sheets; returns the markdown's path. ``earlier``: rows
    of cells measured by an earlier run (read_cells_csv), used for the cells not finished here (their renders and
    models are not here: no contact sheets for them)."""
    folder = Path(folder) if folder is not None else Path(out) / "report"
    assets = folder / "results"
    earlier = earlier or {}
    rows = cell_rows(grid, results, earlier)
    write_csv(rows, assets / "cells.csv")
    scenes = list(grid.scenes)
    cells = grid.cells
    ok_here = {j.id for j in cells if results.get(j.id, {}).get("status") == "ok"}
    reused = [j for j in cells if j.id not in ok_here and j.id in earlier]
    ok = len(ok_here) + len(reused)
    failed = [j for j in grid.jobs if results.get(j.id, {}).get("status") == "failed"
              and not (j.kind == "cell" and j.id in earlier)]
    missing = [j for j in cells if j.id not in results and j.id not in earlier]

    md = [f"# {grid.title}", ""]
    if grid.intro:
        md += [grid.intro.strip(), ""]
    from training.core.version import version

    md += [f"Generated by `{command or 'splatstyler eval ' + grid.path.name}` (splatstyler {version()}) on "
           f"{datetime.date.today().isoformat()} from `{grid.path.name}`: {ok} of {len(cells)} cells finished"
           f"{_reused_note(reused)}, "
           f"{len([j for j in failed if j.kind == 'cell'])} failed, {len(missing)} not run. Every cell and metric: "
           f"[results/cells.csv](results/cells.csv). Values are mean ± sample standard deviation over the seeds "
           f"(and paintings, where a row pools several); n is the number of cells.", ""]

    md += ["## Reconstructions", "", "| reconstruction | test PSNR | SSIM | Gaussians | anisotropy p95 | "
           "largest scale p95 | minutes |", "|---|---|---|---|---|---|---|"]
    recon_rows: dict[str, list[dict]] = defaultdict(list)
    for job in grid.jobs:
        r = results.get(job.id, {})
        if job.kind == "reconstruct" and r.get("status") == "ok":
            recon_rows[f"{job.spec['scene']} {job.spec['variant']}"].append(r.get("reconstruction") or {})
    # reconstructions only an earlier run had: what its cells recorded of them (not its time)
    seen_recons = {j.spec["recon_job"] for j in reused}
    for jid in sorted(seen_recons):
        if results.get(jid, {}).get("status") == "ok":
            continue
        row = next(earlier[j.id] for j in reused if j.spec["recon_job"] == jid)
        spec = next(j.spec for j in reused if j.spec["recon_job"] == jid)
        recon_rows[f"{spec['scene']} {spec['reconstruction']}"].append(
            {k: row.get(f"recon_{k}") for k in ("test_psnr", "test_ssim", "num_gaussians", "aniso_p95", "smax_p95")})
    for name, rs in recon_rows.items():
        md.append(f"| {name} (n={len(rs)}) | {mean_sd(_values(rs, 'test_psnr'))} | {mean_sd(_values(rs, 'test_ssim'))}"
                  f" | {mean_sd(_values(rs, 'num_gaussians'))} | {mean_sd(_values(rs, 'aniso_p95'))} | "
                  f"{mean_sd(_values(rs, 'smax_p95'))} | {mean_sd([s / 60 for s in _values(rs, 'seconds')])} |")
    md += ["", "## Settings", "", "| setting | reconstruction | method | flags (on top of the grid's) |",
           "|---|---|---|---|"]
    for name, st in grid.settings.items():
        md.append(f"| {name} | {st['reconstruction']} | {st['method']} | `{' '.join(st['flags']) or '-'}` |")
    md.append("")

    for group in grid.groups:
        md += [f"## {group.title}", ""]
        if group.about:
            md += [group.about.strip(), ""]
        cells_by = _group_rows(group, rows, by_painting=True)
        metrics = group.metrics
        md += ["| scene | setting | painting | n | " + " | ".join(metrics) + " |",
               "|---|---|---|---|" + "---|" * len(metrics)]
        for scene in scenes:
            for setting in group.settings:
                for painting in group.paintings or list(grid.paintings):
                    rs = cells_by.get((scene, setting, painting), [])
                    if rs:
                        md.append(f"| {scene} | {setting} | {painting} | {len(rs)} | "
                                  + " | ".join(mean_sd(_values(rs, m)) for m in metrics) + " |")
        md.append("")
        if group.expect:
            md += check_expectations(group, rows, scenes) + [""]
        plot = assets / "plots" / f"{group.name}.png"
        if plot_group(group, rows, scenes, plot):
            md += [f"![{group.title}](results/plots/{plot.name})", ""]
        for scene in scenes:
            sheet = assets / "sheets" / f"{group.name}_{scene}.jpg"
            labels = contact_sheet(grid, out, group, scene, results, sheet)
            if labels:
                md += [f"{scene}, seed {grid.seeds[0]}; rows: {', '.join(labels)}; columns: "
                       f"{grid.sheet_views} evenly spaced views, then the painting.", "",
                       f"![{group.title}: {scene}](results/sheets/{sheet.name})", ""]
            md += worst_pair_section(grid, out, group, scene, results,
                                     assets / "sheets" / f"{group.name}_{scene}_worst_pair.jpg")
    if grid.discussion:
        md += ["## Discussion", "", grid.discussion.strip(), ""]
    if failed:
        md += ["## Failed jobs", ""] + [f"- `{j.id}`: {results[j.id].get('error')}" for j in failed] + [""]
    path = folder / "RESULTS.md"
    with atomic_open(path, "w") as f:
        f.write("\n".join(md))
    return path
