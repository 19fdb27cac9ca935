"""Imports run one way: core, scene and model at the bottom, raster above them, the trainers above that, the
evaluation (training/evaluate) above the trainers, the app on top. The test reads every module's imports (those
inside functions too, and those made with ``importlib.import_module``) and fails on one that goes the wrong way. A
trainer's checkpoint is its own (the file format is training/core's), and the pose maths has one home
(training/scene/pose.py).

Within the app: no module imports another in a circle (an import inside a function or through importlib counts as
much as one at the top, so none can be there to dodge a circle, and an importlib name the test cannot read is
refused); the viewer's window (app/viewer/app.py) is its top, imported by nothing of the viewer; a panel
(app/viewer/panels/*_panel.py, and a panel lives nowhere else) is a leaf, imported only by the layout, and nothing in
panels/ imports a panel; only app/cli.py imports the commands, and nothing imports app/cli.py but ``python -m app``
(app/__main__.py): the CLI is a front-end, not a library; the edited document and what it is made of (app/viewer/edit),
the live session (app/viewer/live) and the UI state import no UI and no GL; a module's ``_private`` names are used
only inside it; and nothing in the app but the live session (app/viewer/live/session.py) reaches a trainer (no
``.trainer``): the session is the one door into a trainer, typed commands in, the trainer's status out."""

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
# renderer_gl may read these torch-free modules and nothing else of the engine: one source of defaults, one camera and
# its pose maths
RENDERER_MAY_IMPORT = ("training.raster.constants", "training.model.sh_constants", "training.scene.camera",
                       "training.scene.pose")


def modules(top: str) -> list[Path]:
    return sorted(p for p in (ROOT / top).rglob("*.py") if "__pycache__" not in p.parts)


UNREADABLE = "?"  # an importlib import whose module name is computed where the test cannot read it


def importlib_target(node: ast.AST) -> str | None:
    """The module an ``importlib.import_module(...)`` (or ``import_module``, ``__import__``) call imports: its name,
    ``prefix.*`` for a name built on a written prefix (f"app.commands.{name}": any module there), UNREADABLE for
    one computed elsewhere; None for any other node."""
    if not isinstance(node, ast.Call) or not node.args:
        return None
    f = node.func
    if not ((isinstance(f, ast.Attribute) and f.attr == "import_module")
            or (isinstance(f, ast.Name) and f.id in ("import_module", "__import__"))):
        return None
    arg = node.args[0]
    if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
        return arg.value
    if isinstance(arg, ast.JoinedStr) and arg.values and isinstance(arg.values[0], ast.Constant):
        return arg.values[0].value.rstrip(".") + ".*"
    return UNREADABLE


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file, relative ones resolved, importlib's included."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    found = []
    for node in ast.walk(tree):
        if (target := importlib_target(node)) is not None:
            found.append((node.lineno, target))
        elif isinstance(node, ast.Import):
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
                if len(parts) > 2 and parts[2] == "checkpoint" and parts[1] not in (own, "core"):
                    out.append(f"{where}: a trainer's checkpoint is its own (the file format is "
                               "training/core/checkpoint.py)")
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


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def project_modules() -> dict[str, Path]:
    return {module_name(p): p for top in ("app", "training", "renderer_gl", "assets") for p in modules(top)}


def resolve(name: str, known: dict[str, Path]) -> str | None:
    """The project module an imported name is (``from a.b import c``: a.b.c when it is a module, else a.b)."""
    while name:
        if name in known:
            return name
        name = name.rpartition(".")[0]
    return None


def resolved(imported: str, known: dict[str, Path]) -> set[str]:
    """The project modules an imported name is (every one under ``prefix`` for ``prefix.*``)."""
    if imported.endswith(".*"):
        return {m for m in known if is_under(m, imported[:-2]) and m != imported[:-2]}
    found = resolve(imported, known)
    return {found} if found else set()


def app_graph(known: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the app modules it imports (anywhere in the file, through importlib too)."""
    graph = {}
    for name, path in known.items():
        if is_under(name, "app"):
            found = set().union(*(resolved(imported, known) for _, imported in imports_of(path)))
            graph[name] = {m for m in found if is_under(m, "app") and m != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles (strongly connected components of more than one module), each as a path around it."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


PANEL = "_panel"
PANELS = "app.viewer.panels"  # the panels' package: every panel is here, and nothing here imports a panel
NO_UI = ("app.viewer.edit", "app.viewer.live", "app.viewer.state")  # packages and modules without UI or GL


def private_uses(path: Path, known: dict[str, Path]) -> list[tuple[int, str]]:
    """(line, module._name) for each use of another module's private name: imported from it, or read off it."""
    tree = ast.parse(path.read_text(), filename=str(path))
    module_aliases, out = {}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and not node.level:
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__") and resolve(node.module, known):
                    out.append((node.lineno, f"{node.module}.{alias.name}"))
                if f"{node.module}.{alias.name}" in known:
                    module_aliases[alias.asname or alias.name] = f"{node.module}.{alias.name}"
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.asname and alias.name in known:
                    module_aliases[alias.asname] = alias.name
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in module_aliases
                and node.attr.startswith("_") and not node.attr.startswith("__")):
            out.append((node.lineno, f"{module_aliases[node.value.id]}.{node.attr}"))
    return out


def cli_imports(known: dict[str, Path]) -> list[str]:
    """Imports of app.cli (and importlib names the test cannot read) anywhere in app/, training/ and renderer_gl/
    but app/__main__.py."""
    out = []
    for name, path in sorted(known.items()):
        if not any(is_under(name, top) for top in ("app", "training", "renderer_gl")) or name == "app.__main__":
            continue
        for line, imported in imports_of(path):
            if imported == UNREADABLE:
                out.append(f"{name}:{line} imports a module by a name computed at run time: the layers cannot be "
                           "checked; import it by name")
            elif "app.cli" in resolved(imported, known):
                out.append(f"{name}:{line} imports app.cli: the CLI is a front-end; call the library function it "
                           "calls")
    return list(dict.fromkeys(out))  # "from app.cli import main" names app.cli twice


def imports_ui(path: Path) -> bool:
    return any(is_under(imported, gui) for _, imported in imports_of(path) for gui in GUI_MODULES + ("renderer_gl",))


def ui_reached(name: str, graph: dict[str, set[str]], known: dict[str, Path]) -> list[tuple[str, list[str]]]:
    """The app modules that import UI or GL and that ``name`` reaches through its imports (those inside functions
    too), each with the path it takes; ``name``'s own UI imports are reported apart."""
    out, seen, queue = [], {name}, [(name, [name])]
    while queue:
        here, via = queue.pop(0)
        for m in sorted(graph.get(here, ())):
            if m in seen:
                continue
            seen.add(m)
            if imports_ui(known[m]):
                out.append((m, via + [m]))
            else:
                queue.append((m, via + [m]))
    return out


ROOMS = ("app.viewer.display", "app.viewer.edit", "app.viewer.live", "app.viewer.panels")


def package_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """The viewer's rooms (ROOMS) as nodes: room -> the rooms its modules import."""
    def room(m: str) -> str | None:
        return next((r for r in ROOMS if is_under(m, r)), None)

    out: dict[str, set[str]] = {r: set() for r in ROOMS}
    for name, imported in graph.items():
        here = room(name)
        if here is not None:
            out[here] |= {r for r in map(room, imported) if r is not None and r != here}
    return out


DOOR = "app.viewer.live.session"  # the one module of the app that holds a running trainer


def trainer_reaches(path: Path) -> list[int]:
    """Lines that read a ``.trainer`` attribute (a session's trainer, or anything's)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    return sorted({node.lineno for node in ast.walk(tree)
                   if isinstance(node, ast.Attribute) and node.attr == "trainer"})


def app_violations() -> list[str]:
    known = project_modules()
    graph = app_graph(known)
    out = [f"import circle: {' -> '.join(c)}" for c in cycles(graph)] + cli_imports(known)
    for name, imported in sorted(graph.items()):
        if name.endswith(PANEL) and not is_under(name, PANELS):
            out.append(f"{name} is a panel outside {PANELS}: the panels live together")
        for m in sorted(imported):
            where = f"{name} imports {m}"
            if m == "app.viewer.app" and is_under(name, "app.viewer"):
                out.append(f"{where}: the window is the viewer's top, nothing of the viewer imports it")
            if m.endswith(PANEL) and is_under(name, PANELS):
                out.append(f"{where}: panels do not import each other")
            elif m.endswith(PANEL) and name != "app.viewer.layout":
                out.append(f"{where}: only the layout puts panels in the window")
            if is_under(m, "app.commands") and name != "app.cli" and not is_under(name, "app.commands"):
                out.append(f"{where}: only app/cli.py imports the commands")
        if any(is_under(name, n) for n in NO_UI):
            for line, imported_name in imports_of(known[name]):
                if any(is_under(imported_name, gui) for gui in GUI_MODULES + ("renderer_gl",)):
                    out.append(f"{name}:{line} imports {imported_name}: the document and its parts, the live "
                               "session and the UI state have no UI")
            for reached, via in ui_reached(name, graph, known):
                out.append(f"{name} reaches {reached} (through {' -> '.join(via)}), which imports UI: the "
                           "document and its parts, the live session and the UI state have no UI, even at one "
                           "remove")
    for cycle in cycles(package_graph(graph)):
        out.append(f"package circle: {' -> '.join(cycle)}: the viewer's rooms import one way")
    for name, path in sorted(known.items()):
        if is_under(name, "app") and name != DOOR:
            out += [f"{name}:{line} reaches .trainer: the live session is the one door into a trainer (read its "
                    "trainer_status(), submit a command)" for line in trainer_reaches(path)]
        if is_under(name, "app"):
            for line, used in private_uses(path, known):
                if resolve(used.rpartition(".")[0], known) != name:
                    out.append(f"{name}:{line} uses {used}: a module's _names are its own")
    return out


# the pose maths has one home, training/scene/pose.py: no other module defines these again
POSE_FUNCTIONS = ("look_at", "orbit", "slerp", "catmull_rom", "matrix_to_quat", "quat_to_matrix", "rotation_to_quat",
                  "quat_to_rotation", "interpolate_camera", "jacobian_limits", "splat_footprints")
POSE_MODULE = "training/scene/pose.py"


def pose_copies() -> list[str]:
    out = []
    for top in ("app", "training", "renderer_gl", "assets"):
        for path in modules(top):
            rel = path.relative_to(ROOT)
            if rel.as_posix() == POSE_MODULE:
                continue
            for node in ast.parse(path.read_text(), filename=str(path)).body:  # functions, not a class's methods
                if isinstance(node, ast.FunctionDef) and node.name.lstrip("_") in POSE_FUNCTIONS:
                    out.append(f"{rel}:{node.lineno} defines {node.name}: the pose maths is {POSE_MODULE}'s")
    return out


def test_the_pose_maths_has_one_home():
    found = pose_copies()
    assert not found, "\n".join(found)


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
    (tmp_path / "training" / "stylize" / "sideways.py").write_text(
        "from training.reconstruct.checkpoint import load_checkpoint\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    found = violations()
    assert any("bad.py:2 imports training.stylize.trainer: scene is below stylize" in v for v in found), found
    assert any("bad.py:3 imports moderngl" in v for v in found), found
    assert any("sideways.py:1 imports training.reconstruct.checkpoint: a trainer's checkpoint" in v for v in found)


def test_the_app_has_no_circles_and_its_panels_are_leaves():
    found = app_violations()
    assert not found, "\n".join(found)


def test_the_app_checker_sees_a_circle_a_panel_import_and_a_private_name(tmp_path, monkeypatch):
    """Planted in a copy of the tree: a circle closed by an import inside a function, one closed through importlib
    with a name built on a prefix, a panel that imports another, a panel outside the panels' package, a document and
    a live-session module that import UI, another module's private name, the CLI imported as a library, importlib
    with a name the checker cannot read, and a panel that reaches into the session's trainer; each is reported."""
    import shutil

    for top in ("app", "training", "renderer_gl", "assets"):
        shutil.copytree(ROOT / top, tmp_path / top, ignore=shutil.ignore_patterns("__pycache__"))
    viewer = tmp_path / "app" / "viewer"
    editor = viewer / "edit" / "editor.py"
    editor.write_text(editor.read_text() + "\n\ndef dodge():\n    from app.viewer.edit.document import Document\n")
    (viewer / "panels" / "colour_panel.py").write_text((viewer / "panels" / "colour_panel.py").read_text()
                                                       + "\nfrom app.viewer.panels.style_panel import heatmap\n")
    (viewer / "edit" / "document.py").write_text((viewer / "edit" / "document.py").read_text()
                                                 + "\nfrom imgui_bundle import imgui\n")
    (viewer / "live" / "runs.py").write_text((viewer / "live" / "runs.py").read_text() + "\nimport renderer_gl\n")
    (viewer / "stray_panel.py").write_text("")
    (viewer / "files.py").write_text((viewer / "files.py").read_text()
                                     + "\nfrom app.viewer.live.session import _one_line\n")
    (viewer / "panels" / "gizmo_panel.py").write_text((viewer / "panels" / "gizmo_panel.py").read_text()
                                                      + "\n\ndef peek(session):\n    return session.trainer.config\n")
    evaluate = tmp_path / "app" / "evaluate"
    (evaluate / "grid.py").write_text((evaluate / "grid.py").read_text() + "\n\ndef hidden(name):\n"
                                      "    import importlib\n    return importlib.import_module(f'app.commands.{name}')"
                                      "\n\n\ndef run():\n    from app.cli import main\n\n\n"
                                      "def unseen(name):\n    return importlib.import_module(name)\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    found = app_violations()
    assert any(v.startswith("import circle:") and "app.evaluate.grid" in v and "app.commands.eval" in v
               for v in found), found
    assert any(v.startswith("app.evaluate.grid:") and "imports app.cli: the CLI is a front-end" in v for v in found)
    assert any(v.startswith("app.evaluate.grid:") and "by a name computed at run time" in v for v in found), found
    assert any(v.startswith("import circle:") and "app.viewer.edit.editor" in v and "app.viewer.edit.document" in v
               for v in found), found
    assert any("colour_panel imports app.viewer.panels.style_panel: panels do not import each other" in v
               for v in found), found
    assert any("app.viewer.stray_panel is a panel outside app.viewer.panels" in v for v in found), found
    assert any("app.viewer.edit.document:" in v and "imgui_bundle" in v for v in found), found
    assert any("app.viewer.live.runs:" in v and "imports renderer_gl" in v for v in found), found
    assert any("app.viewer.files:" in v and "uses app.viewer.live.session._one_line" in v for v in found), found
    assert any(v.startswith("app.viewer.panels.gizmo_panel:") and "reaches .trainer" in v for v in found), found


@pytest.mark.parametrize("module", ["training.stylize.defaults", "training.raster.constants",
                                    "training.reconstruct.config", "training.model.sh_constants",
                                    "training.scene.camera", "training.scene.pose", "renderer_gl"])
def test_light_modules_load_without_torch(module):
    """The CLI's help text and the renderer read these; loading them must not load torch."""
    if not (ROOT / (module.replace(".", "/") + ".py")).exists() and not (ROOT / module).is_dir():
        pytest.skip(f"{module} is not in this tree")
    code = f"import sys, {module}; print('torch' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"


def test_importing_the_document_and_the_live_session_loads_no_ui():
    """What the rooms without UI promise, checked by importing them: every module of app/viewer/edit and
    app/viewer/live, and the UI state, in a fresh interpreter, leave imgui_bundle, glfw and moderngl unloaded."""
    names = [".".join(p.relative_to(ROOT).with_suffix("").parts) for top in ("app/viewer/edit", "app/viewer/live")
             for p in modules(top)] + ["app.viewer.state"]
    names = [n.removesuffix(".__init__") for n in names]
    code = ("import importlib, sys\n"
            f"for name in {names!r}:\n"
            "    importlib.import_module(name)\n"
            f"print(sorted(m for m in {GUI_MODULES!r} if m in sys.modules))\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]", proc.stdout


def documented_layers() -> list[str]:
    """The layer list of docs/architecture.md (top first): the first word of each line of the block after the
    ``layers`` marker."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    block = text.split("<!-- layers", 1)[1].split("```", 2)[1]
    return [line.split()[0] for line in block.strip().splitlines() if line.strip()]


def test_the_architecture_doc_is_the_import_order():
    """docs/architecture.md draws the layers as an ordered list; every import of every module (those inside
    functions too) goes to its own layer or one under it, and the list names every package of the engine."""
    layers = documented_layers()
    assert set(layers) >= {"app", "renderer_gl"} | {f"training.{p}" for p in TRAINING_RANKS}, layers

    def layer_of(module: str) -> int | None:
        found = [i for i, name in enumerate(layers) if is_under(module, name)]
        return max(found, key=lambda i: len(layers[i])) if found else None

    known = project_modules()
    out = []
    for name, path in sorted(known.items()):
        mine = layer_of(name)
        if mine is None:
            continue
        for line, imported in imports_of(path):
            for target in resolved(imported, known):
                theirs = layer_of(target)
                if theirs is not None and theirs < mine:
                    out.append(f"{path.relative_to(ROOT)}:{line} imports {target}: {layers[mine]} is drawn under "
                               f"{layers[theirs]}")
    assert not out, "\n".join(out)
