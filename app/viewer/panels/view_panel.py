"""The 3D view as the central node of the docked layout: the view's picture (an offscreen texture, redrawn only when
something it shows changed) fills the node, and the mouse and keys over it turn the camera or draw a selection.

Panels dock around it and never cover it, so its rectangle is the part of the window a person sees the scene in:
the camera's aspect ratio, the selection gestures and the split divider all refer to it.
"""

from __future__ import annotations

from imgui_bundle import imgui

from app.viewer.display import gizmo
from app.viewer.camera import camera_span
from app.viewer.display.gestures import handle_gesture, handle_pick

VIEW_WINDOW = "3D view"


def view_window(doc, session, ui) -> None:
    """The gui function of the central dockable window (it calls begin/end itself: no padding, no scrolling)."""
    gizmo.begin_frame()
    imgui.push_style_var(imgui.StyleVar_.window_padding, imgui.ImVec2(0, 0))
    flags = (imgui.WindowFlags_.no_scrollbar | imgui.WindowFlags_.no_scroll_with_mouse
             | imgui.WindowFlags_.no_collapse)
    visible, _ = imgui.begin(VIEW_WINDOW, None, flags)
    imgui.pop_style_var()
    if visible:
        _contents(doc, session, ui)
    imgui.end()


def _contents(doc, session, ui) -> None:
    io = imgui.get_io()
    avail = imgui.get_content_region_avail()
    origin = imgui.get_cursor_screen_pos()
    scale = io.display_framebuffer_scale
    width, height = max(int(avail.x), 1), max(int(avail.y), 1)
    ui.window.view_rect = (int(origin.x), int(origin.y), width, height)  # window coordinates (logical pixels)
    size = (max(int(width * scale.x), 1), max(int(height * scale.y), 1))  # framebuffer pixels
    view = ui.view
    # input first, then the picture: a move is drawn in the frame that received it
    buttons = (imgui.ButtonFlags_.mouse_button_left | imgui.ButtonFlags_.mouse_button_right
               | imgui.ButtonFlags_.mouse_button_middle)
    if gizmo.holds_mouse(ui):
        imgui.dummy(imgui.ImVec2(width, height))  # the gizmo has the mouse: the canvas neither orbits nor selects
    else:
        imgui.invisible_button("3d view canvas", imgui.ImVec2(width, height), buttons)
    hovered, active = imgui.is_item_hovered(), imgui.is_item_active()
    ui.window.view_hovered = hovered or active
    left_free = not gizmo.left_is_taken(ui)
    view.handle_mouse(imgui, hovered, active, left_orbits=ui.edit.tool == "orbit" and left_free)
    if not (io.key_ctrl or io.key_super):  # under Ctrl or Super the keys are shortcuts, not camera moves
        span = camera_span(doc.cameras)
        view.handle_keys(imgui, min(ui.window.frame_dt, 0.1), fly_speed=0.5 * span,
                         enabled=not io.want_text_input and (imgui.is_window_focused() or hovered))
    else:
        view.flying = False
    training = session.running and session.status().state == "running"
    view.draw(size, split_ready=ui.training.before is not None, training=training)
    texture = view.texture
    draw_list = imgui.get_window_draw_list()
    if texture is not None and texture.size == size:
        # GL textures start at the bottom row: flip v so the picture stands upright
        draw_list.add_image(imgui.ImTextureRef(texture.glo), origin,
                            imgui.ImVec2(origin.x + width, origin.y + height), imgui.ImVec2(0, 1), imgui.ImVec2(1, 0))
    if left_free:
        handle_gesture(doc, session, ui, hovered)  # drawn over the picture
    handle_pick(ui, hovered)  # the measure and up tools' picks, drawn over the picture
    gizmo.view_gizmo(doc, session, ui, hovered)

