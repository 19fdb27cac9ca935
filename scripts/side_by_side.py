"""Run one bench or profile command on two commits in turn, on this machine, and print each round and the ratio.

    python scripts/side_by_side.py A B [--rounds N] [--key KEY [--where FIELD=VALUE ...]] -- COMMAND [ARGS ...]

A and B are git revisions of this repository. Each is checked out in a temporary ``git worktree`` (removed at the
end); COMMAND runs in that checkout with ``PYTHONPATH`` set to it, with this interpreter's ``bin`` folder first on
``PATH`` (so ``python`` is the same venv's for both), in the order A, B, A, B, ... for N rounds: a load that drifts
during the run falls on both commits alike. A command that starts with ``splatstyler`` runs as ``python -m app``:
the venv's ``splatstyler`` script imports the entry point of the commit it was installed from, which another
commit may not have. One untimed run of each comes first (``--warmup``,
default 1): a fresh checkout compiles its numba kernels into its own ``__pycache__`` on its first run.

The figure of a run is its wall time, with ``--cpu`` its CPU time (user + sys of the command and the processes it
waited for: on a machine other jobs share, steadier than wall time), or with ``--key`` a value from the JSON objects the command prints on stdout,
one a line (``bench ... --json``, ``scripts/profile_step.py``): ``--where n=4096`` picks the row when there are
several, and a dotted key (``step.cpu_ms``) reads inside nested objects. ``--json-file PATH`` reads the JSON from a
file the command writes instead (relative to the checkout). The table gives each round, then the medians and the
ratio median(B) / median(A) with the spread of the per-round ratios; for a time, A / B is B's speed-up.

Example (CCFT's 4k x 4k case; both runs at 1 thread would be ``OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1`` before it):

    python scripts/side_by_side.py aebd291 HEAD --rounds 3 --key ms --where n=4096 --where m=4096 -- \\
        splatstyler bench ccft --sizes 4096 --no-pot --json
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


class FigureError(ValueError):
    """A run's output did not contain the figure asked for."""


def parse_where(items: list[str]) -> dict[str, str]:
    where = {}
    for item in items:
        field, sep, value = item.partition("=")
        if not sep or not field:
            raise argparse.ArgumentTypeError(f"--where takes FIELD=VALUE, got {item!r}")
        where[field] = value
    return where


def json_rows(text: str) -> list[dict]:
    """The JSON objects in ``text``: the whole text as one document (a file, an object or a list of objects), else
    each line that parses as an object (a bench's ``--json`` lines among other output)."""
    try:
        doc = json.loads(text)
    except ValueError:
        doc = None
    if isinstance(doc, dict):
        return [doc]
    if isinstance(doc, list):
        return [row for row in doc if isinstance(row, dict)]
    rows = []
    for line in text.splitlines():
        line = line.strip()
        if not line.startswith("{"):
            continue
        try:
            row = json.loads(line)
        except ValueError:
            continue
        if isinstance(row, dict):
            rows.append(row)
    return rows


def _lookup(row: dict, key: str):
    value = row
    for part in key.split("."):
        if not isinstance(value, dict) or part not in value:
            raise KeyError(part)
        value = value[part]
    return value


def _matches(row: dict, where: dict[str, str]) -> bool:
    for field, wanted in where.items():
        try:
            value = _lookup(row, field)
        except KeyError:
            return False
        # compared as the command printed them: 4096 matches "4096", true matches "true"
        if (json.dumps(value) if not isinstance(value, str) else value) != wanted:
            return False
    return True


def figure_from(text: str, key: str, where: dict[str, str]) -> float:
    """The number at ``key`` in the one JSON row of ``text`` that ``where`` selects."""
    rows = [row for row in json_rows(text) if _matches(row, where)]
    if not rows:
        raise FigureError(f"no JSON row{' with ' + str(where) if where else ''} in the output")
    found = []
    for row in rows:
        try:
            found.append(_lookup(row, key))
        except KeyError:
            continue
    if not found:
        raise FigureError(f"no key {key!r} in the {len(rows)} JSON row(s) selected")
    if len(found) > 1:
        raise FigureError(f"{len(found)} JSON rows have {key!r} ({found}): pick one with --where FIELD=VALUE")
    value = found[0]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FigureError(f"{key!r} is {value!r}, not a number")
    return float(value)


def summarize(a: list[float], b: list[float]) -> dict:
    """Medians of each side, their ratio B / A, and the per-round ratios' median and range."""
    if len(a) != len(b) or not a:
        raise ValueError("both commits need the same number of rounds, at least one")
    per_round = [y / x if x else float("inf") for x, y in zip(a, b)]
    med_a, med_b = statistics.median(a), statistics.median(b)
    return {"median_a": med_a, "median_b": med_b, "b_over_a": med_b / med_a if med_a else float("inf"),
            "round_ratios": per_round, "round_ratio_median": statistics.median(per_round),
            "round_ratio_min": min(per_round), "round_ratio_max": max(per_round)}


def table(labels: tuple[str, str], a: list[float], b: list[float], unit: str) -> str:
    s = summarize(a, b)
    la, lb = labels
    lines = [f"| round | A {la} ({unit}) | B {lb} ({unit}) | B / A |", "|---|---|---|---|"]
    for i, (x, y, r) in enumerate(zip(a, b, s["round_ratios"]), 1):
        lines.append(f"| {i} | {x:.4g} | {y:.4g} | {r:.3f} |")
    lines.append(f"| median | {s['median_a']:.4g} | {s['median_b']:.4g} | **{s['b_over_a']:.3f}** |")
    lines.append("")
    lines.append(f"B / A = {s['b_over_a']:.3f} (median B over median A; per round {s['round_ratio_min']:.3f} to "
                 f"{s['round_ratio_max']:.3f}); A / B = {1 / s['b_over_a']:.3f}" if s["b_over_a"] else
                 "B / A = 0")
    return "\n".join(lines)


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, text=True).stdout.strip()


def _load() -> str:
    try:
        return f"{os.getloadavg()[0]:.1f}"
    except OSError:
        return "?"


class Run:
    def __init__(self, checkout: Path, command: list[str], python: Path, key: str | None, where: dict[str, str],
                 json_file: str | None, timeout: float | None, show: bool, cpu: bool = False):
        self.checkout, self.command, self.python, self.cpu = checkout, command, python, cpu
        self.key, self.where, self.json_file, self.timeout, self.show = key, where, json_file, timeout, show

    def __call__(self) -> tuple[float, float, float]:
        """(figure, wall s, CPU s of the command and its children)."""
        env = dict(os.environ, PYTHONPATH=str(self.checkout))
        env["PATH"] = f"{self.python.parent}{os.pathsep}{env.get('PATH', '')}"
        if self.json_file:
            (self.checkout / self.json_file).unlink(missing_ok=True)
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(self.command, cwd=self.checkout, env=env, capture_output=True, text=True,
                              timeout=self.timeout)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        if self.show:
            sys.stderr.write(proc.stdout + proc.stderr)
        if proc.returncode != 0:
            raise SystemExit(f"side_by_side: {shlex.join(self.command)} failed in {self.checkout} "
                             f"(exit {proc.returncode}):\n{proc.stderr[-3000:]}")
        if self.key is None:
            return (cpu if self.cpu else wall), wall, cpu
        text = (self.checkout / self.json_file).read_text() if self.json_file else proc.stdout
        try:
            return figure_from(text, self.key, self.where), wall, cpu
        except FigureError as exc:
            raise SystemExit(f"side_by_side: {exc} (checkout {self.checkout}); its stdout ended:\n"
                             f"{proc.stdout[-2000:]}") from None


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="scripts/side_by_side.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a", help="commit A (the reference)")
    p.add_argument("b", help="commit B")
    p.add_argument("--rounds", type=int, default=3, help="timed runs of each commit, alternating (default 3)")
    p.add_argument("--warmup", type=int, default=1, help="untimed runs of each first (default 1)")
    p.add_argument("--key", help="the figure: this key of the command's JSON output (default: wall time)")
    p.add_argument("--cpu", action="store_true", help="the figure: the command's CPU time, user + sys, not its wall "
                   "time")
    p.add_argument("--where", action="append", default=[], metavar="FIELD=VALUE",
                   help="with --key: the JSON row whose FIELD is VALUE (repeatable)")
    p.add_argument("--json-file", help="with --key: read the JSON from this file the command writes (relative to "
                   "the checkout), not from its stdout")
    p.add_argument("--unit", default=None, help="the figure's unit, for the table (default: s for wall time)")
    p.add_argument("--python", default=sys.executable, help="the venv's interpreter (default: this one)")
    p.add_argument("--timeout", type=float, default=None, help="seconds one run may take")
    p.add_argument("--show-output", action="store_true", help="copy each run's output to stderr")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = parser()
    cut = argv.index("--") if "--" in argv else len(argv)
    args = p.parse_args(argv[:cut])
    command = argv[cut + 1:]
    if command[:1] == ["splatstyler"]:
        command = ["python", "-m", "app", *command[1:]]
    if not command:
        p.error("no command: put it after --")
    if args.rounds < 1 or args.warmup < 0:
        p.error("--rounds must be at least 1 and --warmup at least 0")
    try:
        where = parse_where(args.where)
    except argparse.ArgumentTypeError as exc:
        p.error(str(exc))
    if where and not args.key:
        p.error("--where needs --key")
    if args.json_file and not args.key:
        p.error("--json-file needs --key")
    if args.cpu and args.key:
        p.error("--cpu and --key are two different figures: give one")

    repo = Path(_git(Path.cwd(), "rev-parse", "--show-toplevel"))
    try:
        shas = [_git(repo, "rev-parse", "--verify", f"{rev}^{{commit}}") for rev in (args.a, args.b)]
    except subprocess.CalledProcessError as exc:
        p.error(f"not a commit: {exc.stderr.strip()}")
    labels = (args.a, args.b)
    unit = args.unit or ("s CPU" if args.cpu else "s" if args.key is None else args.key)
    python = Path(args.python).absolute()  # not resolved: a venv's python is a link to the base interpreter

    with tempfile.TemporaryDirectory(prefix="side-by-side-") as tmp:
        checkouts = []
        try:
            for name, sha in zip("ab", shas):
                path = Path(tmp) / name
                _git(repo, "worktree", "add", "--detach", "--quiet", str(path), sha)
                checkouts.append(path)
            runs = [Run(path, command, python, args.key, where, args.json_file, args.timeout, args.show_output,
                        args.cpu)
                    for path in checkouts]
            print(f"A = {args.a} ({shas[0][:10]}), B = {args.b} ({shas[1][:10]}); {shlex.join(command)}; "
                  f"{args.rounds} round(s) after {args.warmup} warm-up(s), {os.cpu_count()} CPUs", flush=True)
            for i in range(args.warmup):
                for label, run in zip("AB", runs):
                    _, wall, _ = run()
                    print(f"warm-up {i + 1} {label}: {wall:.1f} s wall", flush=True)
            a, b = [], []
            for i in range(args.rounds):
                for label, run, out in zip("AB", runs, (a, b)):
                    load = _load()
                    figure, wall, cpu = run()
                    out.append(figure)
                    print(f"round {i + 1} {label}: {figure:.4g} {unit} ({wall:.1f} s wall, {cpu:.1f} s CPU, "
                          f"load {load})", flush=True)
        finally:
            for path in checkouts:
                subprocess.run(["git", "-C", str(repo), "worktree", "remove", "--force", str(path)],
                               capture_output=True)
    print()
    print(table(labels, a, b, unit))
    return 0


if __name__ == "__main__":
    sys.exit(main())
