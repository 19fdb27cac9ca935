"""Nothing the user made in the viewer is lost (issue 38), checked through the real LiveSession, stages and Document
as the window's buttons and menus drive them, without a window: a stop during the final colour transfer keeps the
finished stylization; File > Open model starts a new scene that Ctrl+S never writes over the project opened before;
a project that cannot be shown whole leaves nothing half-opened for the next save to write; a save with no project
open takes a free name; a reconstruction's checkpoint does not need the data folder at the end; settings given while
a run loads reach that run; Stylize starts from every model of the scene; embedded models of two projects keep
their own copies."""

from __future__ import annotations

import shutil
import threading
import time

import numpy as np
import pytest
import torch

from app.project import FileRef, ModelEntry, Project, open_project, save_project
from app.viewer import files
from app.viewer.app import ViewerApp
from app.viewer.live import runs
from app.viewer.live.session import Failed, LiveSession, Saved, Stage
from training.core.messages import Stepped
from app.viewer.live.stages import reconstruct_stage, stylize_stage
from app.viewer.state import Paths
from tests.viewer_harness import make_demo_scene
from training.model.gaussians import Gaussians
from training.model.ply_io import read_ply, write_ply


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    return make_demo_scene(tmp_path_factory)


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


def saved_paths(session) -> list[str]:
    return [m.path for m in session.poll() if isinstance(m, Saved)]


# ------------------------------------------------------------------------------------------ item 1
@pytest.mark.slow
def test_a_stop_during_the_final_colour_transfer_keeps_the_finished_stylization(demo_scene, vgg, tmp_path):
    """Stop (or a window close, or Ctrl+Q: each stops the session) while the finished stylization renders its views
    for the post colour transfer: the stylized model is written, with a checkpoint whose resume applies the
    transfer; a stop before the end keeps the model so far and a checkpoint, as before."""
    from training.stylize.checkpoint import load_stylize_checkpoint
    from training.stylize.trainer import StylizeConfig

    scene_dir, style, model = demo_scene
    cfg = StylizeConfig(preset="quick", max_side=32, iters_per_view=1)
    for when in ("transfer", "step 3"):
        out = tmp_path / when.replace(" ", "_")
        inner = stylize_stage(scene_dir, style, out, config=cfg, model=model)
        session = LiveSession()
        seen = {"renders": 0}

        def build(previous, inner=inner, session=session, when=when, seen=seen):
            trainer = inner.build(previous)
            seen["total"] = trainer.total_iters
            if when == "transfer":
                render = trainer.model.render  # each view of the transfer renders through the stylized model

                def counted(*args, **kwargs):  # the transfer renders every view: Stop after its second
                    if trainer.done:
                        seen["renders"] += 1
                        if seen["renders"] == 2:
                            session.stop()
                    return render(*args, **kwargs)

                trainer.model.render = counted
            else:
                trainer.add_listener(lambda e: session.stop() if isinstance(e, Stepped) and e.step == 3 else None)
            return trainer

        session.start([Stage("stylize", build, inner.save, inner.outputs)])
        wait(lambda: not session.running, 600, "the stylization to stop")
        assert session.status().state == "stopped", session.status()
        ply = out / "point_cloud.ply"
        assert saved_paths(session) == [str(ply)] and ply.exists()
        state = load_stylize_checkpoint(out / "stylize_checkpoint.pt")["trainer"]
        stylized = read_ply(ply)
        assert len(stylized) == len(read_ply(model)) and not torch.equal(stylized.sh, read_ply(model).sh)
        assert not state["finished"]  # `stylize --resume` goes on from here (with the transfer)
        if when == "transfer":
            assert seen["renders"] >= 2 and state["iteration"] == seen["total"]
        else:
            assert state["iteration"] == 3


# ------------------------------------------------------------------------------------------ items 2 and 4
def test_ctrl_s_after_open_model_never_writes_over_the_project_opened_before(tmp_path):
    """A project (one model shown, one carried: its file is gone) is open; File > Open model opens another model;
    Save project (Ctrl+S, the File menu) writes a new project holding that model alone, and the opened project's
    file is left as it was."""
    a, gone, other = (write_model(tmp_path / f"{n}.ply", seed=i) for i, n in enumerate(("a", "gone", "other")))
    project = save_project(tmp_path / "p.splatproj", Project([ModelEntry(FileRef(a), "a"),
                                                              ModelEntry(FileRef(gone), "gone")]))
    gone.unlink()
    before = project.read_bytes()
    app = ViewerApp(Paths(out=str(tmp_path / "out")))
    doc, session, ui = app.document, app.session, app.ui
    files.open_project(doc, session, ui, str(project))
    assert len(doc.carried) == 1 and doc.project_source == project
    files.open_model(doc, session, ui, str(other))
    written = files.save_project(doc, session, ui, layout="")
    assert project.read_bytes() == before, "the opened project was written over"
    assert written != project and ui.project.path == str(written)
    saved, _ = open_project(written)
    assert [(m.name, m.file.path) for m in saved.models] == [("other", other)]
    assert open_project(project)[0].models[0].name == "a"


def test_a_save_with_no_project_open_takes_a_free_name_and_keeps_an_earlier_sessions_project(tmp_path):
    """Two viewer sessions writing to the same output folder, each saving with Ctrl+S and no project open: the
    second writes project_2.splatproj, and the first's project.splatproj still holds its model."""
    out = tmp_path / "out"
    written = []
    for i, name in enumerate(("first", "second")):
        app = ViewerApp(Paths(out=str(out)))
        files.open_model(app.document, app.session, app.ui, str(write_model(tmp_path / f"{name}.ply", seed=i)))
        written.append(files.save_project(app.document, app.session, app.ui, layout=""))
        assert "Save project as" in app.ui.messages.lines[-1]  # the name was chosen for the user: said how to choose
    assert written == [out / "project.splatproj", out / "project_2.splatproj"]
    assert [open_project(p)[0].models[0].name for p in written] == ["first", "second"]


# ------------------------------------------------------------------------------------------ item 3
def test_a_project_that_cannot_be_shown_whole_leaves_nothing_half_opened_for_the_next_save(tmp_path):
    """Project A is open. Project B keeps no rows of its model but moves it; project C's model is a PLY with a
    repeated property (the reader refuses it with a ValueError): each opens with its model carried and one line
    saying why, never as a half-cleared scene under A's name, and the next save writes B (or C) with its model
    unchanged while A's file keeps its model."""
    a = write_model(tmp_path / "a.ply")
    b = write_model(tmp_path / "b.ply", seed=1)
    head, body = b.read_bytes().split(b"end_header\n", 1)
    c = tmp_path / "c.ply"
    c.write_bytes(head.replace(b"property float nx\n", b"property float x\n", 1) + b"end_header\n" + body)
    move = np.eye(4)
    move[:3, 3] = [1.0, 0.0, 0.0]
    project_a = save_project(tmp_path / "a.splatproj", Project([ModelEntry(FileRef(a), "a")]))
    project_b = save_project(tmp_path / "b.splatproj", Project([ModelEntry(FileRef(b), "b", kept=np.zeros(0, np.int64),
                                                                           transform=move)]))
    project_c = save_project(tmp_path / "c.splatproj", Project([ModelEntry(FileRef(c), "c")]))
    for project, name in ((project_b, "b"), (project_c, "c")):
        app = ViewerApp(Paths(out=str(tmp_path / "out")))
        doc, session, ui = app.document, app.session, app.ui
        files.open_project(doc, session, ui, str(project_a))
        a_before = project_a.read_bytes()
        ui.messages.guarded("open project", files.open_project, doc, session, ui, str(project))
        assert ui.messages.error == "", ui.messages.error
        assert doc.editor is None and [m.name for m in doc.carried] == [name]
        assert any(f"model '{name}' is in the project but not shown" in line for line in ui.messages.lines)
        written = files.save_project(doc, session, ui, layout="")
        assert written == project and project_a.read_bytes() == a_before
        again, _ = open_project(written)
        assert [m.name for m in again.models] == [name]


# ------------------------------------------------------------------------------------------ item 5
@pytest.mark.slow
def test_a_reconstruction_stopped_after_its_data_folder_moved_still_saves_its_checkpoint(tmp_path):
    """The fingerprint of the data is taken when the reconstruction starts (as the CLI takes it): the data folder
    moved during the run, Stop still writes the checkpoint and the model, and the checkpoint names that data."""
    from assets.demo.assets import demo_assets
    from training.reconstruct.checkpoint import load_checkpoint
    from training.scene.fingerprint import dataset_fingerprint, make_fingerprint

    data = tmp_path / "scene"
    shutil.copytree(demo_assets().scene_dir, data)
    session = LiveSession()
    session.start([reconstruct_stage(data, tmp_path / "r", preset="quick", downscale=4, iterations=5000)],
                  paused=True)
    try:
        wait(lambda: session.status().state == "paused", 120, "the reconstruction to load")
        session.single_step()
        wait(lambda: session.status().step == 1, 60, "one step")
        data.rename(tmp_path / "moved")
    finally:
        session.close()
    assert session.status().state == "stopped", session.status()
    assert session.status().error == ""
    state = load_checkpoint(tmp_path / "r" / "checkpoint.pt")
    assert state["step"] == 1 and (tmp_path / "r" / "point_cloud.ply").exists()
    assert state["fingerprint"] == make_fingerprint(dataset=dataset_fingerprint(tmp_path / "moved"))


# ------------------------------------------------------------------------------------------ item 6
def tiny_reconstructor(iterations: int):
    from assets.demo.scene import make_demo_scene as render_demo_scene
    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
    from training.scene.scene import Scene

    d = render_demo_scene(num_views=8, width=48, height=36, num_points=300)
    return Reconstructor(Scene(d.cameras, d.images, points=d.points, point_colors=d.point_colors),
                         ReconstructConfig(iterations=iterations, device="cpu"))


def test_settings_given_while_a_new_run_loads_are_that_runs_not_the_last_trainers():
    """A run has ended (its trainer is still the session's); a new one starts and, while its trainer is being
    built, a setting changes: the new trainer takes it before its first step, the old one never sees it; a setting
    the new trainer does not have is one line."""
    session = LiveSession()
    session.start([Stage("reconstruct", lambda _: tiny_reconstructor(2), lambda *a: None)])
    wait(lambda: not session.running, 120, "the first run")
    old = session._trainer  # the last run's trainer itself: a test may reach in
    loading, go_on, built = threading.Event(), threading.Event(), []

    def build(_previous):
        loading.set()
        go_on.wait(60)  # a scene and VGG take seconds to load: the window goes on meanwhile
        built.append(tiny_reconstructor(1000))
        return built[-1]

    session.start([Stage("reconstruct", build, lambda *a: None)], paused=True)
    try:
        wait(loading.is_set, 60, "the new run to load")
        answers = [session.update_config(lambda_shape=0.25), session.update_config(no_such_setting=1)]
        go_on.set()
        wait(lambda: session.status().state == "paused", 60, "the new trainer")
        session.single_step()
        wait(lambda: session.trainer_status().step == 1, 60, "the new trainer's first step")
        assert built[0].config.lambda_shape == 0.25 and session.trainer_status().config.lambda_shape == 0.25
        assert old.config.lambda_shape != 0.25
        assert answers == [None, None]  # the second is checked when the trainer is there
        errors = [m.text for m in session.poll() if isinstance(m, Failed)]
        assert errors == ["the reconstruction has no setting no_such_setting"]
    finally:
        go_on.set()
        session.close()


@pytest.mark.slow
def test_a_style_slider_moved_while_the_stylization_loads_is_the_runs_setting(demo_scene, vgg, tmp_path):
    """The Style panel's tau moved between Stylize and the stylizer's first step: the run uses it (before, the
    slider showed it and the run used the old value at every step)."""
    from app.viewer.panels.style_panel import set_stylize

    scene_dir, style, model = demo_scene
    app = ViewerApp(Paths(out=str(tmp_path / "out")), stylize_overrides={"max_side": 32, "iters_per_view": 30})
    doc, session, ui = app.document, app.session, app.ui
    for open_file, path in ((files.open_model, model), (files.open_data, scene_dir), (files.open_style, style)):
        open_file(doc, session, ui, str(path))
    runs.start_stylization(doc, session, ui)
    try:
        assert session.status().state == "loading"
        set_stylize(session, ui, tau=0.07)
        assert ui.messages.error == "" and ui.training.stylize.tau == 0.07
        wait(lambda: session.status().step >= 1, 300, "the first stylization step")
        assert session.trainer_status().config.tau == 0.07
        assert all(abs(h["tau"] - 0.07) < 1e-9 for h in list(session.history))
    finally:
        session.close()


# ------------------------------------------------------------------------------------------ item 7
@pytest.mark.slow
def test_stylize_starts_from_every_model_of_the_scene_and_the_selection_region_fits_it(demo_scene, vgg, tmp_path):
    """A second model added to the scene (File > Add model), selected, and "stylize only the selection": the run
    stylizes the scene as shown, both models as one, changing the added model's colours and none of the first's."""
    scene_dir, style, model = demo_scene
    added = tmp_path / "added.ply"
    shutil.copy(model, added)
    app = ViewerApp(Paths(out=str(tmp_path / "out")), stylize_overrides={"max_side": 32, "iters_per_view": 30})
    doc, session, ui = app.document, app.session, app.ui
    for open_file, path in ((files.open_model, model), (files.open_data, scene_dir), (files.open_style, style)):
        open_file(doc, session, ui, str(path))
    files.add_to_scene(doc, session, ui, str(added))
    n = len(read_ply(model))
    assert doc.editor.count == 2 * n and doc.editor.selected[n:].all() and not doc.editor.selected[:n].any()
    runs.set_style_region(doc, session, ui, "selection")
    runs.start_stylization(doc, session, ui)
    try:
        wait(lambda: session.status().step >= 2 or not session.running, 300, "two stylization steps")
    finally:
        session.close()
    assert session.status().error == "", session.status().error
    run, = saved_paths(session)
    stylized, original = read_ply(run), read_ply(model)
    assert len(stylized) == 2 * n
    assert torch.equal(stylized.sh[:n], original.sh)  # outside the region: exactly as it was
    assert not torch.equal(stylized.sh[n:], original.sh)
    assert len(read_ply(doc.stylized_from)) == 2 * n  # the run's original (style strength) is the scene it started from


# ------------------------------------------------------------------------------------------ item 8
def test_embedded_models_of_two_projects_keep_their_own_copies(tmp_path):
    """Two projects each carrying a model called point_cloud.ply inside (both members are models/0-point_cloud.ply),
    opened one after the other in one session: the first one's copy, which its runs and originals point at, still
    holds the first model."""
    paths = []
    for i in range(2):
        folder = tmp_path / f"run{i}"
        folder.mkdir()
        model = write_model(folder / "point_cloud.ply", n=100 + 20 * i, seed=i)
        paths.append(save_project(tmp_path / f"p{i}.splatproj", Project([ModelEntry(FileRef(model), "m")]),
                                  embed=True))
        model.unlink()
    app = ViewerApp(Paths(out=str(tmp_path / "out")))
    doc, session, ui = app.document, app.session, app.ui
    files.open_project(doc, session, ui, str(paths[0]))
    first = doc.models.files[0].path
    first_sh = read_ply(first).sh.clone()
    files.open_project(doc, session, ui, str(paths[1]))
    second = doc.models.files[0].path
    assert second != first and len(read_ply(second)) == 120
    assert len(read_ply(first)) == 100 and torch.equal(read_ply(first).sh, first_sh)
    assert ui.paths.model == str(second)
