"""Nothing the user made in the viewer is lost, round three (issue 49), through the real Document, LiveSession,
stages, run_sfm and the window's file functions, without a window: Ctrl+S after "Edit the running model" saves the
opened project, not an empty one; a project whose file moved can still be saved; settings given while a run
reconstructs reach the stylization after it; two windows on one output folder keep both runs (folders claimed as a
run starts, a live SfM's partial folder locked); photos sharing a name stem keep their own staged names; unsaved
edits are asked about before anything replaces them, shown in the title, and kept in a recovery project; a project
whose models cannot be shown leaves no model for Stylize; Save As asks before replacing the name it completes."""

from __future__ import annotations

import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from app.project import FileRef, ModelEntry, Project, open_project, save_project
from app.viewer import dialogs, files
from app.viewer.app import ViewerApp
from app.viewer.layout import confirm_exit, window_title
from app.viewer.live import runs
from training.core.status import StylizeStatus
from app.viewer.live.photos import start_photos
from app.viewer.live.session import LiveSession, Saved, Stage
from app.viewer.recovery import Recovery, left_behind
from app.viewer.state import Paths
from tests.viewer_harness import make_demo_scene
from training.core.errors import InputError
from training.model.gaussians import Gaussians
from training.model.ply_io import read_ply, write_ply
from training.scene.image_io import write_image


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    return make_demo_scene(tmp_path_factory)


@pytest.fixture(autouse=True)
def no_dock_layout(monkeypatch):
    """Without a window there is no imgui context to ask for the dock layout: saves write none."""
    monkeypatch.setattr(files, "project_now",
                        lambda doc, ui, layout=None, now=files.project_now: now(doc, ui, layout=layout or ""))


def write_model(path, n=150, seed=0):
    g = torch.Generator().manual_seed(seed)
    write_ply(path, Gaussians(torch.randn(n, 3, generator=g), torch.randn(n, 3, generator=g) - 3,
                              torch.randn(n, 4, generator=g), torch.randn(n, generator=g),
                              torch.randn(n, 1, 3, generator=g), torch.randn(n, 3, 3, generator=g), 1))
    return path


def wait(condition, seconds: float, what: str) -> None:
    t0 = time.time()
    while not condition():
        if time.time() - t0 > seconds:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def tiny_reconstructor(iterations: int):
    from assets.demo.scene import make_demo_scene as render_demo_scene
    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
    from training.scene.scene import Scene

    d = render_demo_scene(num_views=8, width=48, height=36, num_points=300)
    return Reconstructor(Scene(d.cameras, d.images, points=d.points, point_colors=d.point_colors),
                         ReconstructConfig(iterations=iterations, device="cpu"))


def embedded_project(tmp_path: Path, kept: np.ndarray) -> Path:
    """A project carrying its model inside (its file gone), keeping ``kept`` rows."""
    model = write_model(tmp_path / "m.ply")
    project = save_project(tmp_path / "p.splatproj", Project([ModelEntry(FileRef(model), "m", kept=kept)]),
                           embed=True)
    model.unlink()
    return project


def new_app(tmp_path: Path, out: str = "out") -> ViewerApp:
    return ViewerApp(Paths(out=str(tmp_path / out)))


# ------------------------------------------------------------------------------------------ item 1
def test_ctrl_s_after_editing_the_running_model_saves_the_opened_project(tmp_path):
    """A project is open (an embedded model, 75 of its 150 rows kept); a reconstruction runs and the user edits its
    model ("Edit the running model", a deletion); Ctrl+S, during the run and after it, writes the opened project:
    its model with its 75 rows, embedded, not a project of no models."""
    kept = np.arange(0, 150, 2)
    project = embedded_project(tmp_path, kept)
    app = new_app(tmp_path)
    doc, session, ui = app.document, app.session, app.ui
    files.open_project(doc, session, ui, str(project))
    session.start([Stage("reconstruct", lambda _: tiny_reconstructor(1000), lambda *a: None)], paused=True)
    try:
        wait(lambda: session.status().state == "paused", 120, "the run to load")
        runs.edit_live(doc, session, ui)
        doc.editor.select(np.arange(doc.editor.count) < 5)
        doc.delete()
        wait(lambda: (runs.finish_pending(ui), not ui.training.pending)[1], 60, "the deletion to reach the trainer")
        assert ui.messages.error == "" and session.snapshot().means.shape[0] == doc.editor.count
        files.save_project(doc, session, ui, layout="")
    finally:
        session.close()
    for when in ("during the run", "after it"):
        saved, _ = open_project(project)
        assert len(saved.models) == 1, when
        assert np.array_equal(saved.models[0].kept, kept), when
        assert any(n.startswith("models/") for n in zipfile.ZipFile(project).namelist()), when
        files.save_project(doc, session, ui, layout="")
    assert not doc.unsaved()  # the run's model is the run's: its deletions are no edit of the project


# ------------------------------------------------------------------------------------------ item 2
def test_a_project_whose_file_moved_is_saved_from_the_viewers_copy(tmp_path):
    """A project carrying its model is opened and edited; its file is then moved away (or deleted): Save project
    (where it was) and Save project as (elsewhere) both write it, its model still embedded, byte for byte."""
    project = embedded_project(tmp_path, np.arange(0, 150, 3))
    member = next(n for n in zipfile.ZipFile(project).namelist() if n.startswith("models/"))
    model_bytes = zipfile.ZipFile(project).read(member)
    app = new_app(tmp_path)
    doc, session, ui = app.document, app.session, app.ui
    files.open_project(doc, session, ui, str(project))
    doc.editor.select(np.arange(doc.editor.count) < 4)
    doc.delete()
    project.rename(tmp_path / "moved.splatproj")
    for path in (None, tmp_path / "elsewhere.splatproj"):
        written = files.save_project(doc, session, ui, None if path is None else str(path), layout="")
        assert written == (project if path is None else path)
        saved, problems = open_project(written)
        assert problems == [] and len(saved.models[0].kept) == 50 - 4
        assert zipfile.ZipFile(written).read(saved.models[0].file.embedded) == model_bytes
    (tmp_path / "moved.splatproj").unlink()
    (tmp_path / "elsewhere.splatproj").unlink()  # the file saved last: the source of the next save is gone too
    written = files.save_project(doc, session, ui, layout="")
    assert len(open_project(written)[0].models[0].kept) == 46


# ------------------------------------------------------------------------------------------ item 3
@pytest.mark.slow
def test_a_style_setting_changed_while_reconstructing_is_the_stylizations(demo_scene, vgg, tmp_path):
    """Reconstruct + stylize: the Style panel's scene <-> painting slider moves while the reconstruction runs (no
    stylizer yet to hand it to); the stylization that follows is built with the value the panel shows."""
    from app.viewer.panels.style_panel import set_stylize

    scene_dir, style, _ = demo_scene
    app = ViewerApp(Paths(out=str(tmp_path / "out")), recon_iters=3, downscale=4,
                    stylize_overrides={"max_side": 32, "iters_per_view": 30, "lambda_content": 8.0})
    doc, session, ui = app.document, app.session, app.ui
    files.open_data(doc, session, ui, str(scene_dir))
    files.open_style(doc, session, ui, str(style))
    runs.start_reconstruction(doc, session, ui, then_stylize=True)
    try:
        assert session.status().stage in ("", "reconstruct")
        set_stylize(session, ui, lambda_content=0.05)
        assert ui.messages.error == "" and ui.training.stylize.lambda_content == 0.05
        wait(lambda: session.trainer_status(StylizeStatus) is not None or not session.running, 600,
             "the stylization to begin")
        assert session.trainer_status(StylizeStatus).config.lambda_content == 0.05
    finally:
        session.close()


# ------------------------------------------------------------------------------------------ item 4
def test_two_windows_on_one_output_folder_claim_their_own_run_folders(demo_scene, tmp_path):
    """Two windows writing to the same output folder start Reconstruct + stylize one after the other: each run has
    folders of its own, made as it starts, and what each run saves lands in its own (before, both reconstructions
    wrote reconstruction/); the folders a stopped run never wrote to are given back once its thread is gone."""
    scene_dir, style, _ = demo_scene
    apps = [ViewerApp(Paths(out=str(tmp_path / "out")), recon_iters=2, downscale=8) for _ in range(2)]
    saved: list[list[str]] = [[], []]
    for app in apps:
        files.open_data(app.document, app.session, app.ui, str(scene_dir))
        files.open_style(app.document, app.session, app.ui, str(style))
        runs.start_reconstruction(app.document, app.session, app.ui, then_stylize=True)
    try:
        def reconstructed(i: int) -> bool:
            saved[i] += [m.path for m in apps[i].session.poll() if isinstance(m, Saved)]
            return bool(saved[i]) or not apps[i].session.running

        for i in range(2):
            wait(lambda: reconstructed(i), 300, f"window {i + 1}'s reconstruction")
    finally:
        for app in apps:
            app.session.close()
    for i, app in enumerate(apps):
        saved[i] += [m.path for m in app.session.poll() if isinstance(m, Saved)]
    first, second = (Path(paths[0]).parent for paths in saved)
    assert first != second and first.parent == second.parent == tmp_path / "out", saved
    claimed = [list(app.ui.training.claimed) for app in apps]
    assert [p.name for p in claimed[0]] == ["reconstruction", "stylized"]
    assert [p.name for p in claimed[1]] == ["reconstruction_2", "stylized_2"]
    for app, mine, paths in zip(apps, claimed, saved):
        assert all(Path(p).parent in mine for p in paths), (paths, mine)
        runs.give_back_unused(app.session, app.ui)
        for folder in mine:  # kept when a run wrote there, gone when it stayed empty
            assert folder.is_dir() == any(Path(p).parent == folder for p in paths)


def _photos(folder: Path, n: int = 3) -> Path:
    rng = np.random.default_rng(0)
    for i in range(n):
        write_image(folder / f"p{i}.png", np.kron(rng.random((20, 25, 3)), np.ones((8, 8, 1))))
    return folder


def test_two_photos_pipelines_on_one_output_folder_get_folders_of_their_own(tmp_path):
    """New from photos in two windows at the same output folder: the second's scene and reconstruction folders are
    not the first's."""
    photos = _photos(tmp_path / "photos")
    apps = [new_app(tmp_path) for _ in range(2)]
    try:
        for app in apps:
            app.ui.photos.folder = str(photos)
            start_photos(app.document, app.session, app.ui)
        folders = [app.ui.photos.folders for app in apps]
        assert folders[0]["scene"] != folders[1]["scene"]
        assert folders[0]["reconstruction"] != folders[1]["reconstruction"]
    finally:
        for app in apps:
            app.session.close()


def test_a_second_sfm_on_the_same_output_leaves_the_running_ones_partial_folder(tmp_path):
    """Structure from motion runs into OUT; a second run on the same OUT (another window, a second command) starts
    meanwhile: it stops in one line, and the first goes on to its own end (here: photos that overlap nothing),
    never to a FileNotFoundError. A partial folder nobody holds (a killed run's) is removed by the next run."""
    from training.scene.sfm import partial_folder, run_sfm

    photos = _photos(tmp_path / "photos")
    out = tmp_path / "out" / "scene"
    stale = partial_folder(out)
    (stale / ".work").mkdir(parents=True)  # a killed run's: no process holds it
    said, second = [], {}

    def progress(p):
        if p.phase == "features" and not second:
            try:
                run_sfm(photos, out, progress=False, log=said.append)
                second["answer"] = "ran"
            except InputError as exc:
                second["answer"] = str(exc)

    with pytest.raises(InputError) as first:
        run_sfm(photos, out, progress=False, progress_to=progress, log=said.append)
    assert second["answer"].startswith(f"{out}: another structure from motion is writing this scene now")
    assert "overlaps any other" in str(first.value)  # the first run's own end, its folder intact until then
    assert f"      removing {stale}, left by an interrupted run" in said
    assert not stale.exists() and not out.exists()


# ------------------------------------------------------------------------------------------ item 6
def test_photos_sharing_a_name_stem_are_staged_under_names_of_their_own(tmp_path):
    """a.png, a.tif, b.jpeg and b.jpg (the JPEGs larger than the long side allowed, so re-encoded): four photos
    staged as four files, each mapped back to the photo it came from."""
    from training.scene.image_io import read_image
    from training.scene.sfm import _stage_photos

    rng = np.random.default_rng(1)
    pictures = {name: np.clip(level + 0.05 * rng.standard_normal((30, 40, 3)), 0, 1)
                for name, level in (("a.png", 0.1), ("a.tif", 0.35), ("b.jpeg", 0.6), ("b.jpg", 0.85))}
    for name, img in pictures.items():
        write_image(tmp_path / name, img)
    staged = _stage_photos(sorted(tmp_path.glob("*.*")), tmp_path / "staged", 32, log=lambda s: None)
    assert len(list((tmp_path / "staged").iterdir())) == 4  # before: a.png and b.jpg, two written over
    assert sorted(staged.values()) == sorted(pictures)
    assert sorted(p.name for p in (tmp_path / "staged").iterdir()) == sorted(staged)
    for name, original in staged.items():  # each staged file is its own photo, shrunk
        back = read_image(tmp_path / "staged" / name)
        shrunk = read_image(tmp_path / original)
        assert back.shape[1] == 32 and abs(back.mean() - shrunk.mean()) < 0.02, (name, original)


# ------------------------------------------------------------------------------------------ item 7
def test_unsaved_edits_are_asked_about_before_open_model_replaces_them(tmp_path):
    """An edit makes the scene unsaved (title "*"); File > Open model then asks Save / Discard / Cancel: Cancel keeps
    the edits, Save writes them to a project before the model opens, Discard opens it without."""
    a, b = write_model(tmp_path / "a.ply"), write_model(tmp_path / "b.ply", n=80, seed=1)
    app = new_app(tmp_path)
    doc, session, ui = app.document, app.session, app.ui
    files.open_model(doc, session, ui, str(a))
    assert not doc.unsaved() and not window_title(doc, ui).endswith("*")
    doc.editor.select(np.arange(150) < 7)
    doc.delete()
    assert doc.unsaved() and window_title(doc, ui) == "splatstyler - a.ply *"

    def answer(label: str, opening: str = "b.ply") -> None:
        (question,) = ui.questions
        assert question.title == "Unsaved edits" and f"before opening {opening}" in question.text
        ui.questions.clear()
        action = dict(question.answers)[label]
        if action is not None:
            action()

    files.open_model(doc, session, ui, str(b))
    answer("Cancel")
    assert doc.editor.count == 143 and doc.unsaved()
    files.open_model(doc, session, ui, str(b))
    answer("Save")
    assert doc.editor.count == 80 and not doc.unsaved()
    saved, _ = open_project(tmp_path / "out" / "project.splatproj")
    assert len(saved.models[0].kept) == 143
    doc.editor.hide()
    files.open_model(doc, session, ui, str(a))
    answer("Discard", "a.ply")
    assert doc.editor.count == 150 and not doc.unsaved()
    # the close button: a question instead of a close while edits are unsaved, a close once there are none
    doc.editor.select(np.ones(150, bool))
    assert confirm_exit(doc, session, ui) is False and [q.title for q in ui.questions] == ["Unsaved edits"]
    assert confirm_exit(doc, session, ui) is False and len(ui.questions) == 1  # asked once
    ui.questions.clear()
    doc.undo()
    assert doc.unsaved()  # undone is not saved: the version moved on
    files.save_project(doc, session, ui, layout="")
    assert confirm_exit(doc, session, ui) is True and not ui.questions


def test_the_recovery_project_keeps_unsaved_edits_and_is_offered_once_its_window_is_gone(tmp_path):
    """While edits are unsaved, the recovery project is written (at once, then every EVERY_S); another window's,
    still open, is not offered; once a window closes with unsaved edits (a signal: nobody was asked), its recovery
    is offered at the next start, opens as the scene with the edits, saves where the scene's project was, and is
    removed by that save."""
    model = write_model(tmp_path / "m.ply")
    folder = tmp_path / "recovery"
    app = new_app(tmp_path)
    doc, session, ui = app.document, app.session, app.ui
    files.open_model(doc, session, ui, str(model))
    project = files.save_project(doc, session, ui, str(tmp_path / "mine.splatproj"), layout="")
    recovery = Recovery(folder, every_s=60)
    now_project = lambda: files.project_now(doc, ui, layout="")  # noqa: E731
    assert recovery.keep(doc, now_project, str(project), now=0.0) is False  # nothing unsaved: nothing written
    doc.editor.select(np.arange(150) < 20)
    doc.delete()
    assert recovery.keep(doc, now_project, str(project), now=1.0) is True
    assert recovery.path.is_file() and len(open_project(recovery.path)[0].models[0].kept) == 130
    doc.editor.select(np.arange(130) < 30)
    doc.delete()
    assert recovery.keep(doc, now_project, str(project), now=30.0) is False  # not yet due
    assert left_behind(folder) == []  # its window is open
    recovery.close(doc, now_project, str(project))  # the window closes without asking (SIGTERM)
    (kept, note), = left_behind(folder)
    assert kept == recovery.path and note["scene"] == str(project)
    assert len(open_project(kept)[0].models[0].kept) == 100

    again = new_app(tmp_path, "out2")
    doc2, session2, ui2 = again.document, again.session, again.ui
    second = Recovery(folder)
    files.open_recovered(doc2, session2, ui2, str(kept), note["scene"], second.adopted.append)
    assert doc2.editor.count == 100 and doc2.unsaved() and ui2.project.path == str(project)
    assert second.keep(doc2, lambda: files.project_now(doc2, ui2, layout=""), ui2.project.path, now=0.0)
    assert not kept.exists()  # its edits are in this window's recovery now
    files.save_project(doc2, session2, ui2, layout="")
    assert len(open_project(project)[0].models[0].kept) == 100
    second.keep(doc2, lambda: files.project_now(doc2, ui2, layout=""), ui2.project.path, now=1.0)
    second.close(doc2, lambda: files.project_now(doc2, ui2, layout=""))
    assert sorted(p.name for p in folder.iterdir()) == []


# ------------------------------------------------------------------------------------------ item 11
def test_a_project_whose_models_cannot_be_shown_leaves_no_model_for_stylize(demo_scene, tmp_path):
    """A model is open; a project whose only model is gone opens (carried, one line): Stylize has no model to start
    from, rather than the one open before, which is not the project's."""
    scene_dir, style, model = demo_scene
    gone = write_model(tmp_path / "gone.ply")
    project = save_project(tmp_path / "p.splatproj", Project([ModelEntry(FileRef(gone), "gone")]))
    gone.unlink()
    app = new_app(tmp_path)
    doc, session, ui = app.document, app.session, app.ui
    for open_file, path in ((files.open_model, model), (files.open_data, scene_dir), (files.open_style, style)):
        open_file(doc, session, ui, str(path))
    files.open_project(doc, session, ui, str(project))
    assert doc.editor is None and ui.training.base_model == "" and ui.paths.model == ""
    with pytest.raises(ValueError, match="open a model"):
        runs.start_stylization(doc, session, ui)


def test_save_as_asks_before_replacing_the_file_its_suffix_names(tmp_path, monkeypatch):
    """Save project as, typed "scene" where scene.splatproj exists: the dialog asked about "scene", so the window
    asks about scene.splatproj; Cancel leaves it as it was, Replace writes it."""
    model = write_model(tmp_path / "m.ply")
    existing = save_project(tmp_path / "scene.splatproj", Project([ModelEntry(FileRef(model), "other")]))
    before = existing.read_bytes()
    app = new_app(tmp_path)
    doc, session, ui = app.document, app.session, app.ui
    files.open_model(doc, session, ui, str(model))
    monkeypatch.setattr(dialogs, "choose_file", lambda *a, **k: str(tmp_path / "scene"))
    assert dialogs.save_project_as(doc, session, ui) is None
    (question,) = ui.questions
    assert question.text == f"{existing} exists. Replace it?"
    assert existing.read_bytes() == before
    ui.questions.clear()
    dict(question.answers)["Replace"]()
    assert open_project(existing)[0].models[0].name == "m" and ui.project.path == str(existing)
    monkeypatch.setattr(dialogs, "choose_file", lambda *a, **k: str(tmp_path / "new"))
    assert dialogs.save_project_as(doc, session, ui) == tmp_path / "new.splatproj" and not ui.questions
