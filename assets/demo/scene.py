"""The built-in demo scene: a procedural, richly textured 3D still life that our own code models and renders.

A tiled floor, brick walls on three sides and five objects (three spheres, a cube and a pillar) carry solid
procedural textures (gradient noise, tiles, bricks, marble, dots, checker, stripes) whose detail reaches a few
pixels, so that SIFT finds features for SfM and a stylizer has structure to work with. A numpy ray caster renders
it exactly (analytic ray/object intersection, Lambert shading with one directional light, hard shadows, 2x2
supersampling) from cameras along a smooth arc, all looking at the centre. Shading is view-independent, so a
surface point has one colour in every view; the "SfM points" are coloured surface samples that at least one
camera sees.

World frame: z up, floor at z = 0, the objects around the origin, walls at y = +3.5 and x = -7, +7; the cameras
stand on the open y < 0 side. Cameras use the project's OpenCV convention (see ``training.scene.scene``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from assets.demo.noise import GradientNoise, hash_uniform, hsv_to_rgb
from training.scene.pose import look_at
from training.scene.scene import Camera

_EPS = 1e-6
_SHADOW_OFFSET = 1e-4
_CHUNK = 8192  # rays per batch
LIGHT_DIRECTION = np.array([0.45, -0.6, 0.8]) / np.linalg.norm([0.45, -0.6, 0.8])  # towards the light
LOOK_AT = np.array([0.0, 0.3, 0.55])  # where every camera looks


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class _Rect:
    """An axis-aligned rectangle in the plane x[axis] = value, two-sided (the normal faces the incoming ray)."""

    def __init__(self, axis: int, value: float, lo: tuple[float, float], hi: tuple[float, float],
                 normal_sign: float, texture_shift: float = 0.0):
        self.axis, self.value = axis, value
        self.texture_shift = texture_shift  # walls sharing a texture get different parts of it
        self.others = [a for a in range(3) if a != axis]
        self.lo, self.hi = np.array(lo), np.array(hi)
        self.normal = np.zeros(3)
        self.normal[axis] = normal_sign  # the side the cameras see, used for the sampled points

    @property
    def area(self) -> float:
        return float(np.prod(self.hi - self.lo))

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """o, d: (N, 3) -> t (N,) (inf on a miss), normal (N, 3) facing the ray."""
        da = d[:, self.axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.value - o[:, self.axis]) / da
        t = np.where(np.isfinite(t) & (t > _EPS), t, np.inf)
        uv = o[:, self.others] + np.where(np.isfinite(t), t, 0.0)[:, None] * d[:, self.others]
        inside = np.all((uv >= self.lo) & (uv <= self.hi), axis=1)
        t = np.where(inside, t, np.inf)
        n = np.zeros_like(d)
        n[:, self.axis] = np.where(da > 0, -1.0, 1.0)
        return t, n

    def sample(self, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
        p = np.empty((count, 3))
        p[:, self.axis] = self.value
        p[:, self.others] = rng.uniform(self.lo, self.hi, size=(count, 2))
        return p, np.broadcast_to(self.normal, p.shape).copy()

    def local(self, p: np.ndarray) -> np.ndarray:
        """(in-plane u, in-plane v, offset along the normal): for walls u runs along the wall and v up."""
        return np.stack([p[:, self.others[0]] + self.texture_shift, p[:, self.others[1]], p[:, self.axis]], -1)


class _Sphere:
    def __init__(self, center: tuple[float, float, float], radius: float):
        self.center, self.radius = np.array(center), float(radius)

    @property
    def area(self) -> float:
        return 4.0 * np.pi * self.radius**2

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        oc = o - self.center
        a = np.einsum("ij,ij->i", d, d)
        b = np.einsum("ij,ij->i", oc, d)
        c = np.einsum("ij,ij->i", oc, oc) - self.radius**2
        disc = b * b - a * c
        root = np.sqrt(np.maximum(disc, 0.0))
        t0 = (-b - root) / a
        t1 = (-b + root) / a
        t = np.where(t0 > _EPS, t0, np.where(t1 > _EPS, t1, np.inf))
        t = np.where(disc >= 0.0, t, np.inf)
        p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
        return t, (p - self.center) / self.radius

    def sample(self, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
        n = rng.normal(size=(count, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return self.center + self.radius * n, n

    def local(self, p: np.ndarray) -> np.ndarray:
        return p - self.center


class _Box:
    """A box resting on its base, rotated by ``angle`` about the vertical axis."""

    def __init__(self, center: tuple[float, float, float], half: tuple[float, float, float], angle: float):
        self.center, self.half = np.array(center), np.array(half)
        self.rot = _rot_z(angle)  # local -> world

    @property
    def area(self) -> float:
        hx, hy, hz = self.half
        return 8.0 * (hx * hy + hx * hz + hy * hz)

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # Most rays miss the box: test them against its bounding sphere first and run the slabs on the rest.
        t = np.full(len(o), np.inf)
        n = np.zeros_like(d)
        oc = o - self.center
        b = np.einsum("ij,ij->i", oc, d)
        c = np.einsum("ij,ij->i", oc, oc) - float(self.half @ self.half)
        near = np.flatnonzero(b * b - np.einsum("ij,ij->i", d, d) * c >= 0.0)
        if len(near):
            t[near], n[near] = self._slabs(oc[near], d[near])
        return t, n

    def _slabs(self, oc: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ol = oc @ self.rot  # rows times R = R^T applied to each row
        dl = d @ self.rot
        rows = np.arange(len(ol))
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / dl
            t1 = (-self.half - ol) * inv
            t2 = (self.half - ol) * inv
        tlo = np.nan_to_num(np.minimum(t1, t2), nan=-np.inf)
        thi = np.nan_to_num(np.maximum(t1, t2), nan=np.inf)
        axis = np.argmax(tlo, axis=1)
        tmin = tlo[rows, axis]
        tmax = thi.min(axis=1)
        hit = (tmax >= tmin) & (tmin > _EPS)
        t = np.where(hit, tmin, np.inf)
        nl = np.zeros_like(d)
        nl[rows, axis] = -np.sign(dl[rows, axis])
        return t, nl @ self.rot.T

    def sample(self, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
        """Uniform over the five faces other than the base (which rests on the floor and is never seen)."""
        hx, hy, hz = self.half
        # faces: +x, -x, +y, -y, +z with their areas
        areas = np.array([4 * hy * hz, 4 * hy * hz, 4 * hx * hz, 4 * hx * hz, 4 * hx * hy])
        face = rng.choice(5, size=count, p=areas / areas.sum())
        q = rng.uniform(-1.0, 1.0, size=(count, 3)) * self.half
        nl = np.zeros((count, 3))
        for f, (axis, sign) in enumerate(((0, 1), (0, -1), (1, 1), (1, -1), (2, 1))):
            sel = face == f
            q[sel, axis] = sign * self.half[axis]
            nl[sel, axis] = sign
        return q @ self.rot.T + self.center, nl @ self.rot.T

    def local(self, p: np.ndarray) -> np.ndarray:
        return (p - self.center) @ self.rot


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _mix(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    return a + (b - a) * t[..., None]


class DemoWorld:
    """The demo geometry with its textures and lighting; everything seeded by ``seed``.

    Object ids: -1 sky (a miss), then the index into ``self.objects``."""

    def __init__(self, seed: int = 0):
        self.seed = seed
        self.noise = GradientNoise(seed)
        self.objects = [
            _Rect(2, 0.0, (-14.0, -14.0), (14.0, 14.0), +1.0),  # floor
            # Back and side walls: a room open towards the cameras, so that no view looks out at a blank sky.
            _Rect(1, 3.5, (-7.0, 0.0), (7.0, 5.0), -1.0),
            _Rect(0, -7.0, (-6.5, 0.0), (3.5, 5.0), +1.0, texture_shift=-40.0),
            _Rect(0, 7.0, (-6.5, 0.0), (3.5, 5.0), -1.0, texture_shift=40.0),
            _Sphere((0.0, 0.4, 0.95), 0.95),
            _Sphere((-1.75, -0.55, 0.55), 0.55),
            _Sphere((1.55, 1.25, 0.6), 0.6),
            _Box((1.35, -0.85, 0.42), (0.42, 0.42, 0.42), np.radians(28.0)),
            _Box((-1.25, 1.65, 0.95), (0.28, 0.28, 0.95), np.radians(-17.0)),
        ]
        self.textures: list[Callable[[np.ndarray], np.ndarray]] = [
            self._floor, self._wall, self._wall, self._wall, self._marble, self._swirl, self._dots, self._checker, self._stripes,
        ]

    # --- geometry -------------------------------------------------------------------------------------------------

    def intersect(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearest hit of each ray. o, d: (N, 3) -> t (N,) (inf on a miss), object id (N,) (-1 on a miss),
        normal (N, 3) facing the ray (unit)."""
        t_best = np.full(len(o), np.inf)
        ids = np.full(len(o), -1, dtype=np.int64)
        normals = np.zeros_like(d)
        for k, obj in enumerate(self.objects):
            t, n = obj.intersect(o, d)
            closer = t < t_best
            t_best = np.where(closer, t, t_best)
            ids[closer] = k
            normals[closer] = n[closer]
        return t_best, ids, normals

    # --- appearance -----------------------------------------------------------------------------------------------

    def albedo(self, p: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Surface colour (no lighting) of points p (N, 3) on objects ids (N,) -> (N, 3)."""
        out = np.zeros((len(p), 3))
        for k, texture in enumerate(self.textures):
            sel = ids == k
            if np.any(sel):
                out[sel] = texture(self.objects[k].local(p[sel]))
        return np.clip(out, 0.0, 1.0)

    def shade(self, p: np.ndarray, normals: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Lit colour of surface points: albedo x (sky ambient + Lambert x shadow). Independent of the viewer.

        p, normals: (N, 3); ids: (N,) -> (N, 3) in [0, 1]."""
        lambert = np.clip(normals @ LIGHT_DIRECTION, 0.0, None)
        lit = lambert > 0.0
        if np.any(lit):
            origins = p[lit] + _SHADOW_OFFSET * normals[lit]
            t, _, _ = self.intersect(origins, np.broadcast_to(LIGHT_DIRECTION, origins.shape).copy())
            shadow = np.ones(len(p))
            shadow[lit] = np.where(np.isfinite(t), 0.0, 1.0)
            lambert = lambert * shadow
        ambient = 0.32 + 0.12 * normals[:, 2]
        return np.clip(self.albedo(p, ids) * (ambient + 0.62 * lambert)[:, None], 0.0, 1.0)

    def sky(self, d: np.ndarray) -> np.ndarray:
        """Background colour for rays that miss everything, d: (N, 3) unit -> (N, 3)."""
        up = np.clip(d[:, 2], -1.0, 1.0)
        base = _mix(np.array([0.78, 0.84, 0.92]), np.array([0.30, 0.45, 0.78]), _smoothstep(-0.1, 0.6, up))
        clouds = _smoothstep(0.05, 0.45, self.noise.fbm(d * 3.0, octaves=3))
        return _mix(base, np.array([0.96, 0.96, 0.97]), 0.7 * clouds)

    def radiance(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Colour seen along rays o, d: (N, 3) -> (N, 3)."""
        t, ids, normals = self.intersect(o, d)
        out = np.empty((len(o), 3))
        miss = ids < 0
        out[miss] = self.sky(d[miss])
        hit = ~miss
        out[hit] = self.shade(o[hit] + t[hit, None] * d[hit], normals[hit], ids[hit])
        return out

    # --- textures (solid: functions of the point in the object's own frame) ----------------------------------------

    def _speckle(self, q: np.ndarray, frequency: float = 8.0) -> np.ndarray:
        """Fine brightness grain that gives every surface pixel-scale features. (N, 3) -> (N,)."""
        return 0.12 * self.noise(q * frequency)

    def _floor(self, q: np.ndarray) -> np.ndarray:
        size = 0.6
        ix, iy = np.floor(q[:, 0] / size), np.floor(q[:, 1] / size)
        palette = np.array([[0.80, 0.55, 0.30], [0.70, 0.35, 0.25], [0.45, 0.50, 0.58], [0.88, 0.80, 0.62],
                            [0.35, 0.45, 0.35], [0.60, 0.42, 0.55]])
        pick = (hash_uniform(ix, iy, seed=self.seed + 11) * len(palette)).astype(np.int64)
        tile = palette[pick] * (0.8 + 0.35 * hash_uniform(ix, iy, seed=self.seed + 12))[:, None]
        fx, fy = q[:, 0] / size - ix, q[:, 1] / size - iy
        edge = np.minimum(np.minimum(fx, 1.0 - fx), np.minimum(fy, 1.0 - fy))
        grain = 1.0 + 0.3 * self.noise.fbm(q * 2.5, octaves=3) + self._speckle(q)
        colour = tile * grain[:, None]
        colour = _mix(np.array([0.16, 0.14, 0.13]), colour, _smoothstep(0.03, 0.06, edge))
        # Far from the objects the floor calms down to a plain colour, so the distant, grazing floor does not alias.
        r = np.hypot(q[:, 0], q[:, 1])
        return _mix(colour, np.array([0.55, 0.50, 0.45]), _smoothstep(7.0, 12.0, r))

    def _wall(self, q: np.ndarray) -> np.ndarray:
        bw, bh = 0.5, 0.25
        row = np.floor(q[:, 1] / bh)
        x = q[:, 0] / bw + 0.5 * (row % 2)
        col = np.floor(x)
        hue = hash_uniform(col, row, seed=self.seed + 21)
        sat = 0.45 + 0.4 * hash_uniform(col, row, seed=self.seed + 22)
        val = 0.6 + 0.35 * hash_uniform(col, row, seed=self.seed + 23)
        brick = hsv_to_rgb(hue, sat, val)
        # A large painted swirl over the bricks (a mural), so the wall also has structure at the scale of metres.
        paint = self.noise.fbm(q * 0.45, octaves=3)
        mural = hsv_to_rgb(0.6 + 1.5 * paint, 0.8, 0.9)
        brick = _mix(brick, mural, 0.75 * _smoothstep(0.05, 0.12, paint))
        brick = brick * (1.0 + 0.25 * self.noise.fbm(q * 3.0, octaves=3) + self._speckle(q))[:, None]
        fx, fz = x - col, q[:, 1] / bh - row
        edge = np.minimum(np.minimum(fx, 1.0 - fx) * bw, np.minimum(fz, 1.0 - fz) * bh)
        return _mix(np.array([0.82, 0.80, 0.76]), brick, _smoothstep(0.012, 0.022, edge))

    def _marble(self, q: np.ndarray) -> np.ndarray:
        t = np.sin(5.0 * (q[:, 0] + 0.6 * q[:, 2]) + 6.0 * self.noise.fbm(q * 1.6, octaves=4))
        colour = _mix(np.array([0.08, 0.16, 0.55]), np.array([0.92, 0.92, 0.96]), 0.5 + 0.5 * t)
        vein = 1.0 - _smoothstep(0.0, 0.12, np.abs(t))
        colour = _mix(colour, np.array([0.95, 0.70, 0.15]), vein)
        return colour * (1.0 + self._speckle(q))[:, None]

    def _swirl(self, q: np.ndarray) -> np.ndarray:
        hue = 1.6 * self.noise.fbm(q * 2.2, octaves=4) + 0.4 * q[:, 2]
        colour = hsv_to_rgb(hue, 0.85, 0.9)
        return colour * (1.0 + self._speckle(q))[:, None]

    def _dots(self, q: np.ndarray) -> np.ndarray:
        g = q * 6.0
        cell = np.floor(g + 0.5)
        dist = np.linalg.norm(g - cell, axis=1)
        base = np.array([0.18, 0.55, 0.22]) * (1.0 + 0.35 * self.noise.fbm(q * 3.0, octaves=3))[:, None]
        dot = hsv_to_rgb(hash_uniform(cell[:, 0], cell[:, 1], cell[:, 2], seed=self.seed + 31), 0.8, 0.95)
        colour = _mix(dot, base, _smoothstep(0.3, 0.36, dist))
        return colour * (1.0 + self._speckle(q))[:, None]

    def _checker(self, q: np.ndarray) -> np.ndarray:
        # Half a square of offset: the faces lie at multiples of the square size, where floor() would flicker.
        c = np.floor(q / 0.14 + 0.5)
        odd = (c.sum(axis=1) % 2).astype(bool)
        colour = np.where(odd[:, None], np.array([0.85, 0.12, 0.10]), np.array([0.96, 0.82, 0.22]))
        return colour * (1.0 + 0.3 * self.noise.fbm(q * 4.0, octaves=3) + self._speckle(q))[:, None]

    def _stripes(self, q: np.ndarray) -> np.ndarray:
        s = (q[:, 0] + q[:, 1]) * 2.5 + q[:, 2] * 4.0 + 0.5 * self.noise.fbm(q * 2.0, octaves=3)
        k = np.floor(s)
        colour = hsv_to_rgb(hash_uniform(k, seed=self.seed + 41), 0.75, 0.9)
        frac = s - k
        colour = colour * (0.55 + 0.45 * _smoothstep(0.0, 0.08, frac) * _smoothstep(1.0, 0.92, frac))[:, None]
        return colour * (1.0 + self._speckle(q))[:, None]

    # --- cameras --------------------------------------------------------------------------------------------------

    def render(self, camera: Camera, supersample: int = 2) -> np.ndarray:
        """Render one view: (H, W, 3) float32 in [0, 1], each pixel the mean of supersample^2 rays."""
        s = supersample
        offsets = (np.arange(s) + 0.5) / s
        u = (np.arange(camera.width)[:, None] + offsets[None, :]).reshape(-1)  # (W*s,)
        v = (np.arange(camera.height)[:, None] + offsets[None, :]).reshape(-1)  # (H*s,)
        uu, vv = np.meshgrid(u, v)  # (H*s, W*s)
        R = camera.world_to_camera[:3, :3]
        dirs = camera.rays(uu, vv).reshape(-1, 3) @ R  # R^T applied to each row
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        origins = np.broadcast_to(camera.center, dirs.shape).copy()
        # Chunks keep numpy's temporaries small and cache-friendly.
        colour = np.concatenate([self.radiance(origins[i:i + _CHUNK], dirs[i:i + _CHUNK])
                                 for i in range(0, len(dirs), _CHUNK)])
        colour = colour.reshape(camera.height, s, camera.width, s, 3)
        return colour.mean(axis=(1, 3)).astype(np.float32)

    def visible(self, points: np.ndarray, camera: Camera, tolerance: float = 1e-4) -> np.ndarray:
        """Whether each surface point (P, 3) is inside ``camera``'s image and not hidden by anything -> (P,) bool."""
        (u, v), front = (a.T for a in camera.project(points, near=0.05))
        inside = front & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
        result = np.zeros(len(points), dtype=bool)
        if np.any(inside):
            o = np.broadcast_to(camera.center, (int(inside.sum()), 3)).copy()
            to_p = points[inside] - o
            dist = np.linalg.norm(to_p, axis=1)
            t, _, _ = self.intersect(o, to_p / dist[:, None])
            result[inside] = t >= dist - tolerance
        return result

    def sample_surface(self, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``count`` surface samples, denser on the objects than on floor and wall -> points (count, 3),
        normals (count, 3) (the side the cameras see), object ids (count,)."""
        density = np.array([1.0, 0.6, 0.6, 0.6] + [8.0] * (len(self.objects) - 4))
        # The floor beyond the cameras' reach would only waste samples: sample its central part.
        areas = np.array([12.0 * 8.0] + [o.area for o in self.objects[1:]])
        weights = density * areas
        per_object = rng.multinomial(count, weights / weights.sum())
        points, normals, ids = [], [], []
        for k, (obj, n) in enumerate(zip(self.objects, per_object)):
            if k == 0:
                p = np.zeros((n, 3))
                p[:, :2] = rng.uniform((-6.0, -4.5), (6.0, 3.5), size=(n, 2))
                nrm = np.broadcast_to(obj.normal, p.shape).copy()
            else:
                p, nrm = obj.sample(rng, n)
            points.append(p)
            normals.append(nrm)
            ids.append(np.full(n, k, dtype=np.int64))
        return np.concatenate(points), np.concatenate(normals), np.concatenate(ids)


def demo_cameras(num_views: int = 32, width: int = 256, height: int = 192, arc_degrees: float = 150.0,
                 radius: float = 5.6, height_m: float = 2.0, fov_x_degrees: float = 60.0) -> list[Camera]:
    """Cameras on a horizontal arc of ``arc_degrees`` around the objects (rising gently towards the middle of
    the arc), all looking at ``LOOK_AT``; pinhole with the principal point at the image centre."""
    if num_views < 1:
        raise ValueError("num_views must be at least 1")
    fx = 0.5 * width / np.tan(np.radians(fov_x_degrees) / 2.0)
    s = np.linspace(0.0, 1.0, num_views) if num_views > 1 else np.array([0.5])
    angles = np.radians(arc_degrees) * (s - 0.5)
    cameras = []
    for i, (si, a) in enumerate(zip(s, angles)):
        center = np.array([radius * np.sin(a), -radius * np.cos(a), height_m + 0.5 * np.sin(np.pi * si)])
        center[:2] += LOOK_AT[:2]
        cameras.append(Camera(name=f"view_{i:03d}.png", width=width, height=height, fx=float(fx), fy=float(fx),
                              cx=width / 2.0, cy=height / 2.0,
                              world_to_camera=look_at(center, LOOK_AT, up=(0.0, 0.0, 1.0))))
    return cameras


@dataclass
class DemoScene:
    cameras: list[Camera]
    images: list[np.ndarray]  # each (H, W, 3) float32 in [0, 1]
    points: np.ndarray  # (P, 3) float32 surface points seen by at least one camera
    point_colors: np.ndarray  # (P, 3) float32 in [0, 1], the shaded surface colour at each point


def demo_points(world: DemoWorld, cameras: list[Camera], num_points: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``num_points`` coloured surface points, each visible from at least one camera -> (P, 3), (P, 3) float32."""
    rng = np.random.default_rng(seed + 1000)
    candidates, normals, ids = world.sample_surface(rng, 3 * num_points)
    seen = np.zeros(len(candidates), dtype=bool)
    for camera in cameras:
        todo = ~seen
        seen[todo] = world.visible(candidates[todo], camera)
    keep = np.flatnonzero(seen)
    if len(keep) > num_points:
        keep = np.sort(rng.choice(keep, size=num_points, replace=False))
    colours = world.shade(candidates[keep], normals[keep], ids[keep])
    return candidates[keep].astype(np.float32), colours.astype(np.float32)


def make_demo_scene(num_views: int = 32, width: int = 256, height: int = 192, num_points: int = 4000,
                    seed: int = 0, supersample: int = 2, progress: bool = False) -> DemoScene:
    """Render the demo scene from ``demo_cameras(num_views, width, height)`` and sample its SfM-like points."""
    world = DemoWorld(seed)
    cameras = demo_cameras(num_views, width, height)
    views = cameras
    if progress:
        from tqdm import tqdm

        views = tqdm(cameras, desc="rendering demo scene", unit="view")
    images = [world.render(camera, supersample) for camera in views]
    points, colours = demo_points(world, cameras, num_points, seed)
    return DemoScene(cameras, images, points, colours)


def write_demo_scene(folder: str | Path, scene: DemoScene) -> Path:
    """Write ``scene`` as a COLMAP scene folder: ``images/*.png`` and a binary model in ``sparse/0``.

    ``training.scene.loader.load_scene(folder)`` reads it back. Returns ``folder``."""
    from training.scene.colmap_io import write_colmap_model
    from training.scene.image_io import write_image

    folder = Path(folder)
    for camera, image in zip(scene.cameras, scene.images):
        write_image(folder / "images" / camera.name, image)
    model = folder / "sparse" / "0"
    model.mkdir(parents=True, exist_ok=True)
    write_colmap_model(model, scene.cameras, points=scene.points, point_colors=scene.point_colors, binary=True)
    return folder
