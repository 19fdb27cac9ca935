"""The evaluation grid file (TOML) and the jobs it expands into.

A grid names scenes, paintings and settings; every (scene, painting, seed, setting) is a *cell*: reconstruct
(cached and shared by every cell with the same scene, reconstruction variant and seed), stylize, measure. Paths are
relative to the grid file. Example (docs/evaluation.md has the full reference)::

    seeds = [0, 1]                        # each seed seeds the reconstruction and the stylization

    [reconstruct]                         # flags of `splatstyler reconstruct` for every reconstruction
    preset = "quick"
    max_side = 256

    [reconstructions.vanilla]             # a variant: more flags on top of [reconstruct]
    no_shape = true
    no_size = true
    no_depth = true

    [stylize]                             # flags of `splatstyler stylize` for every cell
    preset = "quick"

    [scenes.fox]
    data = "../shared/data/scenes/fox"    # a COLMAP folder or transforms.json ...
    [scenes.fern]
    photos = "../shared/data/scenes/llff_fern/images"   # ... or photos, put through `splatstyler sfm` once

    [paintings]
    starry_night = "../shared/data/styles/starry_night.jpg"

    [settings.ccft]                       # a setting: flags on top of [stylize]
    [settings.nnfm]
    loss = "nnfm"
    paintings = ["starry_night"]          # optional: limit the setting to some scenes, paintings or seeds
    [settings.vanilla]
    reconstruction = "vanilla"            # stylize a reconstruction variant
    [settings.per_view_2d]
    method = "2d"                         # the per-view 2D stylization of the renders (training/evaluate)

    [groups.loss]                         # a table in the report: these settings side by side
    title = "Style loss"
    settings = ["ccft", "nnfm"]
    metrics = ["utilisation", "swd_ratio_pre_ct"]
    expect = [["ccft", ">", "nnfm", "utilisation"]]   # the paper's direction, checked per scene

A flag value ``true`` passes the bare flag (``no_depth = true`` -> ``--no-depth``), ``false`` leaves it out.
"""

from __future__ import annotations

import hashlib
import json
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from training.core.errors import InputError

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")
METHODS = ("stylize", "2d")
SETTING_KEYS = ("reconstruction", "method", "scenes", "paintings", "seeds", "label")
GROUP_KEYS = ("title", "settings", "metrics", "expect", "paintings", "about")
TOP_KEYS = ("title", "intro", "discussion", "seeds", "reconstruct", "reconstructions", "stylize", "scenes",
            "paintings", "settings", "groups", "sheet_views")
EXPECT_OPS = ("<", ">")


@dataclass(frozen=True)
class Job:
    """One unit of work for a worker: ``kind`` is "sfm", "reconstruct" or "cell"; ``deps`` name the jobs whose
    outputs it reads; ``spec`` is plain JSON (it travels to another process or machine); ``inputs`` the
    fingerprint of the grid's files it reads (``with_inputs``), recorded with its result."""

    id: str
    kind: str
    spec: dict[str, Any]
    deps: tuple[str, ...] = ()
    inputs: dict[str, Any] = field(default_factory=dict)


@dataclass
class Group:
    name: str
    title: str
    settings: list[str]
    metrics: list[str]
    expect: list[tuple[str, str, str, str]] = field(default_factory=list)
    paintings: list[str] | None = None
    about: str = ""


@dataclass
class Grid:
    path: Path
    title: str
    intro: str
    discussion: str
    seeds: list[int]
    scenes: dict[str, dict[str, Any]]
    paintings: dict[str, Path]
    settings: dict[str, dict[str, Any]]
    groups: list[Group]
    jobs: list[Job]
    sheet_views: int = 3

    @property
    def cells(self) -> list[Job]:
        return [j for j in self.jobs if j.kind == "cell"]


def _flags(options: dict[str, Any], where: str) -> list[str]:
    """{"max_side": 256, "no_depth": True} -> ["--max-side", "256", "--no-depth"]."""
    out: list[str] = []
    for key, value in options.items():
        flag = "--" + key.replace("_", "-")
        if value is True:
            out.append(flag)
        elif value is False:
            continue
        elif isinstance(value, (int, float, str)):
            out += [flag, str(value)]
        else:
            raise InputError(None, f"{where}: {key} must be a number, a string or true/false, got {value!r}")
    return out


def _short_hash(value: Any) -> str:
    return hashlib.sha1(json.dumps(value, sort_keys=True).encode()).hexdigest()[:8]


def _check_name(name: str, where: str, path: Path) -> str:
    if not NAME.match(name):
        raise InputError(path, f"{where} name {name!r}: use letters, digits and _ . + - only")
    return name


def _table(doc: dict, key: str, path: Path) -> dict:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise InputError(path, f"[{key}] must be a table")
    return value


def load_grid(path: str | Path) -> Grid:
    """Read and check a grid file; expand it into jobs. Every mistake is one InputError naming the file."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(path, "no such grid file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"not a valid TOML file: {exc}") from None
    unknown = sorted(set(doc) - set(TOP_KEYS))
    if unknown:
        raise InputError(path, f"unknown key {unknown[0]!r} (expected one of {', '.join(TOP_KEYS)})")
    base = path.parent

    def resolve(value: Any, where: str) -> Path:
        if not isinstance(value, str):
            raise InputError(path, f"{where} must be a path string")
        p = Path(value).expanduser()
        return p if p.is_absolute() else (base / p).resolve()

    seeds = doc.get("seeds", [0])
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) for s in seeds):
        raise InputError(path, "seeds must be a non-empty list of integers")

    scenes: dict[str, dict[str, Any]] = {}
    for name, spec in _table(doc, "scenes", path).items():
        _check_name(name, "scene", path)
        if not isinstance(spec, dict) or ("data" in spec) == ("photos" in spec):
            raise InputError(path, f"[scenes.{name}] needs exactly one of data = ... or photos = ...")
        extra = sorted(set(spec) - {"data", "photos", "sfm"})
        if extra:
            raise InputError(path, f"[scenes.{name}]: unknown key {extra[0]!r} (data, photos, sfm)")
        key = "data" if "data" in spec else "photos"
        src = resolve(spec[key], f"[scenes.{name}] {key}")
        if not src.exists():
            raise InputError(src, f"[scenes.{name}] {key}: no such file or folder (grid {path})")
        scenes[name] = {key: str(src), "sfm_flags": _flags(spec.get("sfm", {}), f"[scenes.{name}] sfm")}
    if not scenes:
        raise InputError(path, "the grid names no scenes ([scenes.NAME] with data = ... or photos = ...)")

    paintings: dict[str, Path] = {}
    for name, value in _table(doc, "paintings", path).items():
        _check_name(name, "painting", path)
        p = resolve(value, f"[paintings] {name}")
        if not p.is_file():
            raise InputError(p, f"painting {name!r}: no such file (grid {path})")
        paintings[name] = p
    if not paintings:
        raise InputError(path, "the grid names no paintings ([paintings] NAME = \"path\")")

    recon_base = _flags(_table(doc, "reconstruct", path), "[reconstruct]")
    variants = {"enhanced": []}
    for name, spec in _table(doc, "reconstructions", path).items():
        _check_name(name, "reconstruction", path)
        variants[name] = _flags(spec, f"[reconstructions.{name}]")
    stylize_base = _flags(_table(doc, "stylize", path), "[stylize]")

    settings: dict[str, dict[str, Any]] = {}
    for name, spec in _table(doc, "settings", path).items():
        _check_name(name, "setting", path)
        spec = dict(spec)
        meta = {k: spec.pop(k) for k in SETTING_KEYS if k in spec}
        recon = meta.get("reconstruction", "enhanced")
        if recon not in variants:
            raise InputError(path, f"[settings.{name}] reconstruction {recon!r} is not defined "
                                   f"([reconstructions.{recon}])")
        method = meta.get("method", "stylize")
        if method not in METHODS:
            raise InputError(path, f"[settings.{name}] method must be one of {', '.join(METHODS)}")
        for key, known in (("scenes", scenes), ("paintings", paintings)):
            for item in meta.get(key, []):
                if item not in known:
                    raise InputError(path, f"[settings.{name}] {key}: {item!r} is not in [{key}]")
        for s in meta.get("seeds", []):
            if s not in seeds:
                raise InputError(path, f"[settings.{name}] seeds: {s} is not in the grid's seeds")
        settings[name] = {"reconstruction": recon, "method": method, "flags": _flags(spec, f"[settings.{name}]"),
                          "options": spec, "scenes": meta.get("scenes", list(scenes)),
                          "paintings": meta.get("paintings", list(paintings)), "seeds": meta.get("seeds", seeds),
                          "label": meta.get("label", name)}
    if not settings:
        settings["default"] = {"reconstruction": "enhanced", "method": "stylize", "flags": [], "options": {},
                               "scenes": list(scenes), "paintings": list(paintings), "seeds": seeds,
                               "label": "default"}

    groups = []
    for name, spec in _table(doc, "groups", path).items():
        _check_name(name, "group", path)  # it names the group's plot and sheets, and links to them
        if not isinstance(spec, dict):
            raise InputError(path, f"[groups.{name}] must be a table")
        extra = sorted(set(spec) - set(GROUP_KEYS))
        if extra:
            raise InputError(path, f"[groups.{name}]: unknown key {extra[0]!r} ({', '.join(GROUP_KEYS)})")
        for s in spec.get("settings", []):
            if s not in settings:
                raise InputError(path, f"[groups.{name}] settings: {s!r} is not in [settings]")
        expect = []
        for e in spec.get("expect", []):
            if not (isinstance(e, list) and len(e) == 4 and e[1] in EXPECT_OPS and e[0] in settings
                    and e[2] in settings):
                raise InputError(path, f"[groups.{name}] expect: {e!r} is not [setting, \"<\" or \">\", setting, "
                                       f"metric]")
            expect.append(tuple(e))
        groups.append(Group(name=name, title=spec.get("title", name), settings=list(spec.get("settings", [])),
                            metrics=list(spec.get("metrics", [])), expect=expect,
                            paintings=spec.get("paintings"), about=spec.get("about", "")))

    jobs: list[Job] = []
    seen: set[str] = set()
    for scene, sspec in scenes.items():
        if "photos" in sspec:
            jobs.append(Job(id=f"sfm/{scene}", kind="sfm",
                            spec={"scene": scene, "photos": sspec["photos"], "flags": sspec["sfm_flags"]}))
    for name, st in settings.items():
        for scene in st["scenes"]:
            sspec = scenes[scene]
            scene_dep = (f"sfm/{scene}",) if "photos" in sspec else ()
            for seed in st["seeds"]:
                variant = st["reconstruction"]
                rflags = recon_base + variants[variant] + ["--seed", str(seed)]
                rid = f"reconstruct/{scene}-{variant}-seed{seed}-{_short_hash(rflags)}"
                if rid not in seen:
                    seen.add(rid)
                    jobs.append(Job(id=rid, kind="reconstruct", deps=scene_dep,
                                    spec={"scene": scene, "data": sspec.get("data"), "variant": variant,
                                          "seed": seed, "flags": rflags}))
                for painting in st["paintings"]:
                    sflags = stylize_base + st["flags"] + ["--seed", str(seed)]
                    jobs.append(Job(
                        id=f"cell/{scene}/{name}/{painting}/seed{seed}", kind="cell", deps=scene_dep + (rid,),
                        spec={"scene": scene, "data": sspec.get("data"), "setting": name, "painting": painting,
                              "painting_path": str(paintings[painting]), "seed": seed, "method": st["method"],
                              "reconstruction": variant, "recon_job": rid, "flags": sflags,
                              "options": st["options"]}))
    # Cells run in the order the file lists settings: put the settings that matter most first, and an interrupted
    # grid has the important rows.
    return Grid(path=path, title=doc.get("title", path.stem), intro=doc.get("intro", ""),
                discussion=doc.get("discussion", ""), seeds=seeds, scenes=scenes, paintings=paintings,
                settings=settings, groups=groups, jobs=jobs, sheet_views=int(doc.get("sheet_views", 3)))


def with_inputs(grid: Grid) -> list[Job]:
    """The grid's jobs with ``inputs``: the fingerprint (training/scene/fingerprint.py) of the scene each reads (a
    dataset's cameras, or the photos SfM reads) and of a cell's painting. A recorded job whose inputs differ runs
    again, though its file names are the same."""
    from dataclasses import replace

    from training.scene.fingerprint import dataset_fingerprint, file_sha256, photos_fingerprint
    from training.scene.sfm import list_photos

    scenes = {name: ({"dataset": dataset_fingerprint(s["data"])} if "data" in s else
                     {"photos": photos_fingerprint(list_photos(Path(s["photos"])))})
              for name, s in grid.scenes.items()}
    paintings = {name: file_sha256(p) for name, p in grid.paintings.items()}
    out = []
    for job in grid.jobs:
        inputs = dict(scenes[job.spec["scene"]])
        if job.kind == "cell":
            inputs["painting"] = paintings[job.spec["painting"]]
        out.append(replace(job, inputs=inputs))
    return out


def job_dir(out: Path, job: Job | str) -> Path:
    """Where a job keeps its files: OUT/<kind>/<rest of the id> (ids are made of checked names)."""
    return Path(out) / (job.id if isinstance(job, Job) else job)
