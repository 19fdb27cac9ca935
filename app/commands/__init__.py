"""The subcommands, one module each (registered by app/cli.py), and the flags every long command shares.

A long command (minutes to hours of work) calls ``add_run_flags(parser, ...)`` so that ``--no-progress``,
``--debug`` and, where a stopped run can be continued, ``--resume`` are spelled, placed and explained the same way
everywhere, and its ``--help`` lists which of them it takes.
"""

from __future__ import annotations

import argparse
import textwrap

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
