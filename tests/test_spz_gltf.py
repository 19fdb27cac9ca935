"""SPZ and glTF (KHR_gaussian_splatting) files checked by readers we did not write: our SPZ decoded by PlayCanvas's
splat-transform (its own decoder) and read back with plyfile; SPZ written by the spec's reference encoder (the
WebAssembly build splat-transform uses) read by us; our .glb's accessors decoded through pygltflib and the file
passed through the Khronos validator; splat-transform's .glb read by us. Every attribute is compared within the
format's quantisation, stated from the specs below, after the axis turn each format stores (RUB; our models RDF).

SPZ (nianticlabs/spz README "File Format", load-spz.cc), what a decoded value may differ by:
- position: half a fixed-point step, 2^-(fractional bits + 1) (12 bits here);
- log scale: half of 1/16 (8 bits over (log s + 10) * 16);
- alpha: half of 1/255;
- DC colour: half of 1/(0.15 * 255) (8 bits over f_dc * 0.15 * 255 + 127.5);
- SH: round(c * 128) (half of 1/128) then buckets of 2^(8-5) for degree 1 and 2^(8-4) above, half a bucket;
- rotation (v3, v4): the three smaller components as 9-bit magnitudes of at most 1/sqrt 2, half a step each;
  the fourth from the unit norm.
glTF: float32 throughout, so equal to float32 rounding (scale and opacity are exp and sigmoid of ours).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from plyfile import PlyData

from tests.other_tools import splat_transform, validate_gltf
from training.model.export import write_export
from training.model.gaussians import Gaussians
from training.model.model_io import read_model
from training.model.ply_io import write_ply
from training.model.sh import sh_basis
from training.model.sh_constants import SH_C0

POS_TOL = 2.0 ** -13 + 1e-6
LOG_SCALE_TOL = 1 / 32 + 1e-6
ALPHA_TOL = 0.5 / 255 + 1e-6
DC_TOL = 0.5 / (0.15 * 255) + 1e-5
SH1_TOL, SH_REST_TOL = 4.5 / 128 + 1e-6, 8.5 / 128 + 1e-6
ROT_TOL = 0.5 * np.sqrt(0.5) / 511 * 3  # three stored components' half steps, also bounding the derived one


def model(n=500, degree=3, seed=0) -> Gaussians:
    """Random Gaussians inside every format's range (SPZ clamps log scales to [-10, 6), SH to [-1, 1))."""
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g) * 2, log_scales=torch.randn(n, 3, generator=g) * 0.7 - 4,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g) * 2,
                     sh0=torch.randn(n, 1, 3, generator=g) * 0.6,
                     shN=(torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g) * 0.2).clamp(-0.95, 0.95),
                     sh_degree=degree)


RUB = (1.0, -1.0, -1.0)  # RDF to RUB: x kept, y and z negated (a half turn about x)


def turned(g: Gaussians, signs) -> Gaussians:
    """The model turned by diag(signs) (a proper rotation), written here from the definitions, not from
    training/model/axes.py: centres negated per axis, the quaternion's vector part likewise (the reference's flipQ),
    each SH coefficient times Y_k(turned direction) / Y_k(direction), evaluated at a random direction."""
    s = torch.tensor(signs, dtype=torch.float64)
    d = torch.nn.functional.normalize(torch.randn(1, 3, dtype=torch.float64), dim=1)
    sh_signs = (sh_basis(3, d * s)[0, 1:] / sh_basis(3, d)[0, 1:]).round().float()
    k = g.shN.shape[1]
    quat_signs = torch.cat([s.new_ones(1), s]).float()
    return Gaussians(means=g.means * s.float(), log_scales=g.log_scales, quats=g.quats * quat_signs,
                     opacity_logits=g.opacity_logits, sh0=g.sh0, shN=g.shN * sh_signs[:k, None],
                     sh_degree=g.sh_degree)


def arrays(g: Gaussians) -> dict[str, np.ndarray]:
    q = torch.nn.functional.normalize(g.quats.double(), dim=1).numpy()
    return {"means": g.means.double().numpy(), "log_scales": g.log_scales.double().numpy(), "quats": q,
            "alpha": torch.sigmoid(g.opacity_logits.double()).numpy(), "dc": g.sh0[:, 0].double().numpy(),
            "rest": g.shN.double().numpy()}


def ply_arrays(path) -> dict[str, np.ndarray]:
    """A 3DGS PLY read with plyfile (not our reader), as arrays()."""
    v = PlyData.read(str(path))["vertex"].data
    n, rest = len(v), sorted((p for p in v.dtype.names if p.startswith("f_rest_")), key=lambda s: int(s[7:]))

    def cols(names):
        return np.stack([v[c].astype(np.float64) for c in names], axis=1) if names else np.zeros((n, 0))

    q = cols([f"rot_{i}" for i in range(4)])
    return {"means": cols(["x", "y", "z"]), "log_scales": cols([f"scale_{i}" for i in range(3)]),
            "quats": q / np.linalg.norm(q, axis=1, keepdims=True), "alpha": 1 / (1 + np.exp(-v["opacity"])),
            "dc": cols([f"f_dc_{i}" for i in range(3)]),
            "rest": cols(rest).reshape(n, 3, -1).transpose(0, 2, 1)}


def assert_within_spz(got: dict, want: dict) -> None:
    assert np.abs(got["means"] - want["means"]).max() <= POS_TOL
    assert np.abs(got["log_scales"] - want["log_scales"]).max() <= LOG_SCALE_TOL
    assert np.abs(got["alpha"] - want["alpha"]).max() <= ALPHA_TOL
    assert np.abs(got["dc"] - want["dc"]).max() <= DC_TOL
    sign = np.where((got["quats"] * want["quats"]).sum(1) < 0, -1.0, 1.0)[:, None]
    assert np.abs(got["quats"] * sign - want["quats"]).max() <= ROT_TOL
    assert got["rest"].shape == want["rest"].shape
    if want["rest"].shape[1]:
        assert np.abs(got["rest"][:, :3] - want["rest"][:, :3]).max() <= SH1_TOL
        assert np.abs(got["rest"][:, 3:] - want["rest"][:, 3:]).max(initial=0) <= SH_REST_TOL


@pytest.mark.parametrize("version,bands", [(4, 0), (4, 1), (4, 3), (3, 2), (3, 3)])
def test_our_spz_decoded_by_splat_transform(tmp_path, version, bands):
    g = model()
    write_export(tmp_path / "m.spz", g, sh_bands=bands, spz_version=version)
    head = (tmp_path / "m.spz").read_bytes()[:4]
    assert head == b"NGSP" if version == 4 else head[:2] == b"\x1f\x8b"
    splat_transform(tmp_path / "m.spz", tmp_path / "back.ply")
    # splat-transform decodes SPZ without turning axes: what it gives is the file's RUB values
    want = arrays(turned(Gaussians(**{**g.parameters(), "shN": g.shN[:, : (bands + 1) ** 2 - 1]},
                                   sh_degree=bands), RUB))
    assert_within_spz(ply_arrays(tmp_path / "back.ply"), want)


@pytest.mark.parametrize("version", [3, 4])
def test_spz_from_the_reference_encoder_reads_back(tmp_path, version):
    g = model(degree=3, seed=1)
    write_ply(tmp_path / "m.ply", g)
    splat_transform(tmp_path / "m.ply", "--spz-version", version, tmp_path / "ref.spz")
    back = read_model(tmp_path / "ref.spz")
    assert back.sh_degree == 3 and len(back) == len(g)
    # splat-transform writes the PLY's axes as they are (no RUB turn), so we read them turned
    assert_within_spz(arrays(back), arrays(turned(g, RUB)))


def test_spz_far_centres_keep_their_place_with_fewer_fractional_bits(tmp_path):
    g = model(n=50)
    g.means[0] = torch.tensor([5000.0, -3000.0, 100.0])  # beyond 12 fractional bits' reach of +-2048
    write_export(tmp_path / "far.spz", g)
    back = read_model(tmp_path / "far.spz")
    assert np.abs(back.means.double().numpy() - g.means.double().numpy()).max() <= 2.0 ** -11


def gltf_accessors(path) -> tuple[dict, dict[str, np.ndarray]]:
    """(the primitive, attribute name -> (count, width) float64) decoded through pygltflib's parse of the file."""
    from pygltflib import GLTF2

    gltf = GLTF2().load_binary(str(path))
    blob = gltf.binary_blob()
    prim = gltf.meshes[0].primitives[0]
    types = {5126: "<f4", 5121: "u1"}
    out = {}
    for name, index in prim.attributes.__dict__.items():
        if index is None:
            continue
        acc = gltf.accessors[index]
        view = gltf.bufferViews[acc.bufferView]
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc.type]
        dtype = np.dtype(types[acc.componentType])
        start = view.byteOffset + (acc.byteOffset or 0)
        values = np.frombuffer(blob, dtype=dtype, count=acc.count * width, offset=start).reshape(acc.count, width)
        out[name] = values.astype(np.float64) / (255.0 if acc.normalized else 1.0)
        if name == "POSITION":
            # the bounds as float32, the accessor's type (their decimal text is 9 digits: float32 exactly)
            assert np.array_equal(np.float32(acc.min), values.min(axis=0))
            assert np.array_equal(np.float32(acc.max), values.max(axis=0))
    return gltf, out


@pytest.mark.parametrize("bands", [0, 2, 3])
def test_glb_accessors_read_by_pygltflib(tmp_path, bands):
    g = model(n=400, degree=3)
    write_export(tmp_path / "m.glb", g, sh_bands=bands)
    gltf, acc = gltf_accessors(tmp_path / "m.glb")
    prim = gltf.meshes[0].primitives[0]
    assert prim.mode == 0 and gltf.extensionsUsed == ["KHR_gaussian_splatting"]
    ext = prim.extensions["KHR_gaussian_splatting"]
    assert ext["kernel"] == "ellipse" and ext["colorSpace"] == "srgb_rec709_display"
    want = arrays(turned(g, RUB))
    key = "KHR_gaussian_splatting:"
    assert np.array_equal(acc["POSITION"], want["means"].astype(np.float32))
    assert np.allclose(acc[key + "ROTATION"], want["quats"][:, [1, 2, 3, 0]], atol=1e-6)
    assert np.allclose(acc[key + "SCALE"], np.exp(want["log_scales"]), rtol=1e-6, atol=0)
    assert np.allclose(acc[key + "OPACITY"][:, 0], want["alpha"], atol=1e-7)
    assert np.array_equal(acc[key + "SH_DEGREE_0_COEF_0"], want["dc"].astype(np.float32))
    k = 0
    for degree in range(1, 4):
        for i in range(2 * degree + 1):
            name = f"{key}SH_DEGREE_{degree}_COEF_{i}"
            assert (name in acc) == (degree <= bands), name
            if degree <= bands:
                assert np.array_equal(acc[name], want["rest"][:, k].astype(np.float32)), name
            k += 1
    assert not any(f"SH_DEGREE_{bands + 1}" in a for a in acc)
    # COLOR_0, the fallback: the clamped DC colour decoded from sRGB to linear, alpha the opacity
    srgb = np.clip(0.5 + SH_C0 * want["dc"], 0, 1)
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    assert np.abs(acc["COLOR_0"] - np.concatenate([linear, want["alpha"][:, None]], 1)).max() <= 0.5 / 255 + 1e-9


def test_glb_passes_the_khronos_validator(tmp_path):
    write_export(tmp_path / "m.glb", model(n=300, degree=2))
    report = validate_gltf(tmp_path / "m.glb")
    issues = report["issues"]
    # The validator (2.0.0-dev.3.10) predates KHR_gaussian_splatting: it says so (info) and calls the extension's
    # attribute names invalid. Nothing else may be wrong: GLB framing, buffer views, accessors, POSITION bounds.
    errors = [m for m in issues["messages"] if m["severity"] == 0]
    assert {m["code"] for m in errors} == {"MESH_PRIMITIVE_INVALID_ATTRIBUTE"}
    assert all("/attributes/KHR_gaussian_splatting:" in m["pointer"] for m in errors)
    assert len(errors) == 4 + 3 + 5 and issues["numWarnings"] == 0
    assert [m["code"] for m in issues["messages"] if m["severity"] == 2] == ["UNSUPPORTED_EXTENSION"]


def covariances(g: Gaussians) -> torch.Tensor:
    """(N, 3, 3) R S^2 R^T in float64: a Gaussian's shape whatever quaternion describes it."""
    from training.model.rotation import quat_to_rotmat

    r = quat_to_rotmat(torch.nn.functional.normalize(g.quats.double(), dim=1))
    return r @ torch.diag_embed(torch.exp(2 * g.log_scales.double())) @ r.transpose(1, 2)


def test_glb_from_splat_transform_reads_back(tmp_path):
    g = model(n=300, degree=3, seed=2)
    write_ply(tmp_path / "m.ply", g)
    splat_transform(tmp_path / "m.ply", tmp_path / "theirs.glb")
    back = read_model(tmp_path / "theirs.glb")
    want = turned(g, (-1.0, 1.0, -1.0))  # splat-transform's RDF to LUF (half about z) read as RUB: half about y
    assert back.sh_degree == 3 and torch.equal(back.means, want.means)
    assert torch.allclose(torch.sigmoid(back.opacity_logits), torch.sigmoid(want.opacity_logits), atol=1e-6)
    # splat-transform turns rotations as R -> T R, we as T R T (the reference's flipQ): the same ellipsoids
    assert torch.allclose(covariances(back), covariances(want), rtol=1e-4, atol=1e-9)
    assert torch.equal(back.sh0, want.sh0) and torch.equal(back.shN, want.shN)


@pytest.mark.parametrize("fmt,at_least", [("spz", 30.0), ("glb", 80.0)])
def test_a_render_of_the_model_read_back_matches_the_original(tmp_path, fmt, at_least):
    """What a user sees: the model written and read back renders as the original does (axes turned and turned back,
    quantisation within what the eye tolerates; docs/editor.md has the fox's figures from `bench formats`)."""
    from training.evaluate.measure import render_with_depth
    from training.scene.scene import Camera

    g = model(n=400, degree=3, seed=3)
    g = Gaussians(**{**g.parameters(), "means": g.means * 0.3}, sh_degree=3)
    w2c = np.eye(4)
    w2c[:3, 3] = (0.1, -0.2, 3.0)
    cam = Camera("c", 96, 72, 90.0, 90.0, 48.0, 36.0, w2c)
    write_export(tmp_path / f"m.{fmt}", g)
    before = render_with_depth(g, [cam], background=(1.0, 1.0, 1.0))[0][0]
    after = render_with_depth(read_model(tmp_path / f"m.{fmt}"), [cam], background=(1.0, 1.0, 1.0))[0][0]
    assert before.std() > 0.05
    mse = float(np.mean((before.astype(np.float64) - after) ** 2))
    assert 10 * np.log10(1 / max(mse, 1e-30)) >= at_least
