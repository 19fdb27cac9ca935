"""The one exception type for bad user input.

The CLI prints ``str(error)`` as a single line and exits non-zero, so the message must name the file and the
problem on its own (``InputError(path, "problem")`` renders as ``path: problem``).
"""

from __future__ import annotations

from pathlib import Path


class InputError(Exception):
    """A problem with something the user gave us (a file, a folder, an option), reported in one line."""

    def __init__(self, path: str | Path | None, problem: str):
        self.path = None if path is None else Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}" if self.path is not None else problem)
