"""``splatstyler bench gpu``: the whole pipeline on an NVIDIA GPU in one command, with no network.

On a machine where torch sees a CUDA device (the Python packages already installed, gsplat among them), it runs:

1. ``parity``: the cuda backend's parity tests against the reference rasterizer (tests/test_raster_cuda.py) and the
   CUDA display path's cases (the GL renderer's picture; CUDA-GL interop against the pinned copy) from
   tests/test_display_path.py, pytest in a subprocess, from a source checkout; a skipped case's reason is kept;
2. ``raster``: ``bench raster --backends cuda`` at 1920x1080 for each ``--ns`` (default 100k, 1M, 2M);
3. ``viewer``: ``bench viewer`` at 1920x1080 up to the largest N (every accumulation format and display path, and
   where a frame of the CUDA display path goes: raster, convert, transfer, draw and the frame, with the pinned copy
   and with CUDA-GL interop); ``display`` (not among the default steps): ``bench viewer --cuda-only``, the CUDA
   part of ``viewer`` alone, for a short lease;
4. ``reconstruct``: ``reconstruct --preset paper --backend cuda`` of ``--data`` (default: the demo's generated
   scene), with minutes, iterations/s, peak GPU memory (torch's allocator) and test PSNR;
5. ``stylize``: ``stylize --preset paper --backend cuda --device cuda`` of that reconstruction with ``--style``
   (default: the demo's painting), minutes, iterations/s and peak GPU memory, beside the paper's 8.35 minutes on
   an RTX 4090.

A step that fails is recorded with its error and the others still run. Writes OUT/bench_gpu.json (everything) and
OUT/bench_gpu.md (the tables). Without CUDA it says so in one line and exits with status 2.
"""

from __future__ import annotations

import argparse
import json
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

from app.bench import raster, viewer

ROOT = Path(__file__).resolve().parents[2]
STEPS = ("parity", "raster", "viewer", "display", "reconstruct", "stylize")
DEFAULT_STEPS = tuple(s for s in STEPS if s != "display")
PARITY_TESTS = ("tests/test_raster_cuda.py",
                "tests/test_display_path.py::test_cuda_path_draws_what_the_gl_renderer_draws[cuda]",
                "tests/test_display_path.py::test_cuda_interop_draws_what_the_pinned_copy_draws")
DEFAULT_NS = (100_000, 1_000_000, 2_000_000)
PAPER_STYLIZE_MINUTES = 8.35  # the paper's stylization time on an RTX 4090
JSON_NAME, MD_NAME = "bench_gpu.json", "bench_gpu.md"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", default="bench_gpu", metavar="OUT",
                        help="folder for bench_gpu.json, bench_gpu.md and the runs' outputs (default ./bench_gpu)")
    parser.add_argument("--data", default=None, metavar="DATA",
                        help="scene to reconstruct and stylize (default: the demo's generated scene)")
    parser.add_argument("--style", default=None, metavar="IMAGE", help="painting (default: the demo's)")
    parser.add_argument("--ns", default=None, help="comma-separated Gaussian counts (default 100k,1M,2M)")
    parser.add_argument("--size", default="1920x1080", help="image size of the raster and viewer benches")
    parser.add_argument("--steps", default=",".join(DEFAULT_STEPS),
                        help=f"comma-separated subset of {','.join(STEPS)} (default {','.join(DEFAULT_STEPS)}: the "
                             "viewer step includes the display step's figures)")
    parser.add_argument("--repeat", type=int, default=5, help="timed runs per raster/viewer figure")


def cuda_unavailable() -> str | None:
    """Why this machine cannot run the benchmark (one line), or None."""
    import torch

    if not torch.cuda.is_available():
        build = torch.version.cuda
        return ("bench gpu needs an NVIDIA GPU with CUDA, and torch sees none "
                + (f"(torch {torch.__version__} built for CUDA {build})" if build else
                   f"(torch {torch.__version__} is a CPU-only build; see docs/gpu.md)"))
    return None


def run(args: argparse.Namespace) -> list[dict]:
    from training.core.errors import InputError

    why = cuda_unavailable()
    if why is not None:
        raise InputError(None, why)  # the CLI prints it in one line and exits with status 2
    steps = [s.strip() for s in args.steps.split(",") if s.strip()]
    bad = [s for s in steps if s not in STEPS]
    if bad:
        raise InputError(None, f"--steps: unknown step {', '.join(bad)}; expected some of {', '.join(STEPS)}")
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    ns = [int(float(v)) for v in args.ns.split(",")] if args.ns else list(DEFAULT_NS)
    results = collect(out, steps, ns, args.size, args.repeat, data=args.data, style=args.style, backend="cuda")
    write_report(results, out)
    print(f"wrote {out / JSON_NAME} and {out / MD_NAME}", file=sys.stderr)
    return pipeline_rows(results)


# ---------------------------------------------------------------------------------------------------- the steps
def machine() -> dict:
    import torch

    info = {"python": platform.python_version(), "torch": torch.__version__, "torch_cuda": torch.version.cuda,
            "host": platform.node()}
    if torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(0)
        info["gpu_memory_gib"] = torch.cuda.get_device_properties(0).total_memory / 2**30
        try:
            smi = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                                 capture_output=True, text=True, timeout=30)
            info["driver"] = smi.stdout.strip().splitlines()[0] if smi.returncode == 0 else None
        except (OSError, subprocess.SubprocessError, IndexError):
            info["driver"] = None
    try:
        from cuda import bindings

        info["cuda_python"] = bindings.__version__
    except Exception as exc:  # not installed: the display path then has no CUDA-GL interop
        info["cuda_python"] = f"unavailable: {type(exc).__name__}: {exc}".splitlines()[0]
    try:
        import gsplat

        info["gsplat"] = gsplat.__version__
    except Exception as exc:  # not installed, or its CUDA extension cannot load: say which
        info["gsplat"] = f"unavailable: {type(exc).__name__}: {exc}".splitlines()[0]
    try:
        import moderngl

        from renderer_gl import create_context
        from renderer_gl.context import context_backend

        ctx = create_context("egl")
        info["gl"] = context_backend(ctx)
        info["gl_vendor"] = str(ctx.info.get("GL_VENDOR", "?"))
        info["moderngl"] = moderngl.__version__
        ctx.release()
    except Exception as exc:  # no EGL: the viewer step will fail and say so too
        info["gl"] = f"unavailable: {exc}".splitlines()[0]
    return info


def _step(name: str, fn) -> dict:
    t0 = time.perf_counter()
    print(f"bench gpu: {name} ...", file=sys.stderr, flush=True)
    try:
        result = {"step": name, "status": "ok", **fn()}
    except Exception as exc:  # one step's failure is a result to report, not the end of the run
        result = {"step": name, "status": "failed", "error": f"{type(exc).__name__}: {exc}".splitlines()[0]}
    result["seconds"] = time.perf_counter() - t0
    print(f"bench gpu: {name} {result['status']} ({result['seconds']:.0f} s)", file=sys.stderr, flush=True)
    return result


def parity_step(tests: tuple[str, ...] = PARITY_TESTS) -> dict:
    """pytest on ``tests`` (files or node ids) in a subprocess; the counts from its summary line and the reasons
    of skipped tests."""
    for test in tests:
        path = ROOT / test.split("::")[0]
        if not path.is_file():
            raise FileNotFoundError(f"{path} (bench gpu runs the parity tests from a source checkout)")
    cmd = [sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", *tests]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=3600)
    summary = (proc.stdout.strip().splitlines() or [""])[-1]
    counts = {k: int(v) for v, k in re.findall(r"(\d+) (passed|failed|skipped|error|errors)", summary)}
    status = "ok" if proc.returncode == 0 and counts.get("passed", 0) > 0 and not counts.get("skipped") else (
        "skipped" if proc.returncode in (0, 5) and not counts.get("passed") else "failed")
    skips = [line.split(" ", 2)[-1] for line in proc.stdout.splitlines() if line.startswith("SKIPPED ")]
    return {"status": status, "command": "python -m pytest -q " + " ".join(tests), "summary": summary,
            "passed": counts.get("passed", 0), "failed": counts.get("failed", 0),
            "skipped": counts.get("skipped", 0), "skip_reasons": skips, "returncode": proc.returncode}


def _bench_rows(module, argv: list[str]) -> list[dict]:
    """The rows of the benchmark ``module`` (app/bench) run with the flags ``argv``."""
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    return module.run(parser.parse_args(argv))


def raster_step(ns: list[int], size: str, repeat: int, backend: str = "cuda") -> dict:
    rows = []
    for n in ns:
        rows += _bench_rows(raster, ["--backends", backend, "--n", str(n), "--size", size,
                                                 "--repeat", str(repeat)])
    return {"command": f"splatstyler bench raster --backends {backend} --size {size} --n N", "rows": rows}


def viewer_step(ns: list[int], size: str, repeat: int) -> dict:
    argv = ["--n", ",".join(map(str, ns)), "--size", size, "--repeat", str(repeat), "--no-cpu",
            "--gpu-sort-max", str(max(ns))]
    return {"command": "splatstyler bench viewer " + " ".join(argv), "rows": _bench_rows(viewer, argv)}


def display_step(ns: list[int], size: str, repeat: int) -> dict:
    argv = ["--cuda-only", "--n", ",".join(map(str, ns)), "--size", size, "--repeat", str(repeat)]
    return {"command": "splatstyler bench viewer " + " ".join(argv), "rows": _bench_rows(viewer, argv)}


def _with_peak_memory(job, on_gpu: bool) -> tuple[dict, float | None]:
    """``job()`` (a pipeline's run, in this process), and torch's peak CUDA memory during it in GiB (None for a run
    on the CPU: 0 GiB would read as a measurement)."""
    import torch

    on_gpu = on_gpu and torch.cuda.is_available()
    if on_gpu:
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats()
    result = job()
    return result, torch.cuda.max_memory_allocated() / 2**30 if on_gpu else None


def _say(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def reconstruct_step(data: Path, out: Path, generated: bool, backend: str = "cuda", preset: str = "paper",
                     extra: list[str] | None = None) -> dict:
    """`splatstyler reconstruct DATA -o OUT --preset PRESET --backend BACKEND EXTRA`, run as the library's job."""
    from app.settings import parse_flags
    from app.settings import reconstruct as settings
    from training.reconstruct.pipeline import reconstruct_to_folder

    flags = ["--preset", preset, "--backend", backend] + (["--downscale", "1"] if generated else []) + list(extra or [])
    config = settings.config_from_args(parse_flags(settings.add_arguments, flags, "reconstruct flags"))
    report, peak = _with_peak_memory(lambda: reconstruct_to_folder(data, out, config, log=_say), backend == "cuda")
    seconds = float(report["seconds"])
    return {"command": f"splatstyler reconstruct {data} -o {out} " + " ".join(flags), "minutes": seconds / 60.0,
            "iterations": report["iterations"], "it_per_s": report["iterations"] / seconds if seconds else None,
            "peak_gpu_gib": peak, "test_psnr": report.get("test_psnr"), "num_gaussians": report["num_gaussians"],
            "image_size": report["settings"]["image_size"]}


def stylize_step(model: Path, data: Path, style: Path, out: Path, backend: str = "cuda", device: str = "cuda",
                 preset: str = "paper", extra: list[str] | None = None) -> dict:
    """`splatstyler stylize MODEL --data DATA --style STYLE -o OUT --preset PRESET ... EXTRA`, run as the library's
    job."""
    from app.settings import parse_flags
    from app.settings import stylize as settings
    from training.stylize.pipeline import stylize_to_folder

    flags = ["--preset", preset, "--backend", backend, "--device", device] + list(extra or [])
    options = settings.stylize_options(parse_flags(settings.add_arguments, flags, "stylize flags"), model)
    report, peak = _with_peak_memory(lambda: stylize_to_folder(model, data, style, out, log=_say, **options),
                                     device == "cuda")
    loop = float(report["time_s"]["stylize_loop"])
    return {"command": f"splatstyler stylize {model} --data {data} --style {style} -o {out} " + " ".join(flags),
            "minutes": loop / 60.0,
            "minutes_total": float(report["time_s"]["total"]) / 60.0, "iterations": report["iterations"],
            "it_per_s": report.get("iterations_per_second"), "peak_gpu_gib": peak,
            "num_gaussians": report["num_gaussians"], "render_size": report["render_size"],
            "paper_minutes_rtx4090": PAPER_STYLIZE_MINUTES}


def collect(out: Path, steps: list[str], ns: list[int], size: str, repeat: int, *, data=None, style=None,
            backend: str = "cuda", recon_extra: list[str] | None = None,
            stylize_extra: list[str] | None = None) -> dict:
    """Run ``steps`` and return everything ``write_report`` writes. ``backend`` "cpu" (with tiny sizes and
    ``*_extra`` flags) runs the same code on a CPU: that is how the tests feed the report writer real figures."""
    results: dict = {"machine": machine(), "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                     "argv": sys.argv[1:], "steps": []}
    generated = data is None
    if generated or style is None:
        from assets.demo.assets import demo_assets

        assets = demo_assets(progress=True)
    data = Path(data) if data is not None else assets.scene_dir
    style = Path(style) if style is not None else assets.style_image
    results["data"], results["style"] = str(data), str(style)
    device = "cuda" if backend == "cuda" else "cpu"
    for name in steps:
        if name == "parity":
            results["steps"].append(_step(name, parity_step))
        elif name == "raster":
            results["steps"].append(_step(name, lambda: raster_step(ns, size, repeat, backend)))
        elif name == "viewer":
            results["steps"].append(_step(name, lambda: viewer_step(ns, size, repeat)))
        elif name == "display":
            results["steps"].append(_step(name, lambda: display_step(ns, size, repeat)))
        elif name == "reconstruct":
            results["steps"].append(_step(name, lambda: reconstruct_step(
                data, out / "reconstruct", generated, backend, extra=recon_extra)))
        elif name == "stylize":
            model = out / "reconstruct" / "point_cloud.ply"
            results["steps"].append(_step(name, lambda: stylize_step(
                model, data, style, out / "stylize", backend, device, extra=stylize_extra)))
    results["finished"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    return results


# ---------------------------------------------------------------------------------------------------- the report
def pipeline_rows(results: dict) -> list[dict]:
    """One row per step, for the console table."""
    rows = []
    for s in results["steps"]:
        row = {"step": s["step"], "status": s["status"], "seconds": s["seconds"]}
        for key in ("minutes", "it_per_s", "peak_gpu_gib", "test_psnr", "summary", "error"):
            if s.get(key) is not None:
                row[key] = s[key]
        rows.append(row)
    return rows


def _fmt(v, spec: str = ".3g") -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return format(v, spec)
    return str(v)


def _table(header: list[str], rows: list[list]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + [
        "| " + " | ".join(_fmt(v) for v in r) + " |" for r in rows]


def markdown(results: dict) -> str:
    m = results["machine"]
    lines = [f"# splatstyler bench gpu ({results['started']})", "",
             f"GPU: {m.get('gpu', 'none')} ({_fmt(m.get('gpu_memory_gib'), '.0f')} GiB), driver "
             f"{_fmt(m.get('driver'))}; torch {m['torch']} (CUDA {_fmt(m.get('torch_cuda'))}); gsplat "
             f"{_fmt(m.get('gsplat'))}; cuda-python {_fmt(m.get('cuda_python'))}; GL: {_fmt(m.get('gl'))} "
             f"({_fmt(m.get('gl_vendor'))}); Python {m['python']}.",
             f"Scene: {results['data']}; painting: {results['style']}.", ""]
    steps = {s["step"]: s for s in results["steps"]}
    failed = [s for s in results["steps"] if s["status"] == "failed"]
    if failed:
        lines += ["## Failed steps", ""] + [f"- {s['step']}: {s['error']}" for s in failed] + [""]
    if "parity" in steps:
        p = steps["parity"]
        lines += ["## CUDA parity tests", "", f"`{p.get('command', '')}`: {p['status']}: {p.get('summary', '')}", ""]
        lines += [f"- skipped: {reason}" for reason in p.get("skip_reasons", [])] + (
            [""] if p.get("skip_reasons") else [])
    if steps.get("raster", {}).get("rows"):
        r = steps["raster"]
        lines += ["## Rasterizer (ms)", "", f"`{r['command']}`", ""]
        lines += _table(["backend", "splats", "size", "forward", "forward + backward", "peak RSS MiB"],
                        [[x["backend"], x["n"], f"{x['width']}x{x['height']}", x["fwd_ms"], x["fwdbwd_ms"],
                          x.get("peak_rss_mb")] for x in r["rows"]]) + [""]
    if steps.get("viewer", {}).get("rows"):
        v = steps["viewer"]
        rows = v["rows"]
        paths = sorted({k for x in rows for k in x if k.startswith("path_")})
        lines += ["## Viewer (ms a frame)", "", f"`{v['command']}`", "",
                  "Frame columns: camera still, no sort. Path columns: a turning camera, sort included.", ""]
        lines += _table(["splats", "f4", "f2", "f1 (dithered)", "f1", "half res", "sort + upload", "GPU sort"]
                        + [p[5:-3] for p in paths] + ["chosen path"],
                        [[x["n"], x.get("frame_ms"), x.get("frame_f2_ms"), x.get("frame_f1_ms"),
                          x.get("frame_f1_plain_ms"), x.get("frame_half_ms"), x.get("sort_upload_ms"),
                          x.get("gpu_sort_ms")] + [x.get(p) for p in paths] + [x.get("display_path")]
                         for x in rows]) + [""]
    lines += breakdown_markdown(steps)
    pipeline = [steps[k] for k in ("reconstruct", "stylize") if k in steps]
    if pipeline:
        lines += ["## Pipeline", ""]
        lines += _table(["step", "status", "minutes", "it/s", "peak GPU GiB", "test PSNR dB", "splats", "paper"],
                        [[s["step"], s["status"], s.get("minutes"), s.get("it_per_s"), s.get("peak_gpu_gib"),
                          s.get("test_psnr"), s.get("num_gaussians"),
                          f"{PAPER_STYLIZE_MINUTES} min (RTX 4090)" if s["step"] == "stylize" else None]
                         for s in pipeline]) + [""]
        lines += [f"- {s['step']}: `{s['command']}`" for s in pipeline if s.get("command")] + [""]
    return "\n".join(lines)


def breakdown_markdown(steps: dict) -> list[str]:
    """The CUDA display path's frame breakdown (app/bench/cuda_frame.py) from the display step's rows, or the
    viewer step's where there is no display step."""
    from app.bench.cuda_frame import STAGES, TRANSFERS

    source = next((steps[k] for k in ("display", "viewer") if steps.get(k, {}).get("rows")), None)
    if source is None:
        return []
    rows = source["rows"]
    lines = ["## Where a frame of the CUDA display path goes (ms)", "", f"`{source['command']}`", "",
             "Stages: each timed with a wait after it (their sum exceeds the frame by what the waits cost). "
             "Frame: as the viewer draws it, then glFinish.", ""]
    table, notes = [], []
    for x in rows:
        if x.get("cuda_breakdown_skipped"):
            notes.append(f"- {x['n']} splats: not measured: {x['cuda_breakdown_skipped']}")
            continue
        for t in TRANSFERS:
            if f"cuda_{t}_frame_ms" in x:
                frame = x[f"cuda_{t}_frame_ms"]
                table.append([x["n"], f"{x['width']}x{x['height']}", t] + [x[f"cuda_{t}_{s}_ms"] for s in STAGES]
                             + [x[f"cuda_{t}_stages_ms"], frame, 1000.0 / frame if frame > 0 else None])
            if x.get(f"cuda_{t}_skipped"):
                notes.append(f"- {x['n']} splats, {t}: not measured: {x[f'cuda_{t}_skipped']}")
    if table:
        lines += _table(["splats", "size", "transfer", *STAGES, "sum of stages", "frame", "fps"], table) + [""]
    return lines + notes + ([""] if notes else [])


def write_report(results: dict, out: Path) -> tuple[Path, Path]:
    """OUT/bench_gpu.json and OUT/bench_gpu.md, each written atomically."""
    from training.core.atomic_write import atomic_open

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_open(out / JSON_NAME, "w") as f:
        json.dump(results, f, indent=2, default=str)
    with atomic_open(out / MD_NAME, "w") as f:
        f.write(markdown(results))
    return out / JSON_NAME, out / MD_NAME
