"""The viewer's runs keep what earlier runs wrote (no window needed: the runs start as the Training panel's buttons
start them): a second reconstruction in the same output folder does not overwrite the first, and a second
stylization of an edited model does not overwrite the edited model the first one started from (the Colour panel
offers it as that result's original)."""

from __future__ import annotations

import time

import pytest

from app.viewer import files
from app.viewer.app import ViewerApp
from app.viewer.live import runs
from app.viewer.live.session import Saved
from app.viewer.state import Paths
from tests.viewer_harness import make_demo_scene
from training.model.ply_io import read_ply

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    return make_demo_scene(tmp_path_factory)


def finish(app: ViewerApp, seconds: float = 300) -> None:
    t0 = time.time()
    while app.session.running:
        assert time.time() - t0 < seconds, "the run did not end"
        time.sleep(0.05)
    for item in app.session.poll():
        if isinstance(item, Saved):
            runs.record_saved(app.document, app.ui, item.stage, item.path)


def test_a_second_reconstruction_keeps_the_first(demo_scene, tmp_path):
    scene_dir, _, _ = demo_scene
    app = ViewerApp(Paths(data=str(scene_dir), out=str(tmp_path / "out")), recon_iters=2, downscale=4)
    doc, session, ui = app.document, app.session, app.ui
    files.open_data(doc, session, ui, str(scene_dir))
    runs.start_reconstruction(doc, session, ui)
    finish(app)
    first = app.ui.training.base_model
    before = open(first, "rb").read()
    runs.start_reconstruction(doc, session, ui)
    finish(app)
    second = app.ui.training.base_model
    assert first != second and open(first, "rb").read() == before
    assert read_ply(second).means.shape[1] == 3


def test_a_second_stylization_keeps_the_edited_model_the_first_started_from(demo_scene, tmp_path):
    scene_dir, style, model = demo_scene
    app = ViewerApp(Paths(model=str(model), data=str(scene_dir), style=str(style), out=str(tmp_path / "out")))
    doc, session, ui = app.document, app.session, app.ui
    for open_file, path in ((files.open_model, model), (files.open_data, scene_dir), (files.open_style, style)):
        open_file(doc, session, ui, str(path))
    ed = app.document.editor
    ed.select(ed.model.means[:, 0] < 0)
    ed.delete()
    kept_first = ed.count
    runs.start_stylization(doc, session, ui)
    app.session.close()
    first_original = doc.stylized_from
    ed = app.document.editor
    ed.select(ed.model.means[:, 1] < 0)
    ed.delete()
    assert ed.count < kept_first
    runs.start_stylization(doc, session, ui)
    app.session.close()
    assert doc.stylized_from != first_original
    assert len(read_ply(first_original)) == kept_first  # still the model the first run started from
    assert len(read_ply(doc.stylized_from)) == app.document.editor.count
