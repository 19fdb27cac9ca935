"""Structure from motion for a folder of photos, through pycolmap: photos in, a COLMAP scene folder out.

Stages: (1) the photos are copied into the work folder (oriented as a viewer shows them and shrunk to ``max_size``
on the long side when larger, otherwise copied byte for byte); (2) SIFT features; (3) matching, exhaustive for up
to ``EXHAUSTIVE_MAX_IMAGES`` photos (every pair: most robust, quadratic cost) and sequential above (each photo with
its neighbours in name order: linear cost, assumes the names follow the capture order, as video frames and most
camera numbering do); (4) incremental mapping, keeping the model with the most registered images; when no initial pair is found or
fewer than half the photos register, mapping is retried with relaxed initialisation (``MAPPING_ATTEMPTS``: forward-
facing captures have small baselines, so COLMAP's 16 degree minimum triangulation angle for the initial pair is
rarely met; 8 degrees registers all 25 LLFF flower photos) and the largest model of all attempts is kept; (5)
undistortion with pycolmap's undistorter, so the result is a pinhole dataset like the one 3DGS's convert.py makes.

Before mapping, the verified matches tell which photos overlap no other photo at all; those, and the photos that
overlap but could not be placed, are named in the result. ``DATA/sfm_report.json`` holds the quality summary
(registered / total, points, mean reprojection error, mean track length, the settings that worked).

Output: ``DATA/images`` (the registered photos, undistorted), ``DATA/sparse/0`` (COLMAP binary model) and
``DATA/database.db`` and ``DATA/sfm_report.json`` (which also holds the fingerprint of the photos and settings,
training/scene/fingerprint.py). Whole or absent: everything is built in a hidden folder beside DATA,
``.DATA.sfm-partial``, which is renamed to DATA once complete, so a failure, Ctrl-C or SIGKILL leaves nothing that
passes for a scene or blocks a rerun (a rerun removes what a killed run left there). A model that places fewer
than half the photos or has fewer than ``MIN_POINTS`` points is a failure (``SfmFailed``) unless
``allow_partial``. The report is the done marker (``sfm_complete``), for ``splatstyler sfm`` and the grid alike.

Progress and stopping: ``progress_to`` receives an ``SfmProgress`` at every photo prepared, every chunk of photos
whose features are extracted and every chunk of image pairs matched (COLMAP reports neither while it works, and
reading its database meanwhile aborts the process, measured: so while someone watches, a progress bar or
``progress_to``, the work is handed to it in chunks, at 0.4 to 0.6 s of overhead per matching chunk, hence at most
``MATCH_CHUNKS`` of them; nobody watching, one call does it all), and at every registration, with the cameras
and points the mapper holds then (read in the mapper's own callbacks: pycolmap's ``IncrementalPipeline`` with its
``ReconstructionManager``). ``cancel`` is polled while COLMAP works (its calls take a ``CancellationToken``) and in
every mapping callback; once it says stop, ``run_sfm`` raises ``Cancelled`` and leaves nothing behind.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from training.core.atomic_write import atomic_open
from training.core.errors import InputError
from training.core import stop as user_stop
from training.core.messages import Cancelled
from training.core.version import version
from training.scene.image_io import is_image_file, read_header, read_image_with_alpha, resize_image, write_image

# Exhaustive matching compares every pair: measured 47 s for 20 photos at 640x480 on 2 cores (190 pairs), so 50
# photos (1225 pairs) is about 5 minutes. Above that, sequential matching keeps the cost linear.
EXHAUSTIVE_MAX_IMAGES = 50
SEQUENTIAL_OVERLAP = 10
CAMERA_MODELS = ("SIMPLE_RADIAL", "OPENCV", "PINHOLE")
DEFAULT_MAX_SIZE = 1600  # the photos' long side, at most (px)
DEFAULT_MAX_FEATURES = 8192  # SIFT features per photo, at most
REPORT_NAME = "sfm_report.json"
PARTIAL_SUFFIX = ".sfm-partial"
LOCK_NAME = ".sfm-lock"  # in the partial folder: held (flock) by the run building it
# Fewer points than this is not a scene to reconstruct: the depth regularizer aligns each view's depth to the SfM
# points it sees and needs at least 10 of them in a view (training/reconstruct/depth_targets.py), and the Gaussians
# start from the points, where the presets' own random start uses 5000 or more; a hundred points spread over a
# capture leave most views under that 10.
MIN_POINTS = 100
# COLMAP's default for a verified image pair (TwoViewGeometryOptions.min_num_inliers)
MIN_PAIR_INLIERS = 15

# The phases run_sfm reports (SfmProgress.phase), each with what a progress line calls it and what it counts.
PHASES = {"photos": ("preparing photos", "photos"), "features": ("extracting features", "photos"),
          "matching": ("matching", "pairs"), "mapping": ("registering", "photos registered"),
          "undistort": ("undistorting", "photos")}
# While watched, feature extraction runs in chunks of this many photos per core (COLMAP takes one photo per core at a
# time; measured on the fern's 20 photos: 10 chunks cost no more than one call, within a shared machine's noise).
EXTRACT_PER_CORE = 2
# While watched, matching runs in at most this many chunks of at least MATCH_CHUNK_MIN pairs: each chunk costs 0.4 to
# 0.6 s of set-up (measured on the fern's 190 pairs, 2 shared cores: 5.0 s in one call, 7.4 s in 4 chunks, 9.1 s
# in 10).
MATCH_CHUNKS = 10
MATCH_CHUNK_MIN = 48
STOP_POLL_S = 0.1  # how often the cancel callable is asked while COLMAP works

# (name, mapper options) tried in order until one registers at least half the photos. The first is COLMAP's own
# default (init_min_tri_angle 16 deg, init_min_num_inliers 100); the relaxed ones lower only what limits the choice
# of the initial pair and the registration of the next images, which is what fails on small-baseline captures.
MAPPING_ATTEMPTS = (
    ("COLMAP defaults", {}),
    ("relaxed initialisation", {"init_min_tri_angle": 8.0, "init_min_num_inliers": 50}),
    ("strongly relaxed initialisation", {"init_min_tri_angle": 4.0, "init_min_num_inliers": 30,
                                         "abs_pose_min_num_inliers": 15}),
)


@dataclass
class SfmResult:
    output: Path
    num_photos: int
    num_registered: int
    num_points: int
    matcher: str
    seconds: dict[str, float] = field(default_factory=dict)
    mapping: str = ""  # which of MAPPING_ATTEMPTS gave the model, as one line
    unregistered: list[str] = field(default_factory=list)  # overlap others but could not be placed
    no_overlap: list[str] = field(default_factory=list)  # share no verified matches with any other photo
    report: dict = field(default_factory=dict)  # what sfm_report.json holds


@dataclass(frozen=True)
class SfmProgress:
    """How far ``run_sfm`` is: ``phase`` (a key of PHASES), ``done`` of ``total`` (photos, pairs, photos registered);
    while mapping, ``attempt`` names the mapping settings tried, and ``cameras`` (pinhole Camera, one per registered
    photo, COLMAP's lens distortion left out) and ``points`` (P, 3) float32 / ``colors`` (P, 3) uint8 are what the
    mapper holds at this registration (None where the reader had no preview asked of it)."""

    phase: str
    done: int
    total: int
    attempt: str = ""
    cameras: tuple | None = None
    points: np.ndarray | None = None
    colors: np.ndarray | None = None

    def line(self) -> str:
        """"registering: 12 of 20 photos registered", the words a status line shows."""
        title, unit = PHASES[self.phase]
        return f"{title}: {self.done} of {self.total} {unit}"


class SfmFailed(InputError):
    """Structure from motion ran but its model places too few photos or has too few points; ``result`` says
    what it found. Nothing was written."""

    def __init__(self, path: Path, problem: str, result: "SfmResult"):
        super().__init__(path, problem)
        self.result = result


def sfm_complete(folder: str | Path) -> bool:
    """Whether ``folder`` holds a finished ``run_sfm`` output: its report, which only a complete one has (the
    done marker of ``splatstyler sfm`` and of the grid)."""
    folder = Path(folder)
    return (folder / REPORT_NAME).is_file() and (folder / "sparse" / "0").is_dir()


def sfm_settings(max_size: int, max_features: int, matcher: str, camera_model: str,
                 refine_principal_point: bool) -> dict:
    """The settings that shape an SfM result, as its fingerprint records them."""
    return {"max_size": int(max_size), "max_features": int(max_features), "matcher": matcher,
            "camera_model": camera_model, "refine_principal_point": bool(refine_principal_point)}


def sfm_fingerprint(photos: str | Path, max_size: int, max_features: int, matcher: str, camera_model: str,
                    refine_principal_point: bool) -> dict:
    """The fingerprint (photos and settings) a run with these arguments records in DATA/sfm_report.json."""
    from training.scene.fingerprint import make_fingerprint, photos_fingerprint

    return make_fingerprint(photos=photos_fingerprint(list_photos(Path(photos))),
                            settings=sfm_settings(max_size, max_features, matcher, camera_model,
                                                  refine_principal_point))


def partial_folder(output: Path) -> Path:
    """Where ``run_sfm`` builds ``output`` before renaming it into place."""
    return output.parent / f".{output.name}{PARTIAL_SUFFIX}"


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


def run_sfm(photos_dir: str | Path, output: str | Path, max_size: int = DEFAULT_MAX_SIZE,
            max_features: int = DEFAULT_MAX_FEATURES,
            matcher: str = "auto", log: Callable[[str], None] = print, progress: bool = True,
            verbose: bool = False, camera_model: str = "SIMPLE_RADIAL",
            refine_principal_point: bool = False, allow_partial: bool = False,
            progress_to: Callable[[SfmProgress], None] | None = None, cancel: Callable[[], bool] | None = None,
            partial_hint: str = "--allow-partial keeps this model") -> SfmResult:
    """Reconstruct cameras and sparse points for the photos in ``photos_dir`` into the scene folder ``output``
    (whole or not at all; see the module docstring). ``progress``: console bars; ``progress_to``: every step's
    SfmProgress (on this thread, or COLMAP's mapping thread: it must return quickly); ``cancel``: asked often, True
    stops the run (``Cancelled``, nothing written); ``partial_hint``: how the caller keeps a model that places too
    few photos, for the SfmFailed line."""
    import pycolmap

    from training.core.atomic_write import make_output_dir
    from training.scene.fingerprint import make_fingerprint, photos_fingerprint

    photos_dir, output = Path(photos_dir), Path(output)
    photos = list_photos(photos_dir)
    if max_size < 16:
        raise InputError(None, f"--max-size must be at least 16 pixels, got {max_size}")
    if max_features < 64:
        raise InputError(None, f"--max-features must be at least 64, got {max_features}")
    settings = sfm_settings(max_size, max_features, matcher, camera_model, refine_principal_point)
    matcher = choose_matcher(matcher, len(photos))
    if camera_model not in CAMERA_MODELS:
        raise InputError(None, f"unknown camera model {camera_model!r} ({', '.join(CAMERA_MODELS)})")
    if output.exists() and not output.is_dir():
        raise InputError(output, "output exists and is not a folder")
    for existing in ("images", "sparse"):
        if (output / existing).exists():
            raise InputError(output, f"already holds a scene ({existing}/); choose a new output folder")
    if output.resolve() == photos_dir.resolve():
        raise InputError(output, "output must not be the photos folder")

    make_output_dir(output.parent)
    partial, lock = _claim_partial(output, log)
    previous_log_level = pycolmap.logging.minloglevel
    if not verbose:
        pycolmap.logging.minloglevel = 3  # COLMAP's own lines would drown ours; its failures reach us as results
    work = partial / ".work"
    seconds: dict[str, float] = {}
    report = _Reporter(progress_to, progress)
    stop = _Stop(cancel)
    try:
        work.mkdir()
        fingerprint = make_fingerprint(photos=photos_fingerprint(photos), settings=settings)
        image_dir = work / "photos"
        t = time.perf_counter()
        staged = _stage_photos(photos, image_dir, max_size, log, report, stop)
        seconds["copy"] = time.perf_counter() - t

        database = work / "database.db"
        log(f"[2/5] extracting SIFT features from {len(photos)} photos (at most {max_features} each)")
        t = time.perf_counter()
        _extract_features(database, image_dir, max_size, max_features, camera_model, report, stop)
        seconds["features"] = time.perf_counter() - t

        t = time.perf_counter()
        if matcher == "exhaustive":
            pairs = len(photos) * (len(photos) - 1) // 2
            log(f"[3/5] exhaustive matching of {pairs} pairs ({len(photos)} photos <= {EXHAUSTIVE_MAX_IMAGES})")
        else:
            log(f"[3/5] sequential matching, each photo with its {SEQUENTIAL_OVERLAP} successors in name order "
                f"({len(photos)} photos > {EXHAUSTIVE_MAX_IMAGES})")
        _match_pairs(database, matcher, work, report, stop)
        seconds["matching"] = time.perf_counter() - t

        names = sorted(staged)
        no_overlap = photos_without_overlap(database, names)
        if len(no_overlap) == len(names):
            raise InputError(photos_dir, f"none of the {len(names)} photos overlaps any other (no pair shares "
                                         f"{MIN_PAIR_INLIERS} verified matches), so there is no good initial image "
                                         "pair: the photos need texture and overlapping views of one scene")
        no_overlap = [staged[n] for n in no_overlap]  # named as the user named them from here on
        if no_overlap:
            log(f"      {len(no_overlap)} photos share no verified matches with any other and cannot be placed: "
                f"{name_list(no_overlap)}")

        log("[4/5] incremental mapping")
        t = time.perf_counter()
        reconstruction, mapping = _map_with_retries(database, image_dir, len(photos), refine_principal_point, log,
                                                    report, stop)
        seconds["mapping"] = time.perf_counter() - t
        if reconstruction is None:
            raise InputError(photos_dir, "structure from motion found no model: no good initial image pair, even "
                                         "with relaxed initialisation (the photos need texture and overlapping "
                                         "views; try more photos)")
        placed = {staged[reconstruction.image(i).name] for i in reconstruction.reg_image_ids()}
        unregistered = [staged[n] for n in names if staged[n] not in placed and staged[n] not in no_overlap]
        if unregistered:
            log(f"      {len(unregistered)} photos overlap others but could not be placed: "
                f"{name_list(unregistered)}")
        quality = {"splatstyler_version": version(), **quality_summary(reconstruction, len(photos))}
        result = SfmResult(output, len(photos), reconstruction.num_reg_images(), reconstruction.num_points3D(),
                           matcher, seconds, mapping, unregistered, no_overlap, quality)
        too_few_photos = 2 * result.num_registered < result.num_photos
        if (too_few_photos or result.num_points < MIN_POINTS) and not allow_partial:
            left_out = unregistered + no_overlap
            raise SfmFailed(photos_dir, f"SfM failed: registered {result.num_registered}/{result.num_photos} "
                                        f"photos, {result.num_points} points (needs at least half the photos and "
                                        f"{MIN_POINTS} points); left out: "
                                        f"{name_list(left_out) if left_out else 'none'} ({partial_hint})", result)

        log(f"[5/5] undistorting {reconstruction.num_reg_images()} registered photos")
        report.start("undistort", reconstruction.num_reg_images())
        t = time.perf_counter()
        best = work / "best"
        best.mkdir()
        reconstruction.write_binary(str(best))
        undistorted = work / "undistorted"
        stop.call(pycolmap.undistort_images, str(undistorted), str(best), str(image_dir), output_type="COLMAP")
        report.to(reconstruction.num_reg_images())
        seconds["undistort"] = time.perf_counter() - t

        quality.update(camera_model=camera_model, refine_principal_point=refine_principal_point, matcher=matcher,
                       mapping=mapping, unregistered=unregistered, no_overlap=no_overlap,
                       seconds={k: round(v, 2) for k, v in seconds.items()}, fingerprint=fingerprint)
        stop.check()  # the last moment a stop leaves nothing: from here the scene is put in place
        os.replace(undistorted / "images", partial / "images")
        os.replace(database, partial / "database.db")
        (partial / "sparse").mkdir()
        os.replace(undistorted / "sparse", partial / "sparse" / "0")
        shutil.rmtree(work)
        with atomic_open(partial / REPORT_NAME, "w") as f:  # the done marker, last
            json.dump(quality, f, indent=2)
        _move_into_place(partial, output)
        (output / LOCK_NAME).unlink(missing_ok=True)  # moved with the folder when it was renamed whole
        return result
    except Cancelled:
        if stop.user():
            raise user_stop.StopRequested(f"during structure from motion; nothing written ({output} appears only "
                                          "once complete)") from None
        raise
    finally:
        report.close()
        shutil.rmtree(partial, ignore_errors=True)
        os.close(lock)
        pycolmap.logging.minloglevel = previous_log_level


class _Reporter:
    """Each phase's count, to ``progress_to`` and, with ``bars``, to a console progress bar."""

    def __init__(self, progress_to: Callable[[SfmProgress], None] | None, bars: bool):
        self.progress_to, self.bars = progress_to, bars
        self.phase, self.done, self.total, self.attempt = "", 0, 0, ""
        self._bar = None

    @property
    def wants_preview(self) -> bool:
        return self.progress_to is not None

    @property
    def watched(self) -> bool:
        """Someone sees the counts move (else the work need not be cut into chunks for them)."""
        return self.progress_to is not None or self.bars

    def start(self, phase: str, total: int, attempt: str = "") -> None:
        from tqdm import tqdm

        self.close()
        self.phase, self.done, self.total, self.attempt = phase, 0, int(total), attempt
        self._bar = tqdm(total=total, desc=PHASES[phase][0], unit="img" if phase != "matching" else "pair",
                         disable=not self.bars or None, leave=False)
        self._say()

    def to(self, done: int, **preview) -> None:
        done = min(int(done), self.total)
        if self._bar is not None and done > self.done:
            self._bar.update(done - self.done)
        self.done = done
        self._say(**preview)

    def _say(self, **preview) -> None:
        if self.progress_to is not None:
            self.progress_to(SfmProgress(self.phase, self.done, self.total, self.attempt, **preview))

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class _Stop:
    """The caller's ``cancel`` and the user's stop (training/core/stop.py, as the calling thread sees it), asked
    between units of work (``check``) and, while a COLMAP call runs, every STOP_POLL_S by a watcher that cancels the
    call's CancellationToken (``call``). Either raises Cancelled where it is seen (COLMAP's mapping callbacks
    included); ``run_sfm`` turns the user's into StopRequested on its way out."""

    def __init__(self, cancel: Callable[[], bool] | None):
        self.cancel = cancel
        self.user = user_stop.current()

    def requested(self) -> bool:
        return (self.cancel is not None and bool(self.cancel())) or self.user()

    def check(self) -> None:
        if self.requested():
            raise Cancelled()

    def call(self, fn, *args, **kwargs):
        """``fn(*args, **kwargs, cancellation_token=...)``, stopped within STOP_POLL_S (plus what COLMAP takes to
        notice) of a stop; Cancelled then."""
        import threading

        import pycolmap

        self.check()
        token, over = pycolmap.CancellationToken(), threading.Event()

        def watch() -> None:
            while not over.wait(STOP_POLL_S):
                if self.requested():
                    token.cancel()
                    return

        watcher = threading.Thread(target=watch, name="sfm-stop", daemon=True)
        watcher.start()
        try:
            return fn(*args, **kwargs, cancellation_token=token)
        except InterruptedError:  # what a cancelled COLMAP call raises
            if self.requested():
                raise Cancelled() from None
            raise
        finally:
            over.set()
            watcher.join()


def _extract_features(database: Path, image_dir: Path, max_size: int, max_features: int, camera_model: str,
                      report: _Reporter, stop: _Stop) -> None:
    """SIFT features of every photo into ``database``, in chunks (so that the count moves); the photos of one size
    share one camera, as COLMAP's single-camera mode makes them in one call (later chunks name the first one's)."""
    import pycolmap

    names = sorted(p.name for p in image_dir.iterdir())
    sizes = {(h.width, h.height) for h in map(read_header, (image_dir / n for n in names))}
    camera_mode = pycolmap.CameraMode.SINGLE if len(sizes) == 1 else pycolmap.CameraMode.AUTO
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = max_size
    extraction.sift.max_num_features = max_features
    reader = pycolmap.ImageReaderOptions()
    # SIMPLE_RADIAL (COLMAP's default: one focal + one radial term) is stable with few views; OPENCV for wide or
    # strongly distorted lenses; PINHOLE for photos already undistorted
    reader.camera_model = camera_model
    chunk = EXTRACT_PER_CORE * max(1, os.cpu_count() or 1) if report.watched else len(names)
    if camera_mode != pycolmap.CameraMode.SINGLE:
        # COLMAP's AUTO mode shares a camera between consecutive photos of one size and focal; chunks would break
        # that chain at each boundary (one more camera to calibrate), so mixed sizes go in one call
        chunk = len(names)
    report.start("features", len(names))
    for i in range(0, len(names), chunk):
        stop.call(pycolmap.extract_features, database, image_dir, image_names=names[i:i + chunk],
                  camera_mode=camera_mode, reader_options=reader, extraction_options=extraction)
        if i == 0 and camera_mode == pycolmap.CameraMode.SINGLE:
            db = pycolmap.Database.open(str(database))
            try:
                reader.existing_camera_id = db.read_all_cameras()[0].camera_id
            finally:
                db.close()
        report.to(i + chunk)


def _match_pairs(database: Path, matcher: str, work: Path, report: _Reporter, stop: _Stop) -> None:
    """Match and verify the pairs COLMAP's exhaustive or sequential pairing names, in chunks (so that the count
    moves; see MATCH_CHUNKS), with COLMAP's default matching and verification."""
    import pycolmap

    db = pycolmap.Database.open(str(database))
    try:
        if matcher == "exhaustive":
            generator = pycolmap.ExhaustivePairGenerator(pycolmap.ExhaustivePairingOptions(), db)
        else:
            pairing = pycolmap.SequentialPairingOptions()
            pairing.overlap = SEQUENTIAL_OVERLAP
            generator = pycolmap.SequentialPairGenerator(pairing, db)
        name_of = {img.image_id: img.name for img in db.read_all_images()}
        pairs = [(name_of[a], name_of[b]) for a, b in generator.all_pairs()]
    finally:
        db.close()
    report.start("matching", len(pairs))
    size = max(MATCH_CHUNK_MIN, -(-len(pairs) // MATCH_CHUNKS)) if report.watched else max(1, len(pairs))
    for i in range(0, len(pairs), size):
        listed = work / "pairs.txt"
        listed.write_text("".join(f"{a} {b}\n" for a, b in pairs[i:i + size]))
        options = pycolmap.ImportedPairingOptions()
        options.match_list_path = listed
        stop.call(pycolmap.match_image_pairs, database, pairing_options=options)
        report.to(i + size)


def _claim_partial(output: Path, log: Callable[[str], None]) -> tuple[Path, int]:
    """Make ``output``'s partial folder for this run and lock it (an open file descriptor holding an exclusive
    ``flock`` on its ``LOCK_NAME``, released when the run ends or its process dies): a second run on the same output
    sees the lock held and stops in one line instead of deleting the first one's work; a partial folder whose lock is
    free was left by an interrupted run and is removed. The folder is made under a temporary name with its lock
    already held and renamed into place, so it is never seen without one."""
    import tempfile

    from training.core.file_lock import held, hold

    partial = partial_folder(output)
    while True:
        claim = Path(tempfile.mkdtemp(prefix=f".{output.name}.", suffix=".sfm-claim", dir=output.parent))
        lock = hold(claim / LOCK_NAME)  # a new file: nobody else holds it
        try:
            os.rename(claim, partial)  # refused while another partial folder (which holds a lock file) is there
            return partial, lock
        except OSError:
            os.close(lock)
            shutil.rmtree(claim, ignore_errors=True)
            if not partial.exists():
                continue
        if held(partial / LOCK_NAME):
            raise InputError(output, f"another structure from motion is writing this scene now ({partial} is "
                                     "held by a running process); wait for it, or choose another output folder")
        log(f"      removing {partial}, left by an interrupted run")
        shutil.rmtree(partial, ignore_errors=True)


def _move_into_place(partial: Path, output: Path) -> None:
    """Rename the finished ``partial`` to ``output``: at once when ``output`` is absent or an empty folder; into an
    existing folder entry by entry, the report (the done marker) last."""
    try:
        os.replace(partial, output)
        return
    except OSError:
        if not output.is_dir():
            raise
    for name in ("images", "database.db", "sparse", REPORT_NAME):
        os.replace(partial / name, output / name)


def _stage_photos(photos: list[Path], image_dir: Path, max_size: int, log: Callable[[str], None],
                  report: _Reporter | None = None, stop: _Stop | None = None) -> dict[str, str]:
    """Copy the photos for COLMAP: byte for byte when they fit in ``max_size`` and need no EXIF rotation (COLMAP
    would not apply it, our loader would), else decoded, oriented, shrunk and re-encoded. Returns each staged file's
    name and the name of the photo it came from: every photo gets a name of its own (a.png and a.tif, or b.jpeg and
    b.jpg re-encoded, would both be a.png, b.jpg), told apart by the original's suffix (a_tif.png)."""
    report = report or _Reporter(None, False)
    image_dir.mkdir(parents=True)
    log(f"[1/5] preparing {len(photos)} photos (long side at most {max_size} px)")
    report.start("photos", len(photos))
    staged: dict[str, str] = {}
    taken: set[str] = set()  # case-folded: a.JPG and a.jpg are one file on some file systems

    def unique(name: str, photo: Path) -> str:
        stem, ext = name[: -len(Path(name).suffix) or None], Path(name).suffix
        candidate, n = name, 1
        while candidate.casefold() in taken:
            n += 1
            candidate = f"{stem}_{photo.suffix.lstrip('.')}{'' if n == 2 else f'_{n - 1}'}{ext}"
        taken.add(candidate.casefold())
        return candidate

    for done, photo in enumerate(photos, 1):
        if stop is not None:
            stop.check()
        header = read_header(photo)
        if header.orientation == 1 and max(header.width, header.height) <= max_size and \
                photo.suffix.lower() in (".png", ".jpg", ".jpeg"):
            read_image_with_alpha(photo)  # fail now, with the file's name, if it is truncated
            name = unique(photo.name, photo)
            shutil.copyfile(photo, image_dir / name)
        else:
            rgb, _ = read_image_with_alpha(photo)
            scale = min(1.0, max_size / max(header.width, header.height))
            if scale < 1.0:
                rgb = resize_image(rgb, max(1, round(header.width * scale)), max(1, round(header.height * scale)))
            ext = ".jpg" if photo.suffix.lower() in (".jpg", ".jpeg") else ".png"
            name = unique(photo.stem + ext, photo)
            write_image(image_dir / name, rgb)
        staged[name] = photo.name
        report.to(done)
    return staged


def name_list(names: list[str], limit: int = 8) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def photos_without_overlap(database: Path, names: list[str]) -> list[str]:
    """The photos (by name) that share at least MIN_PAIR_INLIERS verified matches with no other photo."""
    import pycolmap

    db = pycolmap.Database.open(str(database))
    try:
        name_of = {img.image_id: img.name for img in db.read_all_images()}
        pair_ids, inliers = db.read_two_view_geometry_num_inliers()
    finally:
        db.close()
    overlapping: set[str] = set()
    for pair_id, n in zip(pair_ids, inliers):
        if n >= MIN_PAIR_INLIERS:
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            overlapping.update((name_of.get(a), name_of.get(b)))
    return [n for n in names if n not in overlapping]


def quality_summary(reconstruction, num_photos: int) -> dict:
    """What a user checks first: how many photos were placed and how well the points fit them."""
    return {
        "registered": int(reconstruction.num_reg_images()),
        "photos": int(num_photos),
        "points": int(reconstruction.num_points3D()),
        "mean_reprojection_error_px": float(reconstruction.compute_mean_reprojection_error()),
        "mean_track_length": float(reconstruction.compute_mean_track_length()),
        "mean_observations_per_image": float(reconstruction.compute_mean_observations_per_reg_image()),
    }


def result_lines(result: SfmResult) -> tuple[list[str], list[str]]:
    """What a finished run says: (the summary and where the scene is; notes on the photos left out)."""
    total = sum(result.seconds.values())
    stages = ", ".join(f"{k} {v:.1f}s" for k, v in result.seconds.items())
    lines = [f"{summary_line(result.report)}; {result.matcher} matching; {total:.1f} s ({stages})",
             f"scene written to {result.output} (images/, sparse/0, {REPORT_NAME})"]
    notes = []
    if result.no_overlap:
        notes.append(f"{len(result.no_overlap)} photos overlap no other photo and are left out: "
                     f"{name_list(result.no_overlap)}")
    if result.unregistered:
        notes.append(f"{len(result.unregistered)} photos could not be placed and are left out: "
                     f"{name_list(result.unregistered)}")
    return lines, notes


def summary_line(report: dict) -> str:
    return (f"registered {report['registered']}/{report['photos']} photos, {report['points']} points, mean "
            f"reprojection error {report['mean_reprojection_error_px']:.2f} px, mean track length "
            f"{report['mean_track_length']:.2f}")


def _map_with_retries(database: Path, image_dir: Path, num_photos: int, refine_principal_point: bool,
                      log: Callable[[str], None], report: _Reporter | None = None, stop: _Stop | None = None):
    """Run MAPPING_ATTEMPTS in order until one registers at least half the photos; the largest model of all and a
    one-line account of which settings gave it (None, line when no attempt found a model)."""
    best, best_name, tried = None, "", []
    for k, (name, mapper_options) in enumerate(MAPPING_ATTEMPTS):
        settings = ", ".join(f"{key} {value:g}" for key, value in mapper_options.items())
        label = name + (f" ({settings})" if settings else "")
        rec = _map(database, image_dir, num_photos, refine_principal_point, mapper_options,
                   report or _Reporter(None, False), stop or _Stop(None), label)
        n = 0 if rec is None else rec.num_reg_images()
        tried.append(f"{label}: " + ("no initial pair" if rec is None else f"{n}/{num_photos} registered"))
        if rec is not None and (best is None or n > best.num_reg_images()):
            best, best_name = rec, label
        if best is not None and 2 * best.num_reg_images() >= num_photos:
            break
        if k + 1 < len(MAPPING_ATTEMPTS):
            log(f"      {tried[-1]}; retrying with {MAPPING_ATTEMPTS[k + 1][0]}")
    if best is None:
        return None, "; ".join(tried)
    line = f"mapping settings that worked: {best_name}"
    if len(tried) > 1:
        line += f" (tried: {'; '.join(tried)})"
    log(f"      {line}")
    return best, line


# A preview's points are read again only once this many times the last read's duration has passed (reading them
# holds up the mapper: about 1 ms per thousand points, measured), so previews cost it at most about a tenth.
PREVIEW_COST_RATIO = 10.0


def _map(database: Path, image_dir: Path, num_photos: int, refine_principal_point: bool, mapper_options: dict,
         report: _Reporter, stop: _Stop, attempt: str):
    """Incremental mapping (pycolmap's IncrementalPipeline, as its ``incremental_mapping`` runs it, with our own
    ReconstructionManager so that its callbacks can read the model being built); the reconstruction with the most
    registered images, or None when there is none. A stop raises Cancelled from inside a callback: pycolmap hands
    a callback's exception back out of ``run``."""
    import pycolmap

    options = pycolmap.IncrementalPipelineOptions()
    # a fixed principal point at the image centre biased rotations by ~0.5 deg on a benchmark whose true one is
    # 23 px off centre (shared/docs/notes.md); refining it needs enough views to be stable, so the user chooses
    options.ba_refine_principal_point = bool(refine_principal_point)
    options.image_path = str(image_dir)  # the points' colours are read from the photos
    for key, value in mapper_options.items():
        setattr(options.mapper, key, value)
    manager = pycolmap.ReconstructionManager()
    points_read = {"at": 0.0, "took": 0.0}

    def registered() -> None:
        stop.check()
        if manager.size() == 0:
            return
        rec = manager.get(manager.size() - 1)  # the model being built (a new one after a failed start)
        preview = {}
        if report.wants_preview:
            now = time.perf_counter()
            preview["cameras"] = tuple(_pinhole(rec, i) for i in rec.reg_image_ids())
            if now - points_read["at"] >= PREVIEW_COST_RATIO * points_read["took"]:
                points = list(rec.points3D.values())
                preview["points"] = np.array([p.xyz for p in points], np.float32).reshape(-1, 3)
                preview["colors"] = np.array([p.color for p in points], np.uint8).reshape(-1, 3)
                points_read["at"], points_read["took"] = now, time.perf_counter() - now
        report.to(rec.num_reg_images(), **preview)

    report.start("mapping", num_photos, attempt)
    db = pycolmap.Database.open(str(database))
    try:
        stop.check()
        pipeline = pycolmap.IncrementalPipeline(options, db, manager)
        for kind in ("INITIAL_IMAGE_PAIR_REG_CALLBACK", "NEXT_IMAGE_REG_CALLBACK"):
            pipeline.add_callback(getattr(pycolmap.IncrementalPipelineCallback, kind), registered)
        pipeline.run()
    finally:
        db.close()
    models = [manager.get(i) for i in range(manager.size())]
    models = [m for m in models if m.num_reg_images() > 0]
    if not models:
        return None
    return max(models, key=lambda rec: rec.num_reg_images())


def _pinhole(rec, image_id: int):
    """A registered photo as our pinhole Camera (its lens distortion left out: what a frustum needs)."""
    from training.scene.camera import Camera

    image = rec.image(image_id)
    camera = rec.camera(image.camera_id)
    world_to_camera = np.eye(4)
    world_to_camera[:3] = image.cam_from_world().matrix()
    return Camera(image.name, int(camera.width), int(camera.height), float(camera.focal_length_x),
                  float(camera.focal_length_y), float(camera.principal_point_x), float(camera.principal_point_y),
                  world_to_camera)
