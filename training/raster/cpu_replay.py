"""Frozen geometry: what the cpu rasterizer can reuse while only the colours change (stylization).

With geometry that needs no gradient, everything but the colours is a function of the geometry and the camera:
projection, depth order, tile lists, each pixel's final transmittance, and every composited pair's weight a T
(forward, float32) and its recovered weight (backward, float64). A stylization renders each view of its trajectory
many times (a new view every step, passes along the trajectory), so ``FrozenCache`` keeps an entry per
(geometry, camera): the inputs it was computed from (compared bit for bit on every call, so a changed model or
camera is never served stale results), the screen-space state, and, from the second call on, the composited pairs'
weights. Then the forward is a weighted sum of the colours over those pairs and the colour backward its transpose:
the same float operations in the same order as the compositing kernels, so images and gradients are bit-identical
to a render without the cache (tests/test_raster_cpu.py).

The weights cost 12 bytes per composited pair and direction; past ``MAX_PAIRS`` an entry keeps none. The entries
together hold at most ``MAX_BYTES`` (what does not fit is computed each time); they share one copy of the geometry.
"""

from __future__ import annotations

import threading

import numpy as np
from numba import njit, prange

from training.raster.cpu_jit import JIT

MAX_PAIRS = 8_000_000  # per direction: at most ~100 MB of forward and ~100 MB of backward weights
RECORD_BYTES = 12  # a recorded pair, in either direction
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
        self.out_t = None  # (H, W) float32 final transmittance, after the first forward
        self.out_last = None
        self.tile_pairs = None  # composited pairs per tile, after the first forward
        self.fwd = None  # (rec_off, rec_p, rec_g, rec_w) once recorded
        self.bwd = None  # (j_start, j_count, rec_pix, rec_w) once recorded
        self.cache: FrozenCache | None = None  # the cache that keeps it (None: used for one call only)

    def matches(self, key_arrays, params) -> bool:
        return (params == self.params and self.same_camera(key_arrays)
                and all(_same(a, b) for a, b in zip(key_arrays[:4], self.key_arrays[:4])))

    def same_camera(self, key_arrays) -> bool:
        return all(_same(a, b) for a, b in zip(key_arrays[4:], self.key_arrays[4:]))

    def same_geometry(self, key_arrays) -> bool:
        return all(_same(a, b) for a, b in zip(key_arrays[:4], self.key_arrays[:4]))

    def nbytes(self, with_geometry: bool = True) -> int:
        arrays = list(self.proj) + [self.out_t] + list(self.fwd or ()) + list(self.bwd or ())
        if with_geometry:
            arrays += self.key_arrays[:4]
        return sum(a.nbytes for a in arrays if isinstance(a, np.ndarray))

    def record_offsets(self):
        """Where each tile's records start, and their total, or None before the first forward, for an entry its
        cache did not keep, or when the records would take too much memory (``MAX_PAIRS``, or more than the cache
        has room for). The backward touches exactly the pairs the forward composited (same float operations
        decide), so both directions need this many."""
        if self.tile_pairs is None or self.cache is None:
            return None
        off = np.zeros(self.tile_pairs.size + 1, np.int64)
        np.cumsum(self.tile_pairs, out=off[1:])
        total = int(off[-1])
        if total > MAX_PAIRS or not self.cache.room_for(off.nbytes + total * RECORD_BYTES):
            return None
        return off, total


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
def _replay_fwd(rec_off, rec_p, rec_g, rec_w, feats, width, height, tile_size, tiles_x, out_feat):
    """out_feat (H, W, C) = sum over the recorded pairs of feats[rank] * weight, per pixel in compositing order
    (as ``_composite_fwd`` accumulates)."""
    n_ch = feats.shape[1]
    for t in prange(rec_off.shape[0] - 1):
        ty, tx = t // tiles_x, t % tiles_x
        x0, y0 = tx * tile_size, ty * tile_size
        x1, y1 = min(x0 + tile_size, width), min(y0 + tile_size, height)
        tw = x1 - x0
        acc = np.zeros((tw * (y1 - y0), n_ch), np.float32)
        for k in range(rec_off[t], rec_off[t + 1]):
            p = rec_p[k]
            g = rec_g[k]
            w = rec_w[k]
            for c in range(n_ch):
                acc[p, c] += feats[g, c] * w
        for py in range(y0, y1):
            for px in range(x0, x1):
                p = (py - y0) * tw + (px - x0)
                for c in range(n_ch):
                    out_feat[py, px, c] = acc[p, c]


@njit(parallel=True, **JIT)
def _replay_bwd_rgb(j_start, j_count, rec_pix, rec_w, g_feat, pair_rgb):
    """pair_rgb[j] (zeroed) = sum over entry j's recorded pixels of weight * dL/d(rgb), in the recorded order
    (as ``_composite_bwd_rgb`` accumulates); g_feat (H * W, C >= 3)."""
    for j in prange(j_start.shape[0]):
        n = j_count[j]
        if n == 0:
            continue
        vr = 0.0
        vg = 0.0
        vb = 0.0
        for k in range(j_start[j], j_start[j] + n):
            p = rec_pix[k]
            w = rec_w[k]
            vr += w * np.float64(g_feat[p, 0])
            vg += w * np.float64(g_feat[p, 1])
            vb += w * np.float64(g_feat[p, 2])
        pair_rgb[j, 0] = vr
        pair_rgb[j, 1] = vg
        pair_rgb[j, 2] = vb
