"""Align one model of the scene with another by three point pairs: a point picked on the model to move, then the
point of the other model where it belongs, three times; the similarity that maps the first three onto the second
three (Umeyama's least-squares solution: rotation, uniform scale, translation) moves the model, as one undo step.

A pick is the surface under the cursor: the view's expected depth there (the renderer's depth pass, the same
splats the view draws) unprojected through the view's camera (app/viewer/edit/world_edit.py's pick, which the measure
tools use too).
"""

from __future__ import annotations

import numpy as np

from app.viewer.edit.world_edit import pick

PAIRS = 3


def similarity_from_pairs(src, dst) -> np.ndarray:
    """The 4x4 similarity x -> s R x + t minimising sum |dst - (s R src + t)|^2 (Umeyama 1991); ValueError when
    the points do not fix one (fewer than 3, or all on a line)."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError("alignment needs at least 3 pairs of 3D points")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    var_s = float((a ** 2).sum()) / len(src)
    cov = b.T @ a / len(src)
    u, d, vt = np.linalg.svd(cov)
    if var_s <= 1e-18 or d[1] <= 1e-9 * max(d[0], 1e-300):
        raise ValueError("the picked points are on one line (or one point): pick three points that span a triangle")
    e = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        e[2, 2] = -1.0  # a reflection would fit better; the best rotation flips the weakest axis instead
    r = u @ e @ vt
    s = float(np.trace(np.diag(d) @ e)) / var_s
    m = np.eye(4)
    m[:3, :3] = s * r
    m[:3, 3] = mu_d - s * r @ mu_s
    return m


def add_pick(doc, session, ui, camera, x: float, y: float, fid: int) -> str:
    """A click at (x, y) of the picture ``camera`` shows while aligning: the next point of the pair (moving, then
    fixed); the third pair moves model ``fid``. Returns the line for the user."""
    st = ui.gizmo.align
    point = pick(ui, camera, x, y)
    if point is None:
        return ""  # pick said why
    (st.moving if st.next_is_moving() else st.fixed).append(point)
    if len(st.fixed) < PAIRS:
        which = "on the model to move" if st.next_is_moving() else "where it belongs (on the other model)"
        return f"picked {len(st.moving) + len(st.fixed)} of {2 * PAIRS}: next, a point {which}"
    matrix = similarity_from_pairs(st.moving, st.fixed)
    st.clear()
    st.active = False
    doc.transform(doc.rows_of_file(fid), matrix)
    s = float(np.linalg.det(matrix[:3, :3])) ** (1 / 3)
    return f"aligned model {doc.models.files[fid].name} by three point pairs (scale {s:.4g})"
