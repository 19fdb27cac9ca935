"""The rasterizer's numbers, defined once for every backend (cpu kernels, torch reference, the cuda wrapper's
defaults) and for ``renderer_gl``, which must draw the same picture. Plain Python, no torch or numba: the GL viewer
imports this module without the training stack.

Changing a value here changes the compiled cpu kernels, but numba's on-disk cache only watches the file that
defines each kernel: after an edit here, clear ``training/raster/__pycache__`` (see docs/rasterizer.md).
"""

BACKENDS = ("auto", "cpu", "cuda", "torch")  # rasterizer backends; "auto": cuda where it runs, else cpu
ALPHA_MIN = 1.0 / 255.0  # a Gaussian whose alpha at a pixel is below this is skipped there
ALPHA_MAX = 0.99  # alpha is clamped here (graphdeco's kernels; gsplat uses 0.999)
T_MIN = 1e-4  # a Gaussian that would bring a pixel's transmittance to this or below ends the pixel uncomposited
EPS2D = 0.3  # low-pass added to the 2D covariance's diagonal, in pixels^2 (EWA anti-aliasing)
NEAR_PLANE = 0.01  # Gaussians with camera z outside [NEAR_PLANE, FAR_PLANE] are culled
FAR_PLANE = 1e10
TILE_SIZE = 16  # pixels per side of a compositing tile
# x/z and y/z are clamped inside the projection Jacobian to the field of view widened by this fraction of the
# half-angle's tangent on each side (1.3x the field of view, as the graphdeco and gsplat kernels do): Gaussians far
# off-screen otherwise get huge, wrongly stretched footprints.
FOV_CLAMP_MARGIN = 0.3
