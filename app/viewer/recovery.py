"""The recovery project: while the scene has unsaved edits, the window writes them every ``EVERY_S`` seconds as a
project of their own (atomically, like any project), so a crash, a killed process or a power cut loses at most those
minutes; a save or a discard removes it, and so does a close with nothing unsaved. A signal (SIGTERM, Ctrl-C)
closes the window without asking: the edits are written then, and the next start offers them.

Where: ``$XDG_CONFIG_HOME/splatstyler/recovery`` (default ``~/.config``), beside the window's layout file (its
layout is the user's, so are these edits; a cache may be cleared). Each window writes ``session-<pid>-<time>
.splatproj`` and a ``.json`` beside it (when, and the project or model the scene was, so that a recovered scene
saves where the user's own project is), and holds an exclusive ``flock`` on a ``.lock`` beside them for as long as
it runs: a recovery project whose lock is free belongs to a window that is gone, and is offered at the next start
(Open, Discard, or Later to keep it); another window's, still open, is left alone.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from app.project import save_project as write_project
from training.core.atomic_write import atomic_open
from training.core.file_lock import held, hold

EVERY_S = 120.0  # at most this much work is lost to a crash


def recovery_folder() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "splatstyler" / "recovery"


class Recovery:
    """This window's recovery project: ``keep`` each frame, ``close`` as the window closes."""

    def __init__(self, folder: Path | None = None, every_s: float = EVERY_S):
        self.folder = folder or recovery_folder()
        self.folder.mkdir(parents=True, exist_ok=True)
        stem = f"session-{os.getpid()}-{int(time.time() * 1000)}"
        self.path = self.folder / f"{stem}.splatproj"
        self.every_s = every_s
        self.written_at: float | None = None  # when the recovery project was last written (None: there is none)
        self.adopted: list[Path] = []  # recovery projects of a gone window opened here: removed with ours
        self._lock_path = self.folder / f"{stem}.lock"
        self._lock = hold(self._lock_path)

    def keep(self, doc, project, scene: str = "", now: float | None = None) -> bool:
        """Each frame: while ``doc`` has unsaved edits, write ``project()`` (the session as a Project) when none
        was written for ``every_s`` seconds; once it has none, remove what was written. ``scene``: the project or
        model file the scene is (the note's). True when written now."""
        if not doc.unsaved():
            if self.written_at is not None or self.adopted:
                self.remove()
            return False
        now = time.monotonic() if now is None else now
        if self.written_at is not None and now - self.written_at < self.every_s:
            return False
        self.written_at = now  # a write that fails is tried again after every_s, not at every frame
        self.write(project(), scene)
        for path in self.adopted:  # their edits are in ours now
            forget(path)
        self.adopted = []
        return True

    def write(self, project, scene: str = "") -> None:
        """The recovery project, atomically, then the note beside it (the scene's own project or model)."""
        write_project(self.path, project)
        with atomic_open(self.path.with_suffix(".json"), "w") as f:
            json.dump({"written": time.time(), "scene": scene}, f)

    def remove(self) -> None:
        for path in [self.path] + self.adopted:
            forget(path)
        self.written_at, self.adopted = None, []

    def close(self, doc, project, scene: str = "") -> None:
        """The window closes: unsaved edits are written (``project()``) and kept for the next start, else nothing
        is left; the lock goes either way."""
        try:
            if doc.unsaved():
                self.write(project(), scene)
            else:
                self.remove()
        finally:
            os.close(self._lock)
            self._lock_path.unlink(missing_ok=True)


def left_behind(folder: Path | None = None) -> list[tuple[Path, dict]]:
    """Recovery projects of windows that are gone (their lock is free), newest first, each with its note."""
    folder = folder or recovery_folder()
    if not folder.is_dir():
        return []
    found = []
    for path in folder.glob("session-*.splatproj"):
        if held(path.with_suffix(".lock")):
            continue
        try:
            note = json.loads(path.with_suffix(".json").read_text())
        except (OSError, ValueError):
            note = {}
        if not isinstance(note, dict):
            note = {}
        found.append((path, note))
    return sorted(found, key=lambda item: -item[0].stat().st_mtime)


def forget(path: Path) -> None:
    """A recovery project the user discarded: it, its note and its (free) lock file go."""
    for p in (path, path.with_suffix(".json"), path.with_suffix(".lock")):
        p.unlink(missing_ok=True)
