"""``load_scene``: any supported scene on disk -> ``Scene`` (pinhole cameras, images, points).

Formats, detected from what the path holds:
- a COLMAP scene: a folder with ``sparse/0``, ``sparse`` or the model files themselves, and ``images/`` beside
  (in the folder, or one or two levels up when the path is the model folder);
- a NeRF / instant-ngp scene: a folder with ``transforms.json``, or the json file itself.

``downscale=N`` (N > 1) reads images from a cached ``images_N/`` folder as the 3DGS tools do (for transforms.json,
the top folder of each frame's path gets the ``_N`` suffix). Missing or out-of-date cached images (older than their
source) are made from the originals (OpenImageIO resize, size round(W/N) x round(H/N), written atomically); the
intrinsics are scaled with the size of the image actually read, so a cache made by another tool with other
rounding stays exact. Distortion is then removed (``training.scene.undistort``) at that size.

With ``load_images=False`` no image is decoded or written (only image headers of an existing cache are read):
``scene.images`` is [] and the cameras carry the sizes the images would have.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np

from training.scene.colmap_io import find_model_folder, read_colmap_model
from training.core import stop
from training.core.errors import InputError
from training.scene.image_io import (image_size, is_image_file, read_header, read_image_with_alpha, resize_image,
                               write_image)
from training.scene.raw_view import RawView, copy_lens
from training.scene.scene import Camera, Scene
from training.scene.undistort import pinhole_of, remap, undistorted_pinhole, undistortion_map


def load_scene(path: str | Path, downscale: int = 1, load_images: bool = True) -> Scene:
    """Load the scene at ``path`` (see the module docstring for the formats and ``downscale``)."""
    path = Path(path)
    if isinstance(downscale, bool) or int(downscale) != downscale or downscale < 1:
        raise InputError(path, f"downscale must be a whole number >= 1, got {downscale!r}")
    downscale = int(downscale)
    if not path.exists():
        raise InputError(path, "no such file or folder")

    if path.is_file():
        if path.suffix.lower() != ".json":
            raise InputError(path, "not a scene: expected a folder (COLMAP model + images/) or a transforms.json")
        return _load_transforms(path, downscale, load_images)
    if (path / "transforms.json").is_file():
        return _load_transforms(path / "transforms.json", downscale, load_images)
    model_folder = find_model_folder(path)
    if model_folder is not None:
        return _load_colmap(path, model_folder, downscale, load_images)
    raise _not_a_scene(path)


def _not_a_scene(path: Path) -> InputError:
    """The error for a folder holding neither format, saying what it holds instead."""
    entries = [p for p in path.iterdir() if not p.name.startswith(".")]
    if not entries:
        return InputError(path, "folder is empty: expected a COLMAP model (sparse/0 + images/) or transforms.json")
    photos_dir = path if any(is_image_file(p) for p in entries) else path / "images"
    if photos_dir.is_dir() and any(is_image_file(p) for p in photos_dir.iterdir()):
        return InputError(path, "holds photos but no cameras (no sparse/ COLMAP model, no transforms.json); "
                                f"run `splatstyler sfm {photos_dir} -o DATA` and load DATA")
    return InputError(path, "not a scene: no COLMAP model (sparse/0, sparse/ or cameras/images files) and no "
                            "transforms.json")


# ---- per-format front ends -------------------------------------------------------------------------------------

def _load_colmap(path: Path, model_folder: Path, downscale: int, load_images: bool) -> Scene:
    model = read_colmap_model(model_folder)
    root = next((c for c in (path, model_folder.parent, model_folder.parent.parent) if (c / "images").is_dir()),
                None)
    if root is None:
        raise InputError(path, "COLMAP model found but no images/ folder beside it")
    images_dir = root / "images"
    sources = [images_dir / v.name for v in model.views]
    _check_images_exist(sources, images_dir, f"the COLMAP model in {model_folder}", model.views[0].name)
    cache = _cache_root(root, f"images_{downscale}") / f"images_{downscale}"
    cached = [cache / v.name for v in model.views]
    return _build_scene(path, model.views, sources, cached, downscale, load_images, model.points,
                        model.point_colors)


def _load_transforms(json_path: Path, downscale: int, load_images: bool) -> Scene:
    from training.scene.transforms_io import read_transforms

    pairs = read_transforms(json_path)
    views = [v for v, _ in pairs]
    sources = [p for _, p in pairs]
    _check_images_exist(sources, json_path, json_path.name, str(sources[0]))
    cached = [_cached_path(json_path.parent, s, downscale) for s in sources]
    return _build_scene(json_path, views, sources, cached, downscale, load_images, None, None)


def _check_images_exist(sources: list[Path], where: Path, described_in: str, first_name: str) -> None:
    """Name the first missing image; when none exists at all, the names and the files simply do not match."""
    missing = [s for s in sources if not s.is_file()]
    if not missing:
        return
    if len(missing) == len(sources):
        raise InputError(where, f"image names do not match {described_in}: none of its {len(sources)} images is "
                                f"here (first: {first_name!r})")
    raise InputError(missing[0], f"image named in {described_in} is missing"
                                 + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""))


def _cached_path(root: Path, source: Path, downscale: int) -> Path:
    """images/sub/a.jpg -> images_N/sub/a.jpg (top folder under ``root`` gets the suffix, as 3DGS's images_N)."""
    try:
        rel = source.relative_to(root)
    except ValueError:  # outside the scene folder: a sibling folder of the image's own folder
        folder = f"{source.parent.name}_{downscale}"
        return _cache_root(source.parent.parent, folder) / folder / source.name
    if len(rel.parts) == 1:
        return _cache_root(root, f"images_{downscale}") / f"images_{downscale}" / rel
    folder = f"{rel.parts[0]}_{downscale}"
    return _cache_root(root, folder) / folder / Path(*rel.parts[1:])


def _is_writable(folder: Path) -> bool:
    """Writable, and not marked read-only: as root, os.access says yes even for a folder chmod'ed read-only, and
    data sets are often shared that way."""
    return os.access(folder, os.W_OK) and bool(folder.stat().st_mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


def _cache_root(root: Path, folder: str) -> Path:
    """Where ``folder`` (images_N) lives: beside the data when it exists there or the scene folder is writable;
    for a read-only scene folder, a folder in the user cache named after the scene's path (so a shared, read-only
    data set still gets its images_N cache)."""
    if (root / folder).is_dir() or _is_writable(root):
        return root
    import hashlib

    from training.core.cache_dir import cache_dir

    digest = hashlib.sha1(str(root.resolve()).encode()).hexdigest()[:16]
    return cache_dir("downscaled", f"{root.name}-{digest}")


# ---- shared part: sizes, downscale cache, undistortion ---------------------------------------------------------

def _build_scene(source: Path, views: list[RawView], sources: list[Path], cached: list[Path], downscale: int,
                 load_images: bool, points, point_colors) -> Scene:
    cameras: list[Camera] = []
    images: list[np.ndarray] = []
    masks: list[np.ndarray | None] = []
    maps: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}

    iterator = range(len(views))
    if load_images:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc="loading images", unit="img", disable=None, leave=False)
    for i in iterator:
        if load_images:  # reading and resizing the images is the part that takes seconds
            stop.check()
        view, src = views[i], sources[i]
        rgb = alpha = None
        if load_images:
            rgb, alpha = _read_view_image(src, cached[i], downscale)
            h, w = rgb.shape[:2]
        elif downscale > 1 and _cache_is_fresh(src, cached[i]):
            w, h = image_size(cached[i])
        else:
            w = max(1, round(view.lens.width / downscale))
            h = max(1, round(view.lens.height / downscale))

        full_w, full_h = view.lens.width, view.lens.height
        if load_images and (w, h) != (full_w, full_h):
            # Not the size the model says (or a downscaled copy of it): accept a uniform resize only. Rounding
            # each side to whole pixels moves w*H - h*W by at most (W + H) / 2.
            if abs(w * full_h - h * full_w) > max(full_w, full_h):
                size = f"{w}x{h}" + (f" at downscale {downscale}" if downscale > 1 else "")
                raise InputError(src, f"image is {size}, not the aspect ratio of its camera in {source.name} "
                                      f"({full_w}x{full_h})")
        lens = copy_lens(view.lens)
        if (w, h) != (lens.width, lens.height):
            lens.rescale(w, h)
        pin = undistorted_pinhole(lens)
        cameras.append(Camera(view.name, pin.width, pin.height, pin.fx, pin.fy, pin.cx, pin.cy,
                              view.world_to_camera.copy()))
        if load_images:
            if pinhole_of(lens) is None:
                key = (lens.model.name, lens.width, lens.height, tuple(lens.params))
                if key not in maps:
                    maps[key] = undistortion_map(lens, pin)
                rows, cols = maps[key]
                rgb = remap(rgb, rows, cols)
                alpha = None if alpha is None else remap(alpha, rows, cols)
            images.append(rgb)
            masks.append(alpha)
    return Scene(cameras=cameras, images=images, masks=masks if load_images else [], points=points,
                 point_colors=point_colors, source=source)


def _cache_is_fresh(src: Path, cached: Path) -> bool:
    return cached.is_file() and cached.stat().st_mtime >= src.stat().st_mtime


def _read_view_image(src: Path, cached: Path, downscale: int) -> tuple[np.ndarray, np.ndarray | None]:
    """(H, W, 3) RGB and optional (H, W) alpha, from the ``images_N`` cache when downscaling (made if needed)."""
    if downscale == 1:
        return read_image_with_alpha(src)
    if _cache_is_fresh(src, cached):
        try:
            return read_image_with_alpha(cached)
        except InputError:
            pass  # a damaged cache entry is rebuilt from the original below
    rgb, alpha = read_image_with_alpha(src)
    h, w = rgb.shape[:2]
    size = (max(1, round(w / downscale)), max(1, round(h / downscale)))
    full = rgb if alpha is None else np.concatenate([rgb, alpha[..., None]], axis=2)
    small = resize_image(full, *size)
    write_image(cached, small, dtype=_cache_pixel_type(src))
    os.utime(cached)  # the cache must look newer than its source even on coarse-mtime filesystems
    # the pixels as the cache holds them (8-bit, JPEG-compressed for JPEG sources): the run that builds the cache
    # must train and score on the same images as every later run (the float resize scored 0.14 dB higher)
    return read_image_with_alpha(cached)


def _cache_pixel_type(src: Path) -> str:
    """Keep the source's precision in the cache: 8-bit stays 8-bit, 16-bit PNG/TIFF stay 16-bit, float EXR float."""
    fmt = read_header(src).pixel_type
    ext = src.suffix.lower()
    if ext in (".jpg", ".jpeg", ".bmp", ".webp"):
        return "uint8"
    if fmt in ("half", "float", "double"):
        return "float" if ext in (".exr", ".tif", ".tiff", ".hdr") else "uint16"
    return "uint16" if fmt in ("uint16", "int16", "uint32", "int32") else "uint8"

