"""The live session without a window: a real reconstruction on its training thread, driven by commands as the
viewer drives it; stop and errors save what there is and leave one line for the UI."""

from __future__ import annotations

import time

import pytest

from app.viewer.session import LiveSession, SessionMessage, Stage
from app.viewer.stages import reconstruct_stage
from training.reconstruct.checkpoint import load_checkpoint


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
        paused_at = session.trainer.step_count
        time.sleep(0.5)
        assert session.trainer.step_count == paused_at  # the trainer does not run while paused
        session.single_step()
        wait(lambda: session.trainer.step_count == paused_at + 1, 30, "one step")
        time.sleep(0.3)
        assert session.trainer.step_count == paused_at + 1 and session.status().state == "paused"
        session.pause_at(paused_at + 6)
        session.resume()
        wait(lambda: session.trainer.step_count >= paused_at + 6 and session.status().state == "paused", 60,
             "pause at N")
        time.sleep(0.3)
        assert session.trainer.step_count == paused_at + 6
        assert session.update_config(background="white").startswith("background can only be set before")
        assert session.update_config(lambda_shape=1.0) is None
        session.resume()
        wait(lambda: session.trainer.config.lambda_shape == 1.0, 30, "the config change")
    finally:
        session.close()
    assert session.status().state == "stopped"
    state = load_checkpoint(tmp_path / "r" / "checkpoint.pt")
    assert paused_at + 6 <= state["step"] < 5000
    assert (tmp_path / "r" / "point_cloud.ply").exists()
    kinds = [m.kind for m in session.poll() if isinstance(m, SessionMessage)]
    assert "saved" in kinds


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
    messages = [m for m in session.poll() if isinstance(m, SessionMessage)]
    assert any(m.kind == "error" and m.text == status.error for m in messages)
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
