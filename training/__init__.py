"""The engine: everything torch. Packages by role, bottom to top (a package imports only those below it):

- ``core``: input errors, atomic writes, cache folder, trainer messages (events, snapshots, config updates);
- ``scene``: cameras, scenes and their loaders (COLMAP, transforms.json, images, undistortion, SfM);
- ``model``: the Gaussian model, SH, initialisation, PLY and .splat files;
- ``raster``: ``rasterize()`` over the cpu (numba), cuda (gsplat) and reference (torch) backends;
- ``reconstruct`` and ``stylize``: the two trainers (a dataclass config plus ``step()``) and what only they use.

Nothing here imports ``app`` or ``renderer_gl``, nor any GL or window code.
"""

import os

# Before torch (or numba's OpenMP pool) loads libgomp: idle OpenMP threads sleep instead of spinning. On the 2-core
# machines we target, spinning torch and numba pools steal each other's cores; this made a 10k-Gaussian CPU
# render+backward 2.5x slower (see docs/rasterizer.md). An explicit OMP_WAIT_POLICY in the environment wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# Before pycolmap: its extension carries a zlib of its own and exports its symbols. Loaded before anything has loaded
# the system zlib, it answers OpenImageIO's calls too, and OpenImageIO's PNG writer then aborts the process in
# deflateEnd ("free(): invalid pointer"; measured with pycolmap 4.2.1 and OpenImageIO 3.2: importing pycolmap and then
# writing a PNG crashes, importing zlib first does not). Python's zlib module loads the system one.
import zlib  # noqa: E402,F401
