"""Camera pose maths, beside the pinhole camera (training/scene/camera.py, which owns projecting and unprojecting
points): numpy only, no torch, so that renderer_gl, the demo assets, the viewer, camera paths and every trainer use the
same functions.

- ``look_at``, ``orbit``: a camera at a point looking at another; cameras on a circle around a centre;
- ``pose_matrix``: world-to-camera from a camera centre and a camera-to-world rotation;
- quaternions (w, x, y, z): ``matrix_to_quat`` (Shepperd's method), ``quat_to_matrix`` (one or many), ``slerp``;
- ``catmull_rom``: the centripetal spline through camera centres (no overshoot or loops at unevenly spaced keys);
- ``interpolate_camera``: a camera between two (slerped rotation, centre and intrinsics interpolated), and
  ``path_camera``: a camera on the smooth path through several (video paths, the path consistency protocol);
- ``jacobian_limits``, ``splat_footprints``: where Gaussians land in an image and their 2D covariances (EWA), the
  numpy form of the rasterizer's projection (training/raster), for what needs it on the CPU without torch.

Conventions as everywhere in the project: ``world_to_camera`` is a 4x4 in OpenCV axes (x right, y down, z forward).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np


# ------------------------------------------------------------------------------------------------ poses
def look_at(eye, target, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """(4, 4) world-to-camera for a camera at ``eye`` looking at ``target``; ``up`` is the world direction that
    should appear up in the image (OpenCV's y axis points down, hence the default). Looking straight along ``up``,
    another axis stands in for it."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(-up, z)  # image right; -up because image y points down
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return w2c


def orbit(center, radius: float, count: int, up, elevation_deg: float = 20.0, start=None) -> list[np.ndarray]:
    """``count`` world-to-camera matrices evenly spaced on a circle around ``center`` (perpendicular to ``up``),
    raised by ``elevation_deg``, all looking at ``center``. ``start`` (a world direction) fixes the first one."""
    center, up = np.asarray(center, dtype=np.float64), np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    a = np.asarray(start, dtype=np.float64) if start is not None else np.array([1.0, 0.0, 0.0])
    a = a - up * (a @ up)
    if np.linalg.norm(a) < 1e-9:
        a = np.cross(up, [0.0, 0.0, 1.0]) if abs(up[2]) < 0.9 else np.cross(up, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    el = np.radians(elevation_deg)
    mats = []
    for k in range(count):
        th = 2 * np.pi * k / count
        d = np.cos(el) * (np.cos(th) * a + np.sin(th) * b) + np.sin(el) * up
        mats.append(look_at(center + radius * d, center, up))
    return mats


def pose_matrix(center, rotation_c2w) -> np.ndarray:
    """(4, 4) world-to-camera from a camera centre and a camera-to-world rotation."""
    m = np.eye(4)
    r = np.asarray(rotation_c2w, dtype=np.float64)
    m[:3, :3] = r.T
    m[:3, 3] = -r.T @ np.asarray(center, dtype=np.float64)
    return m


# ------------------------------------------------------------------------------------------------ quaternions
def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """(w, x, y, z), unit, of a rotation matrix (Shepperd's method: stable at every angle)."""
    m = np.asarray(r, dtype=np.float64)
    tr = np.trace(m)
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-300))
        q = [0.0] * 4
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrices of quaternions (w, x, y, z), normalised here: (4,) -> (3, 3), (N, 4) -> (N, 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def slerp(q0, q1, t: float) -> np.ndarray:
    """Constant-speed rotation from q0 to q1 (normalised here) along the shorter arc; t=0 gives q0, t=1 gives q1
    (up to sign, which is the same rotation)."""
    q0 = np.asarray(q0, dtype=np.float64) / np.linalg.norm(q0)
    q1 = np.asarray(q1, dtype=np.float64) / np.linalg.norm(q1)
    d = float(q0 @ q1)
    if d < 0:  # q and -q are the same rotation: take the short way round
        q1, d = -q1, -d
    if d > 0.9995:  # nearly equal: the formula divides by sin of a tiny angle; a normalised lerp is exact enough
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = math.acos(min(1.0, d))
    return (math.sin((1 - t) * theta) * q0 + math.sin(t * theta) * q1) / math.sin(theta)


# ------------------------------------------------------------------------------------------------ paths
def catmull_rom(p0, p1, p2, p3, t: float, alpha: float = 0.5) -> np.ndarray:
    """The point at ``t`` in [0, 1] between p1 and p2 of the Catmull-Rom spline through p0..p3 (alpha 0.5:
    centripetal; Barry and Goldman's pyramidal form)."""
    pts = [np.asarray(p, dtype=np.float64) for p in (p0, p1, p2, p3)]
    knots = [0.0]
    for a, b in zip(pts, pts[1:]):  # coincident keys: a tiny step, not a 0/0
        knots.append(knots[-1] + max(float(np.linalg.norm(b - a)) ** alpha, 1e-9))
    t0, t1, t2, t3 = knots
    u = t1 + t * (t2 - t1)

    def mix(a, b, ta, tb):
        return (tb - u) / (tb - ta) * a + (u - ta) / (tb - ta) * b

    a1, a2, a3 = mix(pts[0], pts[1], t0, t1), mix(pts[1], pts[2], t1, t2), mix(pts[2], pts[3], t2, t3)
    b1, b2 = mix(a1, a2, t0, t2), mix(a2, a3, t1, t3)
    return mix(b1, b2, t1, t2)


def interpolate_camera(c0, c1, t: float, name: str, center=None):
    """The camera (c0's type, a training.scene.camera.Camera) a fraction ``t`` of the way from c0 to c1: rotation
    slerped, centre ``center`` (default: on the straight line), image size and intrinsics interpolated linearly."""
    rotation = quat_to_matrix(slerp(matrix_to_quat(c0.rotation), matrix_to_quat(c1.rotation), t))
    if center is None:
        center = (1 - t) * c0.center + t * c1.center

    def lerp(a, b):
        return (1 - t) * a + t * b

    return replace(c0, name=name, width=int(round(lerp(c0.width, c1.width))),
                   height=int(round(lerp(c0.height, c1.height))), fx=lerp(c0.fx, c1.fx), fy=lerp(c0.fy, c1.fy),
                   cx=lerp(c0.cx, c1.cx), cy=lerp(c0.cy, c1.cy), world_to_camera=pose_matrix(center, rotation))


def path_camera(keys, s: float, name: str, loop: bool = False, size: tuple[int, int] | None = None):
    """The camera at ``s`` on the smooth path through the cameras ``keys``, one unit of ``s`` per segment (``s`` in
    [0, segments]; a ``loop`` returns from the last key to the first): between keys i and i + 1, at s = i + u, the
    centre is on the centripetal Catmull-Rom spline through keys i - 1 .. i + 2 (an open path's ends mirrored, so
    the first and last segments bend too), the rest ``interpolate_camera``'s. With ``size`` (width, height) the two
    keys are first resized to it, so their intrinsics relative to the image size interpolate."""
    n = len(keys)
    segments = n if loop and n > 1 else n - 1
    if segments < 1:
        return replace(keys[0].resized(*(size or (keys[0].width, keys[0].height))), name=name)
    i = min(int(s), segments - 1)
    u = s - i

    def key(j):
        return keys[j % n] if loop else keys[min(max(j, 0), n - 1)]

    c = [key(j).center for j in (i - 1, i, i + 1, i + 2)]
    if not loop:
        if i == 0:
            c[0] = 2 * c[1] - c[2]
        if i + 2 > n - 1:
            c[3] = 2 * c[2] - c[1]
    a, b = (key(i), key(i + 1)) if size is None else (key(i).resized(*size), key(i + 1).resized(*size))
    return interpolate_camera(a, b, u, name, center=catmull_rom(*c, u))


# ------------------------------------------------------------------------------------------------ splats (EWA)
def jacobian_limits(camera, margin: float) -> tuple[float, float, float, float]:
    """The limits of x/z (right, left) and y/z (bottom, top) inside the EWA Jacobian: the field of view widened by
    ``margin`` times its half-angle's tangent on each side (the rasterizer's FOV_CLAMP_MARGIN)."""
    tan_x = 0.5 * camera.width / camera.fx
    tan_y = 0.5 * camera.height / camera.fy
    return ((camera.width - camera.cx) / camera.fx + margin * tan_x, camera.cx / camera.fx + margin * tan_x,
            (camera.height - camera.cy) / camera.fy + margin * tan_y, camera.cy / camera.fy + margin * tan_y)


def splat_footprints(camera, means, quats, scales, eps2d: float, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres (N, 2) and 2D covariances (N, 2, 2) of Gaussians (world ``means``, rotations ``quats`` (w, x,
    y, z), ``scales``) in front of ``camera``: J W R S (J W R S)^T + eps2d I, the Jacobian J taken at x/z, y/z
    clamped by ``jacobian_limits(camera, margin)``, as the rasterizer does: a Gaussian just in front of the camera
    far to the side would otherwise spread over the whole picture."""
    lim_right, lim_left, lim_bottom, lim_top = jacobian_limits(camera, margin)
    p = camera.camera_points(means)
    uv, _ = camera.pixels(p)
    z = p[:, 2]
    w2c = np.asarray(camera.world_to_camera, np.float64)
    m = w2c[:3, :3] @ quat_to_matrix(quats) * np.asarray(scales, np.float64)[:, None]
    u = np.clip(p[:, 0] / z, -lim_left, lim_right)
    v = np.clip(p[:, 1] / z, -lim_top, lim_bottom)
    j = np.zeros((len(z), 2, 3))
    j[:, 0, 0], j[:, 0, 2] = camera.fx / z, -camera.fx * u / z
    j[:, 1, 1], j[:, 1, 2] = camera.fy / z, -camera.fy * v / z
    t = j @ m
    return uv, t @ t.transpose(0, 2, 1) + eps2d * np.eye(2)
