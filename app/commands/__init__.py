"""The subcommands, one module each (registered by app/cli.py), the flags every long command shares, and the
pipeline's long jobs as the console shows them.

A long command (minutes to hours of work) calls ``add_run_flags(parser, ...)`` so that ``--no-progress``,
``--debug`` and, where a stopped run can be continued, ``--resume`` are spelled, placed and explained the same way
everywhere, and its ``--help`` lists which of them it takes. ``reconstruct_in_console`` and ``stylize_in_console``
run the library's jobs (training/*/pipeline.py) with a progress bar, the time estimates and one-line messages, for
their commands and for the headless demo alike.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

# The commands that take add_run_flags's flags (tests/test_cli_conventions.py checks each one).
LONG_COMMANDS = ("reconstruct", "stylize", "sfm", "video", "eval", "demo")


def add_run_flags(parser: argparse.ArgumentParser, *, progress: str = "no progress bar",
                  resume: str | None = None, no_resume: str | None = None) -> argparse._ArgumentGroup:
    """Add the long commands' shared flags, in a group of their own: ``--no-progress`` (``progress`` says what it
    switches off), ``--debug`` and, when ``resume`` (its help) is given, ``--resume``; otherwise ``no_resume`` says
    in ``--help`` why a stopped run of this command is not continued. Returns the group."""
    taken = "--no-progress, --debug and --resume" if resume else "--no-progress and --debug"
    text = f"the flags the long commands ({', '.join(LONG_COMMANDS)}) share; this one takes {taken}"
    if not resume and no_resume:
        text += f" (no --resume: {no_resume})"
    # wrapped here: commands with RawDescriptionHelpFormatter print a group's text as given
    group = parser.add_argument_group("run options", textwrap.fill(text, 78))
    group.add_argument("--no-progress", action="store_true", help=progress)
    # SUPPRESS: `splatstyler --debug COMMAND` sets it before the command's parser runs, which must not reset it
    group.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                       help="show the full traceback of an error (also `splatstyler --debug COMMAND`)")
    if resume:
        group.add_argument("--resume", action="store_true", help=resume)
    return group


def warning(line: str) -> None:
    """A warning as the CLI says it: one line on stderr."""
    print(f"splatstyler: warning: {line}", file=sys.stderr)


def starting() -> None:
    """The imports a training command makes before its first step (torch, numba, the rasterizer, both trainers:
    seconds on a busy machine), made where a stop still ends the process at once: nothing is under way yet, and
    nothing checks for a stop inside an import (training/core/stop.py)."""
    from training.core import stop

    with stop.exit_at_once("while starting; nothing saved"):
        import torch._dynamo  # noqa: F401  (what torch.optim's first optimizer imports: seconds of its own)

        import training.reconstruct.trainer  # noqa: F401
        import training.stylize.trainer  # noqa: F401


def reconstruct_in_console(data, out, config, *, no_progress: bool = False, **options) -> dict:
    """``reconstruct_to_folder`` (training/reconstruct/pipeline.py; ``options`` are its keywords) with a progress
    bar, the run's lines and time estimates above it, warnings in one line, and the summary line at the end."""
    import warnings

    from app.progress import ProgressBar, say_above_bars
    from training.reconstruct.pipeline import reconstruct_to_folder, summary_line

    warnings.formatwarning = lambda message, category, filename, lineno, line=None: (
        f"splatstyler: warning: {message}\n")  # the trainer's warnings, as the CLI's other messages
    bar = ProgressBar(desc="reconstruct", disable=no_progress,
                      postfix={"loss": "loss", "psnr": "psnr", "num_gaussians": "n"})
    try:
        report = reconstruct_to_folder(data, out, config, listener=bar, log=say_above_bars, warn=warning, **options)
    finally:
        bar.close()
    print(summary_line(report, Path(out)), file=sys.stderr)
    return report


def stylize_in_console(model, data, style, out, *, no_progress: bool = False, **options) -> dict:
    """``stylize_to_folder`` (training/stylize/pipeline.py; ``options`` are its keywords) with a progress bar and
    the time estimates, and the lines that sum the result up at the end."""
    import time

    from app.progress import ProgressBar, say_above_bars
    from training.core.run_estimate import RunEstimate, UniformSteps
    from training.stylize.pipeline import stylize_to_folder

    t0 = time.perf_counter()
    # content/style: the norm of the content term's gradient on the render over the style term's (the balance)
    bar = ProgressBar(desc="stylizing", postfix={"loss": "loss", "style_loss": "style",
                                                  "content_to_style": "content/style", "trajectory_position": "view"},
                      disable=no_progress)
    # the steps cost the same throughout (fixed Gaussians and render size): timed, and timed again as the run goes
    estimate = RunEstimate(UniformSteps(), say=say_above_bars, what="stylization")

    def listener(event) -> None:
        bar(event)
        estimate(event)

    try:
        report = stylize_to_folder(Path(model), Path(data), Path(style), Path(out), listener=listener,
                                   log=lambda line: print(line, flush=True), warn=warning,
                                   report_extra=lambda: {"time_estimate": estimate.record()}, **options)
    finally:
        bar.close()
    print(f"stylized {report['num_views']} views in {report['iterations']} iterations "
          f"({time.perf_counter() - t0:.1f} s); wrote {out}")
    if report.get("metrics"):
        from training.evaluate.measure import summary_line

        print(summary_line(report["metrics"]))
    util = report.get("utilisation") or {}
    if "utilisation" in util:
        print(f"painting features used by the last plan: {util['utilisation']:.1%} (column entropy "
              f"{util.get('column_entropy_normalised', float('nan')):.2f} of its maximum)")
    return report
