"""The Edit panel: the selection tools (what a left drag in the 3D view does: gestures.py draws and applies it), the
world-space box and sphere selections and the crop box typed in the panel, and the edits (hide, show, delete, undo,
redo). Its other sections are select_tools_panel.py (more selections), gizmo_panel.py (the gizmo and the scene's
models) and export_panel.py; layout.py puts them in this order in the one Edit window.

Edits apply to the model opened in the viewer (a running trainer's model is shown read-only unless the user edits
it live): undo and redo cover every selection and edit.
"""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.viewer.display.gizmo import box_value, record_box_change
from app.viewer.edit import editor as sel
from app.viewer.live.runs import edit_live
from app.viewer.panels.text_colours import GREY
from app.viewer.state import TOOLS


def selection_section(doc, session, ui) -> None:
    ed = doc.editor
    if ed is None:
        imgui.text_colored(GREY, "open a model to select and edit it")
        return
    edit = ui.edit
    if session.running and not doc.live:
        imgui.text_colored(GREY, "a trainer is running: edits apply to the opened model")
        if imgui.button("Edit the running model"):
            ui.messages.guarded("edit", edit_live, doc, session, ui)
    imgui.text(f"{ed.count:,} Gaussians, {int(ed.selected.sum()):,} selected, {int(ed.hidden.sum()):,} hidden")
    changed, i = imgui.combo("tool", TOOLS.index(edit.tool), list(TOOLS))
    if changed:
        edit.tool = TOOLS[i]
    imgui.set_item_tooltip("what a left drag in the 3D view does (orbit turns the camera)")
    if edit.tool in ("brush", "surface brush"):
        _, edit.brush_radius = imgui.slider_float("brush radius", edit.brush_radius, 2.0, 200.0)
    changed, i = imgui.combo("selection mode", sel.MODES.index(edit.select_mode), list(sel.MODES))
    if changed:
        edit.select_mode = sel.MODES[i]
    for label, action in (("All", ed.select_all), ("None", ed.select_none), ("Invert", ed.invert)):
        if imgui.button(label):
            ui.messages.guarded("select", action)
        imgui.same_line()
    imgui.new_line()
    imgui.separator_text("Box and sphere (world units)")
    box = edit.box
    if box is None:
        lo, hi = ed.model.means.min(axis=0), ed.model.means.max(axis=0)
        box = edit.box = [list(map(float, lo)), list(map(float, hi))]
    for side, label in enumerate(("box min", "box max")):
        shown = box_value(box)
        _, box[side] = imgui.input_float3(label, box[side])
        # the fields change the box as each digit is typed; the undo step is a number's whole typing, from clicking
        # into it to leaving it (Enter, Tab to the next number, a click elsewhere)
        if imgui.is_item_deactivated_after_edit():
            record_box_change(doc, ui, edit.box_typed_from, box_value(box))
        if imgui.is_item_activated():
            edit.box_typed_from = shown
    if imgui.button("Select in box"):
        ui.messages.guarded("select", lambda: ed.select(sel.in_box(ed.model.means, np.array(box[0]),
                                                                   np.array(box[1])), edit.select_mode))
    imgui.same_line()
    if imgui.button("Crop to box"):
        ui.messages.guarded("crop", doc.crop, box[0], box[1], True)
    imgui.same_line()
    if imgui.button("Cut box out"):
        ui.messages.guarded("crop", doc.crop, box[0], box[1], False)
    sphere = edit.sphere
    if sphere is None:
        center = ed.model.means.mean(axis=0)
        sphere = edit.sphere = [list(map(float, center)), float(np.ptp(ed.model.means, axis=0).max() / 4)]
    _, sphere[0] = imgui.input_float3("sphere centre", sphere[0])
    _, sphere[1] = imgui.input_float("sphere radius", sphere[1])
    if imgui.button("Select in sphere"):
        ui.messages.guarded("select", lambda: ed.select(sel.in_sphere(ed.model.means, sphere[0], sphere[1]),
                                                        edit.select_mode))


def edits_section(doc, session, ui) -> None:
    ed = doc.editor
    if ed is None:
        return
    imgui.separator_text("Edits")
    for label, action in (("Hide", doc.hide), ("Show all", doc.show_all), ("Delete", doc.delete)):
        if imgui.button(label):
            ui.messages.guarded(label.lower(), action)
        imgui.same_line()
    imgui.new_line()
    imgui.begin_disabled(not ed.undo_stack)
    if imgui.button("Undo"):
        doc.undo()
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(not ed.redo_stack)
    if imgui.button("Redo"):
        doc.redo()
    imgui.end_disabled()
