"""Project files (``*.splatproj``): one file that restores an editing session, and reads it back, checked once.

**Why a zip with a JSON manifest.** A project holds small structured settings (paths, the camera, stylization
settings, colour parameters, the dock layout) and large per-Gaussian arrays (the kept rows, selection, hidden,
region masks: millions of rows), and optionally whole models. Plain JSON would hold the arrays as text (tens of
MB for a 1M-Gaussian model) and could not embed a model; a folder is not one file a user can move, mail or keep
beside others, and cannot be replaced atomically. A zip is one file, written to a temporary name and renamed
(``training.core.atomic_write``), readable by any tool (``unzip -p P project.json``), with the arrays as ``.npy``
members (compressed) and models stored as they are.

Layout::

    project.json             the manifest below
    arrays/<name>.npy        bool masks and int64 row lists the manifest names
    models/<i>-<file name>   embedded models (only when saved with embed=True), the file's bytes unchanged

Manifest, version 1 (only ``version`` and each model's ``path`` are required; everything else has a default)::

    {"format": "splatstyler-project", "version": 1,
     "models": [{"name": "fox", "path": "fox.ply", "abs_path": "/data/fox.ply", "sha256": "...",
                 "embedded": "models/0-fox.ply" | null,
                 "original": {"path": ..., "abs_path": ..., "sha256": ..., "embedded": ...} | null,
                 "kept": "arrays/m0_kept.npy" | null,       # int64 file rows kept, in order (the editor's index)
                 "selected": "arrays/m0_selected.npy" | null, # bool over the kept rows
                 "hidden": "arrays/m0_hidden.npy" | null,     # bool over the kept rows
                 "transform": [[4x4]],                          # similarity, the model into the scene
                 "colour": [{"region": "arrays/..." | null, "brightness": 0, "contrast": 0, "saturation": 0,
                             "hue": 0, "temperature": 0}, ...],  # regions: bool over the file's rows
                 "strength": 1.0, "strength_regions": [{"region": "arrays/...", "strength": 0.5}]}],
     "dataset": {"path": ..., "abs_path": ...} | null, "painting": {...} | null,
     "stylize": {StylizeConfig fields},
     "camera": {keyframe: world_to_camera, fx, fy, cx, cy, width, height; target_distance} | null,
     "camera_path": {"duration": 8, "fps": 30, "loop": false, "keyframes": [...]},
     "layout": "imgui ini text",
     "up": [0, -1, 0], "world": [[4x4]]}   # the scene's up axis, and a similarity after every model's transform

Paths are stored relative to the project's folder (``path``) and absolute (``abs_path``); opening tries the
relative one first, so a project moved together with its files still opens, and one moved alone too.

Opening (``open_project``) refuses what cannot be a project (not a zip, no manifest, bad JSON, wrong types, a
newer version) with one ``InputError`` line naming the file; files that moved or changed are not fatal: each
gives one line in the returned ``problems`` and the rest opens. Older versions are upgraded step by step by
``MIGRATIONS`` before the manifest is read.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import shutil
import zipfile
import zlib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Callable

import numpy as np

from app.camera_path import CameraPath
from training.core.atomic_write import atomic_path
from training.core.errors import InputError
from training.core.json_numbers import NumberOutOfRange, parse_json
from training.core.npy_io import read_npy
from training.model.colour_edit import ColourAdjustment, ColourEdits
from training.scene.camera import Camera

FORMAT = "splatstyler-project"
FORMAT_VERSION = 1
SUFFIX = ".splatproj"
MANIFEST = "project.json"
# version n -> a function giving the version n+1 manifest; a new version adds its step here
MIGRATIONS: dict[int, Callable[[dict], dict]] = {}
_HASH_CHUNK = 1 << 20
# what a member may inflate to: a manifest is settings and keyframes (kilobytes: 4 MiB holds thousands of keyframes);
# an array has a row per Gaussian, and no scene has 100 million of them. Checked before a member is inflated (a zip
# bomb is refused unread); zipfile itself stops a member at the size its header declares. The manifest's bound is
# also what parsing it may cost: JSON of nothing but "{}," becomes 25 times its size in Python objects (4 MiB: about
# 120 MB; the 64 MiB allowed before took 1.9 GB)
MAX_MANIFEST_BYTES = 4 << 20
MAX_ARRAY_ROWS = 100_000_000
# what the arrays of one project inflate to together, each member once however often the manifest names it: a
# 10-million-Gaussian model's row list (80 MB), selection and hidden flags and 40 colour regions fit; a few kB of
# deflated zeros naming hundreds of distinct 10-million-row members do not
MAX_ARRAY_BYTES = 512 << 20
# an embedded model inflates to at most this many times the bytes it takes in the project (ours are stored, 1:1;
# a deflated PLY, its zero SH padding included, stays under 5:1), or to EMBED_FREE_BYTES whatever its ratio
MAX_EMBED_RATIO = 20
EMBED_FREE_BYTES = 1 << 20
# how a member may be stored: what zipfile inflates (PPMd, for one, it cannot), never encrypted
READABLE_COMPRESSION = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate", zipfile.ZIP_BZIP2: "bzip2",
                        zipfile.ZIP_LZMA: "lzma"}
# what reading a damaged member raises: a checksum or deflate error, a member cut short
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError)


# --------------------------------------------------------------------------------------------- the project
@dataclass
class FileRef:
    """A file the project names. ``path`` is where it was found (or recorded, when it is missing)."""

    path: Path
    sha256: str | None = None
    embedded: str | None = None  # member name in the project zip
    missing: bool = False  # not found at either recorded place (and not embedded)
    changed: bool = False  # found, but its content hash differs from the recorded one


@dataclass
class ModelEntry:
    """One model in the scene and its edits. Row masks over the kept rows; colour regions over the file's rows."""

    file: FileRef
    name: str = ""
    original: FileRef | None = None  # the unstylized model, for style strength
    kept: np.ndarray | None = None  # (M,) int64 file rows kept, in order; None: all
    selected: np.ndarray | None = None  # (M,) bool
    hidden: np.ndarray | None = None  # (M,) bool
    transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    colour: ColourEdits = field(default_factory=ColourEdits)

    @property
    def usable(self) -> bool:
        """Its files are there and unchanged, so its edits fit them."""
        refs = [self.file] + ([self.original] if self.colour.uses_original and self.original else [])
        return not any(r.missing or r.changed for r in refs)


@dataclass
class Project:
    models: list[ModelEntry] = field(default_factory=list)
    dataset: FileRef | None = None
    painting: FileRef | None = None
    stylize: dict = field(default_factory=dict)  # StylizeConfig fields (stylize_config() builds one)
    camera: Camera | None = None  # the view's camera (a pinhole camera) or None
    camera_distance: float = 1.0  # the viewer's orbit centre, this far in front of the camera
    camera_path: CameraPath = field(default_factory=CameraPath)  # the video's path (the Camera path panel's)
    layout: str = ""  # imgui ini text of the dock layout
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, -1.0, 0.0]))
    world: np.ndarray = field(default_factory=lambda: np.eye(4))  # similarity: up axis and scale
    source: Path | None = None  # the file it was opened from (where embedded models are read)
    # copies of embedded models by member name (the viewer's, made when it opened them): what a save writes, so that
    # a project whose file has moved or gone since it was opened can still be saved
    copies: dict[str, Path] = field(default_factory=dict)

    def stylize_config(self):
        """The stylization settings as a StylizeConfig (validated when the project was opened)."""
        from training.stylize.config import StylizeConfig

        return StylizeConfig(**self.stylize)

    def open_model(self, ref: FileRef):
        """The Gaussians of a model file the project names (embedded ones from the project file)."""
        from training.model.model_io import read_model

        if ref.embedded is not None and self.source is not None:
            import tempfile

            with tempfile.TemporaryDirectory() as tmp:
                target = Path(tmp) / Path(ref.embedded).name
                extract_member(self.source, ref.embedded, target)
                try:
                    return read_model(target)
                except InputError as exc:  # the temporary copy is gone: the project and its member are the names
                    raise InputError(self.source, f"embedded model {ref.embedded}: {exc.problem}") from None
        if ref.missing:
            raise InputError(ref.path, "model file not found")
        return read_model(ref.path)



def extract_member(source: Path, member: str, target: Path) -> Path:
    """Copy the project's member (an embedded model) to the file ``target``, streamed (a model may be larger than
    the memory) and atomically; InputError naming the project when the member is damaged."""
    from training.core.atomic_write import atomic_open

    try:
        with zipfile.ZipFile(source) as z:
            info = embedded_member(z, source, member)
            with z.open(info) as src, atomic_open(target, "wb") as dst:
                shutil.copyfileobj(src, dst, _HASH_CHUNK)
    except _ZIP_ERRORS as exc:
        raise InputError(source, f"embedded model {member} cannot be read ({_first_line(exc)})") from None
    return target


def embedded_member(z: zipfile.ZipFile, source: Path, member: str) -> zipfile.ZipInfo:
    """The zip entry of an embedded model, checked before it is inflated: a member that would inflate far beyond
    the bytes it takes (``MAX_EMBED_RATIO``) is refused, so a small project cannot fill the disk it is copied to."""
    try:
        info = z.getinfo(member)
    except KeyError:
        raise InputError(source, f"embedded model {member} is not in the project") from None
    # the bytes the member really has: a header may claim more than the project file holds
    packed = min(info.compress_size, Path(source).stat().st_size)
    if info.file_size > max(EMBED_FREE_BYTES, MAX_EMBED_RATIO * packed):
        raise InputError(source, f"embedded model {member} would inflate to {info.file_size:,} bytes from "
                                 f"{packed:,} (more than {MAX_EMBED_RATIO} times): a damaged or crafted project")
    return info


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(_HASH_CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


# --------------------------------------------------------------------------------------------- saving
def with_suffix(path: str | Path) -> Path:
    """``path`` as a project file's name: ``.splatproj`` added when it lacks it."""
    path = Path(path)
    return path if path.suffix == SUFFIX else path.with_name(path.name + SUFFIX)


def save_project(path: str | Path, project: Project, embed: bool = False) -> Path:
    """Write ``project`` to ``path`` (``.splatproj`` added when missing) atomically. Each model's hash is the one
    its reference carries (taken when the file was opened: the edits refer to those rows, so a file rewritten
    since is flagged when the project opens), else the file's as it is now; ``embed`` copies the model files into
    the project (models already embedded stay embedded, under the same member name). Returns the path written."""
    path = with_suffix(path)
    folder = path.absolute().parent
    arrays: dict[str, np.ndarray] = {}
    embedded: dict[str, tuple[str, object]] = {}  # member -> ("file", path) | ("zip", member in the source)

    def ref(r: FileRef | None, tag: str, hash_it: bool = False, embed_it: bool = False):
        if r is None:
            return None
        out = {"path": _relative(r.path, folder), "abs_path": str(Path(r.path).absolute())}
        embedded_before = r.embedded is not None and (project.source is not None or r.embedded in project.copies)
        if hash_it:
            if r.sha256 is not None or embedded_before:
                # the hash of the file the edits were made on (taken when it was opened): a file changed since
                # stays flagged, and a missing one is recognised when it is back
                out["sha256"] = r.sha256
            elif Path(r.path).is_file():
                out["sha256"] = file_sha256(r.path)
            member = None
            if embedded_before:
                # the member keeps its name: what the viewer noted of it still names it in the file written
                member = r.embedded
                embedded[member] = ("zip", r.embedded)
            elif embed_it:
                if not Path(r.path).is_file():
                    raise InputError(r.path, "cannot embed this model: file not found")
                member = f"models/{tag}-{Path(r.path).name}"
                while member in embedded and embedded[member] != ("file", Path(r.path)):
                    member = f"models/{tag}x-{Path(member).name}"
                embedded[member] = ("file", Path(r.path))
            out["embedded"] = member
        return out

    def array(name: str, a) -> str | None:
        if a is None:
            return None
        member = f"arrays/{name}.npy"
        arrays[member] = np.asarray(a)
        return member

    models = []
    for i, m in enumerate(project.models):
        colour = m.colour
        models.append({
            "name": m.name, **ref(m.file, str(i), True, embed),
            "original": ref(m.original, f"{i}-original", True, embed),
            "kept": array(f"m{i}_kept", None if m.kept is None else np.asarray(m.kept, np.int64)),
            "selected": array(f"m{i}_selected", m.selected), "hidden": array(f"m{i}_hidden", m.hidden),
            "transform": np.asarray(m.transform, float).tolist(),
            "colour": [{"region": array(f"m{i}_colour{j}", region), **adj.to_dict()}
                       for j, (region, adj) in enumerate(colour.adjustments)],
            "strength": float(colour.strength),
            "strength_regions": [{"region": array(f"m{i}_strength{j}", region), "strength": float(s)}
                                 for j, (region, s) in enumerate(colour.strength_regions)],
        })
    manifest = {
        "format": FORMAT, "version": FORMAT_VERSION, "models": models,
        "dataset": ref(project.dataset, "dataset"), "painting": ref(project.painting, "painting"),
        "stylize": _jsonable(project.stylize),
        "camera": None if project.camera is None else {**project.camera.to_dict(),
                                                       "target_distance": float(project.camera_distance)},
        "camera_path": {k: v for k, v in project.camera_path.to_dict().items() if k != "version"},
        "layout": project.layout,
        "up": np.asarray(project.up, float).tolist(), "world": np.asarray(project.world, float).tolist(),
    }
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr(MANIFEST, json.dumps(manifest, indent=1) + "\n")
            for member, a in arrays.items():
                buf = io.BytesIO()
                np.save(buf, a, allow_pickle=False)
                z.writestr(member, buf.getvalue())
            for member, (kind, src) in embedded.items():
                # models are stored, not deflated: PLY floats barely compress and are large
                copy = project.copies.get(src) if kind == "zip" else None
                if kind == "file":
                    z.write(src, member, compress_type=zipfile.ZIP_STORED)
                elif copy is not None and Path(copy).is_file():
                    # the copy the edits were made on, whether or not the project file is still where it was
                    z.write(copy, member, compress_type=zipfile.ZIP_STORED)
                elif project.source is None:
                    raise InputError(copy, f"embedded model {src} cannot be saved: the viewer's copy of it is gone "
                                           "and there is no project file to read it from")
                else:  # streamed from the project it was opened from: a model may be larger than the memory
                    info = zipfile.ZipInfo(member)
                    info.compress_type = zipfile.ZIP_STORED
                    try:
                        with zipfile.ZipFile(project.source) as old, \
                                old.open(embedded_member(old, project.source, src)) as fin, \
                                z.open(info, "w", force_zip64=True) as fout:
                            shutil.copyfileobj(fin, fout, _HASH_CHUNK)
                    except _ZIP_ERRORS as exc:
                        raise InputError(project.source, f"embedded model {src} cannot be read "
                                                         f"({_first_line(exc)})") from None
    return path


def _relative(p, folder: Path) -> str:
    try:
        return os.path.relpath(Path(p).absolute(), folder)
    except ValueError:  # another drive (Windows): only the absolute path means anything
        return str(Path(p).absolute())


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


# --------------------------------------------------------------------------------------------- opening
def open_project(path: str | Path, check_hashes: bool = True) -> tuple[Project, list[str]]:
    """Read a project file. Returns the project and one line per problem it survived (a file not found, a model
    changed since it was saved, a setting that no longer applies); InputError for a file that is not a project."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "project file does not exist" if not path.exists() else "is not a file")
    try:
        z = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError):
        raise InputError(path, "not a splatstyler project (not a zip file)") from None
    with z:
        try:
            info = z.getinfo(MANIFEST)
        except KeyError:
            raise InputError(path, f"not a splatstyler project (no {MANIFEST} inside)") from None
        check_members(z, path)
        if info.file_size > MAX_MANIFEST_BYTES:
            raise InputError(path, f"{MANIFEST} would inflate to {info.file_size:,} bytes; a project's is at most "
                                   f"{MAX_MANIFEST_BYTES:,}")
        try:
            raw = z.read(info)
        except _ZIP_ERRORS as exc:
            raise InputError(path, f"{MANIFEST} cannot be read ({_first_line(exc)})") from None
        try:
            data = parse_json(raw)
        except NumberOutOfRange as exc:
            raise InputError(path, f"{MANIFEST} {exc}") from None
        except (ValueError, UnicodeDecodeError) as exc:
            raise InputError(path, f"{MANIFEST} is not valid JSON ({str(exc).splitlines()[0]})") from None
        except RecursionError:
            raise InputError(path, f"{MANIFEST} nests its JSON too deeply to be a project's") from None
        reader = _Reader(path, z, check_hashes)
        project = reader.project(upgrade(data, path))
    project.source = path
    return project, reader.problems


def check_members(z: zipfile.ZipFile, path: Path) -> None:
    """Every member is one this reader can inflate: not encrypted, and compressed in a way zipfile knows (a project
    from another zip tool may use PPMd); else one line naming the member, before anything is read."""
    for info in z.infolist():
        if info.flag_bits & 0x1:
            raise InputError(path, f"member {info.filename} is encrypted; a project's members are not")
        if info.compress_type not in READABLE_COMPRESSION:
            raise InputError(path, f"member {info.filename} is compressed with method {info.compress_type}, which "
                                   f"this reader cannot inflate ({', '.join(READABLE_COMPRESSION.values())})")


def upgrade(data, name) -> dict:
    """The manifest brought to FORMAT_VERSION through MIGRATIONS, one version at a time."""
    if not isinstance(data, dict):
        raise InputError(name, f"{MANIFEST} must hold a JSON object")
    version = data.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise InputError(name, f"project 'version' must be a whole number >= 1, got {version!r}")
    if version > FORMAT_VERSION:
        raise InputError(name, f"project version {version} was written by a newer splatstyler; this one reads "
                               f"versions 1..{FORMAT_VERSION}")
    while version < FORMAT_VERSION:
        if version not in MIGRATIONS:
            raise InputError(name, f"cannot upgrade a version {version} project (no migration)")
        data = MIGRATIONS[version](dict(data))
        version += 1
        data["version"] = version
    return data


class _Reader:
    """Turns a manifest into a Project: types and shapes checked here, once; missing or changed files listed."""

    def __init__(self, path: Path, z: zipfile.ZipFile, check_hashes: bool):
        self.path, self.z, self.check_hashes = path, z, check_hashes
        self.folder = path.absolute().parent
        self.problems: list[str] = []
        self.arrays: dict[str, np.ndarray] = {}  # member -> its array, as read
        self.array_bytes = 0

    def fail(self, problem: str):
        raise InputError(self.path, problem)

    def project(self, data: dict) -> Project:
        models = data.get("models", [])
        if not isinstance(models, list):
            self.fail("'models' must be a list")
        p = Project(models=[self.model(m, i) for i, m in enumerate(models)])
        p.dataset = self.ref(data.get("dataset"), "dataset")
        p.painting = self.ref(data.get("painting"), "painting")
        p.stylize = self.stylize(data.get("stylize", {}))
        if data.get("camera") is not None:
            p.camera = Camera.from_dict(data["camera"], "camera", self.path, name="view")
            p.camera_distance = self.number(data["camera"], "target_distance", 1.0, "camera.", positive=True)
        path = data.get("camera_path", {})
        if not isinstance(path, dict):
            self.fail("'camera_path' must be an object")
        keys = path.get("keyframes", [])
        if not isinstance(keys, list):
            self.fail("'camera_path.keyframes' must be a list")
        p.camera_path = CameraPath([Camera.from_dict(k, f"keyframe {i}", self.path) for i, k in enumerate(keys)],
                                   self.number(path, "duration", 8.0, "camera_path.", positive=True),
                                   self.number(path, "fps", 30.0, "camera_path.", positive=True),
                                   bool(path.get("loop", False)))
        # a path file's limits, keyframes or not: the viewer draws the path and renders it to a video
        p.camera_path.validate_timing(self.path)
        if p.camera_path.keyframes:
            p.camera_path.validate(self.path)
        p.layout = data.get("layout", "")
        if not isinstance(p.layout, str):
            self.fail("'layout' must be text")
        p.up = self.vector(data.get("up", [0.0, -1.0, 0.0]), "up")
        p.world = self.similarity(data.get("world", np.eye(4).tolist()), "world")
        return p

    # -------------------------------------------------------------- pieces
    def number(self, d: dict, key: str, default, where: str = "", positive=False, lo=None, hi=None) -> float:
        v = d.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            self.fail(f"'{where}{key}' must be a finite number, got {v!r}")
        if positive and v <= 0:
            self.fail(f"'{where}{key}' must be positive, got {v!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            self.fail(f"'{where}{key}' must be in [{lo}, {hi}], got {v!r}")
        return float(v)

    def vector(self, v, where: str) -> np.ndarray:
        try:
            a = np.array(v, dtype=np.float64)
        except (TypeError, ValueError):
            self.fail(f"'{where}' must be 3 numbers")
        if a.shape != (3,) or not np.isfinite(a).all():
            self.fail(f"'{where}' must be 3 finite numbers, not all 0")
        with np.errstate(all="ignore"):
            unit = a / np.linalg.norm(a)
        # a length that overflows (1e308) or underflows (5e-324) gives no direction, not a zero or a wrong one
        if not np.isfinite(unit).all() or abs(np.linalg.norm(unit) - 1.0) > 1e-9:
            self.fail(f"'{where}' must be a direction: 3 numbers, not all 0, whose length is a finite number "
                      f"(got {a.tolist()})")
        return unit

    def similarity(self, v, where: str) -> np.ndarray:
        from training.model.transform import split_similarity

        try:
            m = np.array(v, dtype=np.float64)
            split_similarity(m)
        except (TypeError, ValueError) as exc:
            self.fail(f"'{where}': {exc}")
        return m

    def array(self, member, where: str, dtype: str, length: int | None = None) -> np.ndarray | None:
        if member is None:
            return None
        if not isinstance(member, str):
            self.fail(f"'{where}' must name an array member, got {member!r}")
        try:
            info = self.z.getinfo(member)
        except KeyError:
            self.fail(f"'{where}' names {member}, which is not in the project")

        def check(shape: tuple[int, ...], kind: np.dtype) -> None:
            ok = kind == np.dtype(bool) if dtype == "bool" else kind.kind in "iu"
            if len(shape) != 1 or not ok:
                self.fail(f"{member} must be a 1-D {dtype} array, got {kind} {shape}")
            rows = shape[0]
            if rows > MAX_ARRAY_ROWS:
                self.fail(f"{member} holds {rows:,} rows; a project array holds at most {MAX_ARRAY_ROWS:,}")
            if length is not None and rows != length:
                self.fail(f"{member} has {rows} rows, expected {length}")

        if member in self.arrays:  # a member several entries name (one region, many adjustments) is read once
            a = self.arrays[member]
            check(a.shape, a.dtype)
        else:
            def within_budget(shape: tuple[int, ...], kind: np.dtype) -> None:
                check(shape, kind)
                total = self.array_bytes + math.prod(shape) * kind.itemsize
                if total > MAX_ARRAY_BYTES:
                    self.fail(f"its arrays inflate to more than {MAX_ARRAY_BYTES:,} bytes ({member} brings them to "
                              f"{total:,}); a damaged or crafted project")

            try:
                # the header first, bounded by the member's size: its type and length are checked before anything
                # else is inflated
                with self.z.open(info) as f:
                    a = read_npy(f, info.file_size, within_budget)
            except _ZIP_ERRORS as exc:
                self.fail(f"{member} is not a readable .npy array ({_first_line(exc)})")
            self.arrays[member] = a
            self.array_bytes += a.nbytes
        return a.astype(np.int64) if dtype == "int" else a

    def ref(self, d, what: str, recorded_hash: bool = False) -> FileRef | None:
        if d is None:
            return None
        if isinstance(d, str):
            d = {"path": d}
        if not isinstance(d, dict) or not isinstance(d.get("path"), str) or not d["path"]:
            self.fail(f"{what}: 'path' must be a file name")
        sha = d.get("sha256")
        if sha is not None and (not isinstance(sha, str) or len(sha) != 64):
            self.fail(f"{what}: 'sha256' must be 64 hex digits")
        embedded = d.get("embedded")
        if embedded is not None:
            if not isinstance(embedded, str) or embedded not in self.z.namelist():
                self.fail(f"{what}: embedded model {embedded!r} is not in the project")
            return FileRef(Path(d.get("abs_path") or d["path"]), sha, embedded)
        candidates = [self.folder / d["path"]] + ([Path(d["abs_path"])] if d.get("abs_path") else [])
        found = next((c for c in candidates if c.exists()), None)
        if found is None:
            tried = " or ".join(dict.fromkeys(str(c) for c in candidates))
            self.problems.append(f"{candidates[0]}: {what} not found (looked for {tried})")
            return FileRef(candidates[-1], sha, missing=True)
        ref = FileRef(Path(os.path.normpath(found)), sha)
        if sha is not None and self.check_hashes and found.is_file() and file_sha256(found) != sha:
            ref.changed = True
            self.problems.append(f"{ref.path}: {what} changed since the project was saved (content hash differs)")
        return ref

    def stylize(self, d) -> dict:
        from training.stylize.config import StylizeConfig

        if not isinstance(d, dict):
            self.fail("'stylize' must be an object")
        known = {f.name for f in fields(StylizeConfig)}
        unknown = sorted(set(d) - known)
        if unknown:
            self.problems.append(f"{self.path}: stylization settings {', '.join(unknown)} are not known to this "
                                 "splatstyler: ignored")
        kept = {k: (tuple(v) if k == "background" and isinstance(v, list) else v) for k, v in d.items() if k in known}
        try:
            StylizeConfig(**kept).validate()
        except (TypeError, ValueError) as exc:
            self.problems.append(f"{self.path}: stylization settings: {exc}: the defaults are used")
            return {}
        return kept

    def model(self, d, i: int) -> ModelEntry:
        where = f"models[{i}]"
        if not isinstance(d, dict):
            self.fail(f"{where} must be an object")
        name = d.get("name") or Path(str(d.get("path", ""))).stem
        file = self.ref(d, f"model '{name}'")
        original = self.ref(d.get("original"), f"original model of '{name}'")
        kept = self.array(d.get("kept"), f"{where}.kept", "int")
        if kept is not None and (len(kept) and kept.min() < 0 or len(np.unique(kept)) != len(kept)):
            self.fail(f"{where}.kept must hold distinct row numbers >= 0")
        n = None if kept is None else len(kept)
        selected = self.array(d.get("selected"), f"{where}.selected", "bool", n)
        hidden = self.array(d.get("hidden"), f"{where}.hidden", "bool", n if n is not None else
                            (None if selected is None else len(selected)))
        adjustments, regions = [], []
        for j, c in enumerate(_list(d.get("colour", []), f"{where}.colour", self)):
            params = {k: self.number(c, k, 0.0, f"{where}.colour[{j}].") for k in ColourAdjustment().to_dict()}
            adj = ColourAdjustment(**params)
            try:
                adj.validate()
            except ValueError as exc:
                self.fail(f"{where}.colour[{j}]: {exc}")
            adjustments.append((self.array(c.get("region"), f"{where}.colour[{j}].region", "bool"), adj))
        for j, c in enumerate(_list(d.get("strength_regions", []), f"{where}.strength_regions", self)):
            regions.append((self.array(c.get("region"), f"{where}.strength_regions[{j}].region", "bool"),
                            self.number(c, "strength", 1.0, f"{where}.strength_regions[{j}].", lo=0, hi=1)))
        lengths = {len(r) for r, _ in adjustments + regions if r is not None}
        if len(lengths) > 1:
            self.fail(f"{where}: its colour and strength regions differ in length")
        colour = ColourEdits(adjustments, self.number(d, "strength", 1.0, f"{where}.", lo=0, hi=1), regions)
        if colour.uses_original and original is None:
            self.fail(f"{where}: style strength below 1 needs an 'original' model")
        return ModelEntry(file, name, original, kept, selected, hidden,
                          self.similarity(d.get("transform", np.eye(4).tolist()), f"{where}.transform"), colour)


def _list(v, where: str, reader: _Reader) -> list[dict]:
    if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
        reader.fail(f"'{where}' must be a list of objects")
    return v
