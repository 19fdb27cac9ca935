"""Project files (app/project.py): a session saved and opened again unchanged, hand-written and older manifests,
files that moved or changed (one line each, the rest opens), and files that are not projects (one line, nothing
lost)."""

from __future__ import annotations

import json
import shutil
import zipfile

import numpy as np
import pytest
import torch

import app.project as project_module
from app.camera_path import CameraPath
from app.project import FileRef, ModelEntry, Project, file_sha256, open_project, save_project
from training.core.errors import InputError
from training.model.colour_edit import ColourAdjustment, ColourEdits
from training.model.gaussians import Gaussians
from training.model.ply_io import write_ply
from training.scene.camera import Camera


def model(n=200, degree=1, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g), log_scales=torch.randn(n, 3, generator=g) - 3,
                     quats=torch.randn(n, 4, generator=g), opacity_logits=torch.randn(n, generator=g),
                     sh0=torch.randn(n, 1, 3, generator=g), shN=torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g),
                     sh_degree=degree)


def key(x: float) -> Camera:
    m = np.eye(4)
    m[:3, 3] = [x, 0.5, 2.0]
    return Camera("keyframe", 640, 360, 500.0, 510.0, 320.0, 180.0, m)


def full_project(folder) -> Project:
    write_ply(folder / "stylized.ply", model(seed=1))
    write_ply(folder / "photo.ply", model(seed=2))
    (folder / "painting.jpg").write_bytes(b"not read here")
    (folder / "data").mkdir(exist_ok=True)
    rng = np.random.default_rng(0)
    kept = np.flatnonzero(rng.random(200) > 0.2)
    region = rng.random(200) > 0.5
    transform = np.eye(4)
    transform[:3, :3] = 2.0 * np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    transform[:3, 3] = [1, 2, 3]
    colour = ColourEdits([(region, ColourAdjustment(hue=30, saturation=0.2)), (None, ColourAdjustment(0.1))],
                         strength=0.6, strength_regions=[(~region, 0.0)])
    entry = ModelEntry(FileRef(folder / "stylized.ply"), "fox", FileRef(folder / "photo.ply"), kept,
                       rng.random(len(kept)) > 0.7, rng.random(len(kept)) > 0.9, transform, colour)
    return Project([entry], FileRef(folder / "data"), FileRef(folder / "painting.jpg"),
                   stylize={"loss": "nnfm", "tau": 0.5, "background": (1.0, 1.0, 1.0)}, camera=key(0.0),
                   camera_distance=2.5, camera_path=CameraPath([key(0.0), key(1.0)], 6.0, 24.0, True),
                   layout="[Window][Scene]\nPos=0,0\n", up=np.array([0.0, 0.0, 1.0]),
                   world=np.diag([2.0, 2, 2, 1]))


def assert_same(a: Project, b: Project) -> None:
    ma, mb = a.models[0], b.models[0]
    assert ma.file.path.resolve() == mb.file.path.resolve() and ma.name == mb.name
    assert ma.original.path.resolve() == mb.original.path.resolve()
    for k in ("kept", "selected", "hidden", "transform"):
        assert np.array_equal(getattr(ma, k), getattr(mb, k))
    assert [adj for _, adj in ma.colour.adjustments] == [adj for _, adj in mb.colour.adjustments]
    for (ra, _), (rb, _) in zip(ma.colour.adjustments + ma.colour.strength_regions,
                                mb.colour.adjustments + mb.colour.strength_regions):
        assert (ra is None and rb is None) or np.array_equal(ra, rb)
    assert ma.colour.strength == mb.colour.strength
    assert [s for _, s in ma.colour.strength_regions] == [s for _, s in mb.colour.strength_regions]
    assert a.stylize == b.stylize and a.layout == b.layout
    assert np.array_equal(a.camera.world_to_camera, b.camera.world_to_camera) and a.camera.fy == b.camera.fy
    assert a.camera_distance == b.camera_distance
    assert a.camera_path.to_dict() == b.camera_path.to_dict()  # keyframes, duration, fps, loop
    assert np.array_equal(a.up, b.up) and np.array_equal(a.world, b.world)
    assert a.dataset.path.resolve() == b.dataset.path.resolve()


def test_a_saved_project_opens_unchanged(tmp_path):
    p = full_project(tmp_path)
    written = save_project(tmp_path / "session", p)
    assert written == tmp_path / "session.splatproj" and zipfile.is_zipfile(written)
    q, problems = open_project(written)
    assert problems == []
    assert_same(p, q)
    assert q.stylize_config().loss == "nnfm" and q.stylize_config().background == (1.0, 1.0, 1.0)
    manifest = json.loads(zipfile.ZipFile(written).read("project.json"))
    assert manifest["version"] == 1 and manifest["models"][0]["path"] == "stylized.ply"
    assert manifest["models"][0]["sha256"] == file_sha256(tmp_path / "stylized.ply")


def test_a_project_moved_with_its_files_opens_and_one_moved_alone_too(tmp_path):
    (tmp_path / "a").mkdir()
    save_project(tmp_path / "a" / "s.splatproj", full_project(tmp_path / "a"))
    shutil.move(tmp_path / "a", tmp_path / "b")  # the folder moved: the relative paths find the files
    q, problems = open_project(tmp_path / "b" / "s.splatproj")
    assert problems == [] and q.models[0].file.path == tmp_path / "b" / "stylized.ply"
    shutil.copy(tmp_path / "b" / "s.splatproj", tmp_path / "alone.splatproj")  # alone: nothing at the old paths
    q, problems = open_project(tmp_path / "alone.splatproj")
    assert len(problems) == 4  # model, original, dataset, painting: one line each
    assert all("\n" not in line for line in problems)
    assert any(line.startswith(f"{tmp_path / 'stylized.ply'}: model 'fox' not found") for line in problems)
    assert q.models[0].file.missing and not q.models[0].usable
    assert q.layout.startswith("[Window]") and len(q.camera_path.keyframes) == 2  # the rest opened


def test_a_changed_model_is_one_line(tmp_path):
    p = full_project(tmp_path)
    save_project(tmp_path / "s.splatproj", p)
    write_ply(tmp_path / "stylized.ply", model(seed=7))
    q, problems = open_project(tmp_path / "s.splatproj")
    assert problems == [f"{tmp_path / 'stylized.ply'}: model 'fox' changed since the project was saved (content hash "
                        "differs)"]
    assert q.models[0].file.changed and not q.models[0].usable


def test_embedded_models_open_without_their_files(tmp_path):
    p = full_project(tmp_path)
    save_project(tmp_path / "s.splatproj", p, embed=True)
    (tmp_path / "stylized.ply").unlink()
    (tmp_path / "photo.ply").unlink()
    q, problems = open_project(tmp_path / "s.splatproj")
    assert problems == []
    g = q.open_model(q.models[0].file)
    assert torch.equal(g.sh0, model(seed=1).sh0)
    assert torch.equal(q.open_model(q.models[0].original).means, model(seed=2).means)
    save_project(tmp_path / "again.splatproj", q)  # re-saved: still embedded, read from the first file
    r, problems = open_project(tmp_path / "again.splatproj")
    assert problems == [] and torch.equal(r.open_model(r.models[0].file).sh0, model(seed=1).sh0)


def write_manifest(path, manifest: dict, arrays: dict | None = None):
    import io

    with zipfile.ZipFile(path, "w") as z:
        z.writestr("project.json", json.dumps(manifest))
        for name, a in (arrays or {}).items():
            buf = io.BytesIO()
            np.save(buf, a)
            z.writestr(name, buf.getvalue())
    return path


def test_a_minimal_hand_written_v1_manifest_opens_with_defaults(tmp_path):
    write_ply(tmp_path / "m.ply", model())
    q, problems = open_project(write_manifest(tmp_path / "min.splatproj", {"version": 1,
                                                                            "models": [{"path": "m.ply"}]}))
    assert problems == []
    m = q.models[0]
    assert m.name == "m" and m.kept is None and m.selected is None and np.array_equal(m.transform, np.eye(4))
    assert m.colour.is_identity and q.camera is None and q.camera_path.keyframes == [] and q.layout == ""
    assert np.array_equal(q.world, np.eye(4)) and q.stylize == {} and q.dataset is None


def test_an_older_version_is_upgraded_through_the_migrations(tmp_path, monkeypatch):
    """A future version 2 renames a field; a version 1 file goes through MIGRATIONS[1] before it is read."""
    def v1_to_v2(data):
        data["layout"] = data.pop("dock_layout", "")
        return data

    write_ply(tmp_path / "m.ply", model())
    path = write_manifest(tmp_path / "old.splatproj", {"version": 1, "models": [{"path": "m.ply"}],
                                                         "dock_layout": "[Docking]\n"})
    monkeypatch.setattr(project_module, "FORMAT_VERSION", 2)
    monkeypatch.setitem(project_module.MIGRATIONS, 1, v1_to_v2)
    q, problems = open_project(path)
    assert problems == [] and q.layout == "[Docking]\n"


@pytest.mark.parametrize("content, message", [
    (b"not a zip", "not a splatstyler project (not a zip file)"),
    ({"version": 3, "models": []}, "project version 3 was written by a newer splatstyler"),
    ({"models": []}, "project 'version' must be a whole number"),
    ({"version": 1, "models": [{"path": "m.ply", "transform": np.diag([1.0, 2, 1, 1]).tolist()}]},
     "models[0].transform': a transform must be a rotation"),
    ({"version": 1, "models": [{"path": "m.ply", "kept": "arrays/k.npy"}]}, "names arrays/k.npy, which is not"),
    ({"version": 1, "models": [{"path": "m.ply", "colour": [{"hue": 400}]}]}, "hue must be in [-180, 180]"),
    ({"version": 1, "models": [{"path": "m.ply", "strength": 0.5}]}, "style strength below 1 needs an 'original'"),
    ({"version": 1, "models": [], "up": [1e308, 1e308, 0]}, "'up' must be a direction"),  # its norm overflows
    ({"version": 1, "models": [], "camera_path": {"keyframes": [], "duration": 1e7, "fps": 1e6}},
     "fps must be in (0, 240]"),  # checked with no keyframes too: the viewer adds them and renders the path
    ({"version": 1, "models": [], "camera_path": {"keyframes": [], "duration": 1e4, "fps": 60}},
     "600000 frames"),
])
def test_what_is_not_a_project_is_one_line(tmp_path, content, message):
    write_ply(tmp_path / "m.ply", model())
    path = tmp_path / "bad.splatproj"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        write_manifest(path, content)
    with pytest.raises(InputError) as info:
        open_project(path)
    assert str(info.value).startswith(f"{path}: ") and message in str(info.value) and "\n" not in str(info.value)


def test_mismatched_array_lengths_and_a_failed_save_lose_nothing(tmp_path):
    write_ply(tmp_path / "m.ply", model())
    path = write_manifest(tmp_path / "bad.splatproj",
                          {"version": 1, "models": [{"path": "m.ply", "kept": "arrays/k.npy",
                                                     "selected": "arrays/s.npy"}]},
                          {"arrays/k.npy": np.arange(5), "arrays/s.npy": np.zeros(4, bool)})
    with pytest.raises(InputError, match="arrays/s.npy has 4 rows, expected 5"):
        open_project(path)
    good = save_project(tmp_path / "good.splatproj", full_project(tmp_path))
    before = good.read_bytes()
    broken = full_project(tmp_path)
    broken.models[0].file = FileRef(tmp_path / "gone.ply")
    with pytest.raises(InputError, match="cannot embed this model: file not found"):
        save_project(good, broken, embed=True)
    assert good.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []  # no temporary left


def test_a_member_many_regions_name_is_read_once(tmp_path):
    """200 colour adjustments over one region member of a million rows: the member is inflated once and the
    regions share it (read 200 times, a 10-million-row one took 2 GB)."""
    import tracemalloc

    write_ply(tmp_path / "m.ply", model())
    path = write_manifest(tmp_path / "regions.splatproj",
                          {"version": 1, "models": [{"path": "m.ply", "colour": [{"region": "arrays/r.npy",
                                                                                  "hue": 1}] * 200}]},
                          {"arrays/r.npy": np.zeros(1_000_000, bool)})
    tracemalloc.start()
    try:
        q, problems = open_project(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    regions = [region for region, _ in q.models[0].colour.adjustments]
    assert len(regions) == 200 and all(r is regions[0] for r in regions) and len(regions[0]) == 1_000_000
    assert peak < 20e6, f"{peak / 1e6:.0f} MB to open it"


def test_stylize_settings_that_are_not_numbers_of_their_kind_are_one_line_and_the_defaults_used(tmp_path):
    """JSON's Infinity for tau, a float where a whole number goes (k, seed): each is one problem line and the
    project opens with the default settings, which a stylization can run with (Infinity ran before)."""
    write_ply(tmp_path / "m.ply", model())
    for stylize, word in (({"tau": float("inf")}, "tau must be a finite number, got inf"),
                          ({"k": 4.0}, "k must be a whole number, got 4.0"),
                          ({"seed": 1.5}, "seed must be a whole number, got 1.5")):
        path = write_manifest(tmp_path / "s.splatproj", {"version": 1, "models": [{"path": "m.ply"}],
                                                          "stylize": stylize})
        assert "Infinity" in zipfile.ZipFile(path).read("project.json").decode() or "inf" not in word
        q, problems = open_project(path)
        assert q.stylize == {} and len(problems) == 1 and word in problems[0], problems
    path = write_manifest(tmp_path / "ok.splatproj", {"version": 1, "models": [{"path": "m.ply"}],
                                                       "stylize": {"k": 4, "tau": 0.5}})
    assert open_project(path)[0].stylize_config().k == 4
