"""The installed splatstyler's version, as ``splatstyler --version`` prints it and every report.json records it
(``"splatstyler_version"``): a result read months later says which code made it."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path


@lru_cache(maxsize=1)
def version() -> str:
    """The package's version from its installed metadata; from pyproject.toml when run from a checkout that was
    never installed."""
    from importlib.metadata import PackageNotFoundError, version as installed

    try:
        return installed("splatstyler")
    except PackageNotFoundError:
        import tomllib

        pyproject = Path(__file__).resolve().parents[2] / "pyproject.toml"
        return tomllib.loads(pyproject.read_text())["project"]["version"]
