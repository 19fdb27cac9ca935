"""Where splatstyler keeps things it can rebuild: converted weights, generated demo assets."""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir(*parts: str) -> Path:
    """``$SPLATSTYLER_CACHE`` or ``$XDG_CACHE_HOME/splatstyler`` (``~/.cache/splatstyler``), joined with parts."""
    root = os.environ.get("SPLATSTYLER_CACHE")
    if not root:
        xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        root = str(Path(xdg) / "splatstyler")
    path = Path(root).joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path
