"""The ``splatstyler`` console command: one parser, one module per subcommand in ``app/commands``, registered here
and nowhere else. Nothing of the product imports this module but ``python -m app`` (app/__main__.py) and the
console script (tests/test_import_layers.py checks; tests may): what a command does is a library function
(training/*/pipeline.py, app/settings, ...) the command only puts a face on.

Each command module has ``register(subparsers)``, which adds its parser and sets ``func`` to a function taking the
parsed arguments and returning an exit code. Modules import their heavy dependencies inside that function so that
``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import re
import sys

from app.commands import bench, crop, demo, export, info, reconstruct, render, sfm, stylize, video, view
from app.commands import eval as evaluate

# Order here is the order in `splatstyler --help`.
COMMANDS = (demo, view, sfm, info, reconstruct, stylize, evaluate, export, crop, render, video, bench)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="splatstyler",
        description="Reconstruct a scene as 3D Gaussians from photos and stylize it after a painting.",
    )
    from training.core.version import version

    parser.add_argument("--version", action="version", version=f"splatstyler {version()}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in COMMANDS:
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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(join_negative_values(sys.argv[1:] if argv is None else list(argv)))
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from app import stop_signals
    from training.core.errors import InputError

    restore_signals = stop_signals.install()
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt as stop:  # its text, if any, says where the run stopped and what was kept
        print(f"splatstyler: stopped by {stop_signals.signal_name()} {stop}".rstrip(), file=sys.stderr)
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
        if args.debug:
            raise
        print(f"splatstyler: error: {type(exc).__name__}: {exc} (run with --debug for the traceback)", file=sys.stderr)
        return 1
    finally:
        restore_signals()


if __name__ == "__main__":
    sys.exit(main())
