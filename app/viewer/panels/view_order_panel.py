"""The View order panel: the cameras on their best-fit plane, numbered in the order the stylization visits them, the
current view red and the next yellow (under the interleaved schedule they move at every step), the pass along the
path; a click goes to that camera."""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.viewer.live.runs import current_view_index, stylize_progress, trajectory
from app.viewer.panels.text_colours import GREY


def view_order_panel(doc, session, ui) -> None:
    items = trajectory(doc, session, ui)
    if not items:
        imgui.text_colored(GREY, "open a dataset to see the camera trajectory")
        return
    current = current_view_index(session)
    centers = np.array([c for _, c, _ in items], dtype=np.float64)
    xy = plane_coordinates(centers)
    avail = imgui.get_content_region_avail()
    side = max(60.0, min(avail.x, avail.y - 30))
    origin = imgui.get_cursor_screen_pos()
    imgui.invisible_button("trajectory canvas", imgui.ImVec2(side, side))
    clicked = imgui.is_item_clicked()
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    scale = (side - 24) / max(float((hi - lo).max()), 1e-9)
    pts = [(origin.x + 12 + (p[0] - lo[0]) * scale, origin.y + 12 + (p[1] - lo[1]) * scale) for p in xy]
    draw = imgui.get_window_draw_list()
    path_col = imgui.IM_COL32(60, 220, 255, 200)
    for a, b in zip(pts[:-1], pts[1:]):
        draw.add_line(imgui.ImVec2(*a), imgui.ImVec2(*b), path_col, 1.5)
    nxt = None if current is None else (current + 1) % len(items)
    for pos, ((source, _, virtual), p) in enumerate(zip(items, pts)):
        if pos == current:
            col, r = imgui.IM_COL32(255, 70, 50, 255), 6.0
        elif pos == nxt:
            col, r = imgui.IM_COL32(255, 210, 40, 255), 5.0
        else:
            col, r = imgui.IM_COL32(230, 230, 230, 255), 3.5
        if virtual:
            draw.add_circle(imgui.ImVec2(*p), r, col, 0, 1.5)
        else:
            draw.add_circle_filled(imgui.ImVec2(*p), r, col)
            draw.add_text(imgui.ImVec2(p[0] + 5, p[1] - 14), imgui.IM_COL32(200, 200, 200, 255), str(pos))
    if clicked:
        mouse = imgui.get_mouse_pos()
        d = [np.hypot(p[0] - mouse.x, p[1] - mouse.y) for p in pts]
        pos = int(np.argmin(d))
        if d[pos] < 15:
            ui.requests.camera = items[pos][0]
    ui.window.drawn_order = [source for source, _, virtual in items if not virtual]
    ui.window.order_points = pts  # where each trajectory position is drawn (tests look for the marks there)
    where = stylize_progress(session)
    imgui.text(f"{len(items)} views in order" + (f"; {where}" if where else "") + "; click a camera to go there")


def plane_coordinates(points: np.ndarray) -> np.ndarray:
    """(P, 3) -> (P, 2): coordinates on the best-fit plane (the two main axes of the camera centres)."""
    centred = points - points.mean(axis=0)
    if len(points) < 3:
        return np.stack([centred[:, 0], centred[:, 1]], axis=1)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return centred @ vt[:2].T
