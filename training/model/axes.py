"""The axis conventions of model files, converted here and nowhere else.

Our models keep the axes of the reconstruction's world as graphdeco's 3DGS stores them in a PLY: "RDF" (x right,
y down, z forward, the OpenCV camera convention; ``.splat`` and the compressed PLY store the same axes). A
convention is named by where its x, y and z axes point: R/L (right, left), U/D (up, down), F/B (front, i.e. away
from the viewer, as an OpenCV camera looks; back). The sixteen names and their order are the SPZ reference's
``CoordinateSystem`` (nianticlabs/spz ``splat-types.h``; the file's code is the index + 1): eight y-up/down
("standard") and eight z-up/down ("rotated") conventions. What each format stores, and why, is in docs/editor.md
("Axes"): SPZ the PLY's RDF (as splat-transform, SuperSplat and the reference's ``ply_to_spz`` write it) unless the
file names other axes; glTF its own left-up-front (LUF, as the glTF spec and splat-transform have it).

Turning Gaussians from one convention to another is the signed permutation M with ``p' = M p``. A centre becomes
M m. Within a family (M diagonal, signs s) a rotation R becomes M R M, the quaternion (w, x, y, z) becomes
(w, sy sz x, sx sz y, sx sy z), the reference's ``flipQ``: the covariance M R S^2 R^T M is what it must be, and
it stays right when M mirrors (det -1), where no rotation of the axes could do it. Across families (M swaps y
and z) the rotation becomes P R with P = det(M) M, the proper part, as the reference's ``rotFlipQFunc``: scales
stay with their axes. The SH coefficients follow the colour: c' . Y(d) = c . Y(M^T d), within a family a sign per
coefficient by the parity of its basis function in x, y and z, across families each degree's rotation
(training/model/transform.py, which fits it from the basis, mirrors included).
"""

from __future__ import annotations

import numpy as np
import torch

from training.model.gaussians import Gaussians

AXES = ("LDB", "RDB", "LUB", "RUB", "LDF", "RDF", "LUF", "RUF",
        "LFD", "RFD", "LFU", "RFU", "LBD", "RBD", "LBU", "RBU")
MODEL_AXES = "RDF"
_DIRECTIONS = {"R": (1, 0, 0), "L": (-1, 0, 0), "U": (0, 1, 0), "D": (0, -1, 0), "B": (0, 0, 1), "F": (0, 0, -1)}

# The parity in (x, y, z) of each degree 1..3 basis function in 3DGS order (training/model/sh.py):
# degree 1: y, z, x; degree 2: xy, yz, 2zz-xx-yy, xz, xx-yy; degree 3: y(3xx-yy), xyz, y(4zz-xx-yy),
# z(2zz-3xx-3yy), x(4zz-xx-yy), z(xx-yy), x(xx-3yy). tests/test_model_axes.py checks it against sh_basis.
SH_REST_PARITY = ((0, 1, 0), (0, 0, 1), (1, 0, 0),
                  (1, 1, 0), (0, 1, 1), (0, 0, 0), (1, 0, 1), (0, 0, 0),
                  (0, 1, 0), (1, 1, 1), (0, 1, 0), (0, 0, 1), (1, 0, 0), (0, 0, 1), (1, 0, 0))


def axes_name(name: str) -> str:
    """``name`` (any case) as one of AXES; ValueError naming the choices otherwise."""
    upper = str(name).upper()
    if upper not in AXES:
        raise ValueError(f"unknown axes {name!r}; expected one of {', '.join(AXES)}")
    return upper


def axes_matrix(source: str, target: str) -> np.ndarray:
    """(3, 3) signed permutation M with p_target = M p_source."""
    def basis(name: str) -> np.ndarray:  # columns: where the convention's x, y, z point
        return np.array([_DIRECTIONS[c] for c in axes_name(name)], dtype=np.float64).T

    return basis(target).T @ basis(source)


def sh_signs(signs, count: int) -> np.ndarray:
    """(count,) the factor each of the first ``count`` degree 1..3 coefficients takes when the axes flip by
    ``signs`` (sx, sy, sz)."""
    s = np.asarray(signs, dtype=np.float64)
    return np.array([np.prod(s ** np.array(p)) for p in SH_REST_PARITY[:count]])


def convert_axes(gaussians: Gaussians, source: str, target: str, in_place: bool = False) -> Gaussians:
    """The same Gaussians with the axes of ``source`` turned into those of ``target`` (module doc). ``in_place``
    changes the tensors of ``gaussians`` (readers use it to hold one copy of a large model); the same axes return
    ``gaussians`` itself."""
    m = axes_matrix(source, target)
    if np.array_equal(m, np.eye(3)):
        return gaussians
    g = gaussians if in_place else gaussians.detached()
    dtype, device = g.means.dtype, g.means.device
    k = g.shN.shape[1]
    with torch.no_grad():
        if np.count_nonzero(m) == 3 and np.array_equal(np.abs(m), np.eye(3)):  # one family: flips only
            s = np.diag(m)
            g.means.mul_(torch.tensor(s, dtype=dtype, device=device))
            flip_q = [1.0, s[1] * s[2], s[0] * s[2], s[0] * s[1]]
            g.quats.mul_(torch.tensor(flip_q, dtype=g.quats.dtype, device=device))
            if k:
                g.shN.mul_(torch.tensor(sh_signs(s, k), dtype=g.shN.dtype, device=device)[None, :, None])
        else:
            from training.model.transform import quat_multiply, sh_rotation
            from training.scene.pose import matrix_to_quat

            g.means.copy_(g.means @ torch.tensor(m.T, dtype=dtype, device=device))
            proper = m * np.linalg.det(m)
            q = quat_multiply(matrix_to_quat(proper)[None], g.quats.detach().cpu().double().numpy())
            g.quats.copy_(torch.from_numpy(q))
            if k:
                x = torch.tensor(sh_rotation(m, g.sh_degree), dtype=g.shN.dtype, device=device)
                g.shN.copy_(torch.einsum("ij,njc->nic", x, g.shN))
    return g
