"""The Edit panel and the selection gestures in the 3D view (rectangle, brush, lasso), as SuperSplat users know
them; world-space box and sphere selections and the crop box are typed in the panel.

Edits apply to the model opened in the viewer (a running trainer's model is shown read-only): undo and redo cover
every selection and edit; ``Export`` writes the edited model, or its selection only.
"""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.viewer import select_tools_panel
from app.viewer import selection as sel
from app.viewer.gizmo import box_value, record_box_change
from app.viewer.state import TOOLS

GREY = imgui.ImVec4(0.6, 0.6, 0.6, 1.0)


def _pixels(app, x: float, y: float) -> tuple[float, float]:
    """imgui's (logical) mouse position -> pixels of the view's camera (framebuffer pixels from the view's corner)."""
    scale = imgui.get_io().display_framebuffer_scale
    left, top = app.window.view_rect[:2]
    return (x - left) * scale.x, (y - top) * scale.y


def view_camera(app):
    """The camera of the picture the view shows (its size in framebuffer pixels)."""
    io = imgui.get_io()
    w = int(app.window.view_rect[2] * io.display_framebuffer_scale.x)
    h = int(app.window.view_rect[3] * io.display_framebuffer_scale.y)
    return app.view.camera.camera(w, h)


def handle_gesture(app, hovered: bool, active: bool) -> None:
    """With a selection tool chosen, a left drag that starts on the 3D view selects instead of orbiting."""
    if app.edit.tool == "orbit" or app.editor is None or app.view.camera is None:
        app.edit.gesture = []
        return
    mouse = imgui.get_mouse_pos()
    if imgui.is_mouse_clicked(imgui.MouseButton_.left) and hovered:
        app.edit.gesture = [(mouse.x, mouse.y)]
    elif app.edit.gesture and imgui.is_mouse_down(imgui.MouseButton_.left):
        if (mouse.x, mouse.y) != app.edit.gesture[-1]:
            app.edit.gesture.append((mouse.x, mouse.y))
        draw_gesture(app)
    elif app.edit.gesture and imgui.is_mouse_released(imgui.MouseButton_.left):
        points = [_pixels(app, x, y) for x, y in app.edit.gesture]
        app.edit.gesture = []
        app.guarded("select", select_by_gesture, app, points)


def select_by_gesture(app, points: list[tuple[float, float]]) -> None:
    if app.edit.tool in select_tools_panel.VIEW_TOOLS:
        return select_tools_panel.gesture(app, points)
    cam = view_camera(app)
    means = app.editor.model.means
    if app.edit.tool == "rect":
        (x0, y0), (x1, y1) = points[0], points[-1]
        picked = sel.in_rect(means, cam, x0, y0, x1, y1)
    elif app.edit.tool == "brush":
        scale = imgui.get_io().display_framebuffer_scale.x
        picked = np.zeros(len(means), bool)
        for x, y in points:
            picked |= sel.in_brush(means, cam, x, y, app.edit.brush_radius * scale)
    else:
        picked = sel.in_lasso(means, cam, points)
    app.editor.select(picked, app.edit.select_mode)


def draw_gesture(app) -> None:
    draw = imgui.get_window_draw_list()  # the 3D view's own: clipped to it, and redrawn whole every frame
    col = imgui.IM_COL32(255, 200, 60, 230)
    pts = app.edit.gesture
    if app.edit.tool == "rect":
        (x0, y0), (x1, y1) = pts[0], pts[-1]
        draw.add_rect(imgui.ImVec2(min(x0, x1), min(y0, y1)), imgui.ImVec2(max(x0, x1), max(y0, y1)), col, 0.0,
                      1.5)
    elif app.edit.tool in ("brush", "surface brush"):
        for x, y in pts[-1:]:
            draw.add_circle(imgui.ImVec2(x, y), app.edit.brush_radius, col, 0, 1.5)
    else:
        for (ax, ay), (bx, by) in zip(pts[:-1], pts[1:]):
            draw.add_line(imgui.ImVec2(ax, ay), imgui.ImVec2(bx, by), col, 1.5)


def edit_panel(app) -> None:
    ed = app.editor
    if ed is None:
        imgui.text_colored(GREY, "open a model to select and edit it")
        return
    if app.session.running and not app.edit.live:
        imgui.text_colored(GREY, "a trainer is running: edits apply to the opened model")
        if imgui.button("Edit the running model"):
            app.guarded("edit", app.edit_live)
    imgui.text(f"{ed.count:,} Gaussians, {int(ed.selected.sum()):,} selected, {int(ed.hidden.sum()):,} hidden")
    changed, i = imgui.combo("tool", TOOLS.index(app.edit.tool), list(TOOLS))
    if changed:
        app.edit.tool = TOOLS[i]
    imgui.set_item_tooltip("what a left drag in the 3D view does (orbit turns the camera)")
    if app.edit.tool in ("brush", "surface brush"):
        _, app.edit.brush_radius = imgui.slider_float("brush radius", app.edit.brush_radius, 2.0, 200.0)
    changed, i = imgui.combo("selection mode", sel.MODES.index(app.edit.select_mode), list(sel.MODES))
    if changed:
        app.edit.select_mode = sel.MODES[i]
    for label, action in (("All", ed.select_all), ("None", ed.select_none), ("Invert", ed.invert)):
        if imgui.button(label):
            app.guarded("select", action)
        imgui.same_line()
    imgui.new_line()
    imgui.separator_text("Box and sphere (world units)")
    box = app.edit.box
    if box is None:
        lo, hi = ed.model.means.min(axis=0), ed.model.means.max(axis=0)
        box = app.edit.box = [list(map(float, lo)), list(map(float, hi))]
    for side, label in enumerate(("box min", "box max")):
        shown = box_value(box)
        _, box[side] = imgui.input_float3(label, box[side])
        # the fields change the box as each digit is typed; the undo step is a number's whole typing, from clicking
        # into it to leaving it (Enter, Tab to the next number, a click elsewhere)
        if imgui.is_item_deactivated_after_edit():
            record_box_change(app, app.edit.box_typed_from, box_value(box))
        if imgui.is_item_activated():
            app.edit.box_typed_from = shown
    if imgui.button("Select in box"):
        app.guarded("select", lambda: ed.select(sel.in_box(ed.model.means, np.array(box[0]), np.array(box[1])),
                                                app.edit.select_mode))
    imgui.same_line()
    if imgui.button("Crop to box"):
        app.guarded("crop", ed.crop, box[0], box[1], True)
    imgui.same_line()
    if imgui.button("Cut box out"):
        app.guarded("crop", ed.crop, box[0], box[1], False)
    sphere = app.edit.sphere
    if sphere is None:
        center = ed.model.means.mean(axis=0)
        sphere = app.edit.sphere = [list(map(float, center)), float(np.ptp(ed.model.means, axis=0).max() / 4)]
    _, sphere[0] = imgui.input_float3("sphere centre", sphere[0])
    _, sphere[1] = imgui.input_float("sphere radius", sphere[1])
    if imgui.button("Select in sphere"):
        app.guarded("select", lambda: ed.select(sel.in_sphere(ed.model.means, sphere[0], sphere[1]),
                                                app.edit.select_mode))
    select_tools_panel.more_selections(app)
    from app.viewer.gizmo import gizmo_section

    gizmo_section(app)
    imgui.separator_text("Edits")
    for label, action in (("Hide", ed.hide), ("Show all", ed.show_all), ("Delete", ed.delete)):
        if imgui.button(label):
            app.guarded(label.lower(), action)
        imgui.same_line()
    imgui.new_line()
    imgui.begin_disabled(not ed.undo_stack)
    if imgui.button("Undo"):
        ed.undo()
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(not ed.redo_stack)
    if imgui.button("Redo"):
        ed.redo()
    imgui.end_disabled()
    imgui.separator_text("Export")
    from app.viewer.export_panel import export_section

    export_section(app)
