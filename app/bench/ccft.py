"""``splatstyler bench ccft``: time and peak memory of the CCFT loss against dense POT on the same problem.

For each n (rendered features) and m (style features) the loss runs forward and backward (C = 768, K = 16, 50
Sinkhorn iterations by default) on ReLU-like random features, then POT's ``sinkhorn_unbalanced`` solves the same
transport problem densely: the same support, cost 1e3 off it (exp(-1e3 / eps) is 0 in float64), restricted to the
reachable style features (POT stops at a column with no mass; those columns carry no edge in CCFT), with the same
iteration count. Rows report both times, the ratio and the largest plan difference.

``cpu_ms`` / ``pot_cpu_ms``: the process's CPU time (all threads) over the same calls: on a machine other jobs share,
a steadier figure than wall time (CCFT runs on both cores, POT mostly on one).

Peak memory: every case runs in a fresh subprocess; peak_mb is the process's peak RSS (``ru_maxrss``) during the
measured call minus its RSS just before it, so it counts everything the call allocates (torch's CPU allocations,
numpy, numba) on top of the inputs. Timings come from a shared machine unless you know otherwise: take them as noisy.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

DEFAULT_SIZES = "1024,4096,16384"
# Dense POT holds several float64 n x m matrices at once besides its input M (-M/reg, exp, the ones matrix c, K, the
# plan): measured 2.0 GB peak at 16384 x 4096 and 8.0 GB at 16384 x 16384 (94 s, 2 cores) on top of the 2 GB cost
# matrix, i.e. ~32 bytes an entry. On a 24 GB machine shared with other jobs that case is left to an explicit
# --pot-max-entries 300000000: by default it is skipped (with the reason in the row), never swapped.
POT_BYTES_PER_ENTRY = 32 + 8
DEFAULT_POT_MAX_ENTRIES = 4096 * 16384


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--sizes", default=DEFAULT_SIZES,
                        help=f"comma-separated feature counts used for both n and m (default {DEFAULT_SIZES})")
    parser.add_argument("--channels", type=int, default=768, help="feature channels C (default 768)")
    parser.add_argument("-k", "--k", type=int, default=16, help="top-K support per rendered feature (default 16)")
    parser.add_argument("--iters", type=int, default=50, help="Sinkhorn iterations (default 50)")
    parser.add_argument("--epsilon", type=float, default=0.05, help="entropic regularisation (default 0.05)")
    parser.add_argument("--tau", type=float, default=0.5, help="column capacity strength (default 0.5)")
    parser.add_argument("--repeat", type=int, default=3, help="timed CCFT runs per case, median reported (default 3)")
    parser.add_argument("--pot-max-entries", type=int, default=DEFAULT_POT_MAX_ENTRIES,
                        help="skip dense POT above n * m entries (default %(default)s: ~3 GB of float64 matrices)")
    parser.add_argument("--no-pot", action="store_true", help="time CCFT only")


def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def _current_rss_mb() -> float:
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def _ccft_worker(args: argparse.Namespace) -> dict:
    import time

    import numpy as np
    import torch

    from training.stylize.ccft import ccft_loss

    g = torch.Generator().manual_seed(args.seed)
    # a warm-up on a tiny problem loads the compiled Sinkhorn kernel before anything is measured
    ccft_loss(torch.rand(64, 8, generator=g), torch.rand(64, 8, generator=g), k=4, iters=2)
    X = torch.randn(args.n, args.channels, generator=g).add_(0.2).relu_()  # in place: no transient copies
    Y = torch.randn(args.m, args.channels, generator=g).add_(0.2).relu_()
    times, cpu, parts = [], [], []
    rss_before = peak_mb = None
    result = None
    for r in range(args.repeat):
        x = X.clone().requires_grad_(True)
        if r == 0:
            rss_before = _current_rss_mb()
        c0 = time.process_time()
        t0 = time.perf_counter()
        result = ccft_loss(x, Y, k=args.k, epsilon=args.epsilon, tau=args.tau, iters=args.iters)
        t1 = time.perf_counter()
        result.loss.backward()
        t2 = time.perf_counter()
        cpu.append(time.process_time() - c0)
        if r == 0:
            peak_mb = _peak_rss_mb() - rss_before
        times.append(t2 - t0)
        parts.append({**result.timings, "backward": t2 - t1})
        if r + 1 < args.repeat:
            del result, x
    assert result is not None
    order = np.argsort(times)
    mid = parts[int(order[len(order) // 2])]
    np.savez(args.out, indices=result.plan.indices.numpy(), cost=result.cost.numpy().astype(np.float64),
             plan=result.plan.values.numpy(), reachable=result.reachable.numpy())
    return {
        "ms": 1e3 * float(np.median(times)),
        "cpu_ms": 1e3 * float(np.median(cpu)),
        "similarity_topk_ms": 1e3 * mid["similarity_topk"],
        "cost_ms": 1e3 * mid["cost"],
        "sinkhorn_ms": 1e3 * mid["sinkhorn"],
        "guide_ms": 1e3 * mid["guide"],
        "backward_ms": 1e3 * mid["backward"],
        "peak_mb": peak_mb,
        "reachable": int(result.reachable.sum()),
        "utilisation": result.utilisation,
        "threads": torch.get_num_threads(),
    }


def _pot_worker(args: argparse.Namespace) -> dict:
    import time
    import warnings

    import numpy as np
    import ot

    data = np.load(args.out)
    indices, cost, ours, reachable = data["indices"], data["cost"], data["plan"], data["reachable"]
    n, m = args.n, args.m
    cols = np.flatnonzero(reachable)
    col_of = np.full(m, -1, dtype=np.int64)
    col_of[cols] = np.arange(len(cols))
    M = np.full((n, len(cols)), 1e3)
    np.put_along_axis(M, col_of[indices], cost, axis=1)
    a = np.full(n, 1.0 / n)
    b = np.full(len(cols), 1.0 / len(cols))
    rss_before = _current_rss_mb()
    c0 = time.process_time()
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # POT says it overwrites c for reg_type='entropy': expected
        P = ot.unbalanced.sinkhorn_unbalanced(a, b, M, args.epsilon, (float("inf"), args.tau), reg_type="entropy",
                                              numItermax=args.iters, stopThr=0, method="sinkhorn")
    pot_s = time.perf_counter() - t0
    pot_cpu = time.process_time() - c0
    pot_peak = _peak_rss_mb() - rss_before
    on_support = np.take_along_axis(P, col_of[indices], axis=1)
    np.put_along_axis(P, col_of[indices], 0.0, axis=1)  # what POT put off the support must be zero
    diff = max(float(np.abs(on_support - ours).max()), float(np.abs(P).max()))
    return {"pot_ms": 1e3 * pot_s, "pot_cpu_ms": 1e3 * pot_cpu, "pot_peak_mb": pot_peak, "max_abs_diff_vs_pot": diff,
            "pot_columns": int(len(cols))}


def _spawn(kind: str, n: int, m: int, args: argparse.Namespace, out: Path) -> dict:
    cmd = [sys.executable, "-m", "app.bench.ccft", kind, "--n", str(n), "--m", str(m),
           "--channels", str(args.channels), "--k", str(args.k), "--iters", str(args.iters),
           "--epsilon", str(args.epsilon), "--tau", str(args.tau), "--repeat", str(args.repeat), "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        return {"error": f"{kind} worker failed ({proc.returncode}): {tail}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run(args: argparse.Namespace) -> list[dict]:
    from tqdm import tqdm

    try:
        sizes = [int(s) for s in str(args.sizes).split(",") if s.strip()]
    except ValueError:
        from training.core.errors import InputError

        raise InputError(None, f"--sizes must be comma-separated integers, got {args.sizes!r}") from None
    cases = [(n, m) for n in sizes for m in sizes]
    rows = []
    with tempfile.TemporaryDirectory(prefix="splatstyler-bench-ccft-") as tmp:
        for n, m in tqdm(cases, desc="bench ccft", unit="case", file=sys.stderr):
            out = Path(tmp) / f"plan_{n}_{m}.npz"
            row: dict = {"n": n, "m": m, "C": args.channels, "K": args.k, "iters": args.iters}
            row.update(_spawn("ccft-worker", n, m, args, out))
            if args.no_pot:
                row["pot_ms"] = None
                row["pot_skipped"] = "--no-pot"
            elif n * m > args.pot_max_entries:
                row["pot_ms"] = None
                row["max_abs_diff_vs_pot"] = None
                gb = POT_BYTES_PER_ENTRY * n * m / 1e9
                row["pot_skipped"] = (f"dense POT at {n}x{m} needs ~{gb:.0f} GB (cost matrix + ~4 float64 "
                                      f"temporaries) > --pot-max-entries {args.pot_max_entries}")
            elif "error" not in row:
                row.update(_spawn("pot-worker", n, m, args, out))
                if row.get("pot_ms") and row.get("ms"):
                    row["pot_over_ccft"] = row["pot_ms"] / row["ms"]
                    row["pot_over_sinkhorn"] = row["pot_ms"] / row["sinkhorn_ms"]
                    row["pot_cpu_over_ccft_cpu"] = row["pot_cpu_ms"] / row["cpu_ms"]
            rows.append(row)
    return rows


def _worker_main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m app.bench.ccft")
    p.add_argument("kind", choices=["ccft-worker", "pot-worker"])
    p.add_argument("--n", type=int, required=True)
    p.add_argument("--m", type=int, required=True)
    p.add_argument("--channels", type=int, default=768)
    p.add_argument("--k", type=int, default=16)
    p.add_argument("--iters", type=int, default=50)
    p.add_argument("--epsilon", type=float, default=0.05)
    p.add_argument("--tau", type=float, default=0.5)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)
    result = _ccft_worker(a) if a.kind == "ccft-worker" else _pot_worker(a)
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    _worker_main()
