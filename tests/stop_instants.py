"""SIGTERM at random instants of the long commands, each checked as a user relies on it: exit 143 with the
"stopped by SIGTERM" line (or exit 0 when the command had already finished), no traceback and no stack dump, the
work so far kept where a step had run (a checkpoint that ``--resume`` accepts and finishes from), and how long the
stop took (signal to exit).

A command's instants are drawn uniformly over the whole of one run of it, measured first (a calibration run to its
end), from 0.15 s after launch: before that the interpreter itself is starting and no code of ours runs yet (our
handler goes in within about 0.1 s, app/cli.py). The draw is seeded; the seed is printed, and ``--seed`` replays it.

tests/test_stop_signals.py runs a handful of instants in CI; the long run is

    python -m tests.stop_instants --instants 200 --out WORK [--commands reconstruct,stylize,sfm,demo] [--seed N]

which prints one line per instant and a table (instants, clean, finished first, worst and median stop latency per
command), and writes WORK/stop_instants.json.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
EARLIEST_S = 0.15
STOP_TIMEOUT_S = 60.0
SFM_PHOTOS = 8  # of the fern's 20: enough to register, small enough to be quick


@dataclass
class Command:
    """One command to stop: ``argv(out)`` runs it into ``out``; ``resume(out)`` continues what a stop kept (None:
    nothing to continue); ``kept(out)`` says whether the stop left something to resume."""

    name: str
    argv: object
    resume: object = None
    kept: object = None


@dataclass
class Instant:
    command: str
    delay_s: float
    outcome: str  # "stopped", "finished first" or "FAILED: why"
    latency_s: float | None = None
    resumed: bool | None = None
    stderr_tail: str = ""


@dataclass
class Inputs:
    """What the commands read: the demo scene and painting, a model of the scene, and (when ../shared is there) a
    few of the fern's photos."""

    scene: Path
    painting: Path
    model: Path
    photos: Path | None = None
    extra: dict = field(default_factory=dict)


def splatstyler(*args: str) -> list[str]:
    return [sys.executable, "-m", "app", *args]


def prepare_inputs(work: Path) -> Inputs:
    """The demo assets, a 150-step reconstruction of the demo scene at 64 px (the model the stylize runs read) and
    the photos for sfm."""
    from assets.demo.assets import demo_assets

    assets = demo_assets()
    model_dir = work / "model"
    if not (model_dir / "point_cloud.ply").is_file():
        subprocess.run(splatstyler("reconstruct", str(assets.scene_dir), "-o", str(model_dir), "--iters", "150",
                                   "--max-side", "64", "--no-progress", "--overwrite"), cwd=ROOT, check=True,
                       capture_output=True)
    photos = None
    fern = SHARED / "scenes" / "llff_fern" / "images"
    if fern.is_dir():
        photos = work / "photos"
        if not photos.is_dir():
            photos.mkdir(parents=True)
            for p in sorted(fern.iterdir())[:SFM_PHOTOS]:
                shutil.copy(p, photos / p.name)
    return Inputs(assets.scene_dir, assets.style_image, model_dir / "point_cloud.ply", photos)


def commands(inputs: Inputs) -> dict[str, Command]:
    recon = ["--iters", "120", "--max-side", "64", "--no-progress"]
    styl = ["--max-side", "48", "--iters-per-view", "1", "--min-total-iters", "40", "--metric-pairs", "2",
            "--no-progress"]
    out = {
        "reconstruct": Command(
            "reconstruct",
            lambda o: splatstyler("reconstruct", str(inputs.scene), "-o", str(o), *recon),
            lambda o: splatstyler("reconstruct", str(inputs.scene), "-o", str(o), "--resume", "--no-progress"),
            lambda o: (o / "checkpoint.pt").is_file()),
        "stylize": Command(
            "stylize",
            lambda o: splatstyler("stylize", str(inputs.model), "--data", str(inputs.scene), "--style",
                                  str(inputs.painting), "-o", str(o), *styl),
            lambda o: splatstyler("stylize", str(inputs.model), "--data", str(inputs.scene), "--style",
                                  str(inputs.painting), "-o", str(o), "--resume", *styl),
            lambda o: (o / "stylize_checkpoint.pt").is_file()),
        "demo": Command(
            "demo",
            lambda o: splatstyler("demo", "--headless", "-o", str(o), "--recon-iters", "150", "--iters-per-view",
                                  "1", "--no-progress"),
            # the scene the demo printed and reconstructed (the generated one, in the assets' cache)
            lambda o: splatstyler("reconstruct", str(inputs.scene), "-o", str(o / "reconstruction"),
                                  "--resume", "--no-progress"),
            lambda o: (o / "reconstruction" / "checkpoint.pt").is_file()
            and not (o / "reconstruction" / "report.json").is_file()),
    }
    if inputs.photos is not None:
        out["sfm"] = Command(
            "sfm",
            lambda o: splatstyler("sfm", str(inputs.photos), "-o", str(o), "--max-size", "320", "--max-features",
                                  "1024", "--no-progress"),
            # nothing is kept: the same command again must find nothing in its way
            lambda o: splatstyler("sfm", str(inputs.photos), "-o", str(o), "--max-size", "320", "--max-features",
                                  "1024", "--no-progress"),
            lambda o: True)
    return out


def calibrate(command: Command, work: Path) -> float:
    """Seconds one whole run of ``command`` takes here."""
    out = work / f"{command.name}_calibration"
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    proc = subprocess.run(command.argv(out), cwd=ROOT, capture_output=True, text=True, timeout=1800)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{command.name} does not run to its end: {proc.stderr[-2000:]}")
    return seconds


def stop_at(command: Command, delay_s: float, out: Path, check_resume: bool = True) -> Instant:
    """Run ``command`` into ``out``, send SIGTERM ``delay_s`` after launch, and check what it did."""
    shutil.rmtree(out, ignore_errors=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    err_path = out.parent / f"{out.name}.stderr"
    with open(err_path, "w") as err:  # a file, not a pipe nobody reads while it runs
        proc = subprocess.Popen(command.argv(out), cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err)
        time.sleep(delay_s)
        sent = None
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            sent = time.perf_counter()
        try:
            proc.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            return Instant(command.name, delay_s, f"FAILED: still running {STOP_TIMEOUT_S:.0f} s after SIGTERM",
                           stderr_tail=err_path.read_text()[-1500:])
    latency = None if sent is None else time.perf_counter() - sent
    text = err_path.read_text()
    tail = text[-1500:]
    if "Traceback" in text or "stack trace" in text or "Exception ignored" in text:
        return Instant(command.name, delay_s, "FAILED: a traceback or stack dump", latency, stderr_tail=tail)
    if proc.returncode == 0:
        if sent is not None:
            return Instant(command.name, delay_s, "FAILED: exit 0 after SIGTERM", latency, stderr_tail=tail)
        return Instant(command.name, delay_s, "finished first")
    if proc.returncode != 143 or "splatstyler: stopped by SIGTERM" not in text:
        return Instant(command.name, delay_s, f"FAILED: exit {proc.returncode} without the stop line", latency,
                       stderr_tail=tail)
    resumed = None
    if check_resume and command.resume is not None and command.kept(out):
        again = subprocess.run(command.resume(out), cwd=ROOT, capture_output=True, text=True, timeout=1800)
        resumed = again.returncode == 0
        if not resumed:
            return Instant(command.name, delay_s, f"FAILED: the run after the stop exited {again.returncode}",
                           latency, False, again.stderr[-1500:])
    return Instant(command.name, delay_s, "stopped", latency, resumed)


def run(names: list[str], instants: int, work: Path, seed: int, check_resume: bool = True,
        log=print) -> list[Instant]:
    """``instants`` SIGTERMs spread over ``names`` in turn (after one calibration run of each)."""
    inputs = prepare_inputs(work)
    available = commands(inputs)
    missing = [n for n in names if n not in available]
    if missing:
        raise SystemExit(f"not available here: {', '.join(missing)} (sfm needs ../shared/data)")
    rng = random.Random(seed)
    log(f"stop instants: seed {seed}")
    lengths = {}
    for name in names:
        lengths[name] = calibrate(available[name], work)
        log(f"{name}: a whole run takes {lengths[name]:.1f} s")
    results = []
    for k in range(instants):
        name = names[k % len(names)]
        delay = rng.uniform(EARLIEST_S, lengths[name])
        result = stop_at(available[name], delay, work / f"{name}_{k:03d}", check_resume)
        results.append(result)
        lat = "" if result.latency_s is None else f", stopped {result.latency_s:.2f} s after the signal"
        res = "" if result.resumed is None else f", resumed {'ok' if result.resumed else 'FAILED'}"
        log(f"[{k + 1}/{instants}] {name} at {delay:.2f} s: {result.outcome}{lat}{res}")
        if result.outcome.startswith("FAILED"):
            log(result.stderr_tail)
        shutil.rmtree(work / f"{name}_{k:03d}", ignore_errors=True)
    return results


def table(results: list[Instant]) -> list[dict]:
    rows = []
    for name in dict.fromkeys(r.command for r in results):
        mine = [r for r in results if r.command == name]
        lat = sorted(r.latency_s for r in mine if r.latency_s is not None)
        rows.append({"command": name, "instants": len(mine),
                     "clean": sum(not r.outcome.startswith("FAILED") for r in mine),
                     "finished_first": sum(r.outcome == "finished first" for r in mine),
                     "resumed": sum(bool(r.resumed) for r in mine),
                     "latency_max_s": lat[-1] if lat else None,
                     "latency_median_s": lat[len(lat) // 2] if lat else None})
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--instants", type=int, default=200)
    parser.add_argument("--commands", default="reconstruct,stylize,sfm,demo")
    parser.add_argument("--out", type=Path, required=True, help="work folder")
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--no-resume", action="store_true", help="skip the --resume check after each stop")
    args = parser.parse_args()
    seed = args.seed if args.seed is not None else random.SystemRandom().randrange(2 ** 31)
    args.out.mkdir(parents=True, exist_ok=True)
    results = run(args.commands.split(","), args.instants, args.out, seed, not args.no_resume,
                  log=lambda line: print(line, flush=True))
    rows = table(results)
    print(f"{'command':<12} {'instants':>8} {'clean':>6} {'finished first':>15} {'resumed':>8} "
          f"{'worst stop (s)':>15} {'median (s)':>11}")
    for r in rows:
        worst = "-" if r["latency_max_s"] is None else f"{r['latency_max_s']:.2f}"
        med = "-" if r["latency_median_s"] is None else f"{r['latency_median_s']:.2f}"
        print(f"{r['command']:<12} {r['instants']:>8} {r['clean']:>6} {r['finished_first']:>15} "
              f"{r['resumed']:>8} {worst:>15} {med:>11}")
    (args.out / "stop_instants.json").write_text(json.dumps(
        {"seed": seed, "python": sys.version.split()[0], "cpus": os.cpu_count(), "table": rows,
         "instants": [asdict(r) for r in results]}, indent=2))
    return 0 if all(not r.outcome.startswith("FAILED") for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
