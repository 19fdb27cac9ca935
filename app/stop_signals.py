"""SIGTERM is Ctrl-C: what ``timeout``, systemd, Docker, SLURM and Ray send to stop a command ends it the way a
keyboard interrupt does (each long command saves its checkpoint or its model so far and says so in one line),
with exit status 143 instead of 130.

The handler only records the signal (training/core/stop.py says why it never raises); each long loop checks the
record between its units of work and raises the stop from there. A second signal changes nothing: the save the
first one started finishes (outputs are written to a temporary name and renamed: even a SIGKILL leaves the previous
file whole).

pycolmap's glog installs a failure handler for SIGTERM when it is first imported (a stack dump, then death, and
nothing saved), so ``install`` imports pycolmap with the two signals blocked and puts Python's handlers back before
it unblocks them: a signal sent meanwhile waits, and then reaches ours.
"""

from __future__ import annotations

import signal

from training.core import stop


def install():
    """Put the handlers in; returns a function that puts back the ones found (main() calls it on its way out, so
    a caller in the same process, a test, keeps its own)."""
    stop.reset()
    signals = (signal.SIGTERM, signal.SIGINT)
    previous = {sig: signal.getsignal(sig) for sig in signals}
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, signals)
    try:
        import pycolmap  # noqa: F401  (its glog handler goes in here, and ours replaces it below)

        for sig in signals:
            signal.signal(sig, stop.handle_signal)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    return restore


def exit_code() -> int:
    """128 + the signal that stopped the command (130 for Ctrl-C, 143 for SIGTERM)."""
    return 128 + (stop.signal_number() or signal.SIGINT)


def signal_name() -> str:
    return signal.Signals(stop.signal_number() or signal.SIGINT).name
