"""Tests that need a system library or program skip, when it is missing, with the reason and the Debian/Ubuntu
package that provides it (``.ci/run`` installs them all, so CI runs every test); conftest's summary lists them at
the end of the run, so a first run on a fresh machine says what to install instead of failing."""

from __future__ import annotations

import ctypes
import ctypes.util
import shutil

import pytest

APT_HINT = "apt-get install"  # every such skip reason contains it: the summary finds them by it


def missing_library(name: str, apt: str, sonames: tuple[str, ...] = ()) -> str:
    """'' when the shared library loads, else the skip reason."""
    for soname in (*sonames, ctypes.util.find_library(name)):
        if not soname:
            continue
        try:
            ctypes.CDLL(soname)
            return ""
        except OSError:
            continue
    return f"lib{name} not found (Debian/Ubuntu: {APT_HINT} {apt})"


def missing_program(name: str, apt: str) -> str:
    return "" if shutil.which(name) else f"{name} not found (Debian/Ubuntu: {APT_HINT} {apt})"


def requires_library(name: str, apt: str, sonames: tuple[str, ...] = ()):
    reason = missing_library(name, apt, sonames)
    return pytest.mark.skipif(bool(reason), reason=reason or "present")


def requires_program(name: str, apt: str):
    reason = missing_program(name, apt)
    return pytest.mark.skipif(bool(reason), reason=reason or "present")
