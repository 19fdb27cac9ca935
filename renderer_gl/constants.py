"""The numbers renderer_gl must share with the training rasterizer to draw the same picture.

They are defined here (torch-free) because the training package has no torch-free module holding them yet; the
values are those of training/raster/reference.py and training/model/sh.py, and tests/test_renderer_gl.py checks
that they still agree.
"""

ALPHA_MIN = 1.0 / 255.0  # a Gaussian's alpha below this at a pixel is skipped
ALPHA_MAX = 0.99  # alpha is clamped here
T_MIN = 1e-4  # the training rasterizer stops a pixel before transmittance falls to this (not reproducible in GL)
EPS2D = 0.3  # low-pass added to the 2D covariance's diagonal, in pixels^2
NEAR_PLANE = 0.01
FAR_PLANE = 1e10

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
