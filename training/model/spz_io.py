"""Niantic's SPZ (``.spz``): about a tenth of a PLY with the SH bands kept, read by Scaniverse, SuperSplat, the
PlayCanvas engine, Spark, Unity Gaussian Splatting and f3d.

The container and the per-attribute packing are gsply's (``gsply.write_spz``/``read_spz``, MIT, the reference's
layout; pyproject.toml says why that library). What is ours, with the spec's rules (nianticlabs/spz README, "File
Format"; ``load-spz.cc``):

- **Axes**: SPZ stores RUB, our models RDF; training/model/axes.py turns them on the way in and out.
- **Versions**: 4 (the current spec: a 32-byte "NGSP" header, each attribute its own ZSTD stream) by default, 3
  (one gzip stream, "smallest three" rotations) for older readers. Both read back; so do 1 and 2.
- **Quantisation** (what a reader gets back): positions 24-bit signed fixed point with ``fractionalBits`` in the
  header; scales 8-bit, ``(log s + 10) * 16``; rotations (v3, v4) the largest component's index in 2 bits and the
  other three as 9 bits of magnitude plus a sign, scaled by 1/sqrt 2; alpha ``sigmoid(logit) * 255``; colour
  ``f_dc * 0.15 * 255 + 127.5``; SH ``round(c * 128) + 128`` rounded to buckets of 5 bits for degree 1 and 4 bits
  for degrees 2 and 3, the reference's default ``sh1Bits``/``shRestBits`` (gsply keeps all 8 bits; the buckets are
  what makes SPZ small, so we round to them before gsply packs the bytes).
- **Fractional bits**: the reference always writes 12 (1/4096 units), which holds centres within +-2048 units and
  wraps beyond; we write 12 where the model fits and fewer where it does not, so a large scene keeps its shape at
  a coarser step (readers take the step from the header).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from training.core.atomic_write import atomic_path
from training.core.errors import InputError
from training.model.axes import rdf_rub
from training.model.gaussians import Gaussians, num_sh_coeffs

SPZ_VERSIONS = (3, 4)
LATEST_SPZ_VERSION = 4
MAX_FRACTIONAL_BITS = 12  # the reference's fixed choice
SH1_BITS, SH_REST_BITS = 5, 4  # the reference's default PackOptions
MAX_SH_DEGREE = 3


def fractional_bits_for(means: np.ndarray) -> int:
    """The most fractional bits (at most 12) that keep every coordinate within a signed 24-bit integer."""
    reach = float(np.abs(means).max()) if means.size else 0.0
    if reach < 2.0 ** (23 - MAX_FRACTIONAL_BITS) - 1:
        return MAX_FRACTIONAL_BITS
    bits = 23 - math.ceil(math.log2(reach + 1.0))
    if bits < 1:
        raise ValueError(f"cannot write SPZ: a Gaussian centre lies {reach:.3g} units out, beyond the 24-bit "
                         "fixed point's reach")
    return bits


def quantised_sh(shN: np.ndarray) -> np.ndarray:
    """SH coefficients (N, K, 3) rounded as the reference's ``quantizeSH`` rounds them (degree 1 to 5 bits, higher
    degrees to 4), returned as the values those bytes decode to, so that gsply's 8-bit packing stores them as is."""
    q = np.floor(np.abs(shN.astype(np.float64)) * 128.0 + 0.5) * np.sign(shN) + 128.0  # std::round: half away
    buckets = np.full(shN.shape[1], 1 << (8 - SH_REST_BITS), dtype=np.float64)
    buckets[:3] = 1 << (8 - SH1_BITS)
    b = buckets[None, :, None]
    q = np.clip(np.floor((q + b // 2) / b) * b, 0, 255)
    return ((q - 128.0) / 128.0).astype(np.float32)


def _gsdata(gaussians: Gaussians):
    from gsply import GSData, create_ply_format

    a = {k: v.detach().to("cpu", torch.float32).numpy() for k, v in gaussians.parameters().items()}
    return GSData(means=a["means"], scales=a["log_scales"], quats=a["quats"], opacities=a["opacity_logits"],
                  sh0=a["sh0"][:, 0, :], shN=quantised_sh(a["shN"]),
                  _format=create_ply_format(gaussians.sh_degree))


def write_spz(path: str | Path, gaussians: Gaussians, version: int = LATEST_SPZ_VERSION) -> None:
    """Write ``gaussians`` (SH degree 0..3, RDF axes) as an SPZ file of ``version`` (3 or 4), atomically.

    ValueError for an empty or non-finite model, a version other than 3 or 4, or centres beyond 24-bit reach."""
    import gsply

    if version not in SPZ_VERSIONS:
        raise ValueError(f"SPZ version must be 3 or 4, not {version}")
    if len(gaussians) == 0:
        raise ValueError("cannot write an SPZ file of no Gaussians")
    if gaussians.sh_degree > MAX_SH_DEGREE:
        raise ValueError(f"SPZ export holds SH degree 0..{MAX_SH_DEGREE}, the model has {gaussians.sh_degree}")
    for name, t in gaussians.parameters().items():
        if t.numel() and not bool(torch.isfinite(t).all()):
            raise ValueError(f"cannot write an SPZ file: the model has non-finite {name}")
    rub = rdf_rub(gaussians)
    bits = fractional_bits_for(rub.means.detach().cpu().numpy())
    with atomic_path(path) as tmp:
        gsply.write_spz(tmp, _gsdata(rub), version=version, fractional_bits=bits)


def _reason(exc: BaseException, path: Path) -> str:
    """gsply's message without the file name it appends (our InputError puts the name first)."""
    text = str(exc).strip() or type(exc).__name__
    for tail in (f": {path}", f": {path.name}", f" {path}"):
        if text.endswith(tail):
            text = text[: -len(tail)]
    return text.rstrip(" :")


def read_spz(path: str | Path, device: str | torch.device = "cpu") -> Gaussians:
    """Read an SPZ file (versions 1..4) into a model with RDF axes, as its bytes decode (see the module's
    quantisation). InputError naming the file for anything gsply cannot decode or that decodes to no model."""
    import gsply

    path = Path(path)
    try:
        data = gsply.read_spz(path)
    except MemoryError:
        raise
    except Exception as exc:  # gsply says ValueError; gzip, zstd and struct their own: any of them is the file's
        raise InputError(path, f"not a readable SPZ file ({_reason(exc, path)})") from None
    n = len(data.means)
    sh_rest = 0 if data.shN is None else int(np.asarray(data.shN).shape[1])
    degrees = {num_sh_coeffs(d) - 1: d for d in range(MAX_SH_DEGREE + 1)}
    if sh_rest not in degrees:
        raise InputError(path, f"SPZ file holds {sh_rest} SH coefficients per colour; degrees 0..3 are read")
    if n == 0:
        raise InputError(path, "SPZ file holds no Gaussians")
    shN = np.zeros((n, 0, 3), np.float32) if sh_rest == 0 else np.asarray(data.shN, np.float32).reshape(n, -1, 3)
    # alpha bytes 0 and 255 decode to logits of +-inf in some readers: half a step in, as for .splat
    limit = math.log(254.5 / 0.5)
    logits = np.clip(np.nan_to_num(np.asarray(data.opacities, np.float64), nan=0.0), -limit, limit)

    def t(x) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)).to(device)

    rub = Gaussians(means=t(data.means), log_scales=t(data.scales), quats=t(data.quats),
                    opacity_logits=t(logits.reshape(n)), sh0=t(np.asarray(data.sh0).reshape(n, 1, 3)),
                    shN=t(shN), sh_degree=degrees[sh_rest])
    return rdf_rub(rub)
