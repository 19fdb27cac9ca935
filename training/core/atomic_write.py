"""Write files so that a crash or Ctrl-C never leaves a half-written output behind.

Everything goes to a temporary name in the target's folder and is renamed over the target only once complete
(rename is atomic within one filesystem); the file is flushed to the disk before the rename and the folder after it,
so a power cut leaves the old file or the new one, never an empty one under the name.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator

from training.core.errors import InputError


def check_output_dir(path: str | Path, what: str = "output folder") -> None:
    """Fail early, before hours of work, when ``path`` could not be created: the nearest existing ancestor must be
    a writable folder. Creates nothing."""
    path = Path(path).absolute()
    if path.is_dir():
        ancestor = path
    else:
        if path.exists():
            raise InputError(path, f"cannot create the {what}: it exists and is not a folder")
        ancestor = path.parent
        while not ancestor.exists() and ancestor != ancestor.parent:
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            raise InputError(path, f"cannot create the {what}: {ancestor} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise InputError(path, f"cannot create the {what}: no permission to write in {ancestor}")


def make_output_dir(path: str | Path, what: str = "output folder") -> Path:
    """``mkdir -p`` for an output; a folder that cannot be made is an InputError naming it and saying why."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError(path, f"cannot create the {what}: a file of that name (or above it) is in the way") \
            from None
    except OSError as exc:
        raise InputError(path, f"cannot create the {what}: {exc.strerror or exc}") from None
    if not path.is_dir():
        raise InputError(path, f"cannot create the {what}: it exists and is not a folder")
    return path


def _disk_full(exc: BaseException, folder: Path) -> bool:
    """ENOSPC; or a writer that says it in its own words, or not at all (torch.save reports "iostream error"),
    while the filesystem has less than 1 MiB left."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(exc).lower()
    if "no space left" in text or "disk quota" in text:
        return True
    try:
        st = os.statvfs(folder)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < (1 << 20)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is renamed to ``path``, on error it is removed.

    Use it for writers that want a file name (OpenImageIO, numpy, torch.save)."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
    except OSError as exc:  # the one-line form every other input error has, naming the output
        why = exc.strerror or str(exc)
        if isinstance(exc, (FileExistsError, NotADirectoryError)):
            why = "a file is in the way of its folder"
        raise InputError(path, f"cannot write this output: {why}") from None
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        try:
            yield tmp_path
            _fsync(tmp_path)  # its bytes on the disk before the name points at them (else a crash can leave the
            # target renamed but empty: the rename reaches the journal before the data)
        except (OSError, RuntimeError) as exc:
            if not _disk_full(exc, path.parent):
                raise
            raise InputError(path, "no space left on the device; nothing was written under this name (an "
                                   "earlier file there is unchanged)") from None
        # mkstemp creates the file 0600; outputs should get the mode a plain open() would give.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, path)
        _fsync(path.parent, directory=True)  # the rename itself, which lives in the folder
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _fsync(path: Path, directory: bool = False) -> None:
    if directory and os.name == "nt":  # a folder cannot be opened there; NTFS journals the rename itself
        return
    flags = os.O_RDWR if os.name == "nt" else os.O_RDONLY  # Windows flushes only a handle open for writing
    fd = os.open(path, flags | (getattr(os, "O_DIRECTORY", 0) if directory else 0))
    try:
        os.fsync(fd)
    except OSError as exc:
        # some filesystems (network ones, FUSE) cannot flush a folder: the rename is made, and stays
        if not (directory and exc.errno in (errno.EINVAL, errno.ENOTSUP, errno.EBADF)):
            raise
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "wb", **kwargs) -> Iterator[IO]:
    """Like ``open(path, mode)`` for writing, but the file appears at ``path`` only when the block succeeds."""
    with atomic_path(path) as tmp:
        with open(tmp, mode, **kwargs) as f:
            yield f
