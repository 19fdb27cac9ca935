"""The "Scale and up" panel and its picks in the 3D view: measure between two points on the model and rescale the
scene to a known length; level the scene from a picked floor, a plane fitted around a picked point, or the dataset
cameras. The actions are in world_edit.py; every change is a step of the editor's undo history.

Picking: with a pick tool on, a click on the model (press and release without dragging) picks the point under the
cursor; a drag still turns the camera, so a point hidden from here can be picked from elsewhere.
"""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.viewer import world_edit as we

GREY = imgui.ImVec4(0.6, 0.6, 0.6, 1.0)
LINE = imgui.IM_COL32(120, 255, 60, 255)  # green: apart from selection, frustums and paths (orange, yellow, cyan)
HINTS = {"measure": "click two points on the model", "floor": "click three points on the floor",
         "fit": "click a point on the floor"}


def handle_pick(app, hovered: bool) -> None:
    """Called by the 3D view every frame after its input: a click picks with the current tool; the picks are drawn
    over the picture."""
    st = app.world
    if not st.tool or app.view.camera is None:
        return
    from app.viewer.edit_panel import _pixels, view_camera

    io = imgui.get_io()
    if imgui.is_mouse_clicked(imgui.MouseButton_.left):
        st.pressed = hovered and app.edit.tool == "orbit"
    elif st.pressed and imgui.is_mouse_released(imgui.MouseButton_.left):
        st.pressed = False
        if io.mouse_drag_max_distance_sqr[0] <= io.mouse_drag_threshold ** 2:
            mouse = imgui.get_mouse_pos()
            point = app.guarded("pick", we.pick, app, view_camera(app), *_pixels(app, mouse.x, mouse.y))
            if point is not None:
                we.add_point(app, point)
    draw_picks(app)


def draw_picks(app) -> None:
    """The picked points as dots, the measure's line with its length at its middle, the floor's triangle."""
    from app.viewer.edit_panel import view_camera
    from app.viewer.selection import project

    st = app.world
    if not st.points:
        return
    uv, front = project(np.array(st.points), view_camera(app))
    scale = imgui.get_io().display_framebuffer_scale
    left, top = app.window.view_rect[:2]
    screen = [imgui.ImVec2(left + u / scale.x, top + v / scale.y) for u, v in uv]
    draw = imgui.get_window_draw_list()
    n = len(screen)
    if n > 1:
        for i in range(n if n == 3 else n - 1):
            j = (i + 1) % n
            if front[i] and front[j]:
                draw.add_line(screen[i], screen[j], LINE, 2.0)
    for p, ok in zip(screen, front):
        if ok:
            draw.add_circle_filled(p, 4.0, LINE)
    d = we.distance(app)
    if d is not None and front.all():
        text = f"{d:.4g}"
        mid = imgui.ImVec2((screen[0].x + screen[1].x) / 2, (screen[0].y + screen[1].y) / 2)
        size = imgui.calc_text_size(text)
        corner = imgui.ImVec2(mid.x + 6, mid.y - size.y - 4)
        draw.add_rect_filled(imgui.ImVec2(corner.x - 3, corner.y - 2),
                             imgui.ImVec2(corner.x + size.x + 3, corner.y + size.y + 2), imgui.IM_COL32(0, 0, 0, 190))
        draw.add_text(corner, LINE, text)


def _tool_button(app, label: str, tool: str) -> None:
    st = app.world
    on = st.tool == tool
    if on:
        imgui.push_style_color(imgui.Col_.button, imgui.ImVec4(0.15, 0.55, 0.7, 1.0))
    if imgui.button(label):
        st.tool, st.points = ("" if on else tool), []
        if not on:
            app.edit.tool = "orbit"  # a click picks, a drag turns the camera (not a selection gesture)
    if on:
        imgui.pop_style_color()


def measure_panel(app) -> None:
    st = app.world
    ed = app.editor
    if ed is None:
        imgui.text_colored(GREY, "open a model to measure and level it")
        return
    why = we.can_change(app)
    imgui.separator_text("Measure and rescale")
    _tool_button(app, "Measure", "measure")
    imgui.set_item_tooltip("pick two points on the model in the 3D view (a click; a drag turns the camera)")
    d = we.distance(app)
    if st.tool == "measure":
        imgui.same_line()
        imgui.text(f"distance {d:.6g}" if d is not None else HINTS["measure"])
    _, st.length = imgui.input_double("known length", st.length, 0.0, 0.0, "%.6g")
    imgui.begin_disabled(d is None or bool(why))
    if imgui.button("Rescale to this length"):
        app.guarded("rescale", we.rescale_to, app, st.length)
    imgui.end_disabled()
    imgui.separator_text("Up axis")
    imgui.begin_disabled(bool(why))
    if imgui.button("Up from the cameras"):
        app.guarded("level", we.level_from_cameras, app)
    imgui.set_item_tooltip("the dataset cameras' mean up becomes the view's up")
    imgui.end_disabled()
    _tool_button(app, "Pick the floor", "floor")
    imgui.set_item_tooltip("three points on the floor: the plane through them is levelled")
    if st.tool == "floor":
        imgui.same_line()
        imgui.text(f"{len(st.points)} of 3" if st.points else HINTS["floor"])
        imgui.begin_disabled(len(st.points) != 3 or bool(why))
        if imgui.button("Level to the floor"):
            app.guarded("level", we.level_from_floor, app)
        imgui.end_disabled()
    _tool_button(app, "Fit the floor", "fit")
    imgui.set_item_tooltip("a point on the floor: the plane fitted to the Gaussians around it is levelled")
    if st.tool == "fit":
        if st.fit_radius <= 0:
            st.fit_radius = float(np.ptp(ed.model.means, axis=0).max() / 20)
        _, st.fit_radius = imgui.input_double("fit radius", st.fit_radius, 0.0, 0.0, "%.4g")
        imgui.begin_disabled(len(st.points) != 1 or bool(why))
        if imgui.button("Level to the fitted plane"):
            app.guarded("level", we.level_from_fit, app)
        imgui.end_disabled()
    if why and why != "open a model first":
        imgui.text_colored(GREY, why)
    world = we.world_of(app)
    if not np.array_equal(world, np.eye(4)):
        s = float(np.cbrt(np.linalg.det(world[:3, :3])))
        turned = not np.allclose(world[:3, :3] / s, np.eye(3), atol=1e-12)
        what = [f"scaled by {s:.6g}"] * (s != 1.0) + ["turned"] * turned
        imgui.text_colored(GREY, f"the scene is {' and '.join(what) or 'moved'} (Ctrl+Z undoes)")
        imgui.begin_disabled(bool(why))
        if imgui.button("Back to the file's frame"):
            app.guarded("reset", we.set_world, app, np.eye(4))
        imgui.end_disabled()
