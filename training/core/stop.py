"""A stop the user asked for (Ctrl-C, SIGTERM, the window's close), recorded where it arrives and raised only where
the work can stop: between two units of work that a loop owns (a training step, a view rendered, a frame written,
a grid job), from Python code.

Why not raise from the signal handler: Python runs a handler between two bytecodes of the main thread, and an
exception raised there lands wherever that is, inside a C extension's call protocol too. Raised while numba's
dispatcher was returning, it became ``SystemError: ... returned a result with an exception set`` (no checkpoint,
exit 1); raised in a finalizer (llvmlite's ``ObjectRef.__del__``) it was printed and dropped. A recorded request
cannot be lost either way.

Two sources, one question (``requested``): the process's signal (``request``, from app/stop_signals.py), seen by
every thread; and a predicate a thread puts in force for itself (``watching``: the viewer's training thread
watches its session's Stop). ``check()`` raises ``StopRequested`` when either says stop.

``StopRequested`` is a KeyboardInterrupt, so every path that keeps the work on Ctrl-C keeps it here too.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Callable, Iterator


class StopRequested(KeyboardInterrupt):
    """Raised by ``check()`` at a unit-of-work boundary once a stop was asked for."""


_signals: list[int] = []
_local = threading.local()
_exit_at_once: list[str] = []  # while not empty: a stop ends the process at once, saying this line


def handle_signal(signum: int, _frame=None) -> None:
    """The handler a command puts in for SIGTERM and SIGINT (app/stop_signals.py): records the stop, or, inside
    ``exit_at_once``, ends the process there and then."""
    request(signum)
    if _exit_at_once:
        import os

        os.write(2, f"splatstyler: stopped by {signal.Signals(signum).name} {_exit_at_once[-1]}\n".encode())
        os._exit(128 + signum)


@contextmanager
def exit_at_once(line: str) -> Iterator[None]:
    """While inside, a signal ends the process at once with ``line`` (after "stopped by SIGTERM"): for work that
    keeps nothing and checks nowhere (importing torch, seconds on a busy machine), which a recorded stop would
    otherwise wait out. A stop recorded before the block is seen at its end."""
    if requested():  # asked for before the block: as soon as the block would begin
        raise StopRequested(line)
    _exit_at_once.append(line)
    try:
        yield
    finally:
        _exit_at_once.pop()
    if requested():
        raise StopRequested(line)


def request(signum: int = signal.SIGINT) -> bool:
    """Record a stop (a signal handler calls this, and nothing else); True for the first request, False for a later
    one (which changes nothing: the save the first one started must finish)."""
    if _signals:
        return False
    _signals.append(int(signum))
    return True


def reset() -> None:
    """Forget the process's request (a command starting in a process that ran one before: a test)."""
    _signals.clear()


def signal_number() -> int | None:
    """The signal that asked the process to stop, or None."""
    return _signals[0] if _signals else None


def requested() -> bool:
    """Has a stop been asked for, of the process or of this thread's watched work? Cheap: call it often. False on a
    thread inside ``saving``: the save a stop started is not stopped."""
    if getattr(_local, "saving", 0):
        return False
    if _signals:
        return True
    watched = getattr(_local, "predicates", None)
    return bool(watched) and any(p() for p in watched)


def current() -> Callable[[], bool]:
    """``requested`` as this thread sees it now, to be asked from another thread (one that polls for a native call
    this thread waits on)."""
    watched = tuple(getattr(_local, "predicates", ()))
    return lambda: bool(_signals) or any(p() for p in watched)


def check() -> None:
    """Raise ``StopRequested`` if a stop has been asked for; else return at once."""
    if requested():
        raise StopRequested()


@contextmanager
def saving() -> Iterator[None]:
    """While inside, this thread's checks pass: the work a stop keeps (a checkpoint, the model so far) is written
    whole, whatever it calls (a fingerprint reading the scene's cameras checks between them)."""
    _local.saving = getattr(_local, "saving", 0) + 1
    try:
        yield
    finally:
        _local.saving -= 1


@contextmanager
def says(text: str) -> Iterator[None]:
    """A stop inside the block says ``text`` (where it came and what it left), unless it says something already:
    the CLI's line is "stopped by SIGTERM <text>"."""
    try:
        yield
    except StopRequested as exc:
        if str(exc):
            raise
        raise StopRequested(text) from None


def is_stop(exc: BaseException) -> bool:
    """Is ``exc`` a stop? A KeyboardInterrupt, or any exception that surfaced once a stop was asked for (a library
    that turned the interrupt into an error of its own): either way the work is kept as for a stop."""
    return isinstance(exc, KeyboardInterrupt) or requested()


@contextmanager
def watching(predicate: Callable[[], bool]) -> Iterator[None]:
    """While inside, ``requested()`` on this thread is also true when ``predicate()`` is."""
    stack = getattr(_local, "predicates", None)
    if stack is None:
        stack = _local.predicates = []
    stack.append(predicate)
    try:
        yield
    finally:
        stack.remove(predicate)
