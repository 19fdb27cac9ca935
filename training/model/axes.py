"""The axis conventions of model files, converted here and nowhere else.

Our models keep the axes of the reconstruction's world as graphdeco's 3DGS stores them in a PLY: "RDF" (x right,
y down, z forward, the OpenCV camera convention; ``.splat`` and the compressed PLY store the same axes). Two formats
state other axes:

- SPZ: "By default, SPZ stores data in an RUB coordinate system following the OpenGL and three.js convention ...
  PLY (which typically uses RDF)" (nianticlabs/spz README, "Coordinate System").
- glTF: "+Y is up ... right-handed ... the front of a glTF asset faces +Z" (glTF 2.0, "Coordinate System and
  Units"), and KHR_gaussian_splatting: when converting pre-trained data into the glTF coordinate system "the
  positions, quaternions and spherical harmonics will have to be rotated". RUB puts the side an RDF camera saw
  (its -z) at glTF's front (+z).

RDF to RUB is the half turn about x, F = diag(1, -1, -1): a proper rotation, its own inverse, so one function
converts both ways. Under it a centre becomes F m; a Gaussian's rotation R becomes F R F, the quaternion (w, x, y, z)
becomes (w, x, -y, -z) as the reference's ``flipQ`` has it (the covariance F R S^2 R^T F is the same as with F R,
since F S^2 F = S^2); scales and opacities stay; each SH coefficient keeps or flips its sign by the parity of its
basis function in y and z (c'_k Y_k(d) = c_k Y_k(F d), and Y_k(F d) = +-Y_k(d)).
"""

from __future__ import annotations

import torch

from training.model.gaussians import Gaussians

# Y_k(x, -y, -z) / Y_k(x, y, z) for the degree 1..3 basis functions in 3DGS order (training/model/sh.py):
# degree 1: y, z, x; degree 2: xy, yz, 2zz-xx-yy, xz, xx-yy; degree 3: y(3xx-yy), xyz, y(4zz-xx-yy),
# z(2zz-3xx-3yy), x(4zz-xx-yy), z(xx-yy), x(xx-3yy). tests/test_model_axes.py checks it against sh_basis.
SH_REST_SIGNS = (-1, -1, 1,
                 -1, 1, 1, -1, 1,
                 -1, 1, -1, -1, 1, -1, 1)


def rdf_rub(gaussians: Gaussians) -> Gaussians:
    """The same Gaussians with the axes turned half about x: RDF to RUB, and (the same turn) RUB to RDF."""
    flip = torch.tensor([1.0, -1.0, -1.0], dtype=gaussians.means.dtype, device=gaussians.device)
    quat_flip = torch.tensor([1.0, 1.0, -1.0, -1.0], dtype=gaussians.quats.dtype, device=gaussians.device)
    k = gaussians.shN.shape[1]
    sh_signs = torch.tensor(SH_REST_SIGNS[:k], dtype=gaussians.shN.dtype, device=gaussians.device)
    return Gaussians(means=gaussians.means * flip, log_scales=gaussians.log_scales.clone(),
                     quats=gaussians.quats * quat_flip, opacity_logits=gaussians.opacity_logits.clone(),
                     sh0=gaussians.sh0.clone(), shN=gaussians.shN * sh_signs[None, :, None],
                     sh_degree=gaussians.sh_degree)
