"""What the panels share: the keys the help overlay lists, and the overlay itself."""

from __future__ import annotations

from imgui_bundle import imgui

KEYS = [("left drag", "orbit"), ("right / middle drag", "pan"), ("wheel", "zoom"), ("W A S D", "fly"),
        ("Q / E", "down / up"), ("Z / C", "roll"), ("N", "snap to the nearest dataset camera"), ("R", "reset view"),
        ("space", "pause / resume training"), ("Ctrl+Z / Ctrl+Y", "undo / redo an edit"),
        ("Delete", "delete the selection"), ("G / T / Y", "gizmo: move / turn / scale (again: off)"),
        ("H or F1", "this help")]


def help_overlay(app) -> None:
    io = imgui.get_io()
    imgui.set_next_window_pos(imgui.ImVec2(io.display_size.x / 2, io.display_size.y / 2), imgui.Cond_.always,
                              imgui.ImVec2(0.5, 0.5))
    imgui.set_next_window_bg_alpha(0.85)
    flags = imgui.WindowFlags_.always_auto_resize | imgui.WindowFlags_.no_collapse
    expanded, app.window.show_help = imgui.begin("Keys", True, flags)
    if expanded:
        for key, what in KEYS:
            imgui.text(f"{key:<22}{what}")
    imgui.end()
