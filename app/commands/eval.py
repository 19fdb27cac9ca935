"""``splatstyler eval GRID.toml -o OUT``: run an evaluation grid and write its report.

Each cell of the grid (scene x painting x seed x setting; the file format is in app/evaluate/grid.py and
docs/evaluation.md) reconstructs the scene (once per scene, variant and seed, shared by the cells), stylizes it and
measures the result (consistency, style, content: training/evaluate). Resumable: finished jobs are recorded under
OUT/jobs and skipped when the same command runs again; a failed job is recorded with its error, the grid goes on,
and the next run retries it. Runs on this machine with a pool of worker processes (--workers), or on a Ray cluster
(--ray auto, --ray ADDRESS, or --ray local to start one here).

Writes OUT/report/RESULTS.md (tables with the spread across seeds, the paper's directions checked), and under
OUT/report/results/ cells.csv, plots and contact sheets (evenly spaced views, and each group's least consistent
pair of neighbouring views). --cells-from takes an earlier report's cells.csv (a run of the same grid elsewhere)
into the tables for the cells not finished here. Exit status 1 when any job failed.
"""

from __future__ import annotations

import argparse
import fnmatch
import os
from pathlib import Path

from app.commands import add_run_flags


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="run an evaluation grid (TOML): reconstruct, stylize, measure; tables and plots",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("grid", metavar="GRID.toml", help="the grid file")
    p.add_argument("-o", "--output", default=None, metavar="OUT",
                   help="output folder (default: ./<grid name>_out); running again continues it")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="local worker processes (default: one per 2 CPU cores, at least 1)")
    p.add_argument("--threads", type=int, default=None, metavar="T",
                   help="threads per worker for torch and numba (default: CPU cores / workers)")
    p.add_argument("--ray", default=None, metavar="ADDRESS",
                   help="run the jobs as Ray tasks: 'auto' (the running cluster), 'local' (start one here) or an "
                        "address; needs the ray extra")
    p.add_argument("--only", action="append", default=None, metavar="PATTERN",
                   help="run only jobs whose id matches this glob (e.g. 'cell/fox/*'), and what they need; "
                        "repeatable")
    p.add_argument("--list", action="store_true", help="list the jobs and their state, run nothing")
    p.add_argument("--report-only", action="store_true", help="write the report from the recorded results, run nothing")
    p.add_argument("--report-dir", default=None, metavar="DIR", help="where the report goes (default: OUT/report)")
    p.add_argument("--cells-from", action="append", default=None, metavar="CSV",
                   help="an earlier report's results/cells.csv from a run of this grid file (another machine's OUT): "
                        "cells not finished here take their rows from it in the tables and plots; repeatable")
    add_run_flags(p, progress="no progress bar over the jobs (their lines are still printed)",
                  resume="continue the grid in OUT, as every run does (finished jobs are skipped), and fail when "
                         "OUT holds no job of this grid: a mistyped OUT does not start the grid afresh")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.commands import starting

    starting()
    from app.evaluate.grid import load_grid
    from app.evaluate.report import write_report
    from app.evaluate.runner import LocalPool, RayPool, load_results, run_grid
    from training.core.atomic_write import check_output_dir, make_output_dir
    from training.core.errors import InputError

    grid = load_grid(args.grid)
    out = Path(args.output) if args.output else Path(f"{Path(args.grid).stem}_out")
    check_output_dir(out)
    cores = os.cpu_count() or 1
    workers = args.workers or max(1, cores // 2)
    if workers < 1:
        raise InputError(None, "--workers must be at least 1")
    threads = args.threads or max(1, cores // workers)
    only = None
    if args.only:
        only = lambda job: any(fnmatch.fnmatch(job.id, pat) for pat in args.only)  # noqa: E731
        if not any(only(j) for j in grid.jobs):
            raise InputError(None, f"--only {' '.join(args.only)} matches none of the grid's {len(grid.jobs)} jobs")
    if args.list:
        results = load_results(out, grid)
        for job in grid.jobs:
            if only is None or only(job):
                state = results.get(job.id, {}).get("status", "todo")
                print(f"{state:7s} {job.id}")
        return 0
    if args.resume and not load_results(out, grid):
        raise InputError(out, "holds no recorded job of this grid for --resume to continue")
    earlier: dict = {}
    for csv_path in args.cells_from or []:
        from app.evaluate.report import read_cells_csv

        earlier.update(read_cells_csv(Path(csv_path), grid))  # read before the grid runs: a bad file stops it now
    make_output_dir(out)
    command = "splatstyler eval " + str(args.grid) + "".join(f" --cells-from {c}" for c in args.cells_from or [])
    if not args.report_only:
        pool = RayPool(args.ray, threads, num_cpus=cores) if args.ray else LocalPool(workers, threads)
        where = f"Ray ({args.ray})" if args.ray else f"{workers} local worker(s)"
        print(f"eval: {len(grid.cells)} cells on {where}, {threads} thread(s) each", flush=True)
        from app.progress import CountBar

        bar = CountBar("eval", "job", disable=args.no_progress)
        try:
            results = run_grid(grid, out, pool, log=bar.write, only=only, progress=bar.update)
        finally:
            bar.close()
    else:
        results = load_results(out, grid)
    md = write_report(grid, out, results, Path(args.report_dir) if args.report_dir else None, command=command,
                      earlier=earlier)
    failed = [jid for jid, r in results.items() if r.get("status") == "failed"]
    ok = sum(1 for j in grid.cells if results.get(j.id, {}).get("status") == "ok")
    if earlier:
        ok += sum(1 for j in grid.cells if j.id in earlier and results.get(j.id, {}).get("status") != "ok")
    print(f"eval: {ok} of {len(grid.cells)} cells done, {len(failed)} jobs failed; report {md}", flush=True)
    return 1 if failed else 0
