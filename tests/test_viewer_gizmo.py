"""The gizmo and several models in one scene, driven through the real application on GLFW's null platform (imgui's
Test Engine moves the mouse and presses the keys): a gizmo drag of the selection, a second model dropped beside the
first, moved, exported as one PLY, saved as a project and baked by `splatstyler export --project`, and a
three-point alignment. The X11 test (test_viewer_gizmo_x11.py) looks at the screen.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.gizmo_scenes import moved_copy, similarity
from tests.viewer_harness import PRELUDE, make_demo_scene, run_gui


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    return make_demo_scene(tmp_path_factory)


def ply_columns(path) -> dict[str, np.ndarray]:
    """Every vertex property of a PLY, read with plyfile (what other tools read)."""
    from plyfile import PlyData

    v = PlyData.read(str(path))["vertex"]
    return {p.name: np.asarray(v[p.name]) for p in v.properties}


def gaussian_columns(g) -> dict[str, np.ndarray]:
    """The standard 3DGS vertex properties of a model (pre-activation; f_rest channel-major)."""
    cols = {}
    for i, axis in enumerate("xyz"):
        cols[axis] = g.means[:, i].numpy()
    for c in range(3):
        cols[f"f_dc_{c}"] = g.sh0[:, 0, c].numpy()
    k = g.shN.shape[1]
    for c in range(3):
        for j in range(k):
            cols[f"f_rest_{c * k + j}"] = g.shN[:, j, c].numpy()
    cols["opacity"] = g.opacity_logits.numpy()
    for i in range(3):
        cols[f"scale_{i}"] = g.log_scales[:, i].numpy()
    for i in range(4):
        cols[f"rot_{i}"] = g.quats[:, i].numpy()
    return cols


def assert_union(path, parts, atol=0.0) -> None:
    """The PLY at ``path`` holds exactly the Gaussians of ``parts``, in order."""
    got = ply_columns(path)
    expected = [gaussian_columns(g) for g in parts]
    assert len(got["x"]) == sum(len(g) for g in parts)
    for name, values in expected[0].items():
        want = np.concatenate([e[name] for e in expected])
        np.testing.assert_allclose(got[name], want, rtol=0, atol=atol, err_msg=name)


def test_three_point_pairs_give_the_similarity_back():
    from app.viewer.edit.align_points import similarity_from_pairs

    m = similarity(37.0, (0.3, -1.0, 0.4), 1.7, (2.0, -0.5, 3.0))
    src = np.array([[0.1, 0.2, 0.3], [1.5, -0.4, 0.2], [-0.3, 0.9, 1.1]])
    dst = src @ m[:3, :3].T + m[:3, 3]
    np.testing.assert_allclose(similarity_from_pairs(src, dst), m, atol=1e-12)
    with pytest.raises(ValueError, match="one line"):
        similarity_from_pairs([[0, 0, 0], [1, 1, 1], [2, 2, 2]], [[0, 0, 0], [1, 0, 0], [2, 0, 0]])


DRAG = """
from imgui_bundle import imgui
from app.viewer.display import gestures

def drag(ctx, start, offset, steps=8):
    ctx.mouse_move_to_pos(imgui.ImVec2(float(start[0]), float(start[1])))
    settle(ctx, 0.3)
    ctx.mouse_down(0)
    for t in np.linspace(0, 1, steps):
        ctx.mouse_move_to_pos(imgui.ImVec2(float(start[0] + offset[0] * t), float(start[1] + offset[1] * t)))
    ctx.mouse_up(0)
    settle(ctx, 0.5)

def on_screen(points):
    return gestures.on_screen(app.ui, np.asarray(points, float).reshape(-1, 3))[0]
"""


@pytest.mark.slow
def test_gizmo_drag_moves_the_selection_by_the_drag_and_undo_restores_it(demo_scene, tmp_path):
    """G, then a drag from the gizmo's centre (ImGuizmo moves in the screen's plane there): the selected Gaussians
    move so that their centre follows the pointer, the others not at all; the drag is one undo step, and undo
    gives back the same arrays bit for bit; the camera did not orbit."""
    _, _, model = demo_scene
    found = run_gui(PRELUDE + DRAG + f"""
app = ViewerApp(Paths(model={str(model)!r}, out=str(OUT / "out")))

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    ed = app.document.editor
    before = {{name: getattr(ed.model, name).copy() for name in ("means", "scales", "quats", "opacities", "sh")}}
    sel = before["means"][:, 0] > np.percentile(before["means"][:, 0], 70)
    ed.select(sel)
    np.save(OUT / "sel.npy", sel)
    ctx.set_ref("")
    ctx.key_press(imgui.Key.g)
    settle(ctx, 0.5)
    found["op"] = app.ui.gizmo.op
    rotation = app.view.camera.rotation.copy()
    centre = on_screen(before["means"][sel].astype(float).mean(axis=0))[0]
    steps = len(ed.undo_stack)
    drag(ctx, centre, (60, 25))
    found["undo_steps"] = len(ed.undo_stack) - steps
    found["camera_turned"] = float(np.abs(app.view.camera.rotation - rotation).max())
    after = {{name: getattr(ed.model, name).copy() for name in before}}
    found["centre_moved_px"] = (on_screen(after["means"][sel].astype(float).mean(axis=0))[0] - centre).tolist()
    np.savez(OUT / "after.npz", **after)
    np.savez(OUT / "before.npz", **before)
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.z)
    settle(ctx, 0.3)
    found["undo_equal"] = all(np.array_equal(getattr(ed.model, n), before[n]) for n in before)
    found["undo_same_dtype"] = all(getattr(ed.model, n).dtype == before[n].dtype for n in before)
    ctx.key_press(imgui.Key.mod_ctrl | imgui.Key.y)
    settle(ctx, 0.3)
    found["redo_equal"] = all(np.array_equal(getattr(ed.model, n), after[n]) for n in after)
    found["shown_version"] = app.ui.edit.shown_version == ed.version
    app.ui.export.path = str(OUT / "moved.ply")
    open_window(ctx, "Edit")
    ctx.item_click("Export")
    app.save_project(str(OUT / "moved.splatproj"))

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert found["error"] == "", found["error"]
    assert found["op"] == "translate"
    assert found["undo_steps"] == 1  # one drag of eight frames: one undo step
    assert found["camera_turned"] == 0.0  # the drag moved the Gaussians, not the camera
    np.testing.assert_allclose(found["centre_moved_px"], [60, 25], atol=1.0)
    sel = np.load(tmp_path / "sel.npy")
    before, after = np.load(tmp_path / "before.npz"), np.load(tmp_path / "after.npz")
    shift = after["means"][sel] - before["means"][sel]
    assert np.linalg.norm(shift.mean(axis=0)) > 0.1
    np.testing.assert_allclose(shift, np.broadcast_to(shift.mean(axis=0), shift.shape), atol=1e-5)  # one shift
    for name in before.files:
        assert np.array_equal(after[name][~sel], before[name][~sel]), name  # the rest untouched
        if name != "means":
            assert np.array_equal(after[name], before[name]), name  # a move changes only centres
    assert found["undo_equal"] and found["undo_same_dtype"] and found["redo_equal"]
    assert found["shown_version"]
    # the project keeps the moved rows as a second entry of the same file with the move's transform: baked, the
    # same Gaussians as the viewer's export (model by model, so compared as sets of rows)
    from app.cli import main

    assert main(["export", "--project", str(tmp_path / "moved.splatproj"), "-o", str(tmp_path / "baked.ply")]) == 0
    exported, baked = ply_columns(tmp_path / "moved.ply"), ply_columns(tmp_path / "baked.ply")
    names = sorted(exported)
    rows = lambda cols: np.stack([cols[n] for n in names], axis=1)  # noqa: E731
    a, b = rows(exported), rows(baked)
    a, b = a[np.lexsort(a.T[::-1])], b[np.lexsort(b.T[::-1])]
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    assert np.allclose(np.sort(exported["x"])[-1], after["means"][:, 0].max(), atol=1e-5)


def test_numbers_typed_in_the_box_fields_are_undo_steps_and_crop_uses_them(demo_scene, tmp_path):
    """The crop box typed in the Edit panel, one number in each field: each number's typing is one undo step (not
    one per digit), Ctrl+Z puts the box back step by step, Ctrl+Y types it again, and Crop uses the box shown."""
    _, _, model = demo_scene
    found = run_gui(PRELUDE + f"""
from imgui_bundle import imgui
app = ViewerApp(Paths(model={str(model)!r}, out=str(OUT / "out")))

def box():
    return [list(map(float, side)) for side in app.ui.edit.box]

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    open_window(ctx, "Edit")
    ed = app.document.editor
    found["start"] = box()
    lo, hi = found["start"]
    steps = len(ed.undo_stack)
    ctx.item_input_value("box min/$$0", round(lo[0] + 0.25 * (hi[0] - lo[0]), 2))
    found["after_min"] = box()
    ctx.item_input_value("box max/$$2", round(hi[2] - 0.25 * (hi[2] - lo[2]), 2))
    found["typed"] = box()
    found["undo_steps"] = len(ed.undo_stack) - steps
    ctx.set_ref("")
    for name, keys in (("undo_1", imgui.Key.z), ("undo_2", imgui.Key.z), ("redo_1", imgui.Key.y),
                       ("redo_2", imgui.Key.y)):
        ctx.key_press(imgui.Key.mod_ctrl | keys)
        settle(ctx, 0.2)
        found[name] = box()
    count = ed.count
    inside = np.all((ed.model.means >= np.array(box()[0])) & (ed.model.means <= np.array(box()[1])), axis=1)
    open_window(ctx, "Edit")
    ctx.item_click("Crop to box")
    found["crop"] = [count, int(inside.sum()), ed.count]

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert found["error"] == "", found["error"]
    start, after_min, typed = (np.array(found[k]) for k in ("start", "after_min", "typed"))
    assert after_min[0, 0] > start[0, 0] + 0.1 and typed[1, 2] < start[1, 2] - 0.1  # the numbers went in
    assert np.array_equal(typed[0], after_min[0]) and np.array_equal(after_min[1], start[1])
    assert found["undo_steps"] == 2  # one step a number, whatever the digits typed
    np.testing.assert_allclose(found["undo_1"], after_min, atol=1e-6)
    np.testing.assert_allclose(found["undo_2"], start, atol=1e-6)
    np.testing.assert_allclose(found["redo_1"], after_min, atol=1e-6)
    np.testing.assert_allclose(found["redo_2"], typed, atol=1e-6)
    before, inside, after = found["crop"]
    assert before > after == inside > 0  # Crop kept what the typed box holds


@pytest.mark.slow
def test_a_second_model_moved_by_the_gizmo_exports_and_bakes_as_one_model(demo_scene, tmp_path):
    """A PLY dropped while a model is open joins the scene; the gizmo moves, turns (30 degrees along its ring) and
    scales it (model 2 as its target), each drag as the pointer went; Export writes one PLY that is model 1 and
    model 2 moved (training/model/transform.py applied to the second file, SH bands turned; read with plyfile); the project saved from the session bakes to the same file with `splatstyler export --project`,
    and opens again in a new session as the same scene."""
    from app.cli import main
    from training.model.ply_io import read_ply
    from training.model.transform import transform_gaussians

    _, _, model = demo_scene
    second = moved_copy(model, similarity(30.0, (0, 1, 0), 0.6, (16.0, 0.0, 2.0)), tmp_path / "second.ply")
    project = tmp_path / "scene.splatproj"
    found = run_gui(PRELUDE + DRAG + f"""
from app.viewer.camera import ViewerCamera
app = ViewerApp(Paths(model={str(model)!r}, out=str(OUT / "out")))

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    n1 = app.document.editor.count
    app.on_drop(None, [{str(second)!r}])
    ctx.yield_(3)
    found["count"] = app.document.editor.count
    found["n1"] = n1
    found["target"] = app.ui.gizmo.target
    means = app.document.editor.model.means.astype(float)
    mid = means.mean(axis=0)
    app.view.camera = ViewerCamera.looking_at(mid + np.array([0.0, -8.0, -40.0]), mid, up=(0.0, -1.0, 0.0))
    app.view.moved()
    ctx.set_ref("")
    ctx.key_press(imgui.Key.g)
    settle(ctx, 0.5)
    rows = np.arange(app.document.editor.count) >= n1
    cam = app.view.camera
    centre = means[rows].mean(axis=0)
    found["centre"] = centre.tolist()
    found["c2w"] = np.c_[cam.rotation, cam.position].tolist()
    found["focal"] = float(cam.camera(*app.ui.window.view_rect[2:]).fy)  # pixels of the view (scale 1 here)
    found["drag_from"] = on_screen(centre)[0].tolist()
    drag(ctx, on_screen(centre)[0], (-40, 30))
    found["after_move"] = app.document.models.parts[-1].transform.tolist()
    ctx.key_press(imgui.Key.t)  # turn: ImGuizmo's outer ring (0.06 of the view's height) turns about the view axis
    settle(ctx, 0.3)
    c = on_screen(app.document.editor.model.means[rows].astype(float).mean(axis=0))[0]
    found["turn_centre"] = app.document.editor.model.means[rows].astype(float).mean(axis=0).tolist()
    radius = 0.06 * app.ui.window.view_rect[3]
    arc = [np.radians(a) for a in np.linspace(-45, -15, 7)]
    ctx.mouse_move_to_pos(imgui.ImVec2(float(c[0] + radius * np.cos(arc[0])), float(c[1] + radius * np.sin(arc[0]))))
    settle(ctx, 0.3)
    ctx.mouse_down(0)
    for a in arc[1:]:
        ctx.mouse_move_to_pos(imgui.ImVec2(float(c[0] + radius * np.cos(a)), float(c[1] + radius * np.sin(a))))
    ctx.mouse_up(0)
    settle(ctx, 0.5)
    found["after_turn"] = app.document.models.parts[-1].transform.tolist()
    found["forward"] = cam.forward.tolist()
    ctx.key_press(imgui.Key.y)  # scale: the handle at the centre scales uniformly
    settle(ctx, 0.3)
    drag(ctx, on_screen(app.document.editor.model.means[rows].astype(float).mean(axis=0))[0], (50, 0))
    found["parts"] = [[p.file, p.transform.tolist()] for p in app.document.models.parts]
    app.ui.export.path = str(OUT / "merged.ply")
    open_window(ctx, "Edit")
    ctx.item_click("Export")
    ctx.yield_(2)
    app.save_project({str(project)!r})
    found["messages"] = app.ui.messages.lines[-6:]

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert found["error"] == "", found["error"]
    n1 = found["n1"]
    assert found["count"] == 2 * n1 and found["target"] == "model:1"
    # the drag's translation, derived here from the camera: 40 px left and 30 down at the centre's depth
    c2w = np.array(found["c2w"])
    depth = float((np.array(found["centre"]) - c2w[:, 3]) @ c2w[:, 2])
    pixel = depth / found["focal"]
    expected_shift = c2w[:, :3] @ np.array([-40 * pixel, 30 * pixel, 0.0])
    moved = [np.array(p[1]) for p in found["parts"] if p[0] == 1]
    assert len(moved) == 4  # the file as added (identity), moved, turned, scaled
    after_move = np.array(found["after_move"])
    np.testing.assert_allclose(after_move[:3, :3], np.eye(3), atol=1e-9)  # a move, no turn or scale
    np.testing.assert_allclose(after_move[:3, 3], expected_shift, rtol=0.03,
                               atol=0.02 * np.linalg.norm(expected_shift))
    # the turn: 30 degrees along the ring, about the view's axis, around the model's centre (which stays)
    turn = np.array(found["after_turn"]) @ np.linalg.inv(after_move)
    angle = np.degrees(np.arccos(np.clip((np.trace(turn[:3, :3]) - 1) / 2, -1, 1)))
    assert abs(angle - 30.0) < 3.0, angle
    w, v = np.linalg.eig(turn[:3, :3])
    axis = np.real(v[:, np.argmin(np.abs(w - 1))])
    assert abs(axis @ np.array(found["forward"])) > 0.97, axis
    centre = np.array(found["turn_centre"])
    np.testing.assert_allclose(turn[:3, :3] @ centre + turn[:3, 3], centre, atol=1e-4)
    # the scale: uniform, about the centre, no further turn
    matrix = moved[-1]
    grow = matrix @ np.linalg.inv(np.array(found["after_turn"]))
    scale = np.linalg.det(grow[:3, :3]) ** (1 / 3)
    assert scale > 1.05  # dragged right: bigger
    np.testing.assert_allclose(grow[:3, :3], scale * np.eye(3), atol=1e-9)
    np.testing.assert_allclose(grow[:3, :3] @ centre + grow[:3, 3], centre, atol=1e-4)
    # the acceptance check: the export is model 1 followed by the second PLY moved by transform.py
    first, other = read_ply(model), read_ply(second)
    assert any("merged.ply" in line for line in found["messages"]), found["messages"]
    assert_union(tmp_path / "merged.ply", [first, transform_gaussians(other, matrix)], atol=2e-5)
    # the project, baked with no display, is the same union
    assert main(["export", "--project", str(project), "-o", str(tmp_path / "baked.ply")]) == 0
    assert_union(tmp_path / "baked.ply", [first, transform_gaussians(other, matrix)], atol=2e-5)

    reopened = run_gui(PRELUDE + f"""
app = ViewerApp(Paths(out=str(OUT / "again")), project={str(project)!r})

def test(ctx):
    wait(ctx, lambda: app.document.editor is not None and app.view.has_model(0), 60, "the project")
    found["count"] = app.document.editor.count
    found["models"] = [f.name for f in app.document.models.files]
    np.save(OUT / "means.npy", app.document.editor.model.means)
    found["undo"] = len(app.document.editor.undo_stack)

run(app, test)
found["error"] = app.ui.messages.error
found["messages"] = app.ui.messages.lines
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path / "again")
    assert reopened["error"] == "", reopened["error"]
    assert reopened["count"] == 2 * n1 and reopened["models"] == ["model", "second"]
    baked = read_ply(tmp_path / "baked.ply").means.numpy()
    np.testing.assert_allclose(np.load(tmp_path / "again" / "means.npy"), baked, atol=1e-6)
    assert reopened["undo"] == 0
    assert not any("not shown" in line for line in reopened["messages"])


@pytest.mark.slow
def test_three_point_alignment_puts_a_moved_copy_back(demo_scene, tmp_path):
    """A copy of the model turned, scaled and shifted by a known similarity is added; three points clicked on the
    copy and the same three on the original (picks: the depth under the cursor) move the copy back onto the
    original: the recovered transform is the known one's inverse, within what picking a surface allows."""
    _, _, model = demo_scene
    known = similarity(12.0, (0.2, 1.0, 0.1), 0.85, (17.0, 1.0, 1.5))
    copy = moved_copy(model, known, tmp_path / "copy.ply")
    found = run_gui(PRELUDE + DRAG + f"""
from app.viewer.camera import ViewerCamera
app = ViewerApp(Paths(model={str(model)!r}, out=str(OUT / "out")))
known = np.array({known.tolist()!r})

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    n1 = app.document.editor.count
    open_window(ctx, "Edit")
    ctx.item_input_value("##add model path", {str(copy)!r})
    ctx.item_click("Add model to scene")
    found["added"] = app.document.editor.count
    means = app.document.editor.model.means.astype(float)
    mid = means.mean(axis=0)
    app.view.camera = ViewerCamera.looking_at(mid + np.array([0.0, -6.0, -34.0]), mid, up=(0.0, -1.0, 0.0))
    app.view.moved()
    settle(ctx, 0.5)
    open_window(ctx, "Edit")
    ctx.item_click("Align copy by 3 point pairs")
    found["aligning"] = app.ui.gizmo.align.active
    # three well-spread Gaussians of the original, opaque and in front: the same ones on the copy
    a = means[:n1]
    def near(qx, qy):
        spot = np.array([np.percentile(a[:, 0], qx), np.percentile(a[:, 1], qy)])
        return int(np.argmin(np.linalg.norm(a[:, :2] - spot, axis=1) + 0.3 * a[:, 2]))
    picks = [near(20, 25), near(80, 30), near(45, 80)]
    ctx.set_ref("")
    for i in picks:
        for point in (known[:3, :3] @ a[i] + known[:3, 3], a[i]):
            xy = on_screen(point)[0]
            ctx.mouse_move_to_pos(imgui.ImVec2(float(xy[0]), float(xy[1])))
            ctx.mouse_click(0)
            settle(ctx, 0.3)
    found["aligning_after"] = app.ui.gizmo.align.active
    found["transform"] = app.document.models.parts[-1].transform.tolist()
    found["span"] = float(np.ptp(a, axis=0).max())
    found["messages"] = app.ui.messages.lines[-8:]
    found["undo"] = len(app.document.editor.undo_stack)
    testing.capture(ctx, str(OUT / "aligned.png"))
    app.ui.export.path = str(OUT / "aligned.ply")
    ctx.set_ref("Edit")
    ctx.item_click("Export")

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert found["error"] == "", found["error"]
    assert found["added"] == 8000
    assert found["aligning"] and not found["aligning_after"], found["messages"]
    assert found["undo"] == 2  # the model added, the alignment: one step each
    recovered = np.array(found["transform"])  # the copy's file into the scene: should be known^-1
    back = recovered @ known
    s = np.linalg.det(back[:3, :3]) ** (1 / 3)
    assert abs(s - 1) < 0.02, s
    r = back[:3, :3] / s
    angle = np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))
    assert angle < 1.5, angle
    assert np.linalg.norm(back[:3, 3]) < 0.015 * found["span"], back[:3, 3]
    # the copy's file turned, scaled and moved by transform.py (SH bands rotated) is what Export wrote
    from training.model.ply_io import read_ply
    from training.model.transform import transform_gaussians

    assert_union(tmp_path / "aligned.ply", [read_ply(model), transform_gaussians(read_ply(copy), recovered)],
                 atol=2e-5)


def test_a_gizmo_pose_becomes_a_similarity_about_its_centre():
    """What a drag's start and current gizmo matrices become: a turn made exactly orthonormal, a per-axis scale
    made uniform (the mean), both about the gizmo's centre (which stays where it is)."""
    from app.viewer.display.gizmo import similarity_delta
    from training.model.transform import split_similarity

    start = np.eye(4)
    start[:3, 3] = (1.0, 2.0, 3.0)
    turned = start.copy()
    turned[:3, :3] = similarity(20.0, (0, 0, 1), 1.0, (0, 0, 0))[:3, :3] + 1e-4  # float32 drift of ImGuizmo
    d = similarity_delta("rotate", start, turned)
    s, r, _ = split_similarity(d)
    assert s == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(d[:3, 3] + d[:3, :3] @ start[:3, 3], start[:3, 3], atol=1e-12)  # centre fixed
    np.testing.assert_allclose(r, similarity(20.0, (0, 0, 1), 1.0, (0, 0, 0))[:3, :3], atol=1e-3)
    scaled = start.copy()
    scaled[:3, :3] = np.diag([1.5, 2.0, 2.5])
    d = similarity_delta("scale", start, scaled)
    np.testing.assert_allclose(d[:3, :3], 2.0 * np.eye(3), atol=1e-12)
    np.testing.assert_allclose(d @ np.r_[start[:3, 3], 1.0], np.r_[start[:3, 3], 1.0], atol=1e-12)
    moved = start.copy()
    moved[:3, 3] += (0.5, -1.0, 0.0)
    np.testing.assert_allclose(similarity_delta("translate", start, moved)[:3, 3], (0.5, -1.0, 0.0))


def test_the_scene_ledger_maps_source_rows_to_their_files():
    """Parts tile the source rows: a model of 5, a second of 3, then rows 1 and 3 of the first moved and row 2 of
    the second: each source row names its file and its row there."""
    from app.viewer.edit.scene_models import SceneModels

    models = SceneModels.opened("a.ply", 5)
    models.add_part(models.add_file("b.ply"), np.arange(3), np.eye(4))
    models.add_part(0, [1, 3], np.eye(4))
    models.add_part(1, [2], np.eye(4))
    files, rows = models.file_rows(np.array([0, 8, 2, 9, 4, 5, 6, 10]))
    assert files.tolist() == [0, 0, 0, 0, 0, 1, 1, 1]
    assert rows.tolist() == [0, 1, 2, 3, 4, 0, 1, 2]
    assert models.size == 11


@pytest.mark.slow
def test_moves_under_a_scaled_and_turned_world_are_moves_in_the_view(demo_scene, tmp_path):
    """After the measure and up tools gave the scene a world transform W, a second model joins and the gizmo drags
    it: on screen it moves by the dragged pixels (a move in the world), the Export and `export --project` both
    write W applied to model 1 and to the second file moved by its part's transform, and the view shows exactly
    that."""
    from app.cli import main
    from training.model.ply_io import read_ply
    from training.model.transform import transform_gaussians

    _, _, model = demo_scene
    second = moved_copy(model, similarity(0.0, (0, 1, 0), 1.0, (15.0, 0.0, 0.0)), tmp_path / "second.ply")
    world = similarity(30.0, (0, 1, 0), 2.0, (1.0, -2.0, 3.0))
    found = run_gui(PRELUDE + DRAG + f"""
from app.viewer.camera import ViewerCamera
from app.viewer.edit.world_edit import set_world
app = ViewerApp(Paths(model={str(model)!r}, out=str(OUT / "out")))

def test(ctx):
    wait(ctx, lambda: app.view is not None and app.view.has_model(0), 60, "the model")
    n1 = app.document.editor.count
    on_gl_thread(ctx, lambda: set_world(app.document, app.session, app.ui, np.array({world.tolist()!r})))
    app.on_drop(None, [{str(second)!r}])
    ctx.yield_(3)
    means = app.document.editor.model.means.astype(float)
    mid = means.mean(axis=0)
    app.view.camera = ViewerCamera.looking_at(mid + np.array([0.0, -16.0, -80.0]), mid, up=(0.0, -1.0, 0.0))
    app.view.moved()
    settle(ctx, 0.5)
    ctx.set_ref("")
    ctx.key_press(imgui.Key.g)
    settle(ctx, 0.3)
    rows = np.arange(app.document.editor.count) >= n1
    centre = means[rows].mean(axis=0)
    start = on_screen(centre)[0]
    drag(ctx, start, (-40, 30))
    after = app.document.editor.model.means.astype(float)
    found["moved_px"] = (on_screen(after[rows].mean(axis=0))[0] - start).tolist()
    found["still"] = bool(np.array_equal(app.document.editor.model.means[~rows], means[~rows].astype(np.float32)))
    np.save(OUT / "shown.npy", app.document.editor.model.means)
    found["part"] = app.document.models.parts[-1].transform.tolist()
    app.ui.export.path = str(OUT / "merged.ply")
    open_window(ctx, "Edit")
    ctx.item_click("Export")
    app.save_project(str(OUT / "world.splatproj"))

run(app, test)
found["error"] = app.ui.messages.error
Path(os.environ["RESULT"]).write_text(json.dumps(found))
""", tmp_path)
    assert found["error"] == "", found["error"]
    np.testing.assert_allclose(found["moved_px"], [-40, 30], atol=1.0)
    assert found["still"]
    part = np.array(found["part"])
    expected = [transform_gaussians(read_ply(model), world), transform_gaussians(read_ply(second), world @ part)]
    assert_union(tmp_path / "merged.ply", expected, atol=5e-5)
    assert main(["export", "--project", str(tmp_path / "world.splatproj"), "-o", str(tmp_path / "baked.ply")]) == 0
    assert_union(tmp_path / "baked.ply", expected, atol=5e-5)
    shown = np.load(tmp_path / "shown.npy")
    np.testing.assert_allclose(shown, np.concatenate([g.means.numpy() for g in expected]), atol=5e-5)
