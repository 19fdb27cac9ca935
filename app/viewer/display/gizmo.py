"""The transform gizmo (ImGuizmo) over the 3D view: move, turn and scale the selection, one model of the scene, or
the crop box; and the clicks of a three-point alignment.

A drag of the selection or of a model shows the moved Gaussians live (a preview upload, the editor untouched) and
becomes ONE undo step when the mouse is released (Document.transform): a drag is one edit, whatever
number of frames it took. Its transform is a similarity about the gizmo's centre (scale is uniform: a Gaussian's
SH cannot follow a non-uniform scale, training/model/transform.py). The crop box is axis-aligned (Crop and Cut use
it so): it moves and scales per axis, and does not turn.

While the pointer is on a gizmo handle, or a drag of it is under way, the view does not take the mouse: no orbit,
no selection gesture. Keys: G move, T turn, Y scale (the same key again hides the gizmo); R, S, W, ... keep
their camera meaning. The Edit panel's section that chooses what the gizmo moves is gizmo_panel.py.
"""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui, imguizmo

from app.viewer.display.gestures import on_screen, pixels, view_camera
from app.viewer.edit.align_points import add_pick
from app.viewer.edit.colour_view import displayed
from app.viewer.edit.scene_models import with_rows

OPS = ("translate", "rotate", "scale")
KEYS = {"translate": "G", "rotate": "T", "scale": "Y"}
gz = imguizmo.im_guizmo
GL_NEAR, GL_FAR = 0.01, 1000.0  # the gizmo's depth range: it draws over the picture, never clipped by the splats


# ------------------------------------------------------------------ matrices
def _m16(m: np.ndarray):
    return gz.Matrix16(np.asarray(m, np.float64).flatten(order="F").tolist())  # column by column, as GL


def _np(m16) -> np.ndarray:
    return np.asarray(m16.values, np.float64).reshape(4, 4, order="F")


def _translation(t) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


def target_mask(doc, ui) -> np.ndarray | None:
    """The editor rows the gizmo moves (None for the crop box or when nothing is there to move)."""
    st = ui.gizmo
    if st.target == "selection":
        mask = doc.editor.selected.copy()
    elif st.target.startswith("model:"):
        mask = doc.rows_of_file(int(st.target.split(":")[1]))
    else:
        return None
    return mask if mask.any() else None


def object_matrix(doc, session, ui) -> np.ndarray | None:
    """Where the gizmo stands: the centre of what it moves; for the crop box its centre scaled by its size."""
    if ui.gizmo.target == "box":
        box = np.asarray(ui.edit.box, np.float64)
        m = _translation(box.mean(axis=0))
        m[:3, :3] = np.diag(np.maximum(np.abs(box[1] - box[0]), 1e-6))
        return m
    if doc.source is None or session.has_trainer:
        return None  # the view shows a trainer's model: what is moved is the opened model's, once it is shown
    mask = target_mask(doc, ui)
    if mask is None:
        return None
    return _translation(doc.editor.model.means[mask].astype(np.float64).mean(axis=0))


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


def holds_mouse(ui) -> bool:
    """The pointer is on a gizmo handle or a drag of it is under way: the view's canvas must not take the mouse
    (ImGuizmo starts a drag only where no imgui item is hovered), so no orbit and no selection gesture."""
    st = ui.gizmo
    return bool(st.op) and (st.dragging or (st.drawn and (gz.is_over() or gz.is_using())))


def left_is_taken(ui) -> bool:
    """A left click picks an alignment point, or works the gizmo: it neither orbits nor selects."""
    return ui.gizmo.align.active or holds_mouse(ui)


def view_gizmo(doc, session, ui, hovered: bool) -> None:
    """Draw and run the gizmo over the view's picture (call after the picture was drawn)."""
    st = ui.gizmo
    st.drawn = False
    if doc.editor is None or ui.view.camera is None:
        return
    if st.align.active:
        _align_clicks(doc, session, ui, hovered)
    if st.target == "box":
        if ui.edit.box is None:  # the Edit panel fills it on its first frame; the gizmo may come first
            means = doc.editor.model.means
            ui.edit.box = [list(map(float, means.min(axis=0))), list(map(float, means.max(axis=0)))]
        _draw_box(ui)
    if not st.op:
        return
    cam = view_camera(ui)
    view, proj = cam.gl_view_projection(GL_NEAR, GL_FAR)
    x, y, w, h = ui.window.view_rect
    gz.set_drawlist(imgui.get_window_draw_list())
    gz.set_rect(x, y, w, h)
    gz.set_orthographic(False)
    if not st.dragging:
        m = object_matrix(doc, session, ui)
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
        st.dragging, st.start, st.delta = True, object_matrix(doc, session, ui), None
        st.mask = None if st.target == "box" else target_mask(doc, ui)
        st.box_before = box_value(ui.edit.box) if st.target == "box" else None
    if st.dragging:
        now = _np(st.matrix)
        if st.target == "box":
            half = np.linalg.norm(now[:3, :3], axis=0) / 2
            ui.edit.box = [list(map(float, now[:3, 3] - half)), list(map(float, now[:3, 3] + half))]
        else:
            delta = similarity_delta(op, st.start, now)
            if st.delta is None or not np.allclose(delta, st.delta):
                st.delta = delta
                ui.messages.guarded("move", _preview, doc, session, ui, delta)
        if not using:
            st.dragging = False
            if st.target != "box" and st.delta is not None and not np.allclose(st.delta, np.eye(4)):
                ui.messages.guarded("move", doc.transform, st.mask, st.delta)
            elif st.target == "box":
                record_box_change(doc, ui, st.box_before, box_value(ui.edit.box))
            ui.edit.shown_version = None  # the preview goes; the editor's model (moved or not) is shown
            st.delta = st.mask = None


def box_value(box) -> tuple | None:
    return None if box is None else tuple(tuple(float(v) for v in corner) for corner in box)


def record_box_change(doc, ui, before: tuple | None, after: tuple | None) -> None:
    """One undo step for a crop-box change (a gizmo drag, or numbers typed in the Edit panel): the box lives in the
    editor's history as the "crop_box" extra, so Ctrl+Z puts it back where the change began (sync_crop_box moves
    the edit tools' box)."""
    ed = doc.editor
    if ed is None or before is None or after is None or np.allclose(before, after):
        return
    ed.set_extra("crop_box", after, was=before)
    ui.gizmo.box_shown = after


def sync_crop_box(doc, ui) -> None:
    """Per frame: after an undo or redo the crop box is the one of that step."""
    ed = doc.editor
    value = None if ed is None else ed.extras.get("crop_box")
    if value is not ui.gizmo.box_shown:
        ui.gizmo.box_shown = value
        if value is not None:
            ui.edit.box = [list(value[0]), list(value[1])]


def _preview(doc, session, ui, delta: np.ndarray) -> None:
    mask = ui.gizmo.mask
    snap = with_rows(doc.editor.model, mask, doc.moved_arrays(mask, delta))
    view = ui.view
    view.show(displayed(doc, session, snap), 0)  # with the Colour panel's edits, as the view shows the model after it
    view.renderer.set_flags(doc.editor.flags(), 0)
    view.dirty = True


def _draw_box(ui) -> None:
    """The crop box's twelve edges over the view (its faces would hide the splats)."""
    if ui.edit.box is None:
        return
    lo, hi = np.asarray(ui.edit.box, np.float64)
    corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1)
                        for k in (0, 1)])
    xy, front = on_screen(ui, corners)
    draw = imgui.get_window_draw_list()
    col = imgui.IM_COL32(80, 220, 255, 230)
    for a in range(8):
        for bit in (1, 2, 4):
            b = a | bit
            if b != a and front[a] and front[b]:
                draw.add_line(imgui.ImVec2(*xy[a]), imgui.ImVec2(*xy[b]), col, 1.5)


def _align_clicks(doc, session, ui, hovered: bool) -> None:
    st = ui.gizmo
    if hovered and imgui.is_mouse_clicked(imgui.MouseButton_.left):
        mouse = imgui.get_mouse_pos()
        fid = int(st.target.split(":")[1]) if st.target.startswith("model:") else 1
        line = ui.messages.guarded("pick", add_pick, doc, session, ui, view_camera(ui), *pixels(ui, mouse.x, mouse.y),
                                   fid)
        if line:
            ui.messages.say(line)
    pts = [(p, (255, 120, 60)) for p in st.align.moving] + [(p, (90, 255, 120)) for p in st.align.fixed]
    if pts:
        xy, front = on_screen(ui, np.array([p for p, _ in pts]))
        draw = imgui.get_window_draw_list()
        for i, ((_, rgb), (px, py), f) in enumerate(zip(pts, xy, front)):
            if f:
                n = i + 1 if i < len(st.align.moving) else i - len(st.align.moving) + 1
                draw.add_circle_filled(imgui.ImVec2(px, py), 5.0, imgui.IM_COL32(*rgb, 255))
                draw.add_text(imgui.ImVec2(px + 7, py - 7), imgui.IM_COL32(*rgb, 255), str(n))


def gizmo_keys(ui) -> None:
    """G, T, Y choose the gizmo's operation; the same key again hides it."""
    k = imgui.Key
    for op, key in (("translate", k.g), ("rotate", k.t), ("scale", k.y)):
        if imgui.is_key_pressed(key, False):
            ui.gizmo.op = "" if ui.gizmo.op == op else op
