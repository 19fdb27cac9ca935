"""The transform gizmo (ImGuizmo) over the 3D view: move, turn and scale the selection, one model of the scene, or
the crop box; and the clicks of a three-point alignment.

A drag of the selection or of a model shows the moved Gaussians live (a preview upload, the editor untouched) and
becomes ONE undo step when the mouse is released (scene_models.transform_rows): a drag is one edit, whatever
number of frames it took. Its transform is a similarity about the gizmo's centre (scale is uniform: a Gaussian's
SH cannot follow a non-uniform scale, training/model/transform.py). The crop box is axis-aligned (Crop and Cut use
it so): it moves and scales per axis, and does not turn.

While the pointer is on a gizmo handle, or a drag of it is under way, the view does not take the mouse: no orbit,
no selection gesture. Keys: G move, T turn, Y scale (the same key again hides the gizmo); R, S, W, ... keep
their camera meaning.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from imgui_bundle import imgui, imguizmo

from app.viewer.align_points import AlignState

OPS = ("translate", "rotate", "scale")
KEYS = {"translate": "G", "rotate": "T", "scale": "Y"}
gz = imguizmo.im_guizmo


@dataclass
class GizmoState:
    op: str = ""  # "" (no gizmo) | translate | rotate | scale
    target: str = "selection"  # selection | box | model:<index in app.scene_models.files>
    dragging: bool = False
    start: np.ndarray | None = None  # the gizmo's matrix when the drag began
    delta: np.ndarray | None = None  # the similarity dragged so far
    mask: np.ndarray | None = None  # the editor rows the drag moves
    matrix: object = None  # the imguizmo Matrix16 the gizmo edits during a drag
    add_path: str = ""  # the model to add, typed (the file dialog needs zenity or kdialog)
    drawn: bool = False  # the gizmo was drawn in the last frame (ImGuizmo answers "over" from its last pose)
    align: AlignState = field(default_factory=AlignState)
    box_before: tuple | None = None  # the crop box when its drag began
    box_shown: tuple | None = None  # the editor's "crop_box" extra that app.edit.box was last set from


# ------------------------------------------------------------------ matrices
def _m16(m: np.ndarray):
    return gz.Matrix16(np.asarray(m, np.float64).flatten(order="F").tolist())  # column by column, as GL


def _np(m16) -> np.ndarray:
    return np.asarray(m16.values, np.float64).reshape(4, 4, order="F")


def view_projection(cam, near: float = 0.01, far: float = 1000.0):
    """GL view and projection matrices of the project's (OpenCV) camera: x right, y down, z forward becomes GL's
    x right, y up, looking down -z; the principal point off centre shifts the frustum."""
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    view = flip @ np.asarray(cam.world_to_camera, np.float64)
    w, h = cam.width, cam.height
    proj = np.array([[2 * cam.fx / w, 0.0, 1 - 2 * cam.cx / w, 0.0],
                     [0.0, 2 * cam.fy / h, 2 * cam.cy / h - 1, 0.0],
                     [0.0, 0.0, -(far + near) / (far - near), -2 * far * near / (far - near)],
                     [0.0, 0.0, -1.0, 0.0]])
    return view, proj


def _translation(t) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


def target_mask(app) -> np.ndarray | None:
    """The editor rows the gizmo moves (None for the crop box or when nothing is there to move)."""
    from app.viewer.scene_models import rows_of_file

    st = app.gizmo
    if st.target == "selection":
        mask = app.editor.selected.copy()
    elif st.target.startswith("model:"):
        mask = rows_of_file(app, int(st.target.split(":")[1]))
    else:
        return None
    return mask if mask.any() else None


def object_matrix(app) -> np.ndarray | None:
    """Where the gizmo stands: the centre of what it moves; for the crop box its centre scaled by its size."""
    if app.gizmo.target == "box":
        box = np.asarray(app.edit.box, np.float64)
        m = _translation(box.mean(axis=0))
        m[:3, :3] = np.diag(np.maximum(np.abs(box[1] - box[0]), 1e-6))
        return m
    if app.source_gaussians is None or app.session.trainer is not None:
        return None  # the view shows a trainer's model: what is moved is the opened model's, once it is shown
    mask = target_mask(app)
    if mask is None:
        return None
    return _translation(app.editor.model.means[mask].astype(np.float64).mean(axis=0))


def similarity_delta(op: str, start: np.ndarray, now: np.ndarray) -> np.ndarray:
    """The similarity from the gizmo's start to its pose now: the translation moved, the rotation turned (made
    exactly orthonormal), or the mean scale (uniform) about the start's centre."""
    c = start[:3, 3]
    if op == "translate":
        return _translation(now[:3, 3] - c)
    a = now[:3, :3] @ np.linalg.inv(start[:3, :3])
    if op == "rotate":
        u, _, vt = np.linalg.svd(a)
        a = u @ vt
    else:
        s = float(np.mean(np.linalg.norm(now[:3, :3], axis=0) / np.linalg.norm(start[:3, :3], axis=0)))
        a = np.eye(3) * max(s, 1e-6)
    m = np.eye(4)
    m[:3, :3] = a
    return _translation(c) @ m @ _translation(-c)


# ------------------------------------------------------------------ the view's hooks
def begin_frame() -> None:
    """Before the view's window begins (ImGuizmo's per-frame reset)."""
    gz.begin_frame()


def holds_mouse(app) -> bool:
    """The pointer is on a gizmo handle or a drag of it is under way: the view's canvas must not take the mouse
    (ImGuizmo starts a drag only where no imgui item is hovered), so no orbit and no selection gesture."""
    st = app.gizmo
    return bool(st.op) and (st.dragging or (st.drawn and (gz.is_over() or gz.is_using())))


def left_is_taken(app) -> bool:
    """A left click picks an alignment point, or works the gizmo: it neither orbits nor selects."""
    return app.gizmo.align.active or holds_mouse(app)


def view_gizmo(app, hovered: bool) -> None:
    """Draw and run the gizmo over the view's picture (call after the picture was drawn)."""
    st = app.gizmo
    st.drawn = False
    if app.editor is None or app.view.camera is None:
        return
    if st.align.active:
        _align_clicks(app, hovered)
    if st.target == "box":
        if app.edit.box is None:  # the Edit panel fills it on its first frame; the gizmo may come first
            means = app.editor.model.means
            app.edit.box = [list(map(float, means.min(axis=0))), list(map(float, means.max(axis=0)))]
        _draw_box(app)
    if not st.op:
        return
    from app.viewer.edit_panel import view_camera

    cam = view_camera(app)
    view, proj = view_projection(cam)
    x, y, w, h = app.window.view_rect
    gz.set_drawlist(imgui.get_window_draw_list())
    gz.set_rect(x, y, w, h)
    gz.set_orthographic(False)
    if not st.dragging:
        m = object_matrix(app)
        if m is None:
            return
        st.matrix = _m16(m)
    op = st.op
    if st.target == "box" and op == "rotate":
        op = "translate"  # the crop box is axis-aligned: it cannot turn
    operation = {"translate": gz.OPERATION.translate, "rotate": gz.OPERATION.rotate,
                 "scale": gz.OPERATION.scale}[op]
    gz.manipulate(_m16(view), _m16(proj), operation, gz.MODE.world, st.matrix)
    st.drawn = True
    using = gz.is_using()
    if using and not st.dragging:
        st.dragging, st.start, st.delta = True, object_matrix(app), None
        st.mask = None if st.target == "box" else target_mask(app)
        st.box_before = box_value(app.edit.box) if st.target == "box" else None
    if st.dragging:
        now = _np(st.matrix)
        if st.target == "box":
            half = np.linalg.norm(now[:3, :3], axis=0) / 2
            app.edit.box = [list(map(float, now[:3, 3] - half)), list(map(float, now[:3, 3] + half))]
        else:
            delta = similarity_delta(op, st.start, now)
            if st.delta is None or not np.allclose(delta, st.delta):
                st.delta = delta
                app.guarded("move", _preview, app, delta)
        if not using:
            st.dragging = False
            if st.target != "box" and st.delta is not None and not np.allclose(st.delta, np.eye(4)):
                from app.viewer.scene_models import transform_rows

                app.guarded("move", transform_rows, app, st.mask, st.delta)
            elif st.target == "box":
                record_box_change(app, st.box_before, box_value(app.edit.box))
            app.edit.shown_version = None  # the preview goes; the editor's model (moved or not) is shown
            st.delta = st.mask = None


def box_value(box) -> tuple | None:
    return None if box is None else tuple(tuple(float(v) for v in corner) for corner in box)


def record_box_change(app, before: tuple | None, after: tuple | None) -> None:
    """One undo step for a crop-box change (a gizmo drag, or numbers typed in the Edit panel): the box lives in the
    editor's history as the "crop_box" extra, so Ctrl+Z puts it back where the change began (sync_crop_box moves
    app.edit.box)."""
    ed = app.editor
    if ed is None or before is None or after is None or np.allclose(before, after):
        return
    ed.extras = {**ed.extras, "crop_box": before}  # the state an undo returns to has the box before the drag
    ed.set_extra("crop_box", after)
    app.gizmo.box_shown = after


def sync_crop_box(app) -> None:
    """Per frame: after an undo or redo the crop box is the one of that step."""
    ed = app.editor
    value = None if ed is None else ed.extras.get("crop_box")
    if value is not app.gizmo.box_shown:
        app.gizmo.box_shown = value
        if value is not None:
            app.edit.box = [list(value[0]), list(value[1])]


def _preview(app, delta: np.ndarray) -> None:
    from app.viewer.scene_models import moved_arrays, with_rows

    from app.viewer.colour_view import displayed

    snap = with_rows(app.editor.model, app.gizmo.mask, moved_arrays(app, app.gizmo.mask, delta))
    app.view.show(displayed(app, snap), 0)  # with the Colour panel's edits, as the view shows the model after it
    app.view.renderer.set_flags(app.editor.flags(), 0)
    app.view.dirty = True


def _project(app, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Window coordinates of world points, and whether each is in front of the camera."""
    from app.viewer.edit_panel import view_camera
    from app.viewer.selection import project

    uv, front = project(points, view_camera(app))
    scale = imgui.get_io().display_framebuffer_scale
    x, y = app.window.view_rect[:2]
    return np.stack([x + uv[:, 0] / scale.x, y + uv[:, 1] / scale.y], axis=1), front


def _draw_box(app) -> None:
    """The crop box's twelve edges over the view (its faces would hide the splats)."""
    if app.edit.box is None:
        return
    lo, hi = np.asarray(app.edit.box, np.float64)
    corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1)
                        for k in (0, 1)])
    xy, front = _project(app, corners)
    draw = imgui.get_window_draw_list()
    col = imgui.IM_COL32(80, 220, 255, 230)
    for a in range(8):
        for bit in (1, 2, 4):
            b = a | bit
            if b != a and front[a] and front[b]:
                draw.add_line(imgui.ImVec2(*xy[a]), imgui.ImVec2(*xy[b]), col, 1.5)


def _align_clicks(app, hovered: bool) -> None:
    from app.viewer.align_points import add_pick
    from app.viewer.edit_panel import _pixels

    st = app.gizmo
    if hovered and imgui.is_mouse_clicked(imgui.MouseButton_.left):
        mouse = imgui.get_mouse_pos()
        fid = int(st.target.split(":")[1]) if st.target.startswith("model:") else 1
        line = app.guarded("pick", add_pick, app, *_pixels(app, mouse.x, mouse.y), fid)
        if line:
            app.say(line)
    pts = [(p, (255, 120, 60)) for p in st.align.moving] + [(p, (90, 255, 120)) for p in st.align.fixed]
    if pts:
        xy, front = _project(app, np.array([p for p, _ in pts]))
        draw = imgui.get_window_draw_list()
        for i, ((_, rgb), (px, py), f) in enumerate(zip(pts, xy, front)):
            if f:
                n = i + 1 if i < len(st.align.moving) else i - len(st.align.moving) + 1
                draw.add_circle_filled(imgui.ImVec2(px, py), 5.0, imgui.IM_COL32(*rgb, 255))
                draw.add_text(imgui.ImVec2(px + 7, py - 7), imgui.IM_COL32(*rgb, 255), str(n))


# ------------------------------------------------------------------ keys and panel
def gizmo_keys(app) -> None:
    """G, T, Y choose the gizmo's operation; the same key again hides it."""
    k = imgui.Key
    for op, key in (("translate", k.g), ("rotate", k.t), ("scale", k.y)):
        if imgui.is_key_pressed(key, False):
            app.gizmo.op = "" if app.gizmo.op == op else op


def gizmo_section(app) -> None:
    """The Edit panel's section: what the gizmo moves and how, the scene's models, and the alignment."""
    from app.viewer.scene_models import files_shown

    st = app.gizmo
    imgui.separator_text("Gizmo and models")
    shown = files_shown(app)
    names = app.scene_models.files
    targets = ["selection", "box"] + [f"model:{i}" for i in shown]
    labels = ["selection", "crop box"] + [f"model {names[i].name}" for i in shown]
    if st.target not in targets:
        st.target = "selection"
    changed, i = imgui.combo("gizmo moves", targets.index(st.target), labels)
    if changed:
        st.target = targets[i]
    for op, label in (("translate", "Move"), ("rotate", "Turn"), ("scale", "Scale")):
        if imgui.radio_button(f"{label} ({KEYS[op]})", st.op == op):
            st.op = "" if st.op == op else op
        imgui.same_line()
    if imgui.radio_button("Off", not st.op):
        st.op = ""
    grey = imgui.ImVec4(0.6, 0.6, 0.6, 1.0)
    if st.op and st.target != "box" and (app.source_gaussians is None or app.session.trainer is not None):
        imgui.text_colored(grey, "the gizmo moves the opened model: not while a trainer's model is shown")
    elif st.op and st.target == "selection" and not app.editor.selected.any():
        imgui.text_colored(grey, "select Gaussians to move them")
    button = "Add model to scene"
    width = imgui.calc_text_size(button).x + 2 * imgui.get_style().frame_padding.x + imgui.get_style().item_spacing.x
    imgui.set_next_item_width(max(imgui.get_content_region_avail().x - width, 40.0))
    _, st.add_path = imgui.input_text_with_hint("##add model path", "model to add (path)", st.add_path)
    imgui.same_line()
    if imgui.button(button):
        if st.add_path:
            app.guarded("add model", add_to_scene, app, st.add_path)
        else:
            app.guarded("add model", add_from_dialog, app)
    imgui.set_item_tooltip("another model file joins this one: drawn together, exported as one file (empty "
                           "path: a file dialog)")
    if len(shown) > 1:
        for fid in shown:
            imgui.bullet_text(f"{names[fid].name}  ({names[fid].path.name})")
        moving = int(st.target.split(":")[1]) if st.target.startswith("model:") else shown[-1]
        if st.align.active:
            left = 2 * 3 - len(st.align.moving) - len(st.align.fixed)
            side = "on the model to move" if st.align.next_is_moving() else "where it belongs"
            imgui.text_wrapped(f"click {left} more points: next {side}")
            if imgui.button("Cancel alignment"):
                st.align.active = False
                st.align.clear()
        elif imgui.button(f"Align {names[moving].name} by 3 point pairs"):
            st.target, st.op = f"model:{moving}", ""
            st.align.clear()
            st.align.active = True
        imgui.set_item_tooltip("click a point on the model to move, then the same place on the other model; "
                               "three times")


def add_from_dialog(app) -> None:
    from app.viewer.scene_panel import choose_file
    from training.model.model_io import FILE_DIALOG_PATTERN

    path = choose_file("Add model to scene", ["Gaussians", FILE_DIALOG_PATTERN])
    if path:
        add_to_scene(app, path)


def add_to_scene(app, path: str) -> None:
    from app.viewer.scene_models import add_model

    fid = add_model(app, path)
    if fid:
        app.gizmo.target = f"model:{fid}"
        app.say(f"added {path} to the scene ({app.editor.count:,} Gaussians in all); it is selected: move it with "
                "the gizmo (G), or align it by three point pairs; Ctrl+Z takes it out")
