"""Real spherical-harmonic normalisation constants up to degree 3 (3DGS / gsplat basis order and signs).

Plain Python, no torch or numba: the torch SH code (``training.model.sh``), the cpu rasterizer's kernels, the model
(``training.model.gaussians``) and ``renderer_gl`` all read them from here.
"""

SH_C0 = 0.28209479177387814  # Y_0^0; at degree 0, colour = SH_C0 * sh0 + 0.5
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
