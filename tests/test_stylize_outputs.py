"""Bad input found on real captures: a painting with NaN/inf pixels, an output that cannot be created."""

from __future__ import annotations

import numpy as np
import pytest

from app.cli import main
from training.core.atomic_write import atomic_open, check_output_dir, make_output_dir
from training.core.errors import InputError
from training.scene.image_grid import grid, side_by_side
from training.scene.image_io import write_image
from training.stylize.style_image import check_style_array, load_style_image


def test_nan_or_inf_painting_is_refused_with_one_line(tmp_path):
    painting = np.random.default_rng(0).random((80, 90, 3)).astype(np.float32)
    painting[3, 4, 1] = np.nan
    painting[10, 10, 0] = np.inf
    write_image(tmp_path / "bad.exr", painting)
    with pytest.raises(InputError) as info:
        load_style_image(tmp_path / "bad.exr")
    assert "bad.exr" in str(info.value) and "2 pixels that are NaN or infinite" in str(info.value)
    assert "\n" not in str(info.value)
    with pytest.raises(InputError, match="NaN or infinite"):
        check_style_array(painting)


def test_cli_stylize_refuses_nan_painting_before_loading_anything(tmp_path, capsys):
    painting = np.full((80, 80, 3), np.nan, dtype=np.float32)
    write_image(tmp_path / "nan.exr", painting)
    rc = main(["stylize", str(tmp_path / "missing.ply"), "--data", str(tmp_path), "--style",
               str(tmp_path / "nan.exr"), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "nan.exr" in err[0] and "NaN or infinite" in err[0]
    assert not (tmp_path / "out").exists()


def test_outputs_that_cannot_be_created_name_themselves(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file, not a folder"):
        check_output_dir(tmp_path / "file" / "a" / "b")
    with pytest.raises(InputError) as info:
        make_output_dir(tmp_path / "file" / "a")
    assert str(tmp_path / "file" / "a") in str(info.value) and "cannot create the output folder" in str(info.value)
    with pytest.raises(InputError) as info:
        with atomic_open(tmp_path / "file" / "report.json", "w") as f:
            f.write("{}")
    assert "report.json" in str(info.value) and "cannot write this output" in str(info.value)


def test_cli_stylize_output_under_a_file(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    rc = main(["stylize", str(tmp_path / "m.ply"), "--data", str(tmp_path), "--style", str(tmp_path / "s.png"),
               "-o", str(tmp_path / "file" / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "file/out" in err[0] and "cannot create the output folder" in err[0]


def test_grid_letterboxes_mixed_sizes():
    a, b = np.ones((10, 20, 3)), np.zeros((6, 8))
    sheet = grid([[a, b], [b]], gap=2)
    assert sheet.shape == (10 + 6 + 3 * 2, 20 + 8 + 3 * 2, 3)
    assert side_by_side(a, a, gap=0).shape == (10, 40, 3)
