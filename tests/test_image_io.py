"""Image reading/writing through OpenImageIO: formats, bit depths, orientation, grey/alpha, broken files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from training.core.errors import InputError
from training.scene.image_io import image_size, read_header, read_image, read_image_with_alpha, write_image

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
FOX_IMAGE = SHARED / "data" / "scenes" / "fox" / "images" / "0001.jpg"


def _random_image(h=37, w=53, c=3, seed=0):
    return np.random.default_rng(seed).random((h, w, c)).astype(np.float32)


def _write_raw(path: Path, data: np.ndarray, pixel_type: str, **attributes) -> None:
    """Write with OpenImageIO directly (reference writer independent of write_image)."""
    h, w, c = data.shape
    spec = oiio.ImageSpec(w, h, c, pixel_type)
    for key, value in attributes.items():
        spec.attribute(key, value)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(data)
    out.close()


@pytest.mark.parametrize("name,tolerance", [("a.png", 0.5 / 255 + 1e-6), ("a.exr", 0.0), ("a.tif", 0.5 / 65535 + 1e-6)])
def test_round_trip_lossless_formats(tmp_path, name, tolerance):
    img = _random_image()
    write_image(tmp_path / name, img)
    back = read_image(tmp_path / name)
    assert back.dtype == np.float32 and back.shape == img.shape
    assert np.abs(back - img).max() <= tolerance
    assert image_size(tmp_path / name) == (53, 37)


def test_jpeg_round_trip_is_close(tmp_path):
    y, x = np.mgrid[0:64, 0:80] / 80.0
    img = np.stack([x, y, 0.5 * (x + y)], axis=-1).astype(np.float32)  # smooth: JPEG keeps it well
    write_image(tmp_path / "a.jpg", img)
    back = read_image(tmp_path / "a.jpg")
    assert np.abs(back - img).mean() < 0.01


def test_16bit_png_keeps_precision(tmp_path):
    img = _random_image(seed=1)
    _write_raw(tmp_path / "a.png", (img * 65535).round().astype(np.uint16), "uint16")
    back = read_image(tmp_path / "a.png")
    assert read_header(tmp_path / "a.png").pixel_type == "uint16"
    assert np.abs(back - img).max() < 1e-4  # far below 8-bit steps (0.004)


def test_float_exr_is_clipped_to_unit_range(tmp_path):
    img = _random_image() * 3.0 - 1.0
    _write_raw(tmp_path / "a.exr", img, "float")
    back = read_image(tmp_path / "a.exr")
    assert back.min() >= 0.0 and back.max() <= 1.0
    np.testing.assert_allclose(back, np.clip(img, 0, 1), atol=1e-6)


def test_grey_becomes_rgb_and_rgba_gives_alpha(tmp_path):
    grey = _random_image(c=1)
    write_image(tmp_path / "g.png", grey)
    rgb = read_image(tmp_path / "g.png")
    assert rgb.shape == (37, 53, 3)
    assert np.array_equal(rgb[..., 0], rgb[..., 2])
    assert np.abs(rgb[..., 1] - grey[..., 0]).max() <= 0.5 / 255 + 1e-6

    rgba = _random_image(c=4, seed=3)
    write_image(tmp_path / "a.png", rgba)
    rgb, alpha = read_image_with_alpha(tmp_path / "a.png")
    assert rgb.shape == (37, 53, 3) and alpha.shape == (37, 53)
    assert np.abs(alpha - rgba[..., 3]).max() <= 0.5 / 255 + 1e-6
    # PNG stores straight (unassociated) alpha; colour must come back unpremultiplied where alpha > 0
    opaque = rgba[..., 3] > 0.2
    assert np.abs(rgb[opaque] - rgba[..., :3][opaque]).max() < 0.02
    write_image(tmp_path / "a.exr", rgba)  # EXR stores premultiplied colour: straight colour must come back
    rgb, alpha = read_image_with_alpha(tmp_path / "a.exr")
    np.testing.assert_allclose(alpha, rgba[..., 3], atol=1e-6)
    np.testing.assert_allclose(rgb[opaque], rgba[..., :3][opaque], atol=1e-5)
    _, no_alpha = read_image_with_alpha(tmp_path / "g.png")
    assert no_alpha is None


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_matches_openimageio_reorient(tmp_path, orientation):
    img = _random_image(h=5, w=8, seed=orientation)  # non-square, random: every flip/rotation differs
    path = tmp_path / "o.tif"
    _write_raw(path, img, "float", Orientation=orientation)
    ours = read_image(path)
    reference = oiio.ImageBufAlgo.reorient(oiio.ImageBuf(str(path)))
    expected = np.asarray(reference.get_pixels(oiio.FLOAT)).reshape(reference.spec().height,
                                                                     reference.spec().width, 3)
    assert ours.shape == expected.shape
    np.testing.assert_array_equal(ours, expected)
    assert image_size(path) == (expected.shape[1], expected.shape[0])


def test_write_is_atomic_and_leaves_nothing_on_failure(tmp_path):
    with pytest.raises(ValueError):
        write_image(tmp_path / "a.unknownext", _random_image())
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not FOX_IMAGE.exists(), reason="shared fox scene not available (../shared)")
def test_truncated_jpeg_is_an_input_error_naming_the_file(tmp_path):
    data = FOX_IMAGE.read_bytes()
    bad = tmp_path / "cut.jpg"
    bad.write_bytes(data[: len(data) // 3])
    with pytest.raises(InputError) as info:
        read_image(bad)
    message = str(info.value)
    assert "\n" not in message and str(bad) in message and "truncated" in message


def test_truncated_png_and_garbage_and_missing(tmp_path):
    write_image(tmp_path / "ok.png", _random_image(h=64, w=64))
    data = (tmp_path / "ok.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    (tmp_path / "junk.png").write_bytes(b"this is not an image")
    for name in ("cut.png", "junk.png", "missing.png"):
        with pytest.raises(InputError) as info:
            read_image(tmp_path / name)
        assert str(tmp_path / name) in str(info.value) and "\n" not in str(info.value)
