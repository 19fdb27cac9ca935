"""Structure from motion on real photos (fern), and its failures as one-line errors from the CLI."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from training.core.errors import InputError
from training.scene.image_io import read_image, resize_image, write_image
from training.scene.loader import load_scene
from training.scene.sfm import EXHAUSTIVE_MAX_IMAGES, choose_matcher, run_sfm

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
FERN = SHARED / "data" / "scenes" / "llff_fern" / "images"
REPO = Path(__file__).resolve().parents[1]


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "app", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=300)


@pytest.mark.skipif(not FERN.is_dir(), reason="shared llff_fern photos not available (../shared)")
def test_fern_ten_views_register_and_load(tmp_path):
    photos = tmp_path / "photos"
    views = sorted(FERN.iterdir())[::2]  # 10 of the 20 views, spread over the whole capture
    assert len(views) == 10
    for p in views:
        img = read_image(p)
        h, w = img.shape[:2]
        write_image(photos / p.name, resize_image(img, 320, round(h * 320 / w)))
    lines: list[str] = []
    result = run_sfm(photos, tmp_path / "data", max_features=1024, log=lines.append, progress=False)
    assert result.matcher == "exhaustive" and len([s for s in lines if s.startswith("[")]) == 5  # one per stage
    assert sum("mapping settings that worked: COLMAP defaults" in s for s in lines) == 1
    assert result.num_registered >= 8  # at least 80% of the views given
    assert result.num_points > 100

    scene = load_scene(tmp_path / "data")
    assert len(scene.cameras) == result.num_registered
    assert scene.num_points == result.num_points
    for cam, img in zip(scene.cameras, scene.images):
        assert img.shape == (cam.height, cam.width, 3)
        assert 0.9 * 320 < cam.width <= 320 and cam.fx > 0
    # forward-facing capture: every camera looks the same way, and sees most SfM points in front of it
    forwards = np.stack([c.forward for c in scene.cameras])
    assert np.linalg.norm(forwards.mean(0)) > 0.9
    for cam in scene.cameras:
        depth = scene.points @ cam.world_to_camera[2, :3] + cam.world_to_camera[2, 3]
        assert (depth > 0).mean() > 0.95
    # no work files left behind
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == ["database.db", "images", "sfm_report.json",
                                                                      "sparse"]


def test_low_texture_photos_fail_with_one_line(tmp_path):
    y, x = np.mgrid[0:120, 0:160] / 160.0
    for i in range(3):
        write_image(tmp_path / "flat" / f"{i}.png", np.stack([x * 0.1 + 0.4, y * 0 + 0.3, x * 0 + 0.2], -1))
    with pytest.raises(InputError) as info:
        run_sfm(tmp_path / "flat", tmp_path / "out", log=lambda s: None, progress=False)
    assert "no good initial image pair" in str(info.value) and "\n" not in str(info.value)
    assert not (tmp_path / "out").exists()  # nothing half-made


def test_bad_inputs(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no photos"):
        run_sfm(tmp_path / "empty", tmp_path / "out")
    write_image(tmp_path / "one" / "a.png", np.zeros((8, 8, 3)))
    with pytest.raises(InputError, match="at least 2"):
        run_sfm(tmp_path / "one", tmp_path / "out")
    write_image(tmp_path / "one" / "b.png", np.zeros((8, 8, 3)))
    (tmp_path / "taken" / "sparse").mkdir(parents=True)
    with pytest.raises(InputError, match="already holds a scene"):
        run_sfm(tmp_path / "one", tmp_path / "taken")
    (tmp_path / "one" / "c.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    with pytest.raises(InputError) as info:
        run_sfm(tmp_path / "one", tmp_path / "out", log=lambda s: None, progress=False)
    assert info.value.path == tmp_path / "one" / "c.png"
    assert not (tmp_path / "out").exists()


def test_matcher_choice_by_count():
    assert choose_matcher("auto", EXHAUSTIVE_MAX_IMAGES) == "exhaustive"
    assert choose_matcher("auto", EXHAUSTIVE_MAX_IMAGES + 1) == "sequential"
    assert choose_matcher("sequential", 5) == "sequential"


def test_cli_on_empty_folder_exits_nonzero_with_one_line(tmp_path):
    (tmp_path / "empty").mkdir()
    proc = _cli("sfm", str(tmp_path / "empty"), "-o", str(tmp_path / "out"))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("splatstyler: error:") and "no photos" in lines[0]
    assert "Traceback" not in proc.stderr + proc.stdout


def test_cli_help_lists_options():
    proc = _cli("sfm", "--help")
    assert proc.returncode == 0
    for option in ("--max-size", "--max-features", "--matcher", "-o"):
        assert option in proc.stdout


def test_photos_are_staged_upright_and_shrunk(tmp_path):
    import OpenImageIO as oiio

    from training.scene.sfm import _stage_photos

    rng = np.random.default_rng(0)
    rotated = rng.random((20, 40, 3)).astype(np.float32)
    spec = oiio.ImageSpec(40, 20, 3, "uint8")
    spec.attribute("Orientation", 6)  # a phone photo taken in portrait: stored landscape, shown rotated
    out = oiio.ImageOutput.create(str(tmp_path / "phone.jpg"))
    assert out.open(str(tmp_path / "phone.jpg"), spec) and out.write_image(rotated)
    out.close()
    write_image(tmp_path / "big.png", rng.random((60, 90, 3)))
    write_image(tmp_path / "small.png", rng.random((30, 45, 3)))
    staged = tmp_path / "staged"
    _stage_photos(sorted(tmp_path.glob("*.*")), staged, 50, log=lambda s: None)
    upright = read_image(staged / "phone.jpg")
    assert upright.shape == (40, 20, 3)  # the pixels themselves are upright now: COLMAP and we agree
    assert np.abs(upright - read_image(tmp_path / "phone.jpg")).mean() < 0.05
    assert read_image(staged / "big.png").shape == (33, 50, 3)  # long side shrunk to --max-size
    assert (staged / "small.png").read_bytes() == (tmp_path / "small.png").read_bytes()  # untouched: copied


@pytest.mark.slow
@pytest.mark.skipif(not FERN.is_dir(), reason="shared llff_fern photos not available (../shared)")
def test_sfm_that_places_under_half_the_photos_fails_unless_partial_is_allowed(tmp_path):
    """Four fern views among five paintings that overlap nothing: sfm says in one line that it failed
    (registered/total, points, the photos left out), exits 1 and writes nothing; --allow-partial into the same
    folder keeps the model with exit 0."""
    styles = REPO.parent / "shared" / "data" / "styles"
    photos = tmp_path / "photos"
    for p in sorted(FERN.iterdir())[:4] + sorted(styles.glob("*.jpg"))[:5]:
        img = read_image(p)
        h, w = img.shape[:2]
        write_image(photos / f"{p.parent.name}_{p.stem}.png", resize_image(img, 320, max(1, round(h * 320 / w))))
    failed = _cli("sfm", str(photos), "-o", str(tmp_path / "data"), "--max-features", "1024")
    assert failed.returncode == 1, failed.stderr
    line = [s for s in failed.stderr.splitlines() if s.startswith("splatstyler: error")]
    assert len(line) == 1 and "SfM failed: registered" in line[0] and "/9 photos" in line[0], failed.stderr
    assert "styles_" in line[0]  # the photos left out are named
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]  # no model that `info` would load
    partial = _cli("sfm", str(photos), "-o", str(tmp_path / "data"), "--max-features", "1024", "--allow-partial")
    assert partial.returncode == 0, partial.stderr
    assert len(load_scene(tmp_path / "data", load_images=False).cameras) < 9
