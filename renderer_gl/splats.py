"""One model's Gaussians on the GPU: parameter textures, selection flags and the draw-order buffer.

Parameters live in 2D float textures read with texelFetch rather than in shader storage buffers: llvmpipe caps
a storage block at 128 MiB (a degree-3 model of 700k Gaussians), while a 16384-wide RGBA32F texture holds
16384^2 texels. Rows are filled left to right and a Gaussian may straddle two rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import moderngl

GEOM_TEXELS = 3  # (mean, opacity), (quat wxyz), (scale, 0)
MAX_WIDTH = 4096


@dataclass
class SplatArrays:
    """Activated Gaussian parameters as the renderer takes them (float32 after ``checked``).

    means (N, 3); scales (N, 3) standard deviations; quats (N, 4) wxyz, any norm; opacities (N,) in (0, 1);
    sh (N, K, 3) coefficients with K >= (sh_degree + 1)^2, or (N, 3) plain RGB (then sh_degree must be None).
    """

    means: np.ndarray
    scales: np.ndarray
    quats: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    sh_degree: int | None = 0

    def checked(self) -> "SplatArrays":
        f = lambda a: np.ascontiguousarray(np.asarray(a, dtype=np.float32))  # noqa: E731
        means, scales, quats, opac, sh = (f(x) for x in (self.means, self.scales, self.quats, self.opacities,
                                                          self.sh))
        n = means.shape[0] if means.ndim == 2 else -1
        for name, arr, shape in (("means", means, (n, 3)), ("scales", scales, (n, 3)), ("quats", quats, (n, 4)),
                                 ("opacities", opac.reshape(-1), (n,))):
            if arr.shape != shape:
                raise ValueError(f"{name} has shape {arr.shape}, expected {shape}")
        opac = opac.reshape(-1)
        degree = self.sh_degree
        sh, degree = normalise_sh(sh, degree, n)
        return SplatArrays(means, scales, quats, opac, sh, degree)


def normalise_sh(sh: np.ndarray, degree: int | None, n: int) -> tuple[np.ndarray, int]:
    """(N, K, 3) SH coefficients and their degree; plain RGB becomes degree-0 SH giving that colour."""
    sh = np.ascontiguousarray(np.asarray(sh, dtype=np.float32))
    if degree is None:
        if sh.shape != (n, 3):
            raise ValueError(f"plain colours must be ({n}, 3), got {sh.shape}")
        from renderer_gl.constants import SH_C0

        return np.ascontiguousarray(((sh - 0.5) / SH_C0)[:, None, :]), 0
    degree = int(degree)
    if not 0 <= degree <= 3:
        raise ValueError(f"sh_degree must be 0..3, got {degree}")
    k = (degree + 1) ** 2
    if sh.ndim != 3 or sh.shape[0] != n or sh.shape[1] < k or sh.shape[2] != 3:
        raise ValueError(f"SH coefficients have shape {sh.shape}, expected ({n}, >={k}, 3)")
    return np.ascontiguousarray(sh[:, :k]), degree


def _texture_rows(texels: int, width: int) -> int:
    return max(1, -(-texels // width))


def _pack(values: np.ndarray, width: int) -> tuple[bytes, int]:
    """(texels, 4) float32 -> bytes of a width x rows texture, zero-padded."""
    rows = _texture_rows(values.shape[0], width)
    padded = np.zeros((rows * width, values.shape[1]), dtype=values.dtype)
    padded[: values.shape[0]] = values
    return padded.tobytes(), rows


class GPUSplats:
    """Textures and buffers of one model. ``version`` grows on every upload that changes what is drawn."""

    def __init__(self, ctx: moderngl.Context, arrays: SplatArrays):
        self.ctx = ctx
        max_size = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 4096))
        self.width = min(MAX_WIDTH, max_size)
        self.max_rows = max_size
        self.version = 0
        self._geom = self._sh = self._flags = self._index = self._lod_index = None
        self._external_index = None  # an order buffer that lives elsewhere (the GPU sort's), or None
        self._read_order = None
        self.upload(arrays)

    def _texture(self, old, rows: int, components: int, dtype: str, data: bytes):
        if old is not None and old.size == (self.width, rows) and old.components == components:
            old.write(data)
            return old
        if old is not None:
            old.release()
        if rows > self.max_rows:
            raise ValueError(f"model too large for one {self.width}x{self.max_rows} texture ({rows} rows needed)")
        tex = self.ctx.texture((self.width, rows), components, data, dtype=dtype)
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return tex

    def upload(self, arrays: SplatArrays) -> None:
        a = arrays.checked()
        n = a.means.shape[0]
        self.n = n
        self.means = a.means  # kept for depth sorting
        # what a splat contributes to a picture, roughly: its opacity times its footprint (the LOD keeps the largest)
        self.importance = a.opacities * np.max(a.scales, axis=1) ** 2
        self.order = None
        self._lod_key = None
        geom = np.zeros((n, GEOM_TEXELS, 4), dtype=np.float32)
        geom[:, 0, :3] = a.means
        geom[:, 0, 3] = a.opacities
        geom[:, 1] = a.quats
        geom[:, 2, :3] = a.scales
        data, rows = _pack(geom.reshape(-1, 4), self.width)
        self._geom = self._texture(self._geom, rows, 4, "f4", data)
        self._upload_sh(a.sh, a.sh_degree)
        self.set_flags(None)
        if self._index is None or self._index.size != max(n, 1) * 4:
            if self._index is not None:
                self._index.release()
            self._index = self.ctx.buffer(reserve=max(n, 1) * 4)
        self.order_forward = None  # the buffer's order is stale
        self._external_index = self._read_order = None
        self.version_geometry = getattr(self, "version_geometry", 0) + 1
        self.version += 1

    def _upload_sh(self, sh: np.ndarray, degree: int) -> None:
        n, k, _ = sh.shape
        self.sh_degree = degree
        self.sh_stride = -(-k * 3 // 4)
        flat = np.zeros((n, self.sh_stride * 4), dtype=np.float32)
        flat[:, : k * 3] = sh.reshape(n, k * 3)
        data, rows = _pack(flat.reshape(-1, 4), self.width)
        self._sh = self._texture(self._sh, rows, 4, "f4", data)

    def update_colors(self, sh: np.ndarray, sh_degree: int | None) -> None:
        """Rewrite only the colour texture (the stylizer changes nothing else)."""
        sh, degree = normalise_sh(sh, sh_degree, self.n)
        self._upload_sh(sh, degree)
        self.version += 1

    def set_flags(self, flags: np.ndarray | None) -> None:
        """Per-Gaussian uint8 flags: bit 0 selected (tinted), bit 1 hidden; None clears them."""
        if flags is None:
            flags = np.zeros(self.n, dtype=np.uint8)
        flags = np.asarray(flags, dtype=np.uint8).reshape(-1)
        if flags.shape[0] != self.n:
            raise ValueError(f"flags must have {self.n} entries, got {flags.shape[0]}")
        self.flagged = bool(flags.any())
        data, rows = _pack(flags.reshape(-1, 1), self.width)
        self._flags = self._texture(self._flags, rows, 1, "u1", data)
        self.version += 1

    def write_order(self, order: np.ndarray, forward: np.ndarray) -> None:
        self._index.write(np.ascontiguousarray(order, dtype=np.uint32).tobytes())
        self.order_forward = np.array(forward, dtype=np.float64)
        self.order = order
        self._external_index = self._read_order = None
        self._lod_key = None

    def use_order_buffer(self, buffer: moderngl.Buffer, forward: np.ndarray, read_order) -> None:
        """Draw in the order held by ``buffer`` (its first n uint32 entries), a GPU sort's result, without reading
        it back; ``read_order()`` fetches it to the CPU only if the moving preview (``lod_buffer``) needs it."""
        self._external_index = buffer
        self._read_order = read_order
        self.order_forward = np.array(forward, dtype=np.float64)
        self.order = None
        self._lod_key = None

    def lod_buffer(self, fraction: float) -> tuple[moderngl.Buffer, int]:
        """An index buffer of the ``fraction`` most important Gaussians in the current back-to-front order, and
        its length (the moving camera's preview: software GL's cost is per splat)."""
        if self.order is None and self._read_order is not None:
            self.order = np.asarray(self._read_order(), dtype=np.uint32)
        key = (id(self.order), round(float(fraction), 3))
        if self._lod_key != key:
            k = max(1, int(round(self.n * fraction)))
            threshold = np.partition(self.importance, self.n - k)[self.n - k] if k < self.n else -np.inf
            order = self.order if self.order is not None else np.arange(self.n, dtype=np.uint32)
            subset = np.ascontiguousarray(order[self.importance[order] >= threshold], dtype=np.uint32)
            if self._lod_index is None or self._lod_index.size != max(self.n, 1) * 4:
                if self._lod_index is not None:
                    self._lod_index.release()
                self._lod_index = self.ctx.buffer(reserve=max(self.n, 1) * 4)
            self._lod_index.write(subset.tobytes())
            self._lod_count = len(subset)
            self._lod_key = key
        return self._lod_index, self._lod_count

    @property
    def index_buffer(self) -> moderngl.Buffer:
        return self._external_index if self._external_index is not None else self._index

    def bind(self, program: moderngl.Program) -> None:
        self._geom.use(location=0)
        self._sh.use(location=1)
        self._flags.use(location=2)
        for name, loc in (("u_geom", 0), ("u_sh", 1), ("u_flags", 2)):
            if name in program:
                program[name].value = loc
        if "u_sh_stride" in program:
            program["u_sh_stride"].value = self.sh_stride

    def release(self) -> None:
        for obj in (self._geom, self._sh, self._flags, self._index, self._lod_index):
            if obj is not None:
                obj.release()
