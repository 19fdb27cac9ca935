"""The ``.splat`` format of antimatter15's WebGL viewer (read by many web viewers), export and read-back.

Each splat is 32 bytes, little-endian, no header:

    offset  0: position  3 x float32 (world)
    offset 12: scale     3 x float32 (activated: exp(log_scale), standard deviations)
    offset 24: colour    4 x uint8   R, G, B from the SH DC term (0.5 + C0 * f_dc), A = sigmoid(opacity), x255
    offset 28: rotation  4 x uint8   unit quaternion (w, x, y, z) mapped as q * 128 + 128

Splats are sorted by descending importance exp(sum of log-scales) * opacity (volume times opacity), as the
format's reference converter does, so viewers that stream the file show the big, opaque splats first. Values are
quantised by truncation (``astype(uint8)``) after clipping to [0, 255], again as the reference converter does.
The format holds no view-dependent colour: SH above degree 0 is dropped.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from training.core.atomic_write import atomic_open
from training.core.errors import InputError
from training.model.gaussians import SH_C0, Gaussians, rgb_to_sh0

SPLAT_DTYPE = np.dtype([("position", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)),
                        ("rotation", "u1", (4,))])
assert SPLAT_DTYPE.itemsize == 32


def splat_importance(gaussians: Gaussians) -> np.ndarray:
    """(N,) float64 exp(sum log_scales) * opacity, the sort key of the .splat format."""
    log_scales = gaussians.log_scales.detach().to("cpu", torch.float64).numpy()
    logits = gaussians.opacity_logits.detach().to("cpu", torch.float64).numpy()
    return np.exp(log_scales.sum(axis=1)) / (1.0 + np.exp(-logits))


def splat_records(gaussians: Gaussians) -> np.ndarray:
    """(N,) structured array of SPLAT_DTYPE, sorted by descending importance (ties keep model order)."""
    n = len(gaussians)
    params = {k: v.detach().to("cpu", torch.float64).numpy() for k, v in gaussians.parameters().items()}
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh0"):
        bad = int((~np.isfinite(params[name])).reshape(n, -1).any(axis=1).sum()) if n else 0
        if bad:
            raise ValueError(f"cannot export .splat: {bad} Gaussians have non-finite {name}")

    order = np.argsort(-splat_importance(gaussians), kind="stable")
    rgb = 0.5 + SH_C0 * params["sh0"][:, 0, :]
    alpha = 1.0 / (1.0 + np.exp(-params["opacity_logits"]))
    quats = params["quats"]
    norm = np.linalg.norm(quats, axis=1, keepdims=True)
    # A zero quaternion has no rotation to normalise; identity is what every renderer falls back to.
    quats = np.where(norm > 0, quats / np.where(norm > 0, norm, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))

    rec = np.zeros(n, dtype=SPLAT_DTYPE)
    rec["position"] = params["means"]
    rec["scale"] = np.exp(params["log_scales"])
    rec["rgba"] = (np.concatenate([rgb, alpha[:, None]], axis=1) * 255).clip(0, 255).astype(np.uint8)
    rec["rotation"] = (quats * 128 + 128).clip(0, 255).astype(np.uint8)
    return rec[order]


def write_splat(path: str | Path, gaussians: Gaussians) -> None:
    """Write ``gaussians`` as a .splat file (32 bytes per splat, sorted by importance), atomically."""
    records = splat_records(gaussians)
    with atomic_open(path, "wb") as f:
        f.write(records.tobytes())


def read_splat(path: str | Path, device: str | torch.device = "cpu") -> Gaussians:
    """Read a .splat file back as a degree-0 model (colours, opacities and rotations as quantised in the file).

    Raises InputError naming the file when it is missing, empty, not a whole number of 32-byte splats, or holds
    non-finite or non-positive values where the format needs them.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file does not exist" if not path.exists() else "is not a file")
    size = path.stat().st_size
    if size == 0:
        raise InputError(path, ".splat file is empty")
    if size % SPLAT_DTYPE.itemsize:
        raise InputError(path, f".splat file size {size} is not a multiple of {SPLAT_DTYPE.itemsize} bytes "
                               "(truncated or not a .splat file)")
    rec = np.fromfile(path, dtype=SPLAT_DTYPE)
    n = len(rec)
    for name in ("position", "scale"):
        bad = int((~np.isfinite(rec[name])).any(axis=1).sum())
        if bad:
            raise InputError(path, f"{bad} of {n} splats have NaN or infinite {name}")
    bad = int((rec["scale"] <= 0).any(axis=1).sum())
    if bad:
        raise InputError(path, f"{bad} of {n} splats have a scale <= 0")

    rgba = rec["rgba"].astype(np.float64) / 255.0
    # Keep logits finite for alpha 0 or 255: half a quantisation step away from the ends.
    a = rgba[:, 3].clip(0.5 / 255.0, 1.0 - 0.5 / 255.0)
    quats = (rec["rotation"].astype(np.float64) - 128.0) / 128.0
    quats[~quats.any(axis=1)] = (1.0, 0.0, 0.0, 0.0)  # bytes 128,128,128,128 decode to no rotation at all

    def t(x: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)).to(device)

    return Gaussians(
        means=t(rec["position"]),
        log_scales=t(np.log(rec["scale"].astype(np.float64))),
        quats=t(quats),
        opacity_logits=t(np.log(a / (1.0 - a))),
        sh0=rgb_to_sh0(t(rgba[:, None, :3])),
        shN=torch.zeros((n, 0, 3), dtype=torch.float32, device=device),
        sh_degree=0,
    )
