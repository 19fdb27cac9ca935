"""``rasterize()``: differentiable rendering of 3D Gaussians, one function over three backends.

- ``cpu``   numba kernels (training/raster/cpu.py): the fast path on machines without CUDA;
- ``cuda``  gsplat's ``rasterization`` (training/raster/cuda.py) for CUDA tensors when gsplat is installed;
- ``torch`` plain PyTorch (training/raster/reference.py): the reference, and the fallback on any device.

``backend="auto"`` picks cuda for CUDA tensors with gsplat present, else cpu when numba imports, else torch. The
environment variable ``SPLATSTYLER_RASTER_BACKEND`` (auto|cpu|cuda|torch) overrides the argument's ``"auto"``.
All backends share the semantics documented in training/raster/reference.py.
"""

from __future__ import annotations

import functools
import os

import torch

from training.raster.constants import BACKENDS, EPS2D, FAR_PLANE, NEAR_PLANE, TILE_SIZE

RENDER_MODES = {
    # mode: (rgb channels, depth channel, depth divided by alpha)
    "RGB": (True, False, False),
    "D": (False, True, False),
    "ED": (False, True, True),
    "RGB+D": (True, True, False),
    "RGB+ED": (True, True, True),
}


def camera_matrices(camera, dtype=torch.float32, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """``rasterize``'s ``viewmat`` (4, 4) and ``K`` (3, 3) of a pinhole camera (training/scene/camera.py): where the
    scene's numpy cameras become tensors."""
    return (torch.as_tensor(camera.world_to_camera, dtype=dtype, device=device),
            torch.as_tensor(camera.K, dtype=dtype, device=device))


@functools.lru_cache(maxsize=None)
def _have_cpu_kernels() -> bool:
    try:
        import training.raster.cpu  # noqa: F401  (imports numba; kernels compile lazily, cached on disk)
    except ImportError:
        return False
    return True


@functools.lru_cache(maxsize=None)
def have_gsplat() -> bool:
    try:
        import gsplat  # noqa: F401
    except Exception:  # gsplat can fail at import for reasons other than ImportError (CUDA toolkit, ABI)
        return False
    return True


def resolve_device(name: str, backend: str = "auto") -> torch.device:
    """The torch device for ``name`` ("auto", "cpu", "cuda", ...). "auto" follows an explicit ``backend`` (the cpu
    rasterizer takes CPU tensors, the cuda one CUDA tensors: `--backend cpu` on a CUDA machine must not put the model
    on the GPU); otherwise it picks CUDA only where the fast CUDA rasterizer (gsplat) is there too: on CUDA without
    gsplat only the slow torch reference could render, and the numba CPU backend beats it."""
    if name == "auto":
        if backend in ("cpu", "cuda"):
            return torch.device(backend)
        return torch.device("cuda" if torch.cuda.is_available() and have_gsplat() else "cpu")
    return torch.device(name)


def choose_backend(backend: str, device: torch.device) -> str:
    """The backend ``rasterize`` will use for tensors on ``device``."""
    if backend == "auto":
        backend = os.environ.get("SPLATSTYLER_RASTER_BACKEND", "auto").strip().lower() or "auto"
    if backend not in BACKENDS:
        raise ValueError(f"unknown rasterizer backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    if backend == "auto":
        if device.type == "cuda" and have_gsplat():
            return "cuda"
        if device.type == "cpu" and _have_cpu_kernels():
            return "cpu"
        return "torch"
    if backend == "cpu" and device.type != "cpu":
        raise ValueError(f"the cpu rasterizer needs CPU tensors, got {device}")
    if backend == "cuda" and (device.type != "cuda" or not have_gsplat()):
        raise ValueError("the cuda rasterizer needs CUDA tensors and the gsplat package")
    return backend


def rasterize(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    sh_degree: int | None = None,
    background: torch.Tensor | None = None,
    render_mode: str = "RGB",
    near_plane: float = NEAR_PLANE,
    far_plane: float = FAR_PLANE,
    eps2d: float = EPS2D,
    tile_size: int = TILE_SIZE,
    backend: str = "auto",
) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Render N Gaussians seen by one pinhole camera.

    means (N, 3) world; quats (N, 4) wxyz, normalised inside; scales (N, 3) standard deviations; opacities (N,) in
    (0, 1); colors (N, 3) RGB, or (N, K, 3) SH coefficients with K >= (sh_degree+1)^2 when ``sh_degree`` is given
    (colour = SH + 0.5 clamped at 0, view direction from the camera centre); viewmat (4, 4) world-to-camera,
    OpenCV axes; K (3, 3) intrinsics in pixels, pixel (x, y) centred at (x + 0.5, y + 0.5); background (3,) or None.

    Returns image (H, W, C) float32 with C = 3 (RGB), 1 (D, ED) or 4 (RGB+D, RGB+ED; depth last), where
    D = sum d_i a_i T_i and ED = D / alpha; alpha (H, W, 1); info with "means2d" (N, 2) (after backward its
    ``.grad`` is dL/d(pixel-space means)), "radii" (N,) int32 (0 = culled), "depths" (N,) camera z, "backend",
    "timings" (the cpu backend's seconds per stage, the backward's added once it ran; empty for the others).
    All tensor inputs are differentiable.
    """
    if render_mode not in RENDER_MODES:
        raise ValueError(f"unknown render_mode {render_mode!r}; expected one of {', '.join(RENDER_MODES)}")
    width, height, tile_size = int(width), int(height), int(tile_size)
    if width < 1 or height < 1:
        raise ValueError(f"image size must be at least 1x1, got {width}x{height}")
    if tile_size < 1:
        raise ValueError(f"tile_size must be positive, got {tile_size}")
    n = means.shape[0] if means.dim() == 2 else -1
    shapes = {"means": (means, (n, 3)), "quats": (quats, (n, 4)), "scales": (scales, (n, 3)),
              "opacities": (opacities, (n,)), "viewmat": (viewmat, (4, 4)), "K": (K, (3, 3))}
    for name, (tensor, shape) in shapes.items():
        if tuple(tensor.shape) != shape:
            raise ValueError(f"rasterize: {name} has shape {tuple(tensor.shape)}, expected {shape}")
    if sh_degree is None:
        if tuple(colors.shape) != (n, 3):
            raise ValueError(f"rasterize: colors has shape {tuple(colors.shape)}, expected ({n}, 3) "
                             "(pass sh_degree for SH coefficients)")
    else:
        if not 0 <= int(sh_degree) <= 3:
            raise ValueError(f"rasterize: sh_degree must be 0..3, got {sh_degree}")
        sh_degree = int(sh_degree)
        k = (sh_degree + 1) ** 2
        if colors.dim() != 3 or colors.shape[0] != n or colors.shape[1] < k or colors.shape[2] != 3:
            raise ValueError(f"rasterize: SH colors have shape {tuple(colors.shape)}, expected ({n}, >={k}, 3)")
    if background is not None and tuple(background.shape) != (3,):
        raise ValueError(f"rasterize: background has shape {tuple(background.shape)}, expected (3,)")

    use_rgb, use_depth, expected_depth = RENDER_MODES[render_mode]
    chosen = choose_backend(backend, means.device)
    dtype = means.dtype
    viewmat = viewmat.to(device=means.device, dtype=dtype)
    K = K.to(device=means.device, dtype=dtype)
    args = (means, quats, scales, opacities, colors, viewmat, K, width, height, sh_degree, use_rgb, use_depth,
            float(near_plane), float(far_plane), float(eps2d), tile_size)
    timings: dict[str, float] = {}
    if chosen == "cpu":
        from training.raster.cpu import render_features_cpu

        feats, trans, means2d, radii, depths, timings = render_features_cpu(*args)
    elif chosen == "cuda":
        from training.raster.cuda import render_features_cuda

        feats, trans, means2d, radii, depths = render_features_cuda(*args)
    else:
        from training.raster.reference import render_features

        feats, trans, proj, means2d = render_features(*args)
        radii = proj.radii.max(dim=-1).values
        depths = proj.depths.detach()

    alpha = 1.0 - trans
    channels = []
    if use_rgb:
        rgb = feats[..., :3]
        if background is not None:
            rgb = rgb + trans * background.to(device=rgb.device, dtype=rgb.dtype)
        channels.append(rgb)
    if use_depth:
        depth = feats[..., -1:]
        if expected_depth:
            depth = depth / alpha.clamp_min(1e-10)
        channels.append(depth)
    image = channels[0] if len(channels) == 1 else torch.cat(channels, dim=-1)
    if torch.is_grad_enabled() and not image.requires_grad:
        inputs = [t for t in (means, quats, scales, opacities, colors, background) if t is not None]
        if any(t.requires_grad for t in inputs):
            # Nothing visible: the image is constant, but a training loop still calls backward on it, so keep it
            # connected to the inputs (every gradient is zero).
            zero = sum((t * 0).sum() for t in inputs if t.requires_grad)
            image, alpha = image + zero, alpha + zero
    info = {"means2d": means2d, "radii": radii, "depths": depths, "backend": chosen,
            "width": width, "height": height, "tile_size": tile_size, "timings": timings}
    return image, alpha, info
