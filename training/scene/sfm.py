"""Structure from motion for a folder of photos, through pycolmap: photos in, a COLMAP scene folder out.

Stages: (1) the photos are copied into the work folder (oriented as a viewer shows them and shrunk to ``max_size``
on the long side when larger, otherwise copied byte for byte); (2) SIFT features; (3) matching, exhaustive for up
to ``EXHAUSTIVE_MAX_IMAGES`` photos (every pair: most robust, quadratic cost) and sequential above (each photo with
its neighbours in name order: linear cost, assumes the names follow the capture order, as video frames and most
camera numbering do); (4) incremental mapping, keeping the model with the most registered images; (5)
undistortion with pycolmap's undistorter, so the result is a pinhole dataset like the one 3DGS's convert.py makes.

Output: ``DATA/images`` (the registered photos, undistorted), ``DATA/sparse/0`` (COLMAP binary model) and
``DATA/database.db``. Everything is built in a hidden work folder inside DATA and moved into place at the end, so a
failure or Ctrl-C leaves no half-made scene.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from training.core.errors import InputError
from training.scene.image_io import is_image_file, read_header, read_image_with_alpha, resize_image, write_image

# Exhaustive matching compares every pair: measured 47 s for 20 photos at 640x480 on 2 cores (190 pairs), so 50
# photos (1225 pairs) is about 5 minutes. Above that, sequential matching keeps the cost linear.
EXHAUSTIVE_MAX_IMAGES = 50
SEQUENTIAL_OVERLAP = 10


@dataclass
class SfmResult:
    output: Path
    num_photos: int
    num_registered: int
    num_points: int
    matcher: str
    seconds: dict[str, float] = field(default_factory=dict)


def list_photos(folder: Path) -> list[Path]:
    """The photos directly inside ``folder``, sorted by name."""
    if not folder.exists():
        raise InputError(folder, "no such folder")
    if not folder.is_dir():
        raise InputError(folder, "not a folder: give the folder that holds the photos")
    photos = sorted(p for p in folder.iterdir() if is_image_file(p))
    if not photos:
        raise InputError(folder, "no photos found (PNG, JPEG, TIFF, EXR, ...)")
    if len(photos) < 2:
        raise InputError(folder, f"structure from motion needs at least 2 photos, found {len(photos)}")
    return photos


def choose_matcher(matcher: str, num_photos: int) -> str:
    if matcher == "auto":
        return "exhaustive" if num_photos <= EXHAUSTIVE_MAX_IMAGES else "sequential"
    if matcher not in ("exhaustive", "sequential"):
        raise InputError(None, f"unknown matcher {matcher!r} (auto, exhaustive or sequential)")
    return matcher


def run_sfm(photos_dir: str | Path, output: str | Path, max_size: int = 1600, max_features: int = 8192,
            matcher: str = "auto", log: Callable[[str], None] = print, progress: bool = True,
            verbose: bool = False) -> SfmResult:
    """Reconstruct cameras and sparse points for the photos in ``photos_dir`` into the scene folder ``output``."""
    import pycolmap

    photos_dir, output = Path(photos_dir), Path(output)
    photos = list_photos(photos_dir)
    if max_size < 16:
        raise InputError(None, f"--max-size must be at least 16 pixels, got {max_size}")
    if max_features < 64:
        raise InputError(None, f"--max-features must be at least 64, got {max_features}")
    matcher = choose_matcher(matcher, len(photos))
    if output.exists() and not output.is_dir():
        raise InputError(output, "output exists and is not a folder")
    for existing in ("images", "sparse"):
        if (output / existing).exists():
            raise InputError(output, f"already holds a scene ({existing}/); choose a new output folder")
    if output.resolve() == photos_dir.resolve():
        raise InputError(output, "output must not be the photos folder")

    previous_log_level = pycolmap.logging.minloglevel
    if not verbose:
        pycolmap.logging.minloglevel = 3  # COLMAP's own lines would drown ours; its failures reach us as results
    created_output = not output.exists()
    output.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=".sfm-work-", dir=output))
    seconds: dict[str, float] = {}
    try:
        image_dir = work / "photos"
        t = time.perf_counter()
        _stage_photos(photos, image_dir, max_size, log, progress)
        seconds["copy"] = time.perf_counter() - t

        database = work / "database.db"
        sizes = {(h.width, h.height) for h in map(read_header, sorted(image_dir.iterdir()))}
        camera_mode = pycolmap.CameraMode.SINGLE if len(sizes) == 1 else pycolmap.CameraMode.AUTO
        log(f"[2/5] extracting SIFT features from {len(photos)} photos (at most {max_features} each)")
        t = time.perf_counter()
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.max_image_size = max_size
        extraction.sift.max_num_features = max_features
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "SIMPLE_RADIAL"  # COLMAP's default: one focal + one radial term, stable with few views
        pycolmap.extract_features(database, image_dir, camera_mode=camera_mode, reader_options=reader,
                                  extraction_options=extraction)
        seconds["features"] = time.perf_counter() - t

        t = time.perf_counter()
        if matcher == "exhaustive":
            pairs = len(photos) * (len(photos) - 1) // 2
            log(f"[3/5] exhaustive matching of {pairs} pairs ({len(photos)} photos <= {EXHAUSTIVE_MAX_IMAGES})")
            pycolmap.match_exhaustive(database)
        else:
            log(f"[3/5] sequential matching, each photo with its {SEQUENTIAL_OVERLAP} successors in name order "
                f"({len(photos)} photos > {EXHAUSTIVE_MAX_IMAGES})")
            pairing = pycolmap.SequentialPairingOptions()
            pairing.overlap = SEQUENTIAL_OVERLAP
            pycolmap.match_sequential(database, pairing_options=pairing)
        seconds["matching"] = time.perf_counter() - t

        log("[4/5] incremental mapping")
        t = time.perf_counter()
        reconstruction = _map(database, image_dir, work / "models", len(photos), progress)
        seconds["mapping"] = time.perf_counter() - t
        if reconstruction is None:
            raise InputError(photos_dir, "structure from motion found no model: no good initial image pair (the "
                                         "photos need texture and overlapping views; try more photos)")

        log(f"[5/5] undistorting {reconstruction.num_reg_images()} registered photos")
        t = time.perf_counter()
        best = work / "best"
        best.mkdir()
        reconstruction.write_binary(str(best))
        undistorted = work / "undistorted"
        pycolmap.undistort_images(str(undistorted), str(best), str(image_dir), output_type="COLMAP")
        seconds["undistort"] = time.perf_counter() - t

        # the model goes in last: a folder with sparse/0 is a complete scene
        os.replace(undistorted / "images", output / "images")
        os.replace(database, output / "database.db")
        (output / "sparse").mkdir()
        os.replace(undistorted / "sparse", output / "sparse" / "0")
        return SfmResult(output, len(photos), reconstruction.num_reg_images(), reconstruction.num_points3D(),
                         matcher, seconds)
    except BaseException:
        if created_output:
            shutil.rmtree(work, ignore_errors=True)
            if not any(output.iterdir()):
                output.rmdir()
        raise
    finally:
        shutil.rmtree(work, ignore_errors=True)
        pycolmap.logging.minloglevel = previous_log_level


def _stage_photos(photos: list[Path], image_dir: Path, max_size: int, log: Callable[[str], None],
                  progress: bool) -> None:
    """Copy the photos for COLMAP: byte for byte when they fit in ``max_size`` and need no EXIF rotation (COLMAP
    would not apply it, our loader would), else decoded, oriented, shrunk and re-encoded."""
    from tqdm import tqdm

    image_dir.mkdir(parents=True)
    log(f"[1/5] preparing {len(photos)} photos (long side at most {max_size} px)")
    for photo in tqdm(photos, desc="photos", unit="img", disable=not progress or None, leave=False):
        header = read_header(photo)
        if header.orientation == 1 and max(header.width, header.height) <= max_size and \
                photo.suffix.lower() in (".png", ".jpg", ".jpeg"):
            read_image_with_alpha(photo)  # fail now, with the file's name, if it is truncated
            shutil.copyfile(photo, image_dir / photo.name)
            continue
        rgb, _ = read_image_with_alpha(photo)
        scale = min(1.0, max_size / max(header.width, header.height))
        if scale < 1.0:
            rgb = resize_image(rgb, max(1, round(header.width * scale)), max(1, round(header.height * scale)))
        ext = ".jpg" if photo.suffix.lower() in (".jpg", ".jpeg") else ".png"
        write_image(image_dir / (photo.stem + ext), rgb)


def _map(database: Path, image_dir: Path, models_dir: Path, num_photos: int, progress: bool):
    """Incremental mapping; the reconstruction with the most registered images, or None when there is none."""
    import pycolmap
    from tqdm import tqdm

    models_dir.mkdir()
    bar = tqdm(total=num_photos, desc="registered", unit="img", disable=not progress or None, leave=False)
    registered = {"n": 0}

    def on_initial_pair() -> None:
        registered["n"] = 2
        bar.update(2)

    def on_next_image() -> None:
        if registered["n"] < num_photos:
            registered["n"] += 1
            bar.update(1)

    options = pycolmap.IncrementalPipelineOptions()
    try:
        models = pycolmap.incremental_mapping(database, image_dir, models_dir, options=options,
                                              initial_image_pair_callback=on_initial_pair,
                                              next_image_callback=on_next_image)
    finally:
        bar.close()
    if not models:
        return None
    return max(models.values(), key=lambda rec: rec.num_reg_images())
