"""Every test runs under a fixed random seed of its own, so a failure seen once (in CI) can be seen again.

A test's seed is ``zlib.crc32(node id, base)``: the same in every run, on every machine, whatever else runs before
it. The base is 0 unless ``SPLATSTYLER_TEST_SEED`` says otherwise: ``random`` draws a fresh base for the run (to
look for seed-dependent failures), an integer sets it (to replay such a run). The seed is applied to ``random``,
numpy's and torch's global generators before each test, and before each module's fixtures; it is printed (pytest
shows it under "Captured stdout setup" for a failing test, and for every test with ``-rA``) and recorded as the
``random_seed`` property in JUnit XML. Tests that make their own generators with fixed seeds keep them.
"""

from __future__ import annotations

import os
import random
import secrets
import zlib

import numpy as np
import pytest

import training  # noqa: F401  (first: it sets OMP_WAIT_POLICY before torch loads OpenMP; see training/__init__.py)
import torch

SEED_ENV = "SPLATSTYLER_TEST_SEED"


def _base_seed() -> int:
    value = os.environ.get(SEED_ENV, "").strip()
    if not value:
        return 0
    if value.lower() == "random":
        return secrets.randbits(32)
    try:
        return int(value) % 2**32
    except ValueError:
        raise pytest.UsageError(f"{SEED_ENV} must be 'random' or an integer, got {value!r}") from None


def pytest_configure(config):
    # Drawn once per run: a random base must be the same for every test and module of the run, or the printed
    # base would not replay it.
    config._splatstyler_seed_base = _base_seed()


def pytest_report_header(config):
    base = config._splatstyler_seed_base
    how = "fixed" if not os.environ.get(SEED_ENV, "").strip() else f"from {SEED_ENV}"
    return (f"random seeds: crc32(test node id, base {base}) ({how}); "
            f"{SEED_ENV}={base} replays this run, {SEED_ENV}=random draws a new base")


def node_seed(config, nodeid: str) -> int:
    return zlib.crc32(nodeid.encode(), config._splatstyler_seed_base)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)  # every CUDA device too


@pytest.fixture(scope="module", autouse=True)
def _seed_module(request):
    """Module-scoped fixtures run before any test's seed is set: give them a fixed one of their module's."""
    seed_everything(node_seed(request.config, request.node.nodeid))


@pytest.fixture(autouse=True)
def _seed_test(request, record_property):
    base = request.config._splatstyler_seed_base
    seed = node_seed(request.config, request.node.nodeid)
    seed_everything(seed)
    record_property("random_seed", seed)
    print(f"random seed {seed} (node id with base {base}; rerun with {SEED_ENV}={base} to reproduce)")


@pytest.fixture(scope="session")
def vgg():
    """The stylizer's VGG-16 features, loaded once for the whole run (frozen, eval mode: tests share it safely);
    tests that need it skip when no weights can be had."""
    from training.core.errors import InputError
    from training.stylize.vgg_features import load_vgg16_features

    try:
        return load_vgg16_features()
    except InputError as exc:  # no cached weights and no registry to fetch them from
        pytest.skip(f"VGG-16 weights unavailable: {exc}")


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """At the very end: the tests skipped because a system package is missing, and what to install."""
    from tests.system_deps import APT_HINT

    reasons: dict[str, int] = {}
    for report in terminalreporter.stats.get("skipped", []):
        longrepr = report.longrepr
        reason = longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else str(longrepr)
        reason = reason.removeprefix("Skipped: ")
        if APT_HINT in reason:
            reasons[reason] = reasons.get(reason, 0) + 1
    if reasons:
        terminalreporter.section("skipped for a missing system package")
        for reason, count in sorted(reasons.items()):
            terminalreporter.write_line(f"{count} test(s): {reason}")
