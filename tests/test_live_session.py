"""The live session without a window: a real reconstruction on its training thread, driven by commands as the
viewer drives it; stop and errors save what there is and leave one line for the UI."""

from __future__ import annotations

import functools
import time

import numpy as np
import pytest

from app.viewer.live.session import Failed, LiveSession, Saved, Stage
from training.core.trainer import UseModel
from app.viewer.live.stages import reconstruct_stage
from training.reconstruct.checkpoint import load_checkpoint
from training.core.messages import Stepped, StructureChanged


@pytest.fixture(scope="module")
def scene_dir():
    from assets.demo.assets import demo_assets

    return demo_assets().scene_dir


def wait(condition, seconds: float, what: str) -> None:
    t0 = time.time()
    while not condition():
        if time.time() - t0 > seconds:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def test_pause_step_resume_stop_saves_a_checkpoint(scene_dir, tmp_path):
    session = LiveSession()
    session.start([reconstruct_stage(scene_dir, tmp_path / "r", preset="quick", downscale=4, iterations=5000)])
    try:
        wait(lambda: session.status().step >= 3, 120, "three steps")
        session.pause()
        wait(lambda: session.status().state == "paused", 30, "the pause")
        paused_at = session.trainer_status().step
        time.sleep(0.5)
        assert session.trainer_status().step == paused_at  # the trainer does not run while paused
        session.single_step()
        wait(lambda: session.trainer_status().step == paused_at + 1, 30, "one step")
        time.sleep(0.3)
        assert session.trainer_status().step == paused_at + 1 and session.status().state == "paused"
        session.pause_at(paused_at + 6)
        session.resume()
        wait(lambda: session.trainer_status().step >= paused_at + 6 and session.status().state == "paused", 60,
             "pause at N")
        time.sleep(0.3)
        assert session.trainer_status().step == paused_at + 6
        assert session.update_config(background="white").startswith("background can only be set before")
        assert session.update_config(lambda_shape=1.0) is None
        session.resume()
        wait(lambda: session.trainer_status().config.lambda_shape == 1.0, 30, "the config change")
    finally:
        session.close()
    assert session.status().state == "stopped"
    state = load_checkpoint(tmp_path / "r" / "checkpoint.pt")
    assert paused_at + 6 <= state["step"] < 5000
    assert (tmp_path / "r" / "point_cloud.ply").exists()
    assert any(isinstance(m, Saved) for m in session.poll())


def test_an_error_in_the_trainer_is_one_line_and_the_model_is_saved(scene_dir, tmp_path):
    inner = reconstruct_stage(scene_dir, tmp_path / "r", preset="quick", downscale=4, iterations=5000)

    def build(previous):
        trainer = inner.build(previous)
        real_step = trainer.step

        def step():
            if trainer.step_count >= 4:
                raise RuntimeError("the disk is full\nand a second line nobody should see")
            return real_step()

        trainer.step = step
        return trainer

    session = LiveSession()
    session.start([Stage("reconstruct", build, inner.save)])
    wait(lambda: not session.running, 120, "the run to end")
    status = session.status()
    assert status.state == "error" and status.error == "RuntimeError: the disk is full"
    assert any(isinstance(m, Failed) and m.text == status.error for m in session.poll())
    assert load_checkpoint(tmp_path / "r" / "checkpoint.pt")["step"] == 4  # what there was, kept
    # the session goes on: a new run starts after the error
    session.start([reconstruct_stage(scene_dir, tmp_path / "r2", preset="quick", downscale=4, iterations=3)])
    wait(lambda: not session.running, 120, "the second run")
    assert session.status().state == "finished"


def test_bad_input_is_reported_not_raised(tmp_path):
    session = LiveSession()
    session.start([reconstruct_stage(tmp_path / "nowhere", tmp_path / "r")])
    wait(lambda: not session.running, 60, "the run to fail")
    status = session.status()
    assert status.state == "error" and "nowhere" in status.error and "\n" not in status.error


def test_custom_iterations_stretch_the_schedule_as_on_the_cli(scene_dir, tmp_path):
    # the viewer's "iterations" field must not leave quick's densification window sized for 5000 steps
    trainer = reconstruct_stage(scene_dir, tmp_path / "r", preset="quick", downscale=4, iterations=2500).build(None)
    d = trainer.config.densify
    assert (trainer.config.iterations, d.start, d.stop, d.interval, d.reset_every) == (2500, 125, 1250, 84, 750)
    assert trainer.config.sh_interval == 250


def test_each_stage_has_its_own_curves(scene_dir, tmp_path):
    # two stages in one run (as Reconstruct + stylize): the curves show the stage that runs, its steps in order
    session = LiveSession()
    session.start([reconstruct_stage(scene_dir, tmp_path / "a", preset="quick", downscale=4, iterations=6),
                   reconstruct_stage(scene_dir, tmp_path / "b", preset="quick", downscale=4, iterations=4)])
    wait(lambda: not session.running, 120, "the two stages")
    assert session.status().state == "finished"
    steps = [h["step"] for h in session.history]
    assert steps == sorted(set(steps)) and len(steps) == 4, steps


@functools.lru_cache(maxsize=1)
def tiny_scene():
    from assets.demo.scene import make_demo_scene

    return make_demo_scene(num_views=16, width=64, height=48, num_points=800)


def tiny_reconstructor(**densify):
    """A reconstruction of a small demo scene (16 views, 64x48) that densifies from its second step."""
    from training.reconstruct.densify import DensifyConfig
    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
    from training.scene.scene import Scene

    d = tiny_scene()
    dens = DensifyConfig(**{"start": 1, "stop": 1000, "interval": 2, "reset_every": 0, "grad_threshold": 1e-9,
                            **densify})
    return Reconstructor(Scene(d.cameras, d.images, points=d.points, point_colors=d.point_colors),
                         ReconstructConfig(iterations=1000, sh_interval=1000, device="cpu", densify=dens))


def test_a_call_submitted_while_a_stage_ends_never_reaches_the_next_stages_trainer(tmp_path):
    """An export clicked while the reconstruction saves, before the stylization begins: it is refused in one line
    (the model it was asked of is gone), not run on the next stage's trainer."""
    import threading

    saving, go_on = threading.Event(), threading.Event()
    trainers = []

    def build(_previous):
        trainer = tiny_reconstructor(enabled=False)
        trainer.config.iterations = 3 if not trainers else 1000
        trainers.append(trainer)
        return trainer

    def save(trainer, finished, cancel):
        if trainer is trainers[0]:
            saving.set()
            go_on.wait(60)
        return None

    session = LiveSession()
    session.start([Stage("reconstruct", build, save), Stage("stylize", build, save)])
    try:
        wait(saving.is_set, 120, "the first stage to save")
        future = session.submit(UseModel(lambda model, original: model))
        go_on.set()
        wait(future.done, 120, "the call to be answered")
        assert len(trainers) == 2
        assert future.exception() is not None, "it ran on the next stage's trainer"
        assert "reconstruct" in str(future.exception()) and "\n" not in str(future.exception())
    finally:
        go_on.set()
        session.close()


def test_a_live_delete_is_taken_by_a_paused_trainer_that_just_densified(tmp_path):
    """A snapshot taken in the moment between a densifying step's update and the end of that step (the view takes
    one whenever it likes) holds the new Gaussians: the selection made on it, deleted while the trainer is paused,
    reaches the trainer instead of being refused until the next step."""
    from app.viewer.app import ViewerApp
    from app.viewer.state import Paths

    structure = []

    def build(_previous):
        trainer = tiny_reconstructor()
        # the view's snapshot at the moment the step is announced (the UI thread may take one at any moment)
        trainer.add_listener(lambda e: trainer.snapshot() if isinstance(e, Stepped) else None)
        trainer.add_listener(lambda e: structure.append(e.step) if isinstance(e, StructureChanged) else None)
        return trainer

    app = ViewerApp(Paths(out=str(tmp_path / "out")))
    app.session.start([Stage("reconstruct", build, lambda *a: None)], paused=True)
    try:
        wait(lambda: app.session.has_trainer and app.session.status().state == "paused", 120, "the trainer")
        while not structure:
            steps = app.session.trainer_status().step
            app.session.single_step()
            wait(lambda: app.session.trainer_status().step == steps + 1 and app.session.status().state == "paused",
                 60, "a step")
        n = app.session.trainer_status().num_gaussians
        from app.viewer.live.runs import edit_live

        edit_live(app.document, app.session, app.ui)
        ed = app.document.editor
        assert ed.count == n
        ed.select(np.arange(n) % 2 == 0)
        ed.delete()
        (what, future, _), = app.ui.training.pending
        wait(future.done, 60, "the trainer to take the deletion")
        assert future.exception() is None, future.exception()
        assert app.session.trainer_status().num_gaussians == n - (n + 1) // 2
    finally:
        app.session.close()


def test_a_call_submitted_as_the_run_ends_is_answered():
    """submit() in the moment the training thread has answered the calls queued (its run over) and is about to end:
    the call is refused at once (ValueError, as when no trainer runs), not queued where nobody will answer it (its
    Future pending for ever, the UI's pending edit with it). The thread is held in that moment."""
    import threading

    answered, release = threading.Event(), threading.Event()

    class HeldAtTheEnd(LiveSession):
        def _trainer_gone(self):
            super()._trainer_gone()
            answered.set()
            release.wait(60)

    def build(_previous):
        trainer = tiny_reconstructor(enabled=False)
        trainer.config.iterations = 2
        return trainer

    session = HeldAtTheEnd()
    session.start([Stage("reconstruct", build, lambda *a: None)])
    try:
        wait(answered.is_set, 120, "the run to end")
        assert session.running  # the thread is still there: what the UI sees
        future = None
        try:
            future = session.submit(UseModel(lambda model, original: model))
        except ValueError as exc:
            assert str(exc) == "no trainer is running"
        release.set()
        session.close()
        assert future is None or future.done(), "the call was queued after the last answer: it never resolves"
    finally:
        release.set()
        session.close()
