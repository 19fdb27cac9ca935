"""Differentiable rasterization of 3D Gaussians: one entry point, ``rasterize.rasterize()``, over three backends
(``cpu``: our numba kernels with a hand-written backward; ``cuda``: gsplat; ``reference``: plain PyTorch, the
reference the other two are held to), and the rasterizer constants in ``constants`` (torch-free, shared with
``renderer_gl``).

May import ``training.core`` and ``training.model``.
"""
