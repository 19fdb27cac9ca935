"""Run a grid's jobs: a local pool of worker processes by default, or tasks on a Ray cluster.

Jobs run as soon as the jobs they read from have finished (sfm, then the shared reconstruction, then its cells).
The driver records every result in OUT/jobs/<job id>.json as it arrives (atomically): a result with status "ok" is
final, so a killed or interrupted grid started again skips those and continues; a failed job is recorded with its
one-line error, its dependants are marked failed without running, the rest of the grid goes on, and the next run
tries the failed ones again. A record counts only for the same job made from the same inputs: the record holds the
job's spec and the fingerprint of the scene and painting it read (``grid.with_inputs``), and a job whose spec or
inputs changed runs again, and with it every job that reads its outputs; the run says which and why.

Ray (``--ray auto`` or an address): one task per job with one CPU each (``--threads`` of them per task), results
gathered back through Ray; the workers must see the grid's data, paintings and OUT at the same paths (a shared
filesystem), as the reconstruction cache and the renders are files. Ray is an optional extra (``.[ray]``).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing
import os
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable

from app.evaluate.grid import Grid, Job, with_inputs
from app.evaluate.jobs import run_job
from training.evaluate.measure import METRICS_VERSION
from training.core import stop
from training.core.atomic_write import atomic_open
from training.core.errors import InputError
from training.core.version import version

STOP_POLL_S = 0.2  # how often the driver, waiting on its workers, looks for a stop


def result_path(out: Path, job: Job | str) -> Path:
    return Path(out) / "jobs" / ((job.id if isinstance(job, Job) else job) + ".json")


def load_results(out: Path, grid: Grid) -> dict[str, dict[str, Any]]:
    """The recorded results of the grid's jobs (those that have one)."""
    results = {}
    for job in grid.jobs:
        p = result_path(out, job)
        if p.is_file():
            try:
                results[job.id] = json.loads(p.read_text())
            except (OSError, json.JSONDecodeError):
                pass  # a damaged record: the job runs again
    return results


def is_done(result: dict[str, Any] | None, job: Job) -> bool:
    """A recorded "ok" for this very job: a record made with other settings (the grid file changed) or from other
    inputs (``job.inputs``; a record without them, from before they were recorded, cannot be checked and counts),
    or a cell's made with other metrics, does not count."""
    return why_not_done(result, job) is None


def why_not_done(result: dict[str, Any] | None, job: Job) -> str | None:
    """None when ``result`` is a finished record of ``job`` (see ``is_done``), else why not, in words."""
    from training.scene.fingerprint import difference

    if not (result and result.get("status") == "ok"):
        return "not run yet" if not result else "it failed"
    recorded = result.get("job", {})
    old_spec = recorded.get("spec") or {}
    if old_spec != job.spec:
        keys = [k for k in sorted(set(old_spec) | set(job.spec)) if old_spec.get(k) != job.spec.get(k)]
        paths = [k for k in keys if k in ("data", "photos", "painting_path")]
        if paths:
            return "; ".join(f"{k} is {job.spec.get(k)} now, {old_spec.get(k)} then" for k in paths)
        return f"the grid file changed its {', '.join(keys)}"
    if recorded.get("inputs") and job.inputs:
        changed = difference(recorded["inputs"], job.inputs)
        if changed:
            return changed
    # a cell measured by another version of the metrics is measured again (from its saved model)
    if job.kind == "cell" and result.get("metrics_version") != METRICS_VERSION:
        return "measured by another version of the metrics"
    return None


def _record(out: Path, job: Job, result: dict[str, Any]) -> None:
    result = {"job": asdict(job), "splatstyler_version": version(), **result}
    with atomic_open(result_path(out, job), "w") as f:
        json.dump(result, f, indent=2, default=str)
        f.write("\n")


class LocalPool:
    """``workers`` processes (spawned: each starts clean, with its own torch and numba thread pools)."""

    def __init__(self, workers: int, threads: int):
        self.threads = threads
        self.capacity = workers
        os.environ["TQDM_DISABLE"] = "1"  # inherited by the spawned workers: no progress bars in the job logs
        self.pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))

    def submit(self, job: Job, out: Path):
        return self.pool.submit(run_job, asdict(job), str(out), self.threads)

    def wait(self, handles: list) -> list[tuple[Any, dict]]:
        done: set = set()
        while not done:  # in slices: a stop is recorded, not thrown, and is seen between two
            stop.check()
            done, _ = cf.wait(handles, timeout=STOP_POLL_S, return_when=cf.FIRST_COMPLETED)
        out = []
        for h in done:
            try:
                out.append((h, h.result()))
            except Exception as exc:  # the worker process died (killed, out of memory)
                out.append((h, {"status": "failed", "error": f"worker died: {type(exc).__name__}: {exc}"}))
        return out

    def close(self, cancel: bool = False) -> None:
        if cancel:
            # a worker busy with a job would otherwise run it to the end with nobody to record it; what it wrote
            # so far (a reconstruction's checkpoint) is picked up by the next run
            for proc in list(getattr(self.pool, "_processes", {}).values()):
                proc.terminate()
        self.pool.shutdown(wait=not cancel, cancel_futures=cancel)


class RayPool:
    """One Ray task per job; ``address`` "auto", "local" (start one here) or ray://host:port."""

    def __init__(self, address: str, threads: int, num_cpus: int | None = None):
        try:
            import ray
        except ImportError:
            raise InputError(None, "--ray needs Ray: pip install 'splatstyler[ray]' (or pip install ray)") from None
        self.ray = ray
        self.threads = threads
        if not ray.is_initialized():
            env = {"env_vars": {"TQDM_DISABLE": "1"}}
            if address == "local":
                ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, runtime_env=env)
            else:
                ray.init(address=address, log_to_driver=False, runtime_env=env)
        self.task = ray.remote(num_cpus=threads, max_retries=0)(run_job)
        self.capacity = max(1, int(ray.cluster_resources().get("CPU", 1) // threads))

    def submit(self, job: Job, out: Path):
        return self.task.remote(asdict(job), str(out), self.threads)

    def wait(self, handles: list) -> list[tuple[Any, dict]]:
        done: list = []
        while not done:
            stop.check()
            done, _ = self.ray.wait(handles, num_returns=1, timeout=STOP_POLL_S)
        out = []
        for h in done:
            try:
                out.append((h, self.ray.get(h)))
            except Exception as exc:  # the task's worker died
                out.append((h, {"status": "failed", "error": f"Ray task failed: {type(exc).__name__}: {exc}"}))
        return out

    def close(self, cancel: bool = False) -> None:
        pass  # the cluster outlives the grid; a local instance ends with this process


def time_left(results: dict[str, dict[str, Any]], jobs: dict[str, Job], remaining: list[Job],
              capacity: int) -> float | None:
    """About how many seconds ``remaining`` will take on ``capacity`` workers: each job at the mean recorded time of
    the finished jobs most like it (same kind, scene and setting; else same kind and scene; else same kind: a cell
    that moves the geometry takes twice a colour-only one), shared evenly by the workers. None while some kind has
    no finished job to go by."""
    def keys(job: Job) -> list[tuple]:
        scene, setting = job.spec.get("scene"), job.spec.get("setting")
        return [(job.kind, scene, setting), (job.kind, scene, None), (job.kind, None, None)]

    samples: dict[tuple, list[float]] = {}
    for jid, r in results.items():
        if r.get("status") == "ok" and r.get("seconds") and jid in jobs:
            for key in set(keys(jobs[jid])):
                samples.setdefault(key, []).append(float(r["seconds"]))
    total = 0.0
    for job in remaining:
        seen = next((samples[k] for k in keys(job) if k in samples), None)
        if seen is None:
            return None
        total += sum(seen) / len(seen)
    return total / max(1, capacity)


def _to_run(jobs: list[Job], results: dict[str, dict[str, Any]], log: Callable[[str], None]) -> list[Job]:
    """The jobs (in the grid's order: a job after those it reads) that must run: not finished, or finished from
    other settings or inputs, or reading the outputs of one that runs again. Says why for each finished job that
    runs again (cells summed up by reason)."""
    todo: list[Job] = []
    todo_ids: set[str] = set()
    again: dict[str, list[str]] = {}
    unchecked = 0
    for job in jobs:
        result = results.get(job.id)
        why = why_not_done(result, job)
        if why is None:
            rerun = next((d for d in job.deps if d in todo_ids), None)
            if rerun is None:
                unchecked += not result.get("job", {}).get("inputs")
                continue
            why = f"{rerun} runs again"
        todo.append(job)
        todo_ids.add(job.id)
        if result and result.get("status") == "ok":
            if job.kind == "cell":
                again.setdefault(why, []).append(job.id)
            else:
                log(f"eval: {job.id} runs again: {why}")
    for why, ids in again.items():
        log(f"eval: {ids[0]} runs again: {why}" if len(ids) == 1 else
            f"eval: {len(ids)} finished cells run again ({ids[0]}, ...): {why}")
    if unchecked:
        log(f"eval: {unchecked} finished jobs were recorded without the fingerprint of their inputs (an older "
            f"version): kept, though their scenes and paintings could not be checked")
    return todo


def run_grid(grid: Grid, out: Path, pool, log: Callable[[str], None] = print,
             only: Callable[[Job], bool] | None = None,
             progress: Callable[[int, int], None] | None = None) -> dict[str, dict[str, Any]]:
    """Run every job of ``grid`` without an "ok" record (those ``only`` accepts, and what they need) on ``pool``;
    returns all results by job id. ``progress(finished, to_run)`` is called as jobs finish (and once at the start)."""
    out = Path(out)
    results = load_results(out, grid)
    jobs = with_inputs(grid)
    by_id = {j.id: j for j in jobs}
    wanted = [j for j in jobs if only is None or only(j)]
    needed: set[str] = set()
    stack = [j.id for j in wanted]
    while stack:
        jid = stack.pop()
        if jid not in needed:
            needed.add(jid)
            stack.extend(by_id[jid].deps)
    todo = _to_run([j for j in jobs if j.id in needed], results, log)
    skipped = len(needed) - len(todo)
    log(f"eval: {len(todo)} jobs to run ({skipped} already done) in {out}")
    running: dict[Any, Job] = {}
    pending = list(todo)
    todo_ids, finished_ids = {j.id for j in todo}, set()
    finished = 0
    t0 = time.perf_counter()
    if progress is not None:
        progress(0, len(todo))
    try:
        while pending or running:
            for job in list(pending):
                states = [results.get(d, {}).get("status") if d not in todo_ids or d in finished_ids else None
                          for d in job.deps]
                if any(s == "failed" for s in states):
                    failed_dep = next(d for d in job.deps if results.get(d, {}).get("status") == "failed")
                    results[job.id] = {"status": "failed", "error": f"not run: {failed_dep} failed"}
                    _record(out, job, results[job.id])
                    finished_ids.add(job.id)
                    pending.remove(job)
                    finished += 1
                    log(f"[{finished}/{len(todo)}] {job.id}: skipped ({failed_dep} failed)")
                    if progress is not None:
                        progress(finished, len(todo))
                elif all(s == "ok" for s in states) and len(running) < pool.capacity:
                    # no queue beyond the free workers: the next free worker takes the first ready job in the
                    # grid's order, so the settings listed first finish first
                    running[pool.submit(job, out)] = job
                    pending.remove(job)
            if not running:
                break
            for handle, result in pool.wait(list(running)):
                job = running.pop(handle)
                results[job.id] = result
                _record(out, job, result)
                finished_ids.add(job.id)
                finished += 1
                what = f"failed: {result.get('error')}" if result.get("status") != "ok" else \
                    f"ok in {result.get('seconds', 0):.0f} s"
                left = time_left(results, by_id, pending + list(running.values()), pool.capacity)
                eta = "" if left is None or not (pending or running) else f"; about {left / 60:.0f} min left"
                log(f"[{finished}/{len(todo)}] {job.id}: {what} ({(time.perf_counter() - t0) / 60:.1f} min{eta})")
                if progress is not None:
                    progress(finished, len(todo))
    except KeyboardInterrupt:
        pool.close(cancel=True)
        log("eval: interrupted; finished jobs are recorded, run the same command again to continue")
        raise
    pool.close()
    return results
