"""The settings of the pipeline's jobs as command-line flags, one module per job (``sfm``, ``reconstruct``,
``stylize``): each adds the job's flags to a parser and turns the parsed flags into what the job's library function
takes. The commands (app/commands) parse them from the command line; the evaluation (app/evaluate) and the GPU
benchmark read back the flag lists a grid records, or their own, with ``parse_flags``."""

from __future__ import annotations

import argparse
from typing import Callable, Sequence

from training.core.errors import InputError


class _FlagParser(argparse.ArgumentParser):
    """A parser whose complaint is an InputError (one line, exit 2 in the CLI) instead of a usage text and exit."""

    def error(self, message: str):
        raise InputError(None, f"{self.prog}: {message}")


def parse_flags(add_arguments: Callable[[argparse.ArgumentParser], None], flags: Sequence[str],
                what: str) -> argparse.Namespace:
    """The settings ``flags`` (e.g. a grid's ``["--preset", "quick", "--tau", "10"]``) give, parsed by the parser
    ``add_arguments`` builds; InputError naming ``what`` (e.g. "stylize flags") for a flag it does not take."""
    parser = _FlagParser(prog=what, add_help=False)
    add_arguments(parser)
    return parser.parse_args(list(flags))
