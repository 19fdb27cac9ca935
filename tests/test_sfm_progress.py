"""Structure from motion as a window watches it (training/scene/sfm.py): every phase counts up to its total, the
mapper's cameras and points are read as it registers the photos, and a stop in any phase leaves nothing behind.
Real fern photos, shrunk (10 of the 20 views at 320 px)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from training.core.messages import Cancelled
from training.scene.image_io import read_image, resize_image, write_image
from training.scene.loader import load_scene
from training.scene.sfm import PHASES, partial_folder, run_sfm

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
FERN = SHARED / "data" / "scenes" / "llff_fern" / "images"

pytestmark = pytest.mark.skipif(not FERN.is_dir(), reason="shared llff_fern photos not available (../shared)")


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fern10")
    for p in sorted(FERN.iterdir())[::2]:
        img = read_image(p)
        h, w = img.shape[:2]
        write_image(folder / p.name, resize_image(img, 320, round(h * 320 / w)))
    return folder


def test_every_phase_counts_up_and_the_mapper_is_read_as_it_registers(photos, tmp_path):
    seen = []
    result = run_sfm(photos, tmp_path / "data", max_features=1024, log=lambda s: None, progress=False,
                     progress_to=seen.append)
    phases = [p.phase for p in seen]
    assert [ph for i, ph in enumerate(phases) if i == 0 or phases[i - 1] != ph] == list(PHASES)  # each once, in order
    for phase in PHASES:
        counts = [(p.done, p.total) for p in seen if p.phase == phase]
        total = {t for _, t in counts}
        assert len(total) == 1 and counts[-1][0] == counts[-1][1]  # one total, reached
        assert [d for d, _ in counts] == sorted(d for d, _ in counts)
    assert max(p.total for p in seen if p.phase == "matching") == 45  # 10 photos, every pair
    # while mapping: one preview per registration, read from the model the mapper is building
    previews = [p for p in seen if p.phase == "mapping" and p.cameras is not None]
    assert [len(p.cameras) for p in previews] == [p.done for p in previews]
    assert len(previews) >= result.num_registered - 1  # the initial pair, then one by one
    assert previews[0].done == 2 and previews[-1].done == result.num_registered
    assert all(len(p.points) == len(p.colors) for p in previews if p.points is not None)
    points = [len(p.points) for p in previews if p.points is not None]
    assert points[0] > 0 and points[-1] > points[0]
    # the last preview's cameras are the scene's: the same poses (undistortion keeps them), to within what the
    # mapper's bundle adjustment after its last registration may still move them (seen once: 1.2e-3 on a
    # translation of 3.02, a focal length 0.03 % shorter)
    scene = load_scene(tmp_path / "data", load_images=False)
    final = {c.name: c for c in scene.cameras}
    last = previews[-1].cameras
    assert sorted(c.name for c in last) == sorted(final)
    for cam in last:
        assert np.allclose(cam.world_to_camera, final[cam.name].world_to_camera, atol=1e-2)
    assert abs(len(previews[-1].points) - result.num_points) <= 0.05 * result.num_points  # last BA may merge a few


@pytest.mark.parametrize("phase, at, after", [
    ("features", 1, 0.0),  # between two chunks of photos
    ("matching", 0, 0.05),  # inside COLMAP's matching call (its cancellation token)
    ("mapping", 3, 0.0),  # inside the mapper, from its registration callback
])
def test_a_stop_in_any_phase_leaves_nothing(photos, tmp_path, phase, at, after):
    import time

    seen, asked = [], []

    def watch(p):
        seen.append(p)
        if p.phase == phase and p.done >= at and not asked:
            asked.append(time.perf_counter())

    with pytest.raises(Cancelled):
        run_sfm(photos, tmp_path / "data", max_features=1024, log=lambda s: None, progress=False, progress_to=watch,
                cancel=lambda: bool(asked) and time.perf_counter() - asked[0] >= after)
    assert seen[-1].phase == phase and seen[-1].done < seen[-1].total  # stopped in that phase, before its end
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no scene, no partial folder
    assert not partial_folder(tmp_path / "data").exists()
    # and the same run then goes through
    result = run_sfm(photos, tmp_path / "data", max_features=1024, log=lambda s: None, progress=False)
    assert result.num_registered >= 8
