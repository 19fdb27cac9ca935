"""How much memory this process may still take, asked before a reader allocates what a file declares.

A file that passes every check of its format can still describe more than the machine holds (a valid SPZ of
identical Gaussians packs 48 to 1); reading it would end in swapping, the kernel's out-of-memory killer, or a bare
``MemoryError`` that names no file. Readers ask ``check_fits`` first and refuse in one line instead.
"""

from __future__ import annotations

import os
from pathlib import Path

from training.core.errors import InputError


def _meminfo() -> int | None:
    """Linux: MemAvailable + SwapFree in bytes; None elsewhere."""
    try:
        with open("/proc/meminfo") as f:
            fields = {line.split(":")[0]: int(line.split()[1]) * 1024 for line in f if line.count(":") == 1
                      and len(line.split()) >= 2 and line.split()[1].isdigit()}
    except OSError:
        return None
    if "MemAvailable" not in fields:
        return None
    return fields["MemAvailable"] + fields.get("SwapFree", 0)


def _address_space_left() -> int | None:
    """What an address-space limit (``ulimit -v``, RLIMIT_AS) leaves this process; None without one."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft == resource.RLIM_INFINITY:
            return None
        with open("/proc/self/statm") as f:
            used = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (ImportError, OSError, ValueError):
        return None
    return max(0, soft - used)


def memory_available() -> int | None:
    """Bytes this process may still allocate, as far as the system says; None where it says nothing."""
    known = [v for v in (_meminfo(), _address_space_left()) if v is not None]
    return min(known) if known else None


def human_bytes(size: float) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if size < 1000 or unit == "GB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1000
    return f"{size} B"


def check_fits(path: str | Path, count: int, bytes_each: int, what: str) -> None:
    """InputError naming ``path`` when ``count`` items of ``bytes_each`` bytes exceed the memory available."""
    need = int(count) * int(bytes_each)
    free = memory_available()
    if free is not None and need > free:
        raise InputError(path, f"{what} need {human_bytes(need)} of memory to read; {human_bytes(free)} is free")
