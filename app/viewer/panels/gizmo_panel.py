"""The Edit panel's "Gizmo and models" section: what the gizmo moves (the selection, the crop box, one model of the
scene) and how (move, turn, scale: gizmo.py runs it over the 3D view), a model to add to the scene, the scene's
models, and the three-point alignment of one onto another (align_points.py)."""

from __future__ import annotations

from imgui_bundle import imgui

from app.viewer.display.gizmo import KEYS
from app.viewer.dialogs import open_from_dialog
from app.viewer.files import add_to_scene
from app.viewer.panels.text_colours import GREY


def gizmo_section(doc, session, ui) -> None:
    if doc.editor is None:
        return
    st = ui.gizmo
    imgui.separator_text("Gizmo and models")
    shown = doc.files_shown()
    names = doc.models.files
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
    if st.op and st.target != "box" and (doc.source is None or session.has_trainer):
        imgui.text_colored(GREY, "the gizmo moves the opened model: not while a trainer's model is shown")
    elif st.op and st.target == "selection" and not doc.editor.selected.any():
        imgui.text_colored(GREY, "select Gaussians to move them")
    button = "Add model to scene"
    width = imgui.calc_text_size(button).x + 2 * imgui.get_style().frame_padding.x + imgui.get_style().item_spacing.x
    imgui.set_next_item_width(max(imgui.get_content_region_avail().x - width, 40.0))
    _, st.add_path = imgui.input_text_with_hint("##add model path", "model to add (path)", st.add_path)
    imgui.same_line()
    if imgui.button(button):
        if st.add_path:
            ui.messages.guarded("add model", add_to_scene, doc, session, ui, st.add_path)
        else:
            ui.messages.guarded("add model", open_from_dialog, doc, session, ui, "add")
    imgui.set_item_tooltip("another .ply or .splat joins this one: drawn together, exported as one file (empty "
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
