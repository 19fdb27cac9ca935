"""The "Scale and up" panel: measure between two points on the model and rescale the scene to a known length; level
the scene from a picked floor, a plane fitted around a picked point, or the dataset cameras. The actions are in
world_edit.py, the picks in the 3D view in gestures.py; every change is a step of the document's undo history.
"""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.viewer.edit import world_edit as we
from app.viewer.panels.text_colours import GREY

HINTS = {"measure": "click two points on the model", "floor": "click three points on the floor",
         "fit": "click a point on the floor"}


def _tool_button(ui, label: str, tool: str) -> None:
    st = ui.world
    on = st.tool == tool
    if on:
        imgui.push_style_color(imgui.Col_.button, imgui.ImVec4(0.15, 0.55, 0.7, 1.0))
    if imgui.button(label):
        st.tool, st.points = ("" if on else tool), []
        if not on:
            ui.edit.tool = "orbit"  # a click picks, a drag turns the camera (not a selection gesture)
    if on:
        imgui.pop_style_color()


def measure_panel(doc, session, ui) -> None:
    st = ui.world
    ed = doc.editor
    if ed is None:
        imgui.text_colored(GREY, "open a model to measure and level it")
        return
    why = doc.world_problem(we.trainer_shown(session))
    imgui.separator_text("Measure and rescale")
    _tool_button(ui, "Measure", "measure")
    imgui.set_item_tooltip("pick two points on the model in the 3D view (a click; a drag turns the camera)")
    d = we.distance(st)
    if st.tool == "measure":
        imgui.same_line()
        imgui.text(f"distance {d:.6g}" if d is not None else HINTS["measure"])
    _, st.length = imgui.input_double("known length", st.length, 0.0, 0.0, "%.6g")
    imgui.begin_disabled(d is None or bool(why))
    if imgui.button("Rescale to this length"):
        ui.messages.guarded("rescale", we.rescale_to, doc, session, ui, st.length)
    imgui.end_disabled()
    imgui.separator_text("Up axis")
    imgui.begin_disabled(bool(why))
    if imgui.button("Up from the cameras"):
        ui.messages.guarded("level", we.level_from_cameras, doc, session, ui)
    imgui.set_item_tooltip("the dataset cameras' mean up becomes the view's up")
    imgui.end_disabled()
    _tool_button(ui, "Pick the floor", "floor")
    imgui.set_item_tooltip("three points on the floor: the plane through them is levelled")
    if st.tool == "floor":
        imgui.same_line()
        imgui.text(f"{len(st.points)} of 3" if st.points else HINTS["floor"])
        imgui.begin_disabled(len(st.points) != 3 or bool(why))
        if imgui.button("Level to the floor"):
            ui.messages.guarded("level", we.level_from_floor, doc, session, ui)
        imgui.end_disabled()
    _tool_button(ui, "Fit the floor", "fit")
    imgui.set_item_tooltip("a point on the floor: the plane fitted to the Gaussians around it is levelled")
    if st.tool == "fit":
        if st.fit_radius <= 0:
            st.fit_radius = float(np.ptp(ed.model.means, axis=0).max() / 20)
        _, st.fit_radius = imgui.input_double("fit radius", st.fit_radius, 0.0, 0.0, "%.4g")
        imgui.begin_disabled(len(st.points) != 1 or bool(why))
        if imgui.button("Level to the fitted plane"):
            ui.messages.guarded("level", we.level_from_fit, doc, session, ui)
        imgui.end_disabled()
    if why and why != "open a model first":
        imgui.text_colored(GREY, why)
    world = doc.world
    if not np.array_equal(world, np.eye(4)):
        s = float(np.cbrt(np.linalg.det(world[:3, :3])))
        turned = not np.allclose(world[:3, :3] / s, np.eye(3), atol=1e-12)
        what = [f"scaled by {s:.6g}"] * (s != 1.0) + ["turned"] * turned
        imgui.text_colored(GREY, f"the scene is {' and '.join(what) or 'moved'} (Ctrl+Z undoes)")
        imgui.begin_disabled(bool(why))
        if imgui.button("Back to the file's frame"):
            ui.messages.guarded("reset", we.set_world, doc, session, ui, np.eye(4))
        imgui.end_disabled()
