"""The ``splatstyler`` console command: one parser, one module per subcommand in ``app/commands``, registered here
and nowhere else. Nothing of the product imports this module but ``python -m app`` (app/__main__.py) and the
console script (tests/test_import_layers.py checks; tests may): what a command does is a library function
(training/*/pipeline.py, app/settings, ...) the command only puts a face on.

Each command module has ``register(subparsers)``, which adds its parser and sets ``func`` to a function taking the
parsed arguments and returning an exit code. Modules import their heavy dependencies inside that function so that
``--help`` stays fast.

``main`` puts the stop handlers in (app/stop_signals.py) before it imports the commands: a SIGTERM or Ctrl-C from
then on is a stop that saves, and only the interpreter's own start (about 0.1 s) precedes it.
"""

from __future__ import annotations

import argparse
import re
import sys



def build_parser() -> argparse.ArgumentParser:
    from app.commands import bench, crop, demo, export, info, reconstruct, render, sfm, stylize, video, view
    from app.commands import eval as evaluate

    parser = argparse.ArgumentParser(
        prog="splatstyler",
        description="Reconstruct a scene as 3D Gaussians from photos and stylize it after a painting.",
    )
    from training.core.version import version

    parser.add_argument("--version", action="version", version=f"splatstyler {version()}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    # the order of `splatstyler --help`
    for command in (demo, view, sfm, info, reconstruct, stylize, evaluate, export, crop, render, video, bench):
        command.register(sub)
    return parser


# Options whose value is a comma list of numbers: "-0.18,..." after one of them is its value, which argparse would
# otherwise take for an option (negative coordinates are the common case for a crop box).
NUMBER_LIST_OPTIONS = ("--box", "--sphere", "--background")


def join_negative_values(argv: list[str]) -> list[str]:
    """["--box", "-1,0,0,1,1,1"] -> ["--box=-1,0,0,1,1,1"]."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in NUMBER_LIST_OPTIONS and i + 1 < len(argv) and re.match(r"^-[\d.]", argv[i + 1]):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def entry() -> None:
    """The console command: ``main``, and then the process's end without the interpreter's teardown. That teardown
    collects torch's objects module by module, 2-3 s on a busy 2-core machine after the command has finished (or a
    stop has saved), which a user waits out for nothing; the exit handlers (temporary files, worker pools) still
    run, and threads still running are waited for, as a normal exit does."""
    import atexit
    import os
    import threading

    code = main()
    for thread in threading.enumerate():
        if thread is not threading.main_thread() and not thread.daemon:
            thread.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a reader that left (a pipe), a stream closed
            pass
    os._exit(code)


def main(argv: list[str] | None = None) -> int:
    from app import stop_signals

    restore_signals = stop_signals.install()
    try:
        return _run(sys.argv[1:] if argv is None else list(argv))
    finally:
        restore_signals()


def _run(argv: list[str]) -> int:
    from app import stop_signals
    from training.core import stop
    from training.core.errors import InputError

    try:
        with stop.exit_at_once("while starting; nothing saved"):  # the commands' modules import torch: seconds
            parser = build_parser()
    except KeyboardInterrupt as stopped:
        print(f"splatstyler: stopped by {stop_signals.signal_name()} {stopped}", file=sys.stderr)
        return stop_signals.exit_code()
    args = parser.parse_args(join_negative_values(argv))
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        code = int(args.func(args) or 0)
        if stop.requested():  # asked to stop after the last place that checks: the command had done its work
            print(f"splatstyler: stopped by {stop_signals.signal_name()} as the command finished (its outputs are "
                  "complete)", file=sys.stderr)
            return stop_signals.exit_code()
        return code
    except KeyboardInterrupt as stopped:  # its text, if any, says where the run stopped and what was kept
        print(f"splatstyler: stopped by {stop_signals.signal_name()} {stopped}".rstrip(), file=sys.stderr)
        return stop_signals.exit_code()
    except InputError as exc:
        if args.debug:
            raise
        print(f"splatstyler: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `splatstyler eval --list | head`: the reader left, as with any Unix tool say nothing
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit's flush
        return 141  # 128 + SIGPIPE, what a shell reports for a tool the pipe's reader left
    except Exception as exc:  # an unexpected failure still gets one readable line
        if stop.requested():
            return _stopped(stop_signals, exc, args.debug)
        if args.debug:
            raise
        print(f"splatstyler: error: {type(exc).__name__}: {exc} (run with --debug for the traceback)", file=sys.stderr)
        return 1


def _stopped(stop_signals, exc: Exception, debug: bool) -> int:
    """An error that surfaced after a stop was asked for (a library turned the interrupt into one of its own): the
    stop's line and exit status, the error said after it (its traceback with --debug)."""
    if debug:
        import traceback

        traceback.print_exception(exc)
    print(f"splatstyler: stopped by {stop_signals.signal_name()} (what was under way ended with "
          f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})".replace(": )", ")"),
          file=sys.stderr)
    return stop_signals.exit_code()


if __name__ == "__main__":
    entry()
