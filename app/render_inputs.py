"""The values the commands take from their command lines: an image size, a background colour, what a path names (a
PLY, a .splat or a scene), and a Gaussian model file read into the numpy arrays renderer_gl draws."""

from __future__ import annotations

from pathlib import Path


def parse_size(text: str | None) -> tuple[int, int] | None:
    """WxH from --size (None stays None), or an InputError naming the bad value."""
    from training.core.errors import InputError

    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(None, f"--size must look like 640x480, got {text!r}") from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise InputError(None, f"--size {text}: each side must be 1..16384 pixels")
    return w, h


def parse_background(text: str) -> tuple[float, float, float]:
    """R,G,B in 0..1 from --background, or an InputError."""
    from training.core.errors import InputError

    try:
        rgb = tuple(float(v) for v in text.split(","))
    except ValueError:
        rgb = ()
    if len(rgb) != 3 or not all(0.0 <= v <= 1.0 for v in rgb):
        raise InputError(None, f"--background must be three numbers in 0..1 like 1,1,1, got {text!r}")
    return rgb


def detect_kind(path: Path) -> str:
    """A model file's format by read_model's rule (training/model/model_io.py), "scene" for anything else; a file
    named like a model that is none gets read_model's error."""
    from training.model.formats import has_model_suffix
    from training.model.model_io import checked_format, model_format

    fmt = model_format(path)
    if fmt is not None:
        return fmt
    if path.is_file() and has_model_suffix(path):
        checked_format(path)  # raises the format's own precise error
    return "scene"


def load_model_arrays(path: Path):
    """(means, scales, quats, opacities, sh, sh_degree) as float32 numpy, activated, from any model file."""
    from training.model.model_io import read_model

    g = read_model(path)
    arrays = [t.detach().float().cpu().numpy() for t in (g.means, g.scales, g.rotations, g.opacities, g.sh)]
    return (*arrays, g.sh_degree)
