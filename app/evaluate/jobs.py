"""What a worker does with one job of the grid: structure from motion, a reconstruction, or a cell.

``run_job(job, out, threads)`` runs in a worker process (the local pool) or a Ray task, and returns a plain dict (the
result travels back to the driver, which records it). Each job runs the library function of the CLI subcommand its
flags are for (the flags read back by app/settings), in process, with its console output captured in
OUT/logs/<job id>.log. A job whose outputs are already complete
and were made from the same inputs (the fingerprint in them: training/scene/fingerprint.py) returns at once (a
resumed grid); outputs made from other inputs are made again; an interrupted reconstruction or stylization
continues from its checkpoint when that was made from the same inputs.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from app.evaluate.grid import Job, job_dir
from app.settings import parse_flags
from training.core.atomic_write import atomic_open
from training.core.errors import InputError
from training.evaluate.colour_shift import colour_shift
from training.evaluate.measure import METRICS_VERSION
from training.model.model_io import read_model

RECON_CHECKPOINT_EVERY = 250


def data_path(out: Path, spec: dict[str, Any]) -> Path:
    """The scene folder a job reads: the grid's data, or the folder its sfm job wrote."""
    return Path(spec["data"]) if spec.get("data") else job_dir(out, f"sfm/{spec['scene']}")


@contextlib.contextmanager
def _captured(log_path: Path):
    """Send this process's stdout and stderr (Python's and the C libraries' alike) to ``log_path``."""
    log_path.parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with open(log_path, "a", buffering=1) as log:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        old = sys.stdout, sys.stderr
        sys.stdout = sys.stderr = log
        try:
            yield log
        finally:
            sys.stdout.flush()
            sys.stdout, sys.stderr = old
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])


def _command(argv: list[str]) -> None:
    """The command line a job's run is (logged: a user can run it alone)."""
    print(f"$ splatstyler {' '.join(map(str, argv))}", flush=True)


def _say(line: str) -> None:
    print(line, flush=True)


def run_job(job: Job | dict, out: str | Path, threads: int = 1) -> dict[str, Any]:
    """Run one job; returns {"status": "ok", ...results} or {"status": "failed", "error": one line}."""
    if isinstance(job, dict):
        job = Job(**{**job, "deps": tuple(job.get("deps", ()))})
    out = Path(out)
    _limit_threads(threads)
    log_path = out / "logs" / (job.id.replace("/", "__") + ".log")
    t0 = time.perf_counter()
    try:
        with _captured(log_path):
            try:
                result = {"sfm": _sfm, "reconstruct": _reconstruct, "cell": _cell}[job.kind](job, out)
            except InputError as exc:  # said in one line, as the command says it
                print(f"splatstyler: error: {exc}", flush=True)
                raise RuntimeError(f"splatstyler: error: {exc}") from None
            except Exception:
                import traceback

                traceback.print_exc()  # into the job's log
                raise
    except Exception as exc:  # one cell's failure is recorded; the grid goes on
        message = str(exc) if isinstance(exc, RuntimeError) else f"{type(exc).__name__}: {exc}"
        return {"status": "failed", "error": message.splitlines()[0][:400] if message else type(exc).__name__,
                "log": str(log_path), "seconds": time.perf_counter() - t0}
    return {"status": "ok", **result, "log": str(log_path), "seconds": time.perf_counter() - t0}


def _limit_threads(threads: int) -> None:
    """Workers share the machine: each gets ``threads`` threads for torch and numba."""
    try:
        import torch

        torch.set_num_threads(max(1, threads))
    except ImportError:
        pass
    try:
        import numba

        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    except ImportError:
        pass


def _sfm(job: Job, out: Path) -> dict[str, Any]:
    import shutil

    from app.settings import sfm as settings
    from training.scene.fingerprint import difference
    from training.scene.sfm import REPORT_NAME, run_sfm, sfm_complete, sfm_fingerprint, summary_line

    folder = job_dir(out, job)
    report = folder / REPORT_NAME
    photos = job.spec["photos"]
    options = settings.sfm_options(parse_flags(settings.add_arguments, job.spec["flags"], "sfm flags"))
    if sfm_complete(folder):
        recorded = json.loads(report.read_text()).get("fingerprint")
        if not recorded:  # from before fingerprints: kept, as an old checkpoint resumes, with one line
            print(f"the scene in {folder} records no fingerprint of its photos (made by an older version), so they "
                  f"could not be checked; using it as it is", flush=True)
            return {"sfm": _plain_values(json.loads(report.read_text()))}
        changed = difference(recorded, sfm_fingerprint(photos, options["max_size"], options["max_features"],
                                                       options["matcher"], options["camera_model"],
                                                       options["refine_principal_point"]))
        if changed is None:
            return {"sfm": _plain_values(json.loads(report.read_text()))}
        print(f"the scene in {folder} was made from other photos or settings ({changed}): running SfM again",
              flush=True)
    if folder.exists():
        shutil.rmtree(folder)  # the grid's own folder: an older scene, or what a failed run left
    _command(["sfm", photos, "-o", folder, *job.spec["flags"]])
    print(summary_line(run_sfm(photos, folder, log=_say, progress=False, **options).report), flush=True)
    return {"sfm": _plain_values(json.loads(report.read_text()))}


def _plain_values(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if isinstance(v, (int, float, str))}


def _reconstruct(job: Job, out: Path) -> dict[str, Any]:
    from app.settings import reconstruct as settings
    from training.reconstruct.pipeline import reconstruct_to_folder
    from training.scene.fingerprint import dataset_fingerprint, difference

    folder = job_dir(out, job)
    report = folder / "report.json"
    data = data_path(out, job.spec)
    done = report.is_file() and (folder / "point_cloud.ply").is_file()
    if done:
        made = json.loads(report.read_text())
        if made.get("fingerprint"):
            changed = difference(made["fingerprint"], {"dataset": dataset_fingerprint(data)})
        else:  # from before fingerprints: the data's path is all there is to go by
            recorded = made.get("settings", {}).get("data")
            changed = None if recorded == str(data.resolve()) else f"data {data} now, {recorded} then"
        if changed:
            print(f"the reconstruction in {folder} was made from other data ({changed}): reconstructing again",
                  flush=True)
            (folder / "checkpoint.pt").unlink(missing_ok=True)
            done = False
    if not done:
        config = settings.config_from_args(parse_flags(settings.add_arguments, job.spec["flags"], "reconstruct flags"))
        # a killed grid continues where the reconstruction stopped, if it was of this data
        resume = (folder / "checkpoint.pt").is_file()
        _command(["reconstruct", data, "-o", folder, *job.spec["flags"], "--checkpoint-every", RECON_CHECKPOINT_EVERY]
                 + (["--resume", "--force"] if resume else []))
        reconstruct_to_folder(data, folder, config, resume=resume, force=True,
                              checkpoint_every=RECON_CHECKPOINT_EVERY, log=_say)
    r = json.loads(report.read_text())
    keys = ("test_psnr", "test_ssim", "test_lpips", "num_gaussians", "aniso_p95", "smax_p95", "seconds")
    return {"reconstruction": {k: r.get(k) for k in keys}, "model": str(folder / "point_cloud.ply")}


def _cell_made_from(spec: dict[str, Any], recon: Path, data: Path) -> dict[str, Any]:
    """What a cell reads: the scene's cameras, the reconstruction it stylizes, the painting (fingerprints)."""
    from training.scene.fingerprint import dataset_fingerprint, file_sha256

    model = recon / "point_cloud.ply"
    return {"dataset": dataset_fingerprint(data), "model": file_sha256(model) if model.is_file() else None,
            "painting": file_sha256(spec["painting_path"])}


def _cell(job: Job, out: Path) -> dict[str, Any]:
    folder = job_dir(out, job)
    report_path = folder / "report.json"
    recon = job_dir(out, job.spec["recon_job"])
    spec = job.spec
    spec_path = folder / "job.json"
    made = _cell_made_from(spec, recon, data_path(out, spec))
    fresh = False
    if report_path.is_file() and spec_path.is_file():
        recorded = json.loads(spec_path.read_text())
        # {"spec", "inputs"}; a bare spec from before inputs were recorded cannot be checked for them
        fresh = recorded == {"spec": spec, "inputs": made} or (
            recorded == spec and report_path.stat().st_mtime >= (recon / "point_cloud.ply").stat().st_mtime)
    if fresh and spec["method"] == "2d":  # its saved renders are 8-bit PNGs: measured again only by redoing it
        fresh = json.loads(report_path.read_text()).get("metrics_version") == METRICS_VERSION
    if not fresh:  # not run yet, interrupted, or run with other settings before the grid file changed
        if spec["method"] == "2d":
            from app.evaluate.baseline_cell import run_baseline_cell

            run_baseline_cell(recon / "point_cloud.ply", data_path(out, spec), Path(spec["painting_path"]), folder,
                              spec["flags"])
        else:
            from app.settings import stylize as settings
            from training.stylize.checkpoint import CHECKPOINT_NAME
            from training.stylize.pipeline import stylize_to_folder

            model, data = recon / "point_cloud.ply", data_path(out, spec)
            options = settings.stylize_options(parse_flags(settings.add_arguments, spec["flags"], "stylize flags"),
                                               model)
            # a grid stopped in this cell continues it when the checkpoint was made from the same inputs and
            # settings, and starts it afresh otherwise (--force)
            resume = (folder / CHECKPOINT_NAME).is_file()
            _command(["stylize", model, "--data", data, "--style", spec["painting_path"], "-o", folder, *spec["flags"]]
                     + (["--resume", "--force"] if resume else []))
            stylize_to_folder(model, data, Path(spec["painting_path"]), folder, log=_say, resume=resume, force=resume,
                              **options)
        with atomic_open(spec_path, "w") as f:
            json.dump({"spec": spec, "inputs": made}, f, indent=2)
    report = json.loads(report_path.read_text())
    if report.get("metrics_version") != METRICS_VERSION:
        # the metrics changed since this cell ran: measure its saved result again
        if spec["method"] == "2d":
            raise RuntimeError("unreachable: 2d cells are redone whole")
        from app.evaluate.remeasure import remeasure

        print(f"measuring again (metrics version {report.get('metrics_version')} -> {METRICS_VERSION})", flush=True)
        report["metrics"] = remeasure(folder / "point_cloud.ply", recon / "point_cloud.ply", data_path(out, spec),
                                      Path(spec["painting_path"]), spec["flags"])
        report["metrics_version"] = METRICS_VERSION
        with atomic_open(report_path, "w") as f:
            json.dump(report, f, indent=2, default=lambda v: None)
            f.write("\n")
    recon_report = json.loads((recon / "report.json").read_text())
    metrics = dict(report.get("metrics") or {})
    for key, value in (report.get("utilisation") or {}).items():
        metrics.setdefault(key, value)
    metrics["stylize_seconds"] = (report.get("time_s") or {}).get("total")
    metrics["iterations"] = report.get("iterations")
    metrics["step_match_agreement"] = report.get("step_match_agreement")
    for key in ("test_psnr", "test_ssim", "num_gaussians", "aniso_p95", "smax_p95"):
        metrics[f"recon_{key}"] = recon_report.get(key)
    if spec["method"] != "2d" and (folder / "point_cloud.ply").is_file():
        metrics.update(colour_shift(read_model(recon / "point_cloud.ply"), read_model(folder / "point_cloud.ply")))
    return {"metrics": metrics, "metrics_version": report.get("metrics_version"), "renders": report.get("renders", []),
            "folder": str(folder)}
