"""Crafted files through the real console command, as a user runs it: each command in its own process under an
address-space limit, its exit code, its error line and its peak memory checked against the one-line rule.

The rule (docs/editor.md, "Reading model files"): a file that cannot be read is one line on stderr,
``splatstyler: error: ...`` naming the file (and, for a project, the member), exit 2, no traceback, and reading it
takes memory in proportion to the file, not to what its header declares: under ``ADDRESS_SPACE`` a reader that
trusts a declared size dies of a MemoryError (exit 1) instead of refusing the file.

A test module lists its cases (``Case``: a name, a function writing the file, the kind of input it is) and runs
each through ``check_case``; the kind says which commands read it (``COMMANDS``), so a case for another format is
one entry in a list.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
ADDRESS_SPACE = 1536 << 20  # RLIMIT_AS of each command: the bound on a file under 20 MB
PEAK_RSS = 1 << 30  # and what its resident memory may reach (the commands' own baseline is about 0.3 GB)

# The commands that read each kind of input; {file} is the crafted file, {model} a small valid model, {out} a
# path in the test's folder for what a command would write (nothing is, as every probe fails).
COMMANDS: dict[str, list[list[str]]] = {
    "model": [["info", "{file}"], ["export", "{file}", "-o", "{out}.ply"]],
    "mask": [["export", "{model}", "--mask", "{file}", "-o", "{out}.ply"]],
    "project": [["export", "--project", "{file}", "-o", "{out}.ply"]],
    "camera path": [["video", "{model}", "--path", "{file}", "-o", "{out}.mp4"]],
}


@dataclass(frozen=True)
class Case:
    """One crafted file: ``make(path)`` writes it (``path`` has no suffix; it returns the file it wrote). ``kind``
    picks the commands; ``commands`` replaces them (a file only one command refuses); ``names`` are further words
    the error line must hold (a project's member)."""

    name: str
    kind: str
    make: Callable[[Path], Path]
    commands: tuple[tuple[str, ...], ...] | None = None
    names: tuple[str, ...] = ()

    def __str__(self) -> str:
        return self.name


@dataclass(frozen=True)
class Probe:
    argv: list[str]
    code: int
    stdout: str
    stderr: str
    peak_rss: int  # bytes


def run_probe(argv: list[str], cwd: Path, timeout: float = 300.0) -> Probe:
    """``splatstyler ARGV`` in its own process under ADDRESS_SPACE; its own peak resident memory (wait4's)."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen([sys.executable, "-m", "app", *argv], cwd=cwd, env=env, preexec_fn=limit,
                                stdout=out, stderr=err, text=True)
        timer = threading.Timer(timeout, proc.kill)
        timer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        finally:
            timer.cancel()
        proc.returncode = code = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait again
        assert code != -9, f"splatstyler {' '.join(argv)} ran past {timeout:.0f} s"
        out.seek(0)
        err.seek(0)
        return Probe(list(argv), code, out.read(), err.read(), usage.ru_maxrss * 1024)


def check_one_line(probe: Probe, file: Path, names: tuple[str, ...] = ()) -> None:
    """Exit 2, one ``splatstyler: error:`` line naming the file (and ``names``), no traceback, memory bounded."""
    what = f"splatstyler {' '.join(probe.argv)}"
    lines = probe.stderr.strip().splitlines()
    assert probe.code == 2, f"{what}: exit {probe.code}, not 2\n{probe.stderr[-3000:]}"
    assert len(lines) == 1 and lines[0].startswith("splatstyler: error: "), f"{what}: not one line\n{probe.stderr}"
    assert "Traceback" not in probe.stderr and "MemoryError" not in probe.stderr, f"{what}: {probe.stderr}"
    assert file.name in lines[0], f"{what}: the line does not name {file.name}: {lines[0]}"
    for name in names:
        assert name in lines[0], f"{what}: the line does not name {name}: {lines[0]}"
    assert probe.peak_rss < PEAK_RSS, f"{what}: {probe.peak_rss / 1e9:.2f} GB resident"


def check_case(case: Case, folder: Path, model: Path) -> list[Probe]:
    """Write the case's file in ``folder`` and run each of its commands on it; returns the probes (all passed)."""
    file = case.make(folder / case.name.replace(" ", "_"))
    probes = []
    for i, template in enumerate(case.commands or COMMANDS[case.kind]):
        argv = [a.format(file=file, model=model, out=folder / f"out{i}") for a in template]
        probe = run_probe(argv, folder)
        check_one_line(probe, file, case.names)
        probes.append(probe)
    leftovers = sorted(p.name for p in folder.iterdir() if p.name.startswith("out"))
    assert not leftovers, f"{case}: a refused input left {leftovers}"
    return probes
