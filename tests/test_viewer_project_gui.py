"""Projects saved and opened through the real window (File > Save project, Ctrl+S, a project dropped on the window
or named on the command line) on GLFW's null platform: what a project holds survives a save, and a project the
viewer cannot apply is one line in the window while the session goes on. `splatstyler export --project` bakes what
was saved."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
import torch

from app.project import FileRef, ModelEntry, Project, save_project
from tests.viewer_harness import PRELUDE, run_gui
from training.model.colour_edit import ColourAdjustment, ColourEdits
from training.model.gaussians import Gaussians
from training.model.ply_io import write_ply

pytestmark = pytest.mark.slow


@pytest.fixture(autouse=True)
def null_platform(monkeypatch):
    monkeypatch.setenv("SPLATSTYLER_VIEWER_PLATFORM", "null")


def write_model(path, n=150, seed=0):
    g = torch.Generator().manual_seed(seed)
    write_ply(path, Gaussians(torch.randn(n, 3, generator=g), torch.randn(n, 3, generator=g) - 3,
                              torch.randn(n, 4, generator=g), torch.randn(n, generator=g),
                              torch.randn(n, 1, 3, generator=g), torch.randn(n, 3, 3, generator=g), 1))


def test_ctrl_s_keeps_the_embedded_model_of_an_opened_project(tmp_path):
    """A project that carries its model inside, opened and saved again with Ctrl+S, still carries it: it opens
    on a machine that has neither the model file nor the first session's output folder."""
    write_model(tmp_path / "m.ply")
    kept = np.arange(0, 150, 3)
    project = save_project(tmp_path / "p.splatproj", Project([ModelEntry(FileRef(tmp_path / "m.ply"), "m",
                                                                         kept=kept)]), embed=True)
    (tmp_path / "m.ply").unlink()
    first = run_gui(PRELUDE + f"""
from imgui_bundle import imgui
app = ViewerApp(Paths(out=str(OUT / "a")), project={str(project)!r})

def test(ctx):
    wait(ctx, lambda: app.document.editor is not None, 60, "the project's model")
    ed = app.document.editor
    ed.select(np.arange(ed.count) < 10)
    ed.delete()
    found["count"] = ed.count
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.s)
    ctx.yield_(2)

run(app, test)
found["project"] = app.ui.project.path
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert first["error"] == "", first["error"]
    assert first["project"] == str(project) and first["count"] == len(kept) - 10
    assert any(name.startswith("models/") for name in zipfile.ZipFile(project).namelist())
    import shutil

    shutil.rmtree(tmp_path / "a")  # the first session's output folder (where it unpacked the model) is gone too
    second = run_gui(PRELUDE + f"""
app = ViewerApp(Paths(out=str(OUT / "b")))

def test(ctx):
    app.on_drop(None, [{str(project)!r}])
    wait(ctx, lambda: app.document.editor is not None or app.ui.messages.error, 60, "the project's model")
    found["count"] = app.document.editor.count if app.document.editor is not None else 0
    found["messages"] = list(app.ui.messages.lines)

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert second["error"] == "", (second["error"], second["messages"])
    assert second["count"] == first["count"]


def test_a_project_records_the_model_as_opened_not_as_it_is_when_saved(tmp_path, capsys):
    """The model file is rewritten after it was opened (a reconstruction writing to the same folder): the project
    saved afterwards pairs the edits with the model they were made on, so `export --project` refuses the rewritten
    file in one line instead of applying the edits to rows they were not made on."""
    from app.cli import main

    model = tmp_path / "m.ply"
    write_model(model)
    out = run_gui(PRELUDE + f"""
from training.model.ply_io import read_ply, write_ply
app = ViewerApp(Paths(model={str(model)!r}, out=str(OUT / "out")))

def test(ctx):
    ed = app.document.editor
    ed.select(np.arange(ed.count) % 4 == 0)
    ed.delete()
    write_ply({str(model)!r}, read_ply({str(model)!r}).subset(__import__("torch").arange(149, -1, -1)))
    ctx.set_ref("##MainMenuBar")
    ctx.menu_click("File/Save project")
    ctx.yield_(2)

run(app, test)
found["project"] = app.ui.project.path
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert out["error"] == "", out["error"]
    code = main(["export", "--project", out["project"], "-o", str(tmp_path / "baked.ply")])
    err = capsys.readouterr().err
    assert code == 2 and not (tmp_path / "baked.ply").exists()
    assert len(err.strip().splitlines()) == 1 and str(model) in err and "changed since" in err


def test_a_camera_path_over_the_frame_limit_is_one_line_and_the_window_goes_on(tmp_path):
    """A hand-edited project asking for a 4000 s path at 30 fps (120,000 frames; a path file may hold 100,000):
    refused in one line naming the file, the window keeps drawing frames and holds no path."""
    import json

    key = {"world_to_camera": np.eye(4).tolist(), "fx": 100.0, "fy": 100.0, "cx": 32.0, "cy": 24.0,
           "width": 64, "height": 48}
    far = dict(key, world_to_camera=[[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    path = tmp_path / "long.splatproj"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("project.json", json.dumps({"version": 1, "models": [], "camera_path": {
            "duration": 4000.0, "fps": 30, "keyframes": [key, far]}}))
    found = run_gui(PRELUDE + f"""
app = ViewerApp(Paths(out=str(OUT / "out")))

def test(ctx):
    app.on_drop(None, [{str(path)!r}])
    ctx.yield_(3)
    frames = app.frames
    t0 = time.time()
    settle(ctx, 1.0)
    found["frames_in_a_second"] = app.frames - frames
    found["seconds"] = time.time() - t0
    found["keys"] = len(app.document.camera_path.keyframes)

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert found["error"].startswith(f"{path}: ") and "\n" not in found["error"], found["error"]
    assert "100000" in found["error"] and found["keys"] == 0
    assert found["frames_in_a_second"] >= 3 and found["seconds"] < 5


def test_colour_regions_that_do_not_fit_the_model_are_one_line_and_the_project_is_kept(tmp_path):
    """A project whose colour regions have another length than its model's rows: one line when it opens (the edits
    are not applied to rows they were not made for), no error on every frame, and Save keeps the project's entry
    as it was."""
    from app.project import open_project

    write_model(tmp_path / "m.ply")
    region = np.zeros(100, bool)
    region[:50] = True
    path = save_project(tmp_path / "p.splatproj", Project([ModelEntry(
        FileRef(tmp_path / "m.ply"), "m", colour=ColourEdits([(region, ColourAdjustment(brightness=0.3))]))]))
    found = run_gui(PRELUDE + f"""
app = ViewerApp(Paths(out=str(OUT / "out")))

def test(ctx):
    app.on_drop(None, [{str(path)!r}])
    settle(ctx, 1.0)
    found["messages"] = list(app.ui.messages.lines)
    found["error_now"] = app.ui.messages.error
    ctx.set_ref("##MainMenuBar")
    ctx.menu_click("File/Save project")
    ctx.yield_(2)

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert found["error_now"] == "" and found["error"] == "", found["messages"]
    lines = [m for m in found["messages"] if "colour" in m and "100" in m and "150" in m]
    assert len(lines) == 1 and str(tmp_path / "m.ply") in lines[0], found["messages"]
    again, _ = open_project(path)
    assert len(again.models) == 1
    (saved_region, adjustment), = again.models[0].colour.adjustments
    assert np.array_equal(saved_region, region) and adjustment.brightness == pytest.approx(0.3)


def test_save_project_as_asks_for_the_name_and_ctrl_s_then_saves_there(tmp_path):
    """File > Save project as: the system's save dialog (asked to confirm before replacing a file) names the file,
    the project is written there, and Ctrl+S saves there from then on (nothing is written to the output folder)."""
    from app.project import open_project
    from tests.viewer_harness import file_dialog_answering

    write_model(tmp_path / "m.ply")
    chosen = tmp_path / "chosen" / "mine.splatproj"
    chosen.parent.mkdir()
    found = run_gui(PRELUDE + f"""
from imgui_bundle import imgui
app = ViewerApp(Paths(model={str(tmp_path / "m.ply")!r}, out=str(OUT / "out")))

def test(ctx):
    wait(ctx, lambda: app.document.editor is not None, 60, "the model")
    ctx.set_ref("##MainMenuBar")
    ctx.menu_click("File/Save project as...")
    ctx.yield_(2)
    found["after_save_as"] = app.ui.project.path
    ed = app.document.editor
    ed.select(np.arange(ed.count) < 10)
    ed.delete()
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.s)
    ctx.yield_(2)
    found["count"] = ed.count

run(app, test)
found["project"] = app.ui.project.path
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path, env=file_dialog_answering(tmp_path / "dialog", chosen))
    assert found["error"] == "", found["error"]
    assert found["after_save_as"] == found["project"] == str(chosen)
    asked = (tmp_path / "dialog" / "dialog_calls.txt").read_text().splitlines()  # the one call's arguments
    assert "--save" in asked and "--confirm-overwrite" in asked and "Save project as" in asked
    saved, _ = open_project(chosen)
    assert len(saved.models[0].kept) == found["count"] == 140  # Ctrl+S wrote the deletion there
    assert not list((tmp_path / "out").glob("*.splatproj"))


def test_quit_with_unsaved_edits_asks_first_and_a_closed_window_leaves_them_to_recover(tmp_path):
    """Unsaved edits put "*" in the title; Ctrl+Q asks Save / Discard / Cancel in a modal, and Cancel keeps the
    window going with the edits. A close nobody is asked about (what SIGTERM does) keeps them in the recovery
    project, which the next start offers: Open brings the edits back, unsaved, into the next window."""
    write_model(tmp_path / "m.ply")
    first = run_gui(PRELUDE + f"""
from imgui_bundle import hello_imgui, imgui
app = ViewerApp(Paths(model={str(tmp_path / "m.ply")!r}, out=str(OUT / "out")))

def test(ctx):
    wait(ctx, lambda: app.document.editor is not None, 60, "the model")
    ctx.yield_(2)
    found["title before"] = app.ui.window.title
    ed = app.document.editor
    ed.select(np.arange(ed.count) < 10)
    app.document.delete()
    ctx.yield_(3)
    found["title after"] = app.ui.window.title
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.q)
    ctx.yield_(3)
    found["asked"] = [q.title for q in app.ui.questions]
    found["modal"] = ctx.item_exists("//Unsaved edits/Cancel") and ctx.item_exists("//Unsaved edits/Discard")
    ctx.set_ref("//Unsaved edits")
    ctx.item_click("Cancel")
    frames = app.frames
    ctx.yield_(10)
    found["after cancel"] = dict(questions=len(app.ui.questions), exit=hello_imgui.get_runner_params().app_shall_exit,
                                 frames=app.frames - frames, count=app.document.editor.count)
    found["close button"] = hello_imgui.get_runner_params().callbacks.confirm_exit()
    ctx.yield_(3)
    found["asked again"] = [q.title for q in app.ui.questions]
    ctx.set_ref("//Unsaved edits")
    ctx.item_click("Cancel")
    ctx.yield_(3)
    # returning closes the window without a question, as SIGTERM and Ctrl-C do

run(app, test)
recovery = Path(os.environ["XDG_CONFIG_HOME"]) / "splatstyler" / "recovery"
found["recovery"] = sorted(p.name for p in recovery.iterdir())
found["closed"] = app.closed
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert first["title before"] == "splatstyler - m.ply" and first["title after"] == "splatstyler - m.ply *"
    assert first["asked"] == ["Unsaved edits"] and first["modal"]
    assert first["after cancel"] == {"questions": 0, "exit": False, "frames": first["after cancel"]["frames"],
                                     "count": 140} and first["after cancel"]["frames"] >= 5
    assert first["close button"] is False and first["asked again"] == ["Unsaved edits"]
    assert first["closed"] and [n.rsplit(".", 1)[1] for n in first["recovery"]] == ["json", "splatproj"]

    second = run_gui(PRELUDE + f"""
app = ViewerApp(Paths(out=str(OUT / "out2")))

def test(ctx):
    wait(ctx, lambda: app.ui.questions, 60, "the offer")
    found["offer"] = app.ui.questions[0].text
    ctx.yield_(3)
    ctx.set_ref("//Recover unsaved edits")
    ctx.item_click("Open")
    wait(ctx, lambda: app.document.editor is not None, 60, "the recovered edits")
    ctx.yield_(3)
    found["count"] = app.document.editor.count
    found["title"] = app.ui.window.title
    found["project"] = app.ui.project.path

run(app, test)
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert "closed on" in second["offer"] and "m.ply" in second["offer"]
    assert second["count"] == 140 and second["title"].endswith(" *") and second["project"] == ""
