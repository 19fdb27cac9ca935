"""What a run was made from, recorded beside what it made, so that a resumed or skipped run can tell that its
inputs are still the same (GitHub issue 30).

A fingerprint is a plain dict of parts (JSON and ``torch.load(weights_only=True)`` both hold it):

- ``"dataset"``: the scene as the loader reads its cameras at full size: how many, a hash of the image names, of the
  image sizes and of the camera parameters (intrinsics and poses, rounded to 1e-9), and the number of SfM points.
  Not the pixels: hashing every photo would cost more than many runs, and a dataset whose cameras are unchanged
  is the same scene to every trainer here;
- ``"photos"``: structure from motion's input, a folder of photos: their names, byte sizes and contents (SfM reads
  nothing else, and costs far more than the hashing);
- ``"model"``, ``"painting"``: the sha256 of the file;
- ``"settings"``: the settings that shape the result; each caller chooses which (and says why).

``difference(recorded, current)`` names, in words, the first part that differs (parts only one side has are not
compared: a record made before a part existed cannot be checked for it); ``check_same_inputs`` turns that into
the one-line error a resume or a skip stops with (exit 2), or a warning for a record without a fingerprint.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Callable

import numpy as np

from training.core.errors import InputError

FINGERPRINT_VERSION = 1
HINT = "to start afresh, add --force (it replaces what is there) or choose a new output folder"


class InputsChanged(InputError):
    """A checkpoint, report or record was made from other inputs than the ones given now; ``difference`` says
    how, in words."""

    def __init__(self, path: str | Path | None, problem: str, difference: str):
        super().__init__(path, problem)
        self.difference = difference


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def file_sha256(path: str | Path) -> str:
    """sha256 of a file's bytes, read in 1 MiB blocks; InputError naming the file when it cannot be read."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    except OSError as exc:
        raise InputError(path, f"cannot read it ({exc.strerror or exc})") from None
    return h.hexdigest()


def dataset_fingerprint(data: str | Path) -> dict[str, Any]:
    """The ``"dataset"`` part for the scene at ``data`` (a COLMAP folder or a transforms.json scene)."""
    from training.scene.loader import load_scene

    return scene_fingerprint(load_scene(data, load_images=False))


def scene_fingerprint(scene) -> dict[str, Any]:
    """The ``"dataset"`` part of a loaded ``Scene`` (load it at full size, ``downscale=1``, to compare with
    :func:`dataset_fingerprint`)."""
    cams = scene.cameras
    names = "\n".join(c.name for c in cams).encode()
    sizes = np.array([[c.width, c.height] for c in cams], dtype=np.int64)
    params = np.array([[c.fx, c.fy, c.cx, c.cy, *np.asarray(c.world_to_camera, dtype=np.float64)[:3].ravel()]
                       for c in cams], dtype=np.float64).reshape(len(cams), 16)
    params = np.round(params, 9) + 0.0  # + 0.0: -0.0 and 0.0 hash alike
    return {"cameras": len(cams), "names": _sha(names)[:16], "sizes": _sha(sizes.tobytes())[:16],
            "camera_parameters": _sha(params.tobytes())[:16], "points": int(scene.num_points)}


def photos_fingerprint(photos: list[Path]) -> dict[str, Any]:
    """The ``"photos"`` part: names, byte sizes and contents of these photo files."""
    contents = hashlib.sha256()
    for p in photos:
        contents.update(f"{p.name}\0{p.stat().st_size}\0{file_sha256(p)}\n".encode())
    return {"photos": len(photos), "names": _sha("\n".join(p.name for p in photos).encode())[:16],
            "contents": contents.hexdigest()[:16]}


def make_fingerprint(**parts: Any) -> dict[str, Any]:
    """A fingerprint of the given parts (None values left out), with the format's version."""
    return {"version": FINGERPRINT_VERSION, **{k: v for k, v in parts.items() if v is not None}}


def _plain(value: Any) -> Any:
    """Tuples as lists: a value read back from JSON compares equal to the one recorded."""
    return json.loads(json.dumps(value))


def difference(recorded: dict[str, Any], current: dict[str, Any]) -> str | None:
    """The first part in which ``current`` differs from ``recorded``, in words ("the dataset differs (2 cameras
    now, 67 then)"); None when they agree."""
    for part in ("photos", "dataset", "model", "painting", "selection", "settings"):
        if part not in recorded or part not in current:
            continue
        old, new = _plain(recorded[part]), _plain(current[part])
        if old == new:
            continue
        if part in ("dataset", "photos"):
            return _collection_difference(part, old, new)
        if part == "settings":
            keys = [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]
            changed = ", ".join(f"{k} {new.get(k)!r} now, {old.get(k)!r} then" for k in keys[:3])
            return f"the settings differ ({changed}{', ...' if len(keys) > 3 else ''})"
        if part == "selection":
            return "the selection of Gaussians differs"
        return f"the {part} file differs (sha256 {str(new)[:12]} now, {str(old)[:12]} then)"
    return None


def _collection_difference(part: str, old: dict, new: dict) -> str:
    count = "cameras" if part == "dataset" else "photos"
    if old.get(count) != new.get(count):
        return f"the {part} differs ({new.get(count)} {count} now, {old.get(count)} then)"
    what = {"names": "image names" if part == "dataset" else "file names", "sizes": "image sizes",
            "camera_parameters": "camera poses or intrinsics", "points": "number of SfM points",
            "contents": "file contents"}
    key = next((k for k in what if old.get(k) != new.get(k)), None)
    return f"the {part} differs (other {what.get(key, 'contents')})"


def check_same_inputs(recorded: dict[str, Any] | None, current: dict[str, Any], where: str | Path,
                      made: str = "made from other inputs") -> str | None:
    """Stop (InputsChanged, one line naming ``where``, what differs and how to start afresh) when ``recorded``
    differs from ``current``. Returns a one-line warning when nothing was recorded (a file from before
    fingerprints: it resumes unchecked), else None."""
    if not recorded:
        return f"{where}: records no fingerprint of its inputs (made by an older version), so they could not be " \
               f"checked; resuming as if they were the same"
    diff = difference(recorded, current)
    if diff is not None:
        raise InputsChanged(where, f"{made}: {diff}; {HINT}", diff)
    return None


def state_to_resume(state: dict[str, Any], current: dict[str, Any], where: str | Path, force: bool,
                    say: Callable[[str], None], warn: Callable[[str], None]) -> dict[str, Any] | None:
    """A checkpoint's ``state`` (holding the fingerprint of its inputs) to resume from when it was made from the
    inputs ``current`` describes (or records none: ``warn`` says they could not be checked); when they differ,
    InputsChanged, or with ``force`` None (start afresh), which ``say`` says."""
    try:
        warning = check_same_inputs(state.get("fingerprint"), current, where)
    except InputsChanged as exc:
        if not force:
            raise
        say(f"{where}: made from other inputs ({exc.difference}): starting afresh (--force)")
        return None
    if warning:
        warn(warning)
    return state
