"""Back-to-front order of Gaussians for a viewing direction, on the CPU with numpy.

The order sorts by camera-space z = f . (m - c) for forward direction f and camera centre c; the c term is the
same for every Gaussian, so the order depends on f alone: a camera that only moves needs no new sort, and one
that turns needs one only when f has turned by more than a tolerance.

Two key types, chosen by measurement (docs/renderer.md): ``float`` argsorts the float32 depths exactly (ties
back to front by decreasing index, the exact reverse of the training rasterizer's front-to-back order);
``u16`` quantises them to 16 bits, which numpy sorts with a stable radix sort in about half the time but which
may reorder Gaussians closer in depth than 1/65535 of the model's depth span.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

PRECISIONS = ("auto", "float", "u16")
# Above this many Gaussians "auto" sorts 16-bit keys (numbers in docs/renderer.md).
AUTO_U16_ABOVE = 50_000


def depth_keys(means: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """(N,) float32 depth along ``forward`` up to a constant."""
    return means @ np.asarray(forward, dtype=np.float32)


def back_to_front(means: np.ndarray, forward: np.ndarray, precision: str = "auto") -> np.ndarray:
    """(N,) uint32 indices, farthest first."""
    if precision not in PRECISIONS:
        raise ValueError(f"unknown sort precision {precision!r}; expected one of {', '.join(PRECISIONS)}")
    z = depth_keys(means, forward)
    if precision == "auto":
        precision = "u16" if len(z) > AUTO_U16_ABOVE else "float"
    if precision == "float":
        order = np.argsort(z, kind="stable")[::-1]
    else:
        lo, hi = (float(z.min()), float(z.max())) if len(z) else (0.0, 1.0)
        span = hi - lo if hi > lo else 1.0
        # Far (large z) gets the smallest key, so an ascending stable sort is already back to front.
        keys = ((hi - z) * np.float32(65535.0 / span)).astype(np.uint16)
        order = np.argsort(keys, kind="stable")
    return order.astype(np.uint32)


def turned(f_old: np.ndarray | None, f_new: np.ndarray, tolerance_deg: float) -> bool:
    """Whether the viewing direction changed by more than ``tolerance_deg`` (always, with no previous one)."""
    if f_old is None:
        return True
    c = float(np.clip(np.dot(f_old, f_new), -1.0, 1.0))
    return math.degrees(math.acos(c)) > tolerance_deg


class BackgroundSorter:
    """Sorts on a worker thread (numpy's sort releases the GIL) so that a frame can draw with the last order
    while the next one is computed: the sort leaves the draw path at the price of one stale frame."""

    def __init__(self):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="splat-sort")
        self._lock = threading.Lock()
        self._pending: dict[int, tuple[Future, np.ndarray, int]] = {}

    def submit(self, slot: int, means: np.ndarray, forward: np.ndarray, precision: str, version: int) -> None:
        with self._lock:
            if slot in self._pending and not self._pending[slot][0].done():
                return
            fut = self._pool.submit(back_to_front, means, forward, precision)
            self._pending[slot] = (fut, np.array(forward), version)

    def take(self, slot: int):
        """(order, forward, version) of a finished sort for ``slot``, or None."""
        with self._lock:
            item = self._pending.get(slot)
            if item is None or not item[0].done():
                return None
            del self._pending[slot]
        fut, forward, version = item
        return fut.result(), forward, version

    def close(self) -> None:
        self._pool.shutdown(wait=True)
