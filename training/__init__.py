import os

# Before torch (or numba's OpenMP pool) loads libgomp: idle OpenMP threads sleep instead of spinning. On the 2-core
# machines we target, spinning torch and numba pools steal each other's cores; this made a 10k-Gaussian CPU
# render+backward 2.5x slower (see docs/rasterizer.md). An explicit OMP_WAIT_POLICY in the environment wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
