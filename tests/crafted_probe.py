"""Crafted files through the real console command, as a user runs it: each command in its own process under an
address-space limit, its exit code, its error line and its peak memory checked against the one-line rule.

The rule (docs/editor.md, "Reading model files"): a file that cannot be read is one line on stderr,
``splatstyler: error: ...`` naming the file (and, for a project, the member), exit 2, no traceback, and reading it
takes memory in proportion to the file, not to what its header declares: under ``ADDRESS_SPACE`` a reader that
trusts a declared size dies of a MemoryError (exit 1) instead of refusing the file.

A test module lists its cases (``Case``: a name, a function writing the file, the kind of input it is) and runs
each through ``check_case``; the kind says which commands read it (``COMMANDS``), so a case for another format is
one entry in a list.

Each command's process is forked from a server that has already imported what ``python -m app`` imports before it
opens a file (the CLI, torch and the model readers): about 4 s of imports a probe, once instead of some 45 times.
The child then runs what ``python -m app ARGV`` runs (``app.cli.main``) in its own working directory, under the
address-space limit, its stdout and stderr in files: its exit code, its output and its peak resident memory (wait4's,
which counts the imported modules' pages as a fresh process's does) are those of the command.
"""

from __future__ import annotations

import atexit
import json
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
# What its resident memory may reach: 1 GB for a fresh process, whose own baseline (imports) peaks at 0.32 GB; a
# child of the probe server starts from the server's 0.26 GB and skips the imports' transient 64 MB, so its bound is
# lower by those 64 MB: the same room for what reading the file takes.
PEAK_RSS = (1 << 30) - (64 << 20)

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
    """``splatstyler ARGV`` in its own process under ADDRESS_SPACE (forked from the probe server); its own peak
    resident memory (wait4's)."""
    with tempfile.NamedTemporaryFile("w+", suffix=".out") as out, \
            tempfile.NamedTemporaryFile("w+", suffix=".err") as err:
        reply = _server().ask({"argv": list(argv), "cwd": str(cwd), "stdout": out.name, "stderr": err.name,
                               "timeout": timeout})
        assert not reply["timed_out"], f"splatstyler {' '.join(argv)} ran past {timeout:.0f} s"
        return Probe(list(argv), reply["code"], Path(out.name).read_text(), Path(err.name).read_text(),
                      reply["maxrss_kb"] * 1024)


class _Server:
    """The probe server's process: one request (a JSON line) in, one reply out, each request a forked child."""

    def __init__(self):
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen([sys.executable, "-c", "from tests.crafted_probe import serve; serve()"],
                                     cwd=ROOT, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.lock = threading.Lock()

    def ask(self, request: dict) -> dict:
        with self.lock:
            self.proc.stdin.write(json.dumps(request) + "\n")
            self.proc.stdin.flush()
            line = self.proc.stdout.readline()
        assert line, f"the probe server ended (exit {self.proc.poll()})"
        return json.loads(line)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()


_SERVER: list[_Server] = []


def _server() -> _Server:
    if not _SERVER or _SERVER[0].proc.poll() is not None:
        _SERVER[:] = [_Server()]
        atexit.register(_SERVER[0].close)
    return _SERVER[0]


def serve() -> None:
    """The probe server: imports what every command imports before it reads a file, then forks a child per request
    that runs ``app.cli.main(argv)`` as ``python -m app`` would, under ADDRESS_SPACE. No thread is started here
    before a fork (torch starts its pools on first use, which is in the children)."""
    import signal
    import time
    import traceback

    import app.cli
    import training.model.model_io  # noqa: F401  (torch and the readers: what every probed command imports first)

    replies = sys.stdout
    for line in sys.stdin:
        request = json.loads(line)
        pid = os.fork()
        if pid == 0:
            code = 1
            try:
                os.chdir(request["cwd"])
                signal.signal(signal.SIGPIPE, signal.SIG_DFL)
                for fd, path in ((1, request["stdout"]), (2, request["stderr"])):
                    target = os.open(path, os.O_WRONLY | os.O_TRUNC)
                    os.dup2(target, fd)
                    os.close(target)
                sys.stdin = open(os.devnull)
                resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))
                sys.argv = [str(Path(app.cli.__file__).with_name("__main__.py")), *request["argv"]]
                try:
                    code = app.cli.main(request["argv"])
                except SystemExit as exit_:  # as the interpreter ends on it
                    if isinstance(exit_.code, int) or exit_.code is None:
                        code = exit_.code or 0
                    else:
                        print(exit_.code, file=sys.stderr)
                        code = 1
                except BaseException:  # noqa: BLE001  (an uncaught error: its traceback and exit 1, as python does)
                    traceback.print_exc()
                    code = 1
            finally:
                for stream in (sys.stdout, sys.stderr):
                    try:
                        stream.flush()
                    except BaseException:  # noqa: BLE001
                        pass
                os._exit(code if isinstance(code, int) else 1)
        deadline = time.monotonic() + request["timeout"]
        timed_out = False
        while True:
            done, status, usage = os.wait4(pid, os.WNOHANG)
            if done:
                break
            if time.monotonic() > deadline:
                os.kill(pid, signal.SIGKILL)
                timed_out = True
                _, status, usage = os.wait4(pid, 0)
                break
            time.sleep(0.005)
        replies.write(json.dumps({"code": os.waitstatus_to_exitcode(status), "maxrss_kb": usage.ru_maxrss,
                                  "timed_out": timed_out}) + "\n")
        replies.flush()


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
