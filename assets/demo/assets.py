"""The demo's inputs, made by our own code on first use and cached: a COLMAP scene folder and a style painting.

``demo_assets()`` returns the paths, generating them into ``cache_dir("demo", VERSION)`` (or a folder you name) if
they are not there yet. Generation happens in a temporary folder beside the target that is renamed into place
only when complete, so an interrupted run never leaves a half-made asset folder that a later run would trust.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from training.core.cache_dir import cache_dir
from training.core.errors import InputError

# Bump whenever the generators change their output, so that stale caches are not reused.
VERSION = "1"
MANIFEST = "demo_assets.json"

# What the demo uses: small enough that the CPU demo stays quick, enough views and texture for SfM and stylization.
SCENE_PARAMS = {"num_views": 32, "width": 256, "height": 192, "num_points": 4000, "seed": 0, "supersample": 2}
STYLE_PARAMS = {"size": 512, "seed": 0}


@dataclass(frozen=True)
class DemoAssets:
    root: Path  # the folder holding both
    scene_dir: Path  # a COLMAP scene folder (images/ and sparse/0) for training.scene.loader.load_scene
    style_image: Path  # a PNG painting


def _assets_in(root: Path) -> DemoAssets:
    return DemoAssets(root=root, scene_dir=root / "scene", style_image=root / "style.png")


def _manifest() -> dict:
    return {"version": VERSION, "scene": SCENE_PARAMS, "style": STYLE_PARAMS,
            "generator": "assets.demo.scene + assets.demo.painting (procedural, no third-party data)"}


def _is_current(root: Path) -> bool:
    try:
        return json.loads((root / MANIFEST).read_text()) == _manifest()
    except (OSError, ValueError):
        return False


def generate_demo_assets(folder: str | Path, progress: bool = False) -> DemoAssets:
    """Write the demo scene and style into ``folder`` (which should be new or empty). No caching, no renaming."""
    from assets.demo.scene import make_demo_scene, write_demo_scene
    from assets.demo.painting import make_style_image
    from training.scene.image_io import write_image

    assets = _assets_in(Path(folder))
    write_demo_scene(assets.scene_dir, make_demo_scene(progress=progress, **SCENE_PARAMS))
    write_image(assets.style_image, make_style_image(**STYLE_PARAMS))
    (assets.root / MANIFEST).write_text(json.dumps(_manifest(), indent=2) + "\n")
    return assets


def demo_assets(root: str | Path | None = None, force: bool = False, progress: bool = False) -> DemoAssets:
    """The demo scene folder and style image, generated into ``root`` (default ``cache_dir("demo") / VERSION``)
    unless a complete set of the current version is already there (or ``force``).

    A ``root`` that exists, is not empty and is not a demo asset folder is refused (InputError) rather than
    overwritten."""
    target = Path(root) if root is not None else cache_dir("demo") / VERSION
    if target.exists() and not force and _is_current(target):
        return _assets_in(target)
    if target.exists():
        if not target.is_dir():
            raise InputError(target, "exists and is not a folder; choose another output folder")
        ours = (target / MANIFEST).exists()
        if any(target.iterdir()) and not ours:
            raise InputError(target, "folder is not empty and holds no demo assets; choose an empty or new folder")
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        generate_demo_assets(tmp, progress=progress)
        if target.exists():
            # Move the old set aside first: a folder can only be renamed over an empty one.
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
            os.replace(target, old / "assets")
            try:
                os.replace(tmp, target)
            except OSError:
                if target.exists() and _is_current(target):
                    pass  # another process finished first with the same content
                else:
                    os.replace(old / "assets", target)
                    raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            try:
                os.replace(tmp, target)
            except OSError:
                if not (target.exists() and _is_current(target)):  # not a concurrent run that finished first
                    raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return _assets_in(target)
