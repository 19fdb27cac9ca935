"""The Gaussian model: raw parameters and their activations, spherical harmonics, initialisation from SfM points or
at random, and the files other 3DGS tools read (standard PLY, antimatter15's ``.splat``).

May import ``training.core`` and ``training.scene``.
"""
