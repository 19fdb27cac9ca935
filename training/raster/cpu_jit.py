"""numba settings shared by the cpu rasterizer's kernel modules (cpu_project, cpu_sort, cpu_composite).

``cache=True`` keeps compiled kernels in ``training/raster/__pycache__``; numba revalidates a kernel only against
the file that defines it, so every inlined helper lives in the same file as the kernels that inline it, and the
constants imported from ``constants.py`` / ``sh_constants.py`` are the one cross-file dependency (after editing
those, clear the cache). No fastmath anywhere a kernel decides whether a Gaussian composites: forward and backward
must take the very same decisions from the same float operations.
"""

JIT = dict(cache=True, nogil=True)
# Gaussians per work item in the per-Gaussian kernels (projection, SH): large enough to amortise the per-item
# scratch matrices, small enough to balance two to a few dozen threads.
PROJ_CHUNK = 512
