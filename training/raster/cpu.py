"""CPU rasterizer: numba kernels for projection, tile binning, compositing and their hand-written backward.

Same semantics as the reference (training/raster/reference.py), same numbers (training/raster/constants.py).
Pipeline, all on float32 arrays shared with torch without copies (``tensor.numpy()``):

1. ``cpu_project._project_fwd`` (parallel over Gaussians, float64 inside): EWA covariance + low-pass, conic,
   pixel mean, screen box where alpha can reach 1/255, culling (near/far, opacity, off-screen, degenerate).
2. ``cpu_sort.depth_order`` + ``cpu_sort._bin``: the visible Gaussians in global depth order, scattered into
   per-tile lists that come out sorted front to back; ``cpu_sort._pack`` lays their records out in that order.
3. ``cpu_composite._composite_fwd`` (parallel over tiles): front-to-back compositing; keeps each pixel's final T
   and, when a backward may follow, records every composited pair (pixel and alpha) in buffers from ``_RECORDS``.
4. Backward, from those records, only what the inputs that require gradients need (``ctx.needs_input_grad``):
   - geometry (means, quats, scales, opacities or the means2d leaf): ``_composite_bwd`` (every per-pair term),
     then ``cpu_project._project_bwd`` if means, quats or scales need it;
   - colours alone (stylization): ``_composite_bwd_rgb``, only each pair's colour weight; no projection backward
     and no view-direction term of the SH backward.
   SH colours (``_sh_fwd`` / ``_sh_bwd``) are evaluated only for visible Gaussians.
5. Frozen geometry (no gradient, bit-identical to the previous call's, same camera): steps 1-2 are reused, and
   the first forward's records are kept, so later forwards replay them (``cpu_replay``), with bit-identical
   results.

Each call's ``timings`` (seconds per stage, the backward's added when it runs) reach ``rasterize()``'s info.
This module holds the autograd Function and the entry point; the kernels live in cpu_project, cpu_sort,
cpu_composite and cpu_replay.
"""

from __future__ import annotations

import threading
import time
import weakref

import numba
import numpy as np
import torch

from training.raster.cpu_composite import (MAX_TILE_SIZE, TILE_CHUNK, _compact_records, _composite_bwd,
                                           _composite_bwd_rgb, _composite_fwd, _record_capacity, _reduce_pairs)
from training.raster.cpu_project import _project_bwd, _project_fwd, _sh_bwd, _sh_fwd
from training.raster.cpu_replay import FrozenCache, _replay_fwd
from training.raster.cpu_sort import _bin, _pack, depth_order

# Stand in for arrays a kernel is told not to touch (numba wants arrays of the right type).
_NO_MEANS = np.empty((0, 3), np.float32)
_NO_I64 = np.empty(0, np.int64)
_NO_I32 = np.empty(0, np.int32)
_NO_U16 = np.empty(0, np.uint16)
_NO_F32 = np.empty(0, np.float32)

# Geometry that needs no gradient is reused from the previous call when it is bit-identical (see cpu_replay).
FROZEN = FrozenCache()


class _RecordBuffers:
    """Buffers for the forward's records, handed back when the state that used them is freed (after its backward),
    so a training loop reuses two buffers instead of faulting fresh pages in at every step (about 5 ms a step at
    60k Gaussians and 212x378). A buffer is only ever held by one state: a second forward before a backward, or
    another thread's render, gets its own."""

    KEEP = 2

    def __init__(self):
        self._lock = threading.Lock()
        self._free: list[tuple[np.ndarray, np.ndarray]] = []

    def take(self, n: int, owner) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            fit = [i for i, b in enumerate(self._free) if b[0].shape[0] >= n]
            if fit:
                bufs = self._free.pop(min(fit, key=lambda i: self._free[i][0].shape[0]))
            else:
                size = max(n, 1024) + max(n, 1024) // 4  # room for the next steps' growth
                bufs = (np.empty(size, np.uint16), np.empty(size, np.float32))
        weakref.finalize(owner, self._give, bufs)
        return bufs[0][:n], bufs[1][:n]

    def _give(self, bufs) -> None:
        with self._lock:
            self._free.append(bufs)
            self._free.sort(key=lambda b: -b[0].shape[0])
            del self._free[self.KEEP:]


_RECORDS = _RecordBuffers()


class _CompositeState:
    """What the forward pass keeps for the backward pass (numpy arrays, float32 unless noted)."""

    def __init__(self, **kw):
        self.__dict__.update(kw)


def _record_arrays(st, owner):
    """(rec_off, tile_n, pair_n, rec_pix, rec_a) sized for st's tile lists (record buffers owned by ``owner``)."""
    caps = np.empty(st.offsets.shape[0] - 1, np.int64)
    _record_capacity(st.offsets, st.ids, st.rec, st.width, st.height, st.tile_size, st.tiles_x, caps)
    rec_off = np.zeros(caps.shape[0] + 1, np.int64)
    np.cumsum(caps, out=rec_off[1:])
    rec_pix, rec_a = _RECORDS.take(int(rec_off[-1]), owner)
    return rec_off, np.empty(caps.shape[0], np.int64), np.zeros(st.ids.shape[0], np.int32), rec_pix, rec_a


def _compacted(records):
    rec_off, tile_n, pair_n, rec_pix, rec_a = records
    new_off = np.zeros(tile_n.shape[0] + 1, np.int64)
    np.cumsum(tile_n, out=new_off[1:])
    total = int(new_off[-1])
    out_pix, out_a = np.empty(total, np.uint16), np.empty(total, np.float32)
    _compact_records(rec_off, tile_n, rec_pix, rec_a, new_off, out_pix, out_a)
    return new_off, tile_n.copy(), pair_n.copy(), out_pix, out_a


class _RasterizeCPU(torch.autograd.Function):
    """(means, quats, scales, opacities, colors or SH, means2d leaf) -> (features (H,W,C), T_final (H,W,1))."""

    @staticmethod
    def forward(ctx, means, quats, scales, opacities, colors, means2d_leaf, st):
        n = st.means.shape[0]
        H, W = st.height, st.width
        clock = time.perf_counter()
        feats = np.empty((n, st.n_ch), np.float32)
        if st.use_rgb:
            if st.sh_degree is None:
                feats[:, :3] = st.colors
            else:
                rgb = np.empty((n, 3), np.float32)
                _sh_fwd(st.colors, st.means, st.campos, st.sh_degree, st.radii, rgb)
                feats[:, :3] = rgb
                st.rgb = rgb
        if st.use_depth:
            feats[:, -1] = st.depths
        st.feats = feats
        out_feat = np.empty((H, W, st.n_ch), np.float32)
        st.packed_feats = np.ascontiguousarray(feats[st.order])
        now = time.perf_counter()
        st.timings["sh"] = now - clock
        clock = now
        frozen = st.frozen
        if frozen is not None and frozen.records is not None:
            _replay_fwd(st.offsets, st.ids, st.packed_feats, W, H, st.tile_size, st.tiles_x, *frozen.records,
                        out_feat)
            out_t = frozen.out_t.copy()
            st.records = frozen.records
        else:
            out_t = np.empty((H, W), np.float32)
            # Record when a backward may follow, and for frozen geometry the cache keeps (its later calls replay).
            record = st.needs_grad or (frozen is not None and frozen.cache is not None)
            records = _record_arrays(st, st) if record else (_NO_I64, _NO_I64, _NO_I32, _NO_U16, _NO_F32)
            # Tiles differ a lot in cost (sky vs detail): hand them out dynamically, a few at a time.
            with numba.parallel_chunksize(TILE_CHUNK):
                _composite_fwd(st.offsets, st.ids, st.rec, st.packed_feats, W, H, st.tile_size, st.tiles_x,
                               out_feat, out_t, record, *records)
            if record and (records[1] < 0).any():
                raise RuntimeError("cpu rasterizer: a tile composited more pairs than its record capacity")
            st.records = records if record else None
            if frozen is not None and frozen.records is None and record and frozen.keeps_records(
                    int(records[1].sum()), st.ids.shape[0]):
                frozen.records, frozen.out_t = _compacted(records), out_t.copy()
        st.timings["composite"] = time.perf_counter() - clock
        st.out_t = out_t
        ctx.st = st
        return torch.from_numpy(out_feat), torch.from_numpy(out_t).unsqueeze(-1)

    @staticmethod
    def backward(ctx, g_feat, g_t):
        st = ctx.st
        need_means, need_quats, need_scales, need_opac, need_colors, need_m2d = ctx.needs_input_grad[:6]
        need_proj = need_means or need_quats or need_scales
        # With SH colours the means also get the view-direction term of the SH backward.
        sh_means = need_means and st.use_rgb and st.sh_degree is not None
        want_rgb = st.use_rgb and (need_colors or sh_means)  # a depth-only render does not depend on the colours
        n, n_ch = st.feats.shape
        H, W = st.height, st.width
        if st.records is None:
            raise RuntimeError("cpu rasterizer: backward through a render made without gradients")
        clock = time.perf_counter()
        timings = st.timings
        g_feat_np = (g_feat if g_feat is not None else torch.zeros(H, W, n_ch)).float().contiguous().numpy()
        v_means = v_quats = v_scales = v_opac = v_means2d = v_rgb = None
        if need_proj or need_opac or need_m2d:
            g_t_np = (g_t if g_t is not None else torch.zeros(H, W, 1)).float().contiguous().numpy()[..., 0]
            pair_grad = np.zeros((st.ids.shape[0], 6 + n_ch), np.float32)
            with numba.parallel_chunksize(TILE_CHUNK):
                _composite_bwd(st.offsets, st.ids, st.rec, st.packed_feats, W, H, st.tile_size, st.tiles_x,
                               st.out_t, g_feat_np, g_t_np, *st.records, pair_grad)
            now = time.perf_counter()
            timings["composite_bwd"] = now - clock
            clock = now
            gsum = np.zeros((n, 6 + n_ch))
            gsum[st.order] = _reduce_pairs(st.ids, pair_grad, st.order.shape[0])
            v_means2d = gsum[:, 0:2].astype(np.float32)
            v_opac = gsum[:, 5].astype(np.float32)
            if need_proj:
                v_conics = gsum[:, 2:5].astype(np.float32)
                v_depths = gsum[:, 5 + n_ch].astype(np.float32) if st.use_depth else np.zeros(n, np.float32)
                v_means = np.empty((n, 3), np.float32)
                v_quats = np.empty((n, 4), np.float32)
                v_scales = np.empty((n, 3), np.float32)
                _project_bwd(st.means, st.quats, st.scales, st.view, st.kmat, W, H, st.eps2d, st.radii, v_means2d,
                             v_conics, v_depths, v_means, v_quats, v_scales)
            if want_rgb:
                v_rgb = np.ascontiguousarray(gsum[:, 6:9], dtype=np.float32)
        elif want_rgb:
            pair_rgb = np.zeros((st.ids.shape[0], 3), np.float32)
            with numba.parallel_chunksize(TILE_CHUNK):
                _composite_bwd_rgb(st.offsets, st.ids, W, H, st.tile_size, st.tiles_x, st.out_t, g_feat_np,
                                   *st.records, pair_rgb)
            now = time.perf_counter()
            timings["composite_bwd"] = now - clock
            clock = now
            gsum = np.zeros((n, 3))
            gsum[st.order] = _reduce_pairs(st.ids, pair_rgb, st.order.shape[0])
            v_rgb = np.ascontiguousarray(gsum, dtype=np.float32)
        v_colors = None
        if v_rgb is not None:
            if st.sh_degree is None:
                v_colors = v_rgb
            else:
                v_colors = np.empty(st.colors.shape, np.float32)
                _sh_bwd(st.colors, st.means, st.campos, st.sh_degree, st.radii, st.rgb, v_rgb, sh_means, v_colors,
                        v_means if sh_means else _NO_MEANS)
        timings["project_sh_bwd"] = time.perf_counter() - clock
        out = (v_means, v_quats, v_scales, v_opac, v_colors, v_means2d)
        return tuple(None if (g is None or not need) else torch.from_numpy(g)
                     for g, need in zip(out, ctx.needs_input_grad[:6])) + (None,)


def render_features_cpu(
    means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor, colors: torch.Tensor,
    viewmat: torch.Tensor, K: torch.Tensor, width: int, height: int, sh_degree: int | None, use_rgb: bool,
    use_depth: bool, near_plane: float, far_plane: float, eps2d: float, tile_size: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, dict]:
    """The cpu backend of ``training.raster.rasterize.rasterize``: returns (features (H,W,C) without background,
    final transmittance (H,W,1), means2d (N,2) whose .grad receives the screen-space gradient, radii (N,) int32,
    depths (N,), timings). Gradients flow to means, quats, scales, opacities and colors (not to viewmat or K).
    Inputs in another float dtype are converted to float32 (autograd converts their gradients back).
    Geometry that needs no gradient and equals the previous call's bit for bit, seen by the same camera, reuses
    that call's projection, tile lists and composited pairs (cpu_replay): the same results, much faster.
    ``timings``: seconds of each stage (project, sort, sh, composite; after a backward also composite_bwd and
    project_sh_bwd), for the benchmarks."""
    if tile_size > MAX_TILE_SIZE:
        raise ValueError(f"the cpu rasterizer takes tiles of at most {MAX_TILE_SIZE} pixels, got {tile_size}")
    clock = time.perf_counter()
    timings: dict[str, float] = {}
    ins = [t.to(torch.float32) for t in (means, quats, scales, opacities, colors)]
    m_np, q_np, s_np, o_np, c_np = (t.detach().contiguous().numpy() for t in ins)
    n = m_np.shape[0]
    view = viewmat.detach().to(torch.float64).contiguous().numpy()
    kmat = K.detach().to(torch.float64).contiguous().numpy()
    tiles_x = (width + tile_size - 1) // tile_size
    tiles_y = (height + tile_size - 1) // tile_size
    frozen = None
    if not any(t.requires_grad for t in ins[:4]):
        key = (m_np, q_np, s_np, o_np, view, kmat)
        params = (width, height, near_plane, far_plane, eps2d, tile_size)
        frozen = FROZEN.lookup(key, params)
    if frozen is not None:
        means2d, conics, depths, radii, order, offsets, ids, rec = frozen.proj
    else:
        means2d = np.empty((n, 2), np.float32)
        conics = np.empty((n, 3), np.float32)
        depths = np.empty(n, np.float32)
        radii = np.empty((n, 2), np.int32)
        _project_fwd(m_np, q_np, s_np, o_np, view, kmat, width, height, near_plane, far_plane, eps2d,
                     means2d, conics, depths, radii)
        now = time.perf_counter()
        timings["project"] = now - clock
        clock = now
        visible = np.flatnonzero(radii[:, 0] > 0)
        order = depth_order(depths, visible)
        offsets, ids = _bin(order, means2d, radii, tile_size, tiles_x, tiles_y)
        rec = _pack(order, means2d, conics, o_np, radii)
        if not any(t.requires_grad for t in ins[:4]):
            frozen = FROZEN.store(key, params, (means2d, conics, depths, radii, order, offsets, ids, rec))
    timings["sort"] = time.perf_counter() - clock

    # The screen-space gradient exists only where the geometry is trained (as in the reference): a colour-only
    # backward (stylization) computes no per-pair geometric terms, so there would be nothing to put in it.
    geometry_grad = torch.is_grad_enabled() and any(t.requires_grad for t in ins[:4])
    means2d_t = torch.from_numpy(means2d).clone()
    if geometry_grad:
        means2d_t.requires_grad_(True)
    st = _CompositeState(
        means=m_np, quats=q_np, scales=s_np, opac=o_np, colors=c_np, view=view, kmat=kmat, eps2d=eps2d,
        campos=-view[:3, :3].T @ view[:3, 3], sh_degree=sh_degree, use_rgb=use_rgb, use_depth=use_depth,
        n_ch=3 * use_rgb + use_depth, means2d=means2d, conics=conics, depths=depths, radii=radii,
        offsets=offsets, ids=ids, order=order, rec=rec, width=width, height=height, tile_size=tile_size,
        tiles_x=tiles_x, tiles_y=tiles_y, frozen=frozen, timings=timings,
        needs_grad=torch.is_grad_enabled() and any(t.requires_grad for t in ins))
    feat_img, trans = _RasterizeCPU.apply(*ins, means2d_t, st)
    radii_out = torch.from_numpy(radii.max(axis=1))
    # A cached entry's arrays must not be handed out: the caller could write into them.
    depths_out = torch.from_numpy(depths.copy() if frozen is not None else depths)
    return feat_img, trans, means2d_t, radii_out, depths_out, timings
