"""The built-in demo style: a procedurally painted picture of bold, swirling brush strokes.

A noise-driven colour field over a bold palette is the underpainting; a flow field (a few vortices plus gradient
noise, in the spirit of a swirling night sky) steers thousands of strokes painted coarse to fine. Each stroke has a
rounded, tapered body, bristle striations across it and a darker rim where paint piles up, so the style has clear
texture at several scales for the style features to latch on to. Deterministic for a given seed and size.
"""

from __future__ import annotations

import numpy as np

from assets.demo.noise import GradientNoise

# Bold, saturated oil colours; the underpainting walks through them in this order.
PALETTE = np.array([
    [0.05, 0.09, 0.32],  # deep ultramarine
    [0.10, 0.28, 0.70],  # cobalt
    [0.30, 0.62, 0.90],  # cerulean
    [0.96, 0.93, 0.78],  # cream white
    [0.99, 0.80, 0.10],  # cadmium yellow
    [0.95, 0.45, 0.08],  # orange
    [0.80, 0.14, 0.12],  # vermilion
    [0.08, 0.48, 0.32],  # emerald
    [0.05, 0.09, 0.32],  # back to ultramarine, so the walk is cyclic
])

# (stroke width px, stroke length px, strokes per 512x512) for each layer, coarse to fine.
LAYERS = ((18.0, 70.0, 420), (10.0, 44.0, 1300), (5.0, 24.0, 2600))


def _palette_lookup(t: np.ndarray) -> np.ndarray:
    """t (...) in [0, 1) cyclic -> (..., 3) colour interpolated along PALETTE."""
    x = (t % 1.0) * (len(PALETTE) - 1)
    i = np.floor(x).astype(np.int64)
    f = (x - i)[..., None]
    # Narrow the blends so that colours stay pure across most of each band.
    f = np.clip((f - 0.3) / 0.4, 0.0, 1.0)
    return PALETTE[i] * (1.0 - f) + PALETTE[np.minimum(i + 1, len(PALETTE) - 1)] * f


def _fields(noise: GradientNoise, size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The underpainting colour (size, size, 3) and the unit stroke direction field (size, size, 2) (x, y)."""
    y, x = np.mgrid[0:size, 0:size] / size  # in [0, 1)
    p = np.stack([x, y, np.zeros_like(x)], axis=-1)
    # Vortices: strokes circle around them, and their rings get their own colours.
    centres = rng.uniform(0.15, 0.85, size=(4, 2))
    radii = rng.uniform(0.10, 0.2, size=4)
    spins = rng.choice([-1.0, 1.0], size=4)
    flow = np.stack([np.cos(np.pi * noise.fbm(p * 2.0, 3)), np.sin(np.pi * noise.fbm(p * 2.0 + 17.0, 3))], -1)
    ring_t = np.zeros_like(x)
    ring_w = np.zeros_like(x)
    for (cx, cy), r, spin in zip(centres, radii, spins):
        dx, dy = x - cx, y - cy
        dist = np.hypot(dx, dy) + 1e-9
        weight = np.exp(-((dist / (1.6 * r)) ** 2))
        tangent = np.stack([-dy, dx], -1) / dist[..., None] * spin
        flow = flow * (1.0 - weight[..., None]) + 3.0 * tangent * weight[..., None]
        ring_t += weight * (dist / r * 0.9)
        ring_w += weight
    flow /= np.linalg.norm(flow, axis=-1, keepdims=True) + 1e-9
    t = 0.5 + 0.55 * noise.fbm(p * 1.6 + 5.0, 4) + 0.12 * y
    t = t * (1.0 - np.clip(ring_w, 0, 1)) + (0.42 + ring_t) * np.clip(ring_w, 0, 1)
    return _palette_lookup(t), flow


def _stroke_paths(starts: np.ndarray, flow: np.ndarray, length: float, steps: int) -> np.ndarray:
    """Trace strokes along the flow field from (S, 2) start points (x, y px) -> (S, steps + 1, 2)."""
    size = flow.shape[0]
    step = length / steps
    path = [starts]
    pos = starts.copy()
    direction = None
    for _ in range(steps):
        ij = np.clip(pos.astype(np.int64), 0, size - 1)
        d = flow[ij[:, 1], ij[:, 0]]
        if direction is not None:  # keep following the same way round (the field is a line field at vortex edges)
            d = np.where((np.einsum("ij,ij->i", d, direction) < 0)[:, None], -d, d)
        direction = d
        pos = pos + step * d
        path.append(pos)
    return np.stack(path, axis=1)


def _paint_stroke(canvas: np.ndarray, path: np.ndarray, width: float, colour: np.ndarray,
                  rng: np.random.Generator) -> None:
    """Composite one stroke (a polyline (M, 2) in px) onto canvas (H, W, 3) in place."""
    size = canvas.shape[0]
    half = width / 2.0
    lo = np.floor(path.min(axis=0) - half - 1).astype(int)
    hi = np.ceil(path.max(axis=0) + half + 1).astype(int)
    x0, y0 = max(lo[0], 0), max(lo[1], 0)
    x1, y1 = min(hi[0], size), min(hi[1], size)
    if x1 <= x0 or y1 <= y0:
        return
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float32) + np.float32(0.5)
    P = np.stack([xs, ys], -1)[:, :, None, :]  # (h, w, 1, 2)
    path = path.astype(np.float32)
    A, B = path[:-1], path[1:]
    AB = B - A
    seg_len = np.sqrt((AB**2).sum(axis=1)) + np.float32(1e-6)
    PA = P - A  # (h, w, S, 2)
    t = np.clip((PA[..., 0] * AB[:, 0] + PA[..., 1] * AB[:, 1]) / seg_len**2, 0.0, 1.0)
    dist2 = (PA[..., 0] - t * AB[:, 0]) ** 2 + (PA[..., 1] - t * AB[:, 1]) ** 2  # (h, w, S)
    seg = np.argmin(dist2, axis=-1)
    pick = seg[..., None]
    d = np.sqrt(np.take_along_axis(dist2, pick, -1)[..., 0])
    along = (np.concatenate([[0.0], np.cumsum(seg_len)])[seg] + np.take_along_axis(t, pick, -1)[..., 0]
             * seg_len[seg]) / seg_len.sum()
    unit = AB[seg] / seg_len[seg][..., None]
    rel = P[:, :, 0, :] - A[seg]
    across = (unit[..., 0] * rel[..., 1] - unit[..., 1] * rel[..., 0]) / half  # in [-1, 1] inside the stroke
    # Round-ended body, thinning towards the tail as the brush runs out of paint.
    taper = 1.0 - 0.45 * along
    alpha = np.clip((half * taper - d) / 1.2 + 0.5, 0.0, 1.0) * 0.95
    freq = rng.uniform(2.5, 4.5)
    phase = rng.uniform(0, 2 * np.pi)
    bristles = 1.0 + 0.16 * np.sin(2 * np.pi * freq * across + phase) + 0.06 * np.sin(23.0 * across + 3 * phase)
    rim = 1.0 - 0.28 * np.clip((np.abs(across) / taper - 0.7) / 0.3, 0.0, 1.0)
    shade = (bristles * rim)[..., None]
    region = canvas[y0:y1, x0:x1]
    region += alpha[..., None] * (np.clip(colour * shade, 0.0, 1.0) - region)


def make_style_image(size: int = 512, seed: int = 0) -> np.ndarray:
    """Paint the demo style: (size, size, 3) float32 in [0, 1]."""
    rng = np.random.default_rng(seed)
    noise = GradientNoise(seed + 7)
    field_colour, flow = _fields(noise, size, rng)
    canvas = field_colour * 0.85
    scale = size / 512.0
    for width, length, count in LAYERS:
        count = max(1, int(round(count * scale * scale)))
        starts = rng.uniform(0, size, size=(count, 2))
        paths = _stroke_paths(starts, flow, length * scale, steps=8)
        ij = np.clip(starts.astype(np.int64), 0, size - 1)
        colours = field_colour[ij[:, 1], ij[:, 0]]
        # Each loaded brush differs a little in tone from the underpainting beneath it.
        colours = colours * rng.uniform(0.8, 1.15, size=(count, 1)) + rng.normal(0, 0.04, size=(count, 3))
        for path, colour in zip(paths, colours):
            _paint_stroke(canvas, path, width * scale, colour, rng)
    # Canvas weave, visible where paint is thin.
    y, x = np.mgrid[0:size, 0:size]
    weave = 1.0 + 0.03 * np.sin(x * 2.1) * np.sin(y * 2.1)
    return np.clip(canvas * weave[..., None], 0.0, 1.0).astype(np.float32)
