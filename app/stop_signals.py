"""SIGTERM is Ctrl-C: what ``timeout``, systemd, Docker, SLURM and Ray send to stop a command ends it the way a
keyboard interrupt does (each long command saves its checkpoint or its model so far and says so in one line),
with exit status 143 instead of 130.

pycolmap's glog installs a failure handler for SIGTERM when it is first imported (a stack dump, then death, and
nothing saved), so ``install`` imports pycolmap before putting Python's handlers in. The first signal raises
KeyboardInterrupt; later ones are ignored, so that the save the first one started finishes (outputs are written
to a temporary name and renamed: even a SIGKILL leaves the previous file whole).
"""

from __future__ import annotations

import signal

_received: list[int] = []


def install():
    """Put the handlers in; returns a function that puts back the ones found (main() calls it on its way out, so
    a caller in the same process, a test, keeps its own)."""
    import pycolmap  # noqa: F401  (its glog handler must go in before ours, not after)

    _received.clear()
    previous = {sig: signal.signal(sig, _stop) for sig in (signal.SIGTERM, signal.SIGINT)}

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    return restore


def _stop(signum, _frame) -> None:
    if _received:
        return  # already stopping: let the save finish
    _received.append(signum)
    raise KeyboardInterrupt


def exit_code() -> int:
    """128 + the signal that stopped the command (130 for Ctrl-C, 143 for SIGTERM)."""
    return 128 + (_received[0] if _received else signal.SIGINT)


def signal_name() -> str:
    return signal.Signals(_received[0]).name if _received else "SIGINT"
