"""Frozen geometry: what the cpu rasterizer can reuse while only the colours change (stylization).

With geometry that needs no gradient, everything but the colours is a function of the geometry and the camera:
projection, depth order, tile lists, each pixel's final transmittance, and every composited pair with its alpha
(the forward's records, cpu_composite). A stylization renders each view of its trajectory many times (a new view
every step, passes along the trajectory), so ``FrozenCache`` keeps an entry per (geometry, camera): the inputs it
was computed from (compared bit for bit on every call, so a changed model or camera is never served stale
results), the screen-space state, and the first forward's records. From then on the forward replays the records
(``_replay_fwd``: per pair w = alpha T, T *= 1 - alpha, the colour times w summed; no exponential, no test) and the
colour backward walks the same records as it always does: the same float operations in the same order as the
compositing kernels, so images and gradients are bit-identical to a render without the cache
(tests/test_raster_cpu.py).

The records cost ``RECORD_BYTES`` per composited pair; past ``MAX_PAIRS`` an entry keeps none. The entries
together hold at most ``MAX_BYTES`` (what does not fit is computed each time); they share one copy of the geometry.
"""

from __future__ import annotations

import threading

import numpy as np
from numba import njit, prange

from training.raster.cpu_jit import JIT

MAX_PAIRS = 16_000_000  # at most ~100 MB of records per entry
RECORD_BYTES = 6  # a recorded pair: its pixel (uint16) and alpha (float32)
# All entries together: what is not kept is computed again at each visit (slower, never wrong).
MAX_BYTES = 1 << 30


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Bit-for-bit equality (NaN equal to itself, -0.0 different from 0.0): the kernels' results can only be
    reused for exactly the inputs they came from."""
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a.view(np.uint8), b.view(np.uint8))


class FrozenEntry:
    """One (geometry, camera): the inputs' copies, the projection and binning, then what later calls record."""

    def __init__(self, key_arrays, params, proj, shared_geometry=None):
        """``key_arrays``: (means, quats, scales, opacities, view, K); ``shared_geometry``: another entry whose copy
        of the first four equals them bit for bit (kept once, not copied again)."""
        geometry = shared_geometry or [np.array(a, copy=True) for a in key_arrays[:4]]
        self.key_arrays = list(geometry) + [np.array(a, copy=True) for a in key_arrays[4:]]
        self.params = params
        self.proj = proj  # (means2d, conics, depths, radii, order, offsets, ids, rec)
        self.out_t = None  # (H, W) float32 final transmittance, with the records
        self.records = None  # (rec_off, tile_n, pair_n, rec_pix, rec_a), compacted, once recorded
        self.cache: FrozenCache | None = None  # the cache that keeps it (None: used for one call only)

    def matches(self, key_arrays, params) -> bool:
        return (params == self.params and self.same_camera(key_arrays)
                and all(_same(a, b) for a, b in zip(key_arrays[:4], self.key_arrays[:4])))

    def same_camera(self, key_arrays) -> bool:
        return all(_same(a, b) for a, b in zip(key_arrays[4:], self.key_arrays[4:]))

    def same_geometry(self, key_arrays) -> bool:
        return all(_same(a, b) for a, b in zip(key_arrays[:4], self.key_arrays[:4]))

    def nbytes(self, with_geometry: bool = True) -> int:
        arrays = list(self.proj) + [self.out_t] + list(self.records or ())
        if with_geometry:
            arrays += self.key_arrays[:4]
        return sum(a.nbytes for a in arrays if isinstance(a, np.ndarray))

    def keeps_records(self, pairs: int, list_entries: int) -> bool:
        """Whether this entry may keep the records of ``pairs`` composited pairs over ``list_entries`` tile-list
        entries: only an entry its cache keeps, within ``MAX_PAIRS`` and the room the cache has left."""
        nbytes = pairs * RECORD_BYTES + list_entries * 4
        return self.cache is not None and pairs <= MAX_PAIRS and self.cache.room_for(nbytes)


class FrozenCache:
    """Entries per (geometry, camera) of one geometry, safe to share between threads (an entry's fields are written
    once, then read). Storing an entry of another geometry drops the others (a changed model never comes back bit
    for bit). Past ``max_bytes`` nothing more is kept: new cameras are not stored and entries record no weights.
    Not least-recently-used eviction: a stylization visits its views in a cycle, where LRU with room for fewer
    entries than views would never hit; keeping the first ones serves those at every pass."""

    def __init__(self, max_bytes: int = MAX_BYTES):
        self.max_bytes = max_bytes
        self._lock = threading.Lock()
        self._entries: list[FrozenEntry] = []
        self._newest: FrozenEntry | None = None

    @property
    def newest(self) -> FrozenEntry | None:
        """The entry last stored or served (None when empty)."""
        with self._lock:
            return self._newest

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)

    def entries(self) -> list[FrozenEntry]:
        """The entries kept, oldest first (a copy of the list)."""
        with self._lock:
            return list(self._entries)

    def nbytes(self) -> int:
        with self._lock:
            return self._total()

    def _total(self) -> int:
        return sum(e.nbytes(with_geometry=k == 0) for k, e in enumerate(self._entries))

    def lookup(self, key_arrays, params) -> FrozenEntry | None:
        with self._lock:
            entries = list(self._entries)
        if not entries or not entries[0].same_geometry(key_arrays):
            return None
        for entry in entries:  # one geometry: the camera tells the entries apart
            if entry.params == params and entry.same_camera(key_arrays):
                with self._lock:
                    self._newest = entry
                return entry
        return None

    def store(self, key_arrays, params, proj) -> FrozenEntry:
        """A new entry, kept when there is room (else it serves only the call that made it)."""
        with self._lock:
            entries = list(self._entries)
        same = bool(entries) and entries[0].same_geometry(key_arrays)
        entry = FrozenEntry(key_arrays, params, proj, shared_geometry=entries[0].key_arrays[:4] if same else None)
        entry.cache = self
        with self._lock:
            if not same:
                self._entries = []
            self._entries = [e for e in self._entries if not e.matches(key_arrays, params)]
            if not self._entries or self._total() + entry.nbytes(with_geometry=False) <= self.max_bytes:
                self._entries.append(entry)
            else:
                entry.cache = None
            self._newest = entry
        return entry

    def room_for(self, nbytes: int) -> bool:
        with self._lock:
            return self._total() + nbytes <= self.max_bytes

    def clear(self) -> None:
        with self._lock:
            self._entries = []
            self._newest = None


@njit(parallel=True, **JIT)
def _replay_fwd(offsets, ids, feats, width, height, tile_size, tiles_x, rec_off, tile_n, pair_n, rec_pix, rec_a,
                out_feat):
    """out_feat (H, W, C) from the forward's records (cpu_composite._composite_fwd): per pixel, in compositing
    order, w = alpha T and T *= 1 - alpha, the features times w summed, as the forward accumulates them."""
    n_ch = feats.shape[1]
    for t in prange(offsets.shape[0] - 1):
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * tile_size, ty * tile_size
        x1, y1 = min(x0 + tile_size, width), min(y0 + tile_size, height)
        tw = x1 - x0
        n_pix = tw * (y1 - y0)
        T = np.ones(n_pix, np.float32)
        acc = np.zeros((n_pix, 4), np.float32)
        k = rec_off[t]
        k_end = rec_off[t] + tile_n[t]
        j = offsets[t]
        while k < k_end:
            n = pair_n[j]
            if n == 0:
                j += 1
                continue
            g = ids[j]
            f0 = feats[g, 0]
            f1 = feats[g, 1] if n_ch > 1 else np.float32(0.0)
            f2 = feats[g, 2] if n_ch > 2 else np.float32(0.0)
            f3 = feats[g, 3] if n_ch > 3 else np.float32(0.0)
            for i in range(k, k + n):
                code = np.int64(rec_pix[i])
                p = (code >> 8) * tw + (code & 255)
                alpha = abs(rec_a[i])
                tp = T[p]
                w = alpha * tp
                acc[p, 0] += f0 * w
                acc[p, 1] += f1 * w
                acc[p, 2] += f2 * w
                acc[p, 3] += f3 * w
                T[p] = tp * (np.float32(1.0) - alpha)
            k += n
            j += 1
        for py in range(y0, y1):
            for px in range(x0, x1):
                p = (py - y0) * tw + (px - x0)
                for c in range(n_ch):
                    out_feat[py, px, c] = acc[p, c]
