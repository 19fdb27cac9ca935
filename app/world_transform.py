"""The scene's world transform: the similarity that gives a model its real size and sets which way is up.

A capture reconstructed from photos has no known scale and whatever up axis its structure-from-motion picked. The
viewer's measure tool sets the scale from one known length (two picked points), and its up tool turns the scene so
that a picked floor, or the dataset cameras' mean up, points to the viewer's up: -y, the OpenCV/COLMAP frame the
whole project uses (``app/viewer/camera.py``: a photo's up is its -y axis). Both compose into one 4x4 similarity
``x -> s R x + t``, the project's ``world`` (app/project.py), applied to the model's Gaussians
(training/model/transform.py) and to the dataset cameras, so the photos still line up with the model.

No GL and no imgui here: the viewer (app/viewer/edit/world_edit.py) and the tests use these functions alike.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from training.model.transform import quat_multiply, sh_rotation, split_similarity
from training.scene.pose import matrix_to_quat

VIEWER_UP = np.array([0.0, -1.0, 0.0])  # the viewer's up: a photo's -y axis, in the frames our files use


def scale_about(factor: float, centre) -> np.ndarray:
    """4x4 uniform scale by ``factor`` (> 0) that keeps ``centre`` where it is."""
    if not np.isfinite(factor) or factor <= 0:
        raise ValueError(f"a scale must be a positive number, got {factor}")
    m = np.eye(4)
    m[:3, :3] *= factor
    m[:3, 3] = (1.0 - factor) * np.asarray(centre, np.float64)
    return m


def rotation_between(a, b) -> np.ndarray:
    """(3, 3) the smallest rotation turning direction ``a`` onto direction ``b``."""
    a = np.asarray(a, np.float64) / np.linalg.norm(a)
    b = np.asarray(b, np.float64) / np.linalg.norm(b)
    v, c = np.cross(a, b), float(np.dot(a, b))
    if c < -1.0 + 1e-12:  # opposite: a half turn about any axis perpendicular to a
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def level(up, centre, target=VIEWER_UP) -> np.ndarray:
    """4x4 rotation about ``centre`` turning the direction ``up`` onto the viewer's up (``target``)."""
    m = np.eye(4)
    m[:3, :3] = rotation_between(up, target)
    c = np.asarray(centre, np.float64)
    m[:3, 3] = c - m[:3, :3] @ c
    return m


def cameras_up(cameras) -> np.ndarray:
    """The dataset cameras' mean up (unit): the mean of their -y axes, as the viewer orbits about."""
    up = -np.mean([c.camera_to_world[:3, 1] for c in cameras], axis=0)
    n = float(np.linalg.norm(up))
    if n < 1e-6:
        raise ValueError("the cameras' up directions cancel out: pick the floor instead")
    return up / n


def plane_normal(points, toward=None) -> np.ndarray:
    """Unit normal of the plane through 3 points, or fitted (least squares) to more; turned to the side of
    ``toward`` (a direction: which side of a floor is up) when given."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) < 3:
        raise ValueError(f"a plane needs 3 points, got {len(p)}")
    centred = p - p.mean(axis=0)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-300):
        raise ValueError("the points lie on one line: they do not make a plane")
    normal = vt[2]
    if toward is not None and float(np.dot(normal, toward)) < 0:
        normal = -normal
    return normal / np.linalg.norm(normal)


def transform_camera(camera, matrix):
    """The dataset camera moved with the scene by the similarity ``matrix``: it sees the moved scene in the same
    pixels (camera coordinates scale by s, which projection divides out)."""
    s, r, t = split_similarity(matrix)
    c2w = np.asarray(camera.camera_to_world, np.float64)
    rot = r @ c2w[:3, :3]
    centre = s * (r @ c2w[:3, 3]) + t
    w2c = np.eye(4)
    w2c[:3, :3] = rot.T
    w2c[:3, 3] = -rot.T @ centre
    return replace(camera, world_to_camera=w2c)


def transform_snapshot(snap, matrix, version: int):
    """A ModelSnapshot (activated arrays, what the viewer draws) moved by the similarity ``matrix``: the same
    arithmetic as ``transform_gaussians`` on a file's parameters (centres, rotations, scales, SH bands), in
    float64, stored as float32. ``version`` is the new snapshot's (geometry) version."""
    s, r, t = split_similarity(matrix)

    def frozen(a) -> np.ndarray:
        out = np.ascontiguousarray(a, dtype=np.float32)
        out.setflags(write=False)
        return out

    means = frozen(s * snap.means.astype(np.float64) @ r.T + t)
    scales = frozen(snap.scales.astype(np.float64) * s)
    quats = frozen(quat_multiply(matrix_to_quat(r)[None], snap.quats.astype(np.float64)))
    sh = snap.sh
    if snap.sh_degree > 0 and sh.shape[1] > 1:
        rest = sh[:, 1:].astype(np.float64)
        k = rest.shape[1]
        turned = sh_rotation(r, snap.sh_degree) @ rest.transpose(1, 0, 2).reshape(k, -1)
        sh = np.concatenate([sh[:, :1].astype(np.float64), turned.reshape(k, -1, 3).transpose(1, 0, 2)], axis=1)
    return replace(snap, version=version, geometry_version=version, means=means, scales=scales, quats=quats,
                   sh=frozen(sh))


def compose(*matrices) -> np.ndarray:
    """The product of 4x4 similarities, left to right (the last applied first), checked to stay one."""
    m = np.eye(4)
    for a in matrices:
        m = m @ np.asarray(a, np.float64)
    split_similarity(m)
    return m
