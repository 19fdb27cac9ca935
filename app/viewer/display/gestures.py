"""What the mouse does over the 3D view besides turning the camera: the selection gestures (rectangle, brush, lasso,
as SuperSplat users know them, and the surface brush and colour pick of select_tools.py) and the picks of the
measure and up tools (a click, press and release without dragging, picks the point under the cursor; a drag still
turns the camera, so a point hidden from here can be picked from elsewhere). Each is one undo step or one point.

Positions: imgui gives the mouse in logical window pixels; the view's camera is in framebuffer pixels from the
view's corner (``pixels``, ``view_camera``).
"""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.viewer.edit import select_tools as st
from app.viewer.edit import editor as sel
from app.viewer.edit import world_edit as we
from app.viewer.edit.colour_view import displayed

VIEW_TOOLS = ("surface brush", "colour pick")  # the tools of the Edit panel's list that select_tools.py serves
PICK_LINE = imgui.IM_COL32(120, 255, 60, 255)  # green: apart from selection, frustums and paths (orange, yellow, cyan)


def pixels(ui, x: float, y: float) -> tuple[float, float]:
    """imgui's (logical) mouse position -> pixels of the view's camera (framebuffer pixels from the view's corner)."""
    scale = imgui.get_io().display_framebuffer_scale
    left, top = ui.window.view_rect[:2]
    return (x - left) * scale.x, (y - top) * scale.y


def view_camera(ui):
    """The camera of the picture the view shows (its size in framebuffer pixels)."""
    io = imgui.get_io()
    w = int(ui.window.view_rect[2] * io.display_framebuffer_scale.x)
    h = int(ui.window.view_rect[3] * io.display_framebuffer_scale.y)
    return ui.view.camera.camera(w, h)


def on_screen(ui, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Window coordinates of world points, and whether each is in front of the view's camera."""
    uv, front = view_camera(ui).project(points)
    scale = imgui.get_io().display_framebuffer_scale
    x, y = ui.window.view_rect[:2]
    return np.stack([x + uv[:, 0] / scale.x, y + uv[:, 1] / scale.y], axis=1), front


# ------------------------------------------------------------------ selection gestures
def handle_gesture(doc, session, ui, hovered: bool) -> None:
    """With a selection tool chosen, a left drag that starts on the 3D view selects instead of orbiting."""
    edit = ui.edit
    if edit.tool == "orbit" or doc.editor is None or ui.view.camera is None:
        edit.gesture = []
        return
    mouse = imgui.get_mouse_pos()
    if imgui.is_mouse_clicked(imgui.MouseButton_.left) and hovered:
        edit.gesture = [(mouse.x, mouse.y)]
    elif edit.gesture and imgui.is_mouse_down(imgui.MouseButton_.left):
        if (mouse.x, mouse.y) != edit.gesture[-1]:
            edit.gesture.append((mouse.x, mouse.y))
        draw_gesture(ui)
    elif edit.gesture and imgui.is_mouse_released(imgui.MouseButton_.left):
        points = [pixels(ui, x, y) for x, y in edit.gesture]
        edit.gesture = []
        ui.messages.guarded("select", select_by_gesture, doc, session, ui, points)


def select_by_gesture(doc, session, ui, points: list[tuple[float, float]]) -> None:
    """A finished drag or click over the view (points in the view camera's pixels) selects by the current tool."""
    if ui.edit.tool in VIEW_TOOLS:
        return _view_tool(doc, session, ui, points)
    cam = view_camera(ui)
    means = doc.editor.model.means
    if ui.edit.tool == "rect":
        (x0, y0), (x1, y1) = points[0], points[-1]
        picked = sel.in_rect(means, cam, x0, y0, x1, y1)
    elif ui.edit.tool == "brush":
        scale = imgui.get_io().display_framebuffer_scale.x
        picked = np.zeros(len(means), bool)
        for x, y in points:
            picked |= sel.in_brush(means, cam, x, y, ui.edit.brush_radius * scale)
    else:
        picked = sel.in_lasso(means, cam, points)
    doc.editor.select(picked, ui.edit.select_mode)


def shown_sh(doc, session) -> np.ndarray:
    """The colours the view shows for the editor's rows (after the colour edits)."""
    return displayed(doc, session, doc.editor.model).sh


def render_depth(ui, camera) -> np.ndarray:
    """(H, W) depth the renderer composites for ``camera`` (0 where nothing is drawn), top row first."""
    return ui.view.render_arrays(camera, ("depth",))["depth"]


def _view_tool(doc, session, ui, points: list[tuple[float, float]]) -> None:
    """The surface brush's stroke, or the colour pick's click."""
    ed, s = doc.editor, ui.select_tools
    cam = view_camera(ui)
    if ui.edit.tool == "surface brush":
        scale = imgui.get_io().display_framebuffer_scale.x
        picked = st.surface_brush(ed.model.means, cam, points, ui.edit.brush_radius * scale,
                                  render_depth(ui, cam), s.surface_tolerance)
        ed.select(picked, ui.edit.select_mode)
        return
    x, y = points[-1]
    row = st.pick(ed.model, cam, x, y, visible=~ed.hidden)
    if row is None:
        ui.messages.say("colour pick: no Gaussian under the cursor")
        return
    sh = shown_sh(doc, session)
    s.picked = tuple(float(c) for c in st.base_colours(sh[row:row + 1])[0])
    ed.select(st.similar_colour(sh, s.picked, s.colour_tolerance), ui.edit.select_mode)
    ui.messages.say(f"colour pick: RGB {s.picked[0]:.2f} {s.picked[1]:.2f} {s.picked[2]:.2f}, "
                    f"{int(ed.selected.sum()):,} selected")


def draw_gesture(ui) -> None:
    draw = imgui.get_window_draw_list()  # the 3D view's own: clipped to it, and redrawn whole every frame
    col = imgui.IM_COL32(255, 200, 60, 230)
    pts = ui.edit.gesture
    if ui.edit.tool == "rect":
        (x0, y0), (x1, y1) = pts[0], pts[-1]
        draw.add_rect(imgui.ImVec2(min(x0, x1), min(y0, y1)), imgui.ImVec2(max(x0, x1), max(y0, y1)), col, 0.0,
                      1.5)
    elif ui.edit.tool in ("brush", "surface brush"):
        for x, y in pts[-1:]:
            draw.add_circle(imgui.ImVec2(x, y), ui.edit.brush_radius, col, 0, 1.5)
    else:
        for (ax, ay), (bx, by) in zip(pts[:-1], pts[1:]):
            draw.add_line(imgui.ImVec2(ax, ay), imgui.ImVec2(bx, by), col, 1.5)


# ------------------------------------------------------------------ the measure and up tools' picks
def handle_pick(ui, hovered: bool) -> None:
    """Every frame after the view's input: a click picks with the current tool; the picks are drawn over the
    picture."""
    tools = ui.world
    if not tools.tool or ui.view.camera is None:
        return
    io = imgui.get_io()
    if imgui.is_mouse_clicked(imgui.MouseButton_.left):
        tools.pressed = hovered and ui.edit.tool == "orbit"
    elif tools.pressed and imgui.is_mouse_released(imgui.MouseButton_.left):
        tools.pressed = False
        if io.mouse_drag_max_distance_sqr[0] <= io.mouse_drag_threshold ** 2:
            mouse = imgui.get_mouse_pos()
            point = ui.messages.guarded("pick", we.pick, ui, view_camera(ui), *pixels(ui, mouse.x, mouse.y))
            if point is not None:
                we.add_point(tools, point)
    draw_picks(ui)


def draw_picks(ui) -> None:
    """The picked points as dots, the measure's line with its length at its middle, the floor's triangle."""
    tools = ui.world
    if not tools.points:
        return
    xy, front = on_screen(ui, np.array(tools.points))
    screen = [imgui.ImVec2(float(x), float(y)) for x, y in xy]
    draw = imgui.get_window_draw_list()
    n = len(screen)
    if n > 1:
        for i in range(n if n == 3 else n - 1):
            j = (i + 1) % n
            if front[i] and front[j]:
                draw.add_line(screen[i], screen[j], PICK_LINE, 2.0)
    for p, ok in zip(screen, front):
        if ok:
            draw.add_circle_filled(p, 4.0, PICK_LINE)
    d = we.distance(tools)
    if d is not None and front.all():
        text = f"{d:.4g}"
        mid = imgui.ImVec2((screen[0].x + screen[1].x) / 2, (screen[0].y + screen[1].y) / 2)
        size = imgui.calc_text_size(text)
        corner = imgui.ImVec2(mid.x + 6, mid.y - size.y - 4)
        draw.add_rect_filled(imgui.ImVec2(corner.x - 3, corner.y - 2),
                             imgui.ImVec2(corner.x + size.x + 3, corner.y + size.y + 2), imgui.IM_COL32(0, 0, 0, 190))
        draw.add_text(corner, PICK_LINE, text)
