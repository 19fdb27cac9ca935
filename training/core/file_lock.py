"""Which process is using a folder: an exclusive ``flock`` on a lock file, held for as long as the work runs and
released by the kernel when the process ends, however it ends (a crash or SIGKILL too). A second process that finds
the lock held leaves the work alone; one that finds it free knows the work was abandoned."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path


def hold(lock_file: str | Path) -> int:
    """Create ``lock_file`` if needed and take its lock: the open descriptor, which holds the lock until it is
    closed. BlockingIOError when another process holds it."""
    fd = os.open(lock_file, os.O_CREAT | os.O_RDWR, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BaseException:
        os.close(fd)
        raise
    return fd


def held(lock_file: str | Path) -> bool:
    """A live process holds ``lock_file``'s lock (a missing file is no lock)."""
    try:
        fd = os.open(lock_file, os.O_RDWR)
    except FileNotFoundError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False
