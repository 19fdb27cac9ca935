"""SPZ and glTF (KHR_gaussian_splatting) files checked by readers we did not write: our SPZ decoded by PlayCanvas's
splat-transform (its own decoder) and read back with plyfile; SPZ written by the spec's reference encoder (the
WebAssembly build splat-transform uses) read by us; our SPZ decoded by the reference library itself, asked for
several axes, and files it turned into other axes read by us; our .glb's accessors decoded through pygltflib and
the file passed through the Khronos validator; splat-transform's .glb read by us. Every attribute is compared
within the format's quantisation, stated from the specs below.

Axes (docs/editor.md, "Axes"): a model exported here and converted back to PLY by splat-transform must come back
unturned, and splat-transform's own SPZ and .glb of a PLY must open here as that PLY, checked on an "L" of
Gaussians whose arms any turn or mirror moves, and on a reconstruction of the fox (slow). The turns a file may
hold are written here from their definitions (``turned``), not from training/model/axes.py.

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

from pathlib import Path

import numpy as np
import pytest
import torch
from plyfile import PlyData

from app.cli import main
from tests.other_tools import spz_reference_decode, spz_reference_reencode, splat_transform, validate_gltf
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
FOX = Path(__file__).resolve().parents[2] / "shared" / "data" / "scenes" / "fox"


def model(n=500, degree=3, seed=0) -> Gaussians:
    """Random Gaussians inside every format's range (SPZ clamps log scales to [-10, 6), SH to [-1, 1))."""
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g) * 2, log_scales=torch.randn(n, 3, generator=g) * 0.7 - 4,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g) * 2,
                     sh0=torch.randn(n, 1, 3, generator=g) * 0.6,
                     shN=(torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g) * 0.2).clamp(-0.95, 0.95),
                     sh_degree=degree)


RUB = (1.0, -1.0, -1.0)  # RDF to RUB: x kept, y and z negated (a half turn about x)
LUF = (-1.0, -1.0, 1.0)  # RDF to glTF's LUF: x and y negated (a half turn about z)


def l_model(degree: int = 3, seed: int = 0) -> Gaussians:
    """An "L" with a third arm: 12 Gaussians along +x, 8 along -y (up, in our RDF) and 4 along +z, each stretched
    along its arm and tinted by it. Any turn or mirror of the axes moves an arm, so no axis mistake can hide."""
    g = torch.Generator().manual_seed(seed)
    means, log_scales = [torch.zeros(1, 3)], [torch.full((1, 3), -3.0)]
    for axis, sign, count in [(0, 1.0, 12), (1, -1.0, 8), (2, 1.0, 4)]:
        m = torch.zeros(count, 3)
        m[:, axis] = sign * 0.25 * torch.arange(1, count + 1)
        s = torch.full((count, 3), -3.5)
        s[:, axis] = -2.0
        means.append(m)
        log_scales.append(s)
    means, log_scales = torch.cat(means), torch.cat(log_scales)
    n = len(means)
    tint = torch.zeros(n, 1, 3)
    tint[1:13, 0, 0], tint[13:21, 0, 1], tint[21:, 0, 2] = 1.2, 1.2, 1.2
    quats = torch.nn.functional.normalize(torch.tensor([1.0, 0, 0, 0]) + 0.3 * torch.randn(n, 4, generator=g), dim=1)
    return Gaussians(means=means, log_scales=log_scales, quats=quats,
                     opacity_logits=torch.linspace(-1.0, 3.0, n), sh0=tint - 0.4,
                     shN=(torch.rand(n, (degree + 1) ** 2 - 1, 3, generator=g) - 0.5) * 0.9, sh_degree=degree)


@pytest.fixture(scope="module")
def fox(tmp_path_factory) -> Path:
    """A PLY of the fox from ../shared, reconstructed here for a few steps at 1/16 resolution (SH degree 3 active
    from step 90), about 20 s; no reconstruction is stored."""
    from dataclasses import replace

    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
    from training.scene.loader import load_scene

    if not FOX.is_dir():
        pytest.skip(f"needs the fox scene at {FOX}")
    cfg = ReconstructConfig.from_preset("quick", depth="none", random_init_points=3000, seed=0, sh_interval=30)
    cfg = replace(cfg, iterations=120, densify=replace(cfg.densify, start=40, interval=40, stop=110))
    rec = Reconstructor(load_scene(FOX, downscale=16), cfg)
    for _ in range(cfg.iterations):
        rec.step()
    path = tmp_path_factory.mktemp("fox") / "fox.ply"
    write_ply(path, rec.export_gaussians())
    return path


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


def rotation_matrices(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1).reshape(-1, 3, 3)


def assert_same_axes(got: np.ndarray, want: np.ndarray, tol: float) -> None:
    """Quaternions (w, x, y, z) whose rotations give each Gaussian the same principal axes, each up to its sign (a
    half turn about one of its own axes leaves an ellipsoid as it was: converters may differ by one)."""
    d = rotation_matrices(got).transpose(0, 2, 1) @ rotation_matrices(want)
    assert np.abs(np.abs(d) - np.eye(3)).max() <= tol


def assert_sh_within(got: np.ndarray, want: np.ndarray, quantisations: int) -> None:
    """SH quantised in other axes than they are compared in: each degree's 2l+1 coefficients turned by an orthogonal
    matrix, so the error bound holds for their length (per channel), sqrt(2l+1) half buckets per quantisation."""
    for degree, tol in [(1, SH1_TOL), (2, SH_REST_TOL), (3, SH_REST_TOL)]:
        part = slice(degree * degree - 1, (degree + 1) ** 2 - 1)
        if want.shape[1] > part.start:
            error = np.linalg.norm(got[:, part] - want[:, part], axis=1)
            assert error.max() <= quantisations * np.sqrt(2 * degree + 1) * tol, degree


def assert_within_spz(got: dict, want: dict, quats_as_axes: bool = False) -> None:
    """Within the tolerances of the module doc; ``quats_as_axes`` for a file stored in axes of the other family
    (rotations compared as principal axes, SH as each degree's length)."""
    assert np.abs(got["means"] - want["means"]).max() <= POS_TOL
    assert np.abs(got["log_scales"] - want["log_scales"]).max() <= LOG_SCALE_TOL
    assert np.abs(got["alpha"] - want["alpha"]).max() <= ALPHA_TOL
    assert np.abs(got["dc"] - want["dc"]).max() <= DC_TOL
    sign = np.where((got["quats"] * want["quats"]).sum(1) < 0, -1.0, 1.0)[:, None]
    if quats_as_axes:
        assert_same_axes(got["quats"], want["quats"], 4 * ROT_TOL)
    else:
        assert np.abs(got["quats"] * sign - want["quats"]).max() <= ROT_TOL
    assert got["rest"].shape == want["rest"].shape
    if quats_as_axes:
        assert_sh_within(got["rest"], want["rest"], 1)
    elif want["rest"].shape[1]:
        assert np.abs(got["rest"][:, :3] - want["rest"][:, :3]).max() <= SH1_TOL
        assert np.abs(got["rest"][:, 3:] - want["rest"][:, 3:]).max(initial=0) <= SH_REST_TOL


@pytest.mark.parametrize("version,bands", [(4, 0), (4, 1), (4, 3), (3, 2), (3, 3)])
def test_our_spz_decoded_by_splat_transform(tmp_path, version, bands):
    g = model()
    write_export(tmp_path / "m.spz", g, sh_bands=bands, spz_version=version)
    head = (tmp_path / "m.spz").read_bytes()[:4]
    assert head == b"NGSP" if version == 4 else head[:2] == b"\x1f\x8b"
    splat_transform(tmp_path / "m.spz", tmp_path / "back.ply")
    # splat-transform decodes SPZ without turning axes, and we store the PLY's: the model as it is
    want = arrays(Gaussians(**{**g.parameters(), "shN": g.shN[:, : (bands + 1) ** 2 - 1]}, sh_degree=bands))
    assert_within_spz(ply_arrays(tmp_path / "back.ply"), want)


@pytest.mark.parametrize("version", [3, 4])
def test_spz_from_the_reference_encoder_reads_back(tmp_path, version):
    g = model(degree=3, seed=1)
    write_ply(tmp_path / "m.ply", g)
    splat_transform(tmp_path / "m.ply", "--spz-version", version, tmp_path / "ref.spz")
    back = read_model(tmp_path / "ref.spz")
    assert back.sh_degree == 3 and len(back) == len(g)
    # splat-transform writes the PLY's axes as they are, and we read an unlabelled SPZ so: no turn
    assert_within_spz(arrays(back), arrays(g))


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
    want = arrays(turned(g, LUF))  # glTF's axes: left-up-front
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
    # splat-transform writes glTF's LUF (a half turn about z), which we turn back: the model as it was
    assert back.sh_degree == 3 and torch.equal(back.means, g.means)
    assert torch.allclose(torch.sigmoid(back.opacity_logits), torch.sigmoid(g.opacity_logits), atol=1e-6)
    # splat-transform turns rotations as R -> T R, we as T R T (the reference's flipQ): the same ellipsoids
    assert torch.allclose(covariances(back), covariances(g), rtol=1e-4, atol=1e-9)
    assert torch.equal(back.sh0, g.sh0) and torch.equal(back.shN, g.shN)


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


# ------------------------------------------------------------------------------------------------------------- axes
def cli(capsys, *argv) -> str:
    """``splatstyler ARGV`` as a user runs it; its stdout (exit 0 asserted)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


def assert_same_floats(got: dict, want: dict) -> None:
    """A model through float32 files (glTF, PLY): equal to float rounding; rotations as shapes (covariances),
    since a converter may describe the same ellipsoid by another quaternion."""
    assert np.abs(got["means"] - want["means"]).max() <= 1e-5 * max(1.0, np.abs(want["means"]).max())
    assert np.abs(got["log_scales"] - want["log_scales"]).max() <= 1e-5
    assert np.abs(got["alpha"] - want["alpha"]).max() <= 1e-6
    assert np.abs(got["dc"] - want["dc"]).max() <= 1e-6
    assert got["rest"].shape == want["rest"].shape and np.abs(got["rest"] - want["rest"]).max(initial=0) <= 1e-6

    def cov(a):
        r = rotation_matrices(a["quats"])
        return r @ (np.exp(2 * a["log_scales"])[:, :, None] * r.transpose(0, 2, 1))

    c = cov(want)
    assert np.abs(cov(got) - c).max() <= 1e-5 * np.abs(c).max()


SPZ_EXPORTS = [["--spz-version", "4"], ["--spz-version", "3"]]


def export_and_back_through_splat_transform(tmp_path, capsys, ply: Path, flags) -> dict:
    cli(capsys, "export", ply, "-o", tmp_path / "ours.spz", *flags)
    splat_transform(tmp_path / "ours.spz", tmp_path / "back.ply")
    return ply_arrays(tmp_path / "back.ply")


def glb_arrays(path: Path) -> dict[str, np.ndarray]:
    """A .glb's splats as arrays(), in the file's own axes, decoded through pygltflib's parse (gltf_accessors)."""
    _, acc = gltf_accessors(path)
    key = "KHR_gaussian_splatting:"
    q = acc[key + "ROTATION"][:, [3, 0, 1, 2]]
    rest = [acc[f"{key}SH_DEGREE_{d}_COEF_{i}"] for d in range(1, 4) for i in range(2 * d + 1)
            if f"{key}SH_DEGREE_{d}_COEF_{i}" in acc]
    n = len(q)
    return {"means": acc["POSITION"], "log_scales": np.log(acc[key + "SCALE"]),
            "quats": q / np.linalg.norm(q, axis=1, keepdims=True), "alpha": acc[key + "OPACITY"][:, 0],
            "dc": acc[key + "SH_DEGREE_0_COEF_0"], "rest": np.stack(rest, 1) if rest else np.zeros((n, 0, 3))}


@pytest.mark.parametrize("flags", SPZ_EXPORTS, ids=["spz4", "spz3"])
def test_export_converted_back_by_splat_transform_is_not_turned(tmp_path, capsys, flags):
    """Issue 39: what SuperSplat shows of our SPZ is what it shows of our PLY: PLY -> export -> splat-transform
    -> PLY gives every Gaussian back where it was, within the format's step, on the "L"."""
    g = l_model()
    write_ply(tmp_path / "l.ply", g)
    got = export_and_back_through_splat_transform(tmp_path, capsys, tmp_path / "l.ply", flags)
    assert_within_spz(got, arrays(g))
    # the arms point where they pointed: +x, -y (up), +z
    assert got["means"][12, 0] == pytest.approx(3.0, abs=1e-3) and got["means"][20, 1] == pytest.approx(-2.0, abs=1e-3)
    assert got["means"][24, 2] == pytest.approx(1.0, abs=1e-3)


def test_our_glb_is_splat_transforms_glb(tmp_path, capsys):
    """Issue 39, glTF: splat-transform 3.7 writes .glb but does not read it, so the check is that ours holds what
    its own holds for the same PLY (decoded by pygltflib): the same centres in glTF's left-up-front, the same
    ellipsoids, opacities and SH. A glTF viewer then shows ours as it shows splat-transform's."""
    g = l_model()
    write_ply(tmp_path / "l.ply", g)
    cli(capsys, "export", tmp_path / "l.ply", "-o", tmp_path / "ours.glb")
    splat_transform(tmp_path / "l.ply", tmp_path / "theirs.glb")
    theirs = glb_arrays(tmp_path / "theirs.glb")
    assert_same_floats(glb_arrays(tmp_path / "ours.glb"), theirs)
    assert_same_floats(theirs, arrays(turned(g, LUF)))  # and that is glTF's LUF: the long arm along -x


def bounds(capsys, path: Path) -> np.ndarray:
    import json

    s = json.loads(cli(capsys, "info", path, "--json"))
    return np.array([s["bounds_min"], s["bounds_max"]])


@pytest.mark.parametrize("fmt,flags", [("spz", ["--spz-version", "4"]), ("spz", ["--spz-version", "3"]),
                                       ("glb", [])], ids=["spz4", "spz3", "glb"])
def test_splat_transform_files_open_here_as_their_ply(tmp_path, capsys, fmt, flags):
    """Issue 39: a .spz or .glb that splat-transform (SuperSplat's converter) writes from a PLY opens here as the
    PLY does: same bounding box in `info`, every Gaussian in its place."""
    g = l_model()
    write_ply(tmp_path / "l.ply", g)
    splat_transform(tmp_path / "l.ply", *flags, tmp_path / f"theirs.{fmt}")
    tol = POS_TOL if fmt == "spz" else 1e-6
    assert np.abs(bounds(capsys, tmp_path / f"theirs.{fmt}") - bounds(capsys, tmp_path / "l.ply")).max() <= tol
    back = read_model(tmp_path / f"theirs.{fmt}")
    assert np.abs(back.means.double().numpy() - g.means.double().numpy()).max() <= tol


@pytest.mark.slow
@pytest.mark.parametrize("fmt,flags", [("spz", ["--spz-version", "4"]), ("spz", ["--spz-version", "3"]),
                                       ("glb", [])], ids=["spz4", "spz3", "glb"])
def test_fox_both_ways_through_splat_transform(tmp_path, capsys, fox, fmt, flags):
    """Issue 39's acceptance on a real reconstruction: `splatstyler export fox.ply -o f.spz` converted back to PLY
    by splat-transform has every centre within the format's step of the fox's, unturned (`-o f.glb`: the same as
    splat-transform's own .glb of the fox); the file splat-transform writes from the fox's PLY has the PLY's
    bounding box in `splatstyler info`."""
    fox_model = read_model(fox)
    if fmt == "spz":
        assert_within_spz(export_and_back_through_splat_transform(tmp_path, capsys, fox, flags), arrays(fox_model))
    splat_transform(fox, *flags, tmp_path / f"theirs.{fmt}")
    if fmt == "glb":
        cli(capsys, "export", fox, "-o", tmp_path / "ours.glb")
        assert_same_floats(glb_arrays(tmp_path / "ours.glb"), glb_arrays(tmp_path / "theirs.glb"))
    tol = POS_TOL if fmt == "spz" else 1e-6
    box = bounds(capsys, fox)
    assert np.abs(bounds(capsys, tmp_path / f"theirs.{fmt}") - box).max() <= tol
    # the half turns the formats differ by would move this box by far more than a step: the check can fail
    for signs in (RUB, LUF):
        turned_box = np.sort(box * np.array(signs), axis=0)
        assert np.abs(turned_box - box).max() > 100 * POS_TOL


def ref_arrays(r: dict) -> dict[str, np.ndarray]:
    """The reference library's decode (tests/other_tools.py) as arrays()."""
    q = r["rotations"][:, [3, 0, 1, 2]].astype(np.float64)
    return {"means": r["positions"].astype(np.float64), "log_scales": r["scales"].astype(np.float64),
            "quats": q / np.linalg.norm(q, axis=1, keepdims=True), "alpha": 1 / (1 + np.exp(-r["alphas"][:, 0])),
            "dc": r["colors"].astype(np.float64), "rest": r["sh"].astype(np.float64)}


def test_the_reference_library_turns_our_spz_to_any_axes(tmp_path):
    """Our SPZ (version 4) names its axes in the reference's coordinate-system extension, so the reference library,
    asked for the PLY's RDF, gives the model back, and asked for the README's RUB, the model turned half about x;
    its bytes as stored (UNSPECIFIED, what splat-transform reads) are the PLY's. (Version 3: the reference 0.2.3
    finds no extension records in gzip files, docs/editor.md.)"""
    g = l_model()
    write_export(tmp_path / "l.spz", g, spz_version=4)
    for to, want in [("RDF", g), ("UNSPECIFIED", g), ("RUB", turned(g, RUB))]:
        r = spz_reference_decode(tmp_path / "l.spz", to, tmp_path)
        assert r["numPoints"] == len(g) and r["shDegree"] == 3
        assert r["extensions"] == [{"type": 0xADBE0003, "coordinateSystem": 6}]  # 6: RDF
        assert_within_spz(ref_arrays(r), arrays(want))


@pytest.mark.parametrize("axes,version", [("rub", 4), ("rub", 3), ("rfu", 4)])
def test_axes_flag_writes_other_axes_that_every_reader_places(tmp_path, capsys, axes, version):
    """`export --axes rub` stores the SPZ README's right-up-back (what splat-transform, reading bytes as they are,
    then shows turned half about x), named in the file, so the reference library and we place it right; the z-up
    RFU (a quarter turn: SH rotated, not only signed) likewise. The reference reads unnamed RUB as its default, so
    a version 3 file (whose name it does not find) is right there too."""
    g = l_model()
    write_ply(tmp_path / "l.ply", g)
    cli(capsys, "export", tmp_path / "l.ply", "-o", tmp_path / "l.spz", "--axes", axes, "--spz-version", version)
    r = spz_reference_decode(tmp_path / "l.spz", "RDF", tmp_path)
    assert_within_spz(ref_arrays(r), arrays(g), quats_as_axes=axes == "rfu")
    assert_within_spz(arrays(read_model(tmp_path / "l.spz")), arrays(g), quats_as_axes=axes == "rfu")
    if axes == "rub":
        splat_transform(tmp_path / "l.spz", tmp_path / "raw.ply")
        assert_within_spz(ply_arrays(tmp_path / "raw.ply"), arrays(turned(g, RUB)))


def assert_within_two_quantisations(got: dict, want: dict) -> None:
    """A file the reference decoded, turned and packed again: quantised twice where the turn mixed the values
    (rotations, SH), exactly as before where it only moved them (centres stay on the 12-bit grid)."""
    assert np.abs(got["means"] - want["means"]).max() <= POS_TOL
    assert np.abs(got["log_scales"] - want["log_scales"]).max() <= LOG_SCALE_TOL
    assert np.abs(got["alpha"] - want["alpha"]).max() <= ALPHA_TOL
    assert np.abs(got["dc"] - want["dc"]).max() <= DC_TOL
    assert_same_axes(got["quats"], want["quats"], 8 * ROT_TOL)
    assert_sh_within(got["rest"], want["rest"], 2)


@pytest.mark.parametrize("axes", ["RUB", "RFU"])
def test_unlabelled_spz_in_other_axes_reads_with_input_axes(tmp_path, capsys, axes):
    """A file the reference library turned into other axes and saved without saying so (as the README's RUB files
    are): read as the tools read SPZ it stays turned; `--input-axes` names its axes and it comes back as the model,
    SH turned by the reference's own rotation for the z-up RFU."""
    g = l_model()
    write_export(tmp_path / "l.spz", g)
    spz_reference_reencode(tmp_path / "l.spz", tmp_path / "other.spz", axes)
    assert spz_reference_decode(tmp_path / "other.spz", "UNSPECIFIED", tmp_path)["extensions"] == []
    if axes == "RUB":  # taken for the tools' RDF: upside down, as in SuperSplat
        assert_within_spz(arrays(read_model(tmp_path / "other.spz")), arrays(turned(g, RUB)))
    cli(capsys, "export", tmp_path / "other.spz", "--input-axes", axes.lower(), "-o", tmp_path / "fixed.ply")
    assert_within_two_quantisations(ply_arrays(tmp_path / "fixed.ply"), arrays(g))
