"""Imports run one way: core, scene and model at the bottom, raster above them, the trainers above that, the
evaluation (training/evaluate) above the trainers, the app on top. The test reads every module's imports (those
inside functions too) and fails on one that goes the wrong way."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# training packages, bottom to top: a package may import its own modules and those of lower rank
TRAINING_RANKS = {"core": 0, "scene": 1, "model": 2, "raster": 3, "reconstruct": 4, "stylize": 5, "evaluate": 6}
GUI_MODULES = ("moderngl", "glfw", "imgui_bundle", "OpenGL", "glcontext")
# renderer_gl may read these torch-free constant modules and nothing else of the engine: one source of defaults
RENDERER_MAY_IMPORT = ("training.raster.constants", "training.model.sh_constants")


def modules(top: str) -> list[Path]:
    return sorted(p for p in (ROOT / top).rglob("*.py") if "__pycache__" not in p.parts)


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file, relative ones resolved."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            found.append((node.lineno, name))
            # "from training.stylize import defaults" names a module too
            found += [(node.lineno, f"{name}.{alias.name}") for alias in node.names]
    return found


def is_under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def violations() -> list[str]:
    out = []
    for path in modules("training"):
        rel = path.relative_to(ROOT)
        own = rel.parts[1] if len(rel.parts) > 2 else None  # training/<package>/module.py
        for line, name in imports_of(path):
            where = f"{rel}:{line} imports {name}"
            if any(is_under(name, top) for top in ("app", "assets", "renderer_gl")):
                out.append(f"{where}: the engine imports nothing above it")
            if any(is_under(name, gui) for gui in GUI_MODULES):
                out.append(f"{where}: the engine imports no GL or window code")
            parts = name.split(".")
            if parts[0] == "training" and len(parts) > 1 and parts[1] in TRAINING_RANKS and own in TRAINING_RANKS:
                if TRAINING_RANKS[parts[1]] > TRAINING_RANKS[own]:
                    out.append(f"{where}: {own} is below {parts[1]}")
                if is_under(name, "training.raster.reference") and own != "raster":
                    out.append(f"{where}: the trainers take nothing from the test reference")
    for path in modules("renderer_gl"):
        rel = path.relative_to(ROOT)
        for line, name in imports_of(path):
            where = f"{rel}:{line} imports {name}"
            if is_under(name, "torch") or any(is_under(name, w) for w in ("glfw", "imgui_bundle", "app", "assets")):
                out.append(f"{where}: renderer_gl takes numpy arrays and a framebuffer, nothing else")
            if is_under(name, "training") and not any(is_under(name, m) or m.startswith(name + ".")
                                                       for m in RENDERER_MAY_IMPORT) and name != "training":
                out.append(f"{where}: renderer_gl may read only {', '.join(RENDERER_MAY_IMPORT)}")
    for path in modules("assets"):
        rel = path.relative_to(ROOT)
        for line, name in imports_of(path):
            if any(is_under(name, top) for top in ("app", "renderer_gl")):
                out.append(f"{rel}:{line} imports {name}: assets are below the app")
    return out


def test_imports_run_one_way():
    found = violations()
    assert not found, "\n".join(found)


def test_the_checker_sees_a_wrong_way_import(tmp_path, monkeypatch):
    """The walk itself works: an upward import planted in a copy of the tree is reported."""
    import shutil

    for top in ("training", "renderer_gl", "assets"):
        shutil.copytree(ROOT / top, tmp_path / top, ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "training" / "scene" / "bad.py").write_text(
        "def f():\n    from training.stylize.trainer import Stylizer\n    import moderngl\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    found = violations()
    assert any("bad.py:2 imports training.stylize.trainer: scene is below stylize" in v for v in found), found
    assert any("bad.py:3 imports moderngl" in v for v in found), found


@pytest.mark.parametrize("module", ["training.stylize.defaults", "training.raster.constants",
                                    "training.model.sh_constants", "renderer_gl"])
def test_light_modules_load_without_torch(module):
    """The CLI's help text and the renderer read these; loading them must not load torch."""
    if not (ROOT / (module.replace(".", "/") + ".py")).exists() and not (ROOT / module).is_dir():
        pytest.skip(f"{module} is not in this tree")
    code = f"import sys, {module}; print('torch' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"
