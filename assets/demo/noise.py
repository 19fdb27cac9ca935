"""Seeded procedural noise in numpy: 3D gradient (Perlin-style) noise, fractal sums of it, integer hashing.

The demo scene's solid textures and the demo style painting are built from these, so that every pixel of the demo
assets comes from our own code and a seed. Everything is vectorised over arrays of points; results depend only on
the seed and the inputs (no global random state), so generation is reproducible byte for byte.
"""

from __future__ import annotations

import numpy as np

# The 12 edge directions of a cube (Perlin's improved-noise gradients), padded to 16 so that ``hash & 15`` picks one
# without a modulo; the 4 repeats are the ones Perlin's reference uses.
_GRADIENTS = np.array(
    [[1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0],
     [1, 0, 1], [-1, 0, 1], [1, 0, -1], [-1, 0, -1],
     [0, 1, 1], [0, -1, 1], [0, 1, -1], [0, -1, -1],
     [1, 1, 0], [0, -1, 1], [-1, 1, 0], [0, -1, -1]],
    dtype=np.float64,
)
_GX, _GY, _GZ = (np.ascontiguousarray(_GRADIENTS[:, k]) for k in range(3))


class GradientNoise:
    """3D gradient noise with a seeded permutation table; values lie roughly in [-1, 1], zero at lattice points."""

    def __init__(self, seed: int):
        perm = np.random.default_rng(seed).permutation(256).astype(np.int64)
        # Doubled so that nested lookups perm[perm[x] + y] never need a modulo (indices stay below 512).
        self._perm = np.concatenate([perm, perm]).astype(np.int32)
        # A fixed per-octave shift keeps the lattice of every octave from lining up at the origin.
        self._octave_offsets = np.random.default_rng(seed + 1).uniform(0.0, 256.0, size=(16, 3))

    def __call__(self, p: np.ndarray) -> np.ndarray:
        """p: (..., 3) float coordinates -> (...) noise values."""
        p = np.asarray(p, dtype=np.float64)
        shape = p.shape[:-1]
        p = p.reshape(-1, 3)
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        fx0, fy0, fz0 = np.floor(x), np.floor(y), np.floor(z)
        x0 = fx0.astype(np.int32) & 255
        y0 = fy0.astype(np.int32) & 255
        z0 = fz0.astype(np.int32) & 255
        fx, fy, fz = x - fx0, y - fy0, z - fz0
        fx1, fy1, fz1 = fx - 1.0, fy - 1.0, fz - 1.0
        perm, gx, gy, gz = self._perm, _GX, _GY, _GZ
        # Hash the 8 corners: perm[perm[perm[x] + y] + z], as in Perlin's reference.
        px0 = perm[x0]
        px1 = perm[x0 + 1]
        corners = []
        for pxy, dx, dy in ((perm[px0 + y0], fx, fy), (perm[px0 + y0 + 1], fx, fy1),
                            (perm[px1 + y0], fx1, fy), (perm[px1 + y0 + 1], fx1, fy1)):
            for dz, z in ((fz, z0), (fz1, z0 + 1)):
                h = perm[pxy + z] & 15
                corners.append(gx[h] * dx + gy[h] * dy + gz[h] * dz)
        n000, n001, n010, n011, n100, n101, n110, n111 = corners
        u = fx * fx * fx * (fx * (fx * 6.0 - 15.0) + 10.0)
        v = fy * fy * fy * (fy * (fy * 6.0 - 15.0) + 10.0)
        w = fz * fz * fz * (fz * (fz * 6.0 - 15.0) + 10.0)
        nx00 = n000 + u * (n100 - n000)
        nx01 = n001 + u * (n101 - n001)
        nx10 = n010 + u * (n110 - n010)
        nx11 = n011 + u * (n111 - n011)
        nxy0 = nx00 + v * (nx10 - nx00)
        nxy1 = nx01 + v * (nx11 - nx01)
        return (nxy0 + w * (nxy1 - nxy0)).reshape(shape)

    def fbm(self, p: np.ndarray, octaves: int = 4, lacunarity: float = 2.0, gain: float = 0.5) -> np.ndarray:
        """Fractal sum of ``octaves`` noise layers, normalised so the result stays roughly within [-1, 1].

        p: (..., 3) -> (...)."""
        p = np.asarray(p, dtype=np.float64)
        total = np.zeros(p.shape[:-1])
        amplitude, frequency, norm = 1.0, 1.0, 0.0
        for octave in range(octaves):
            total += amplitude * self(p * frequency + self._octave_offsets[octave % 16])
            norm += amplitude
            amplitude *= gain
            frequency *= lacunarity
        return total / norm


def hash_uniform(*coords: np.ndarray, seed: int = 0) -> np.ndarray:
    """A uniform value in [0, 1) for each tuple of integer coordinates (same shape), stable for a given seed.

    Used for per-tile / per-brick / per-cell random colours. Integer mixing in uint64 (wrap-around is intended)."""
    with np.errstate(over="ignore"):
        h = np.full(np.broadcast(*coords).shape, np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(1))
        for i, c in enumerate(coords):
            c = np.asarray(c).astype(np.int64).astype(np.uint64)
            h = h ^ (c * np.uint64(0xBF58476D1CE4E5B9) + np.uint64(0x94D049BB133111EB * (i + 1) & 0xFFFFFFFFFFFFFFFF))
            h = h ^ (h >> np.uint64(31))
            h = h * np.uint64(0xD6E8FEB86659FD93)
            h = h ^ (h >> np.uint64(32))
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Hue in [0, 1) (wraps), saturation and value in [0, 1] (broadcast together) -> (..., 3) RGB in [0, 1]."""
    h, s, v = np.broadcast_arrays(np.asarray(h, np.float64), np.asarray(s, np.float64), np.asarray(v, np.float64))
    h6 = (h % 1.0) * 6.0
    k = np.stack([(5.0 + h6) % 6.0, (3.0 + h6) % 6.0, (1.0 + h6) % 6.0], axis=-1)
    return v[..., None] - v[..., None] * s[..., None] * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)
