"""The photos pipeline in the live session, without a window: the SfM stage (app/viewer/live/sfm_run.py) reports its
phases through the session's status and events, a stop leaves no scene folder and says so in one line, a failure is
one line and the session goes on, and its scene is what the reconstruction stage reads. Real fern photos, shrunk."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from app.viewer.live.session import Failed, LiveSession, Said
from app.settings.sfm import options_from_flags
from app.viewer.live.session import LiveSession, SessionMessage
from app.viewer.live.stages import reconstruct_stage, sfm_stage
from training.core.messages import Stepped, StructureChanged
from training.scene.image_io import read_image, resize_image, write_image
from training.scene.sfm import partial_folder

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
FERN = SHARED / "data" / "scenes" / "llff_fern" / "images"
needs_fern = pytest.mark.skipif(not FERN.is_dir(), reason="shared llff_fern photos not available (../shared)")
QUICK = options_from_flags(["--max-features", "1024"])


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fern10")
    for p in sorted(FERN.iterdir())[::2]:
        img = read_image(p)
        h, w = img.shape[:2]
        write_image(folder / p.name, resize_image(img, 320, round(h * 320 / w)))
    return folder


def wait(condition, seconds: float, what: str) -> None:
    t0 = time.time()
    while not condition():
        if time.time() - t0 > seconds:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def listening(stage, listener):
    """``stage`` with ``listener`` on its trainer's events (called on the stage's own thread, as they happen)."""
    build = stage.build

    def built(previous):
        trainer = build(previous)
        trainer.add_listener(listener)
        return trainer

    stage.build = built
    return stage


def stopping_at(session: LiveSession, stage, condition):
    """``stage`` whose trainer asks ``session`` to stop (Stop, as the button does) at its first event that meets
    ``condition``: on the stage's own thread, so the stop comes exactly there."""
    return listening(stage, lambda event: session.stop() if condition(event) else None)


@needs_fern
def test_stop_while_registering_leaves_no_scene_folder_and_one_line(photos, tmp_path):
    session = LiveSession()
    out = tmp_path / "out" / "scene"
    stage = stopping_at(session, sfm_stage(photos, out, QUICK),
                        lambda e: isinstance(e, Stepped) and e.metrics.get("registered", 0) >= 3)
    session.start([stage, reconstruct_stage(out, tmp_path / "out" / "reconstruction", iterations=3)])
    wait(lambda: not session.running, 300, "the stop")
    status = session.status()
    assert (status.stage, status.state) == ("sfm", "stopped")  # the reconstruction never started
    items = session.poll()
    lines = [m.text for m in items if isinstance(m, Said)]
    assert lines == [f"structure from motion stopped: nothing written ({out} appears only once complete)"]
    assert session.notes == lines and session.saved == []
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == []  # no scene, no partial folder
    assert not partial_folder(out).exists()
    # what the window showed on the way: the phases in words, counted, with the registrations and points
    events = [e for e in items if isinstance(e, Stepped)]
    assert {e.message.split(":")[0] for e in events} >= {"preparing photos", "extracting features", "matching",
                                                         "registering"}
    assert status.detail.startswith("registering: 3 of 10 photos registered")
    assert status.total == 10 and status.step == 3 and status.last_metrics["points"] > 0


@needs_fern
def test_the_scene_is_read_as_the_mapper_builds_it_and_the_reconstruction_starts_from_it(photos, tmp_path):
    session = LiveSession()
    out = tmp_path / "out"
    previews = []

    def watch(event):
        if isinstance(event, StructureChanged):
            previews.append((len(session.cameras() or []), session.snapshot()))

    stage = listening(sfm_stage(photos, out / "scene", QUICK), watch)
    session.start([stage, reconstruct_stage(out / "scene", out / "reconstruction", iterations=3, downscale=2)])
    wait(lambda: not session.running, 300, "the two stages")
    assert session.status().state == "finished", session.status().error
    assert session.saved == [out / "scene", out / "reconstruction" / "point_cloud.ply"]
    # one preview per registration: its cameras and its points, growing
    counts = [n for n, _ in previews]
    assert counts[0] == 2 and counts == sorted(counts) and counts[-1] == 10
    sizes = [len(s) for _, s in previews]
    assert sizes[-1] > sizes[0] > 0
    final = previews[-1][1]
    assert final.sh_degree == 0 and np.all(final.opacities == 1.0) and np.isfinite(final.means).all()
    lines = [m.text for m in session.poll() if isinstance(m, Said)]
    assert any(line.startswith("registered 10/10 photos") for line in lines)
    assert any(line == f"scene written to {out / 'scene'} (images/, sparse/0, sfm_report.json)" for line in lines)


def _texture(seed: int, h: int = 160, w: int = 200) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.kron(rng.random((h // 8, w // 8, 3)), np.ones((8, 8, 1)))


def test_three_photos_that_overlap_nothing_are_one_line_and_the_session_goes_on(tmp_path):
    for i in range(3):  # unrelated textures: features, but no pair with verified matches
        write_image(tmp_path / "photos" / f"p{i}.png", _texture(i))
    session = LiveSession()
    session.start([sfm_stage(tmp_path / "photos", tmp_path / "out" / "scene", QUICK)])
    wait(lambda: not session.running, 120, "the failure")
    status = session.status()
    assert status.state == "error"
    errors = [m.text for m in session.poll() if isinstance(m, Failed)]
    assert len(errors) == 1 and "\n" not in errors[0] and errors[0] == status.error
    assert errors[0].startswith(f"{tmp_path / 'photos'}: none of the 3 photos overlaps any other")
    assert not (tmp_path / "out" / "scene").exists() and not partial_folder(tmp_path / "out" / "scene").exists()
    # an unreadable photo is one line naming it, and the session still takes the next run
    (tmp_path / "photos" / "p9.png").write_bytes(b"\x89PNG\r\n\x1a\n cut short")
    session.start([sfm_stage(tmp_path / "photos", tmp_path / "out" / "scene", QUICK)])
    wait(lambda: not session.running, 120, "the second failure")
    assert session.status().state == "error" and session.status().error.startswith(str(tmp_path / "photos" / "p9.png"))
