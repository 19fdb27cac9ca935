"""The viewer's runs keep what earlier runs wrote (no window needed: the runs start as the Training panel's buttons
start them): a second reconstruction in the same output folder does not overwrite the first, and a second
stylization of an edited model does not overwrite the edited model the first one started from (the Colour panel
offers it as that result's original)."""

from __future__ import annotations

import time

import pytest

from app.viewer.app import Paths, ViewerApp
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
        if getattr(item, "kind", "") == "saved":
            app.record_saved(item.stage, item.text)


def test_a_second_reconstruction_keeps_the_first(demo_scene, tmp_path):
    scene_dir, _, _ = demo_scene
    app = ViewerApp(Paths(data=str(scene_dir), out=str(tmp_path / "out")), recon_iters=2, downscale=4)
    app.open_data(str(scene_dir))
    app.start_reconstruction()
    finish(app)
    first = app.training.base_model
    before = open(first, "rb").read()
    app.start_reconstruction()
    finish(app)
    second = app.training.base_model
    assert first != second and open(first, "rb").read() == before
    assert read_ply(second).means.shape[1] == 3


def test_a_second_stylization_keeps_the_edited_model_the_first_started_from(demo_scene, tmp_path):
    scene_dir, style, model = demo_scene
    app = ViewerApp(Paths(model=str(model), data=str(scene_dir), style=str(style), out=str(tmp_path / "out")))
    app.open_model(str(model))
    app.open_style(str(style))
    ed = app.editor
    ed.select(ed.model.means[:, 0] < 0)
    ed.delete()
    kept_first = ed.count
    app.start_stylization()
    app.session.close()
    first_original = app.colour.stylized_from
    ed = app.editor
    ed.select(ed.model.means[:, 1] < 0)
    ed.delete()
    assert ed.count < kept_first
    app.start_stylization()
    app.session.close()
    assert app.colour.stylized_from != first_original
    assert len(read_ply(first_original)) == kept_first  # still the model the first run started from
    assert len(read_ply(app.colour.stylized_from)) == app.editor.count
