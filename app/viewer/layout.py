"""The window's layout: Hello ImGui's docking with the 3D view as the central node (nothing floats over it), the
panels docked left and right with tabs where they share a side, a status bar that is always visible, and a menu.

The layout is remembered per user (``$XDG_CONFIG_HOME/splatstyler/viewer.ini``, default ``~/.config``) and
"View > Reset layout" puts it back. Fonts and panels follow the monitor's content scale (Hello ImGui's DPI
handling); the window opens at the monitor's work area unless a size is asked for.
"""

from __future__ import annotations

import os
from pathlib import Path

from imgui_bundle import hello_imgui, imgui

LEFT, LEFT_BOTTOM, RIGHT, RIGHT_BOTTOM = "LeftSpace", "LeftBottomSpace", "RightSpace", "RightBottomSpace"
MAIN = "MainDockSpace"


def layout_file() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "splatstyler" / "viewer.ini"


def docking_splits() -> list:
    split = hello_imgui.DockingSplit
    return [split(MAIN, LEFT, imgui.Dir.left, 0.25), split(MAIN, RIGHT, imgui.Dir.right, 0.31),
            split(LEFT, LEFT_BOTTOM, imgui.Dir.down, 0.25), split(RIGHT, RIGHT_BOTTOM, imgui.Dir.down, 0.36)]


def dockable_windows(app) -> list:
    """Every panel, by name (the GUI tests address them so), in the dock it starts in; the first of a dock is the
    tab in front."""
    from app.viewer.colour_panel import colour_panel
    from app.viewer.edit_panel import edit_panel
    from app.viewer.measure_panel import measure_panel
    from app.viewer.path_panel import path_panel
    from app.viewer.scene_panel import scene_panel
    from app.viewer.style_panel import style_panel
    from app.viewer.training_panel import messages_panel, training_panel
    from app.viewer.view_order_panel import view_order_panel
    from app.viewer.view_panel import VIEW_WINDOW, view_window

    def window(label, dock, panel):
        def gui():
            # labels keep about 25 characters beside the widgets, however narrow the dock
            imgui.push_item_width(-imgui.get_font_size() * 12.5)
            app.guarded(label, panel, app)
            imgui.pop_item_width()

        return hello_imgui.DockableWindow(label, dock, gui, True, False)

    view = hello_imgui.DockableWindow(VIEW_WINDOW, MAIN, lambda: view_window(app), True, False)
    view.call_begin_end = False
    view.include_in_view_menu = False
    return [view,
            window("Scene", LEFT, scene_panel), window("Edit", LEFT, edit_panel),
            window("Colour", LEFT, colour_panel),
            window("Scale and up", LEFT, measure_panel),  # the measure and up tools
            window("Camera path", LEFT, path_panel), window("Messages", LEFT_BOTTOM, messages_panel),
            window("Training", RIGHT, training_panel), window("Style", RIGHT, style_panel),
            window("View order", RIGHT_BOTTOM, view_order_panel)]


def configure(rp, app) -> None:
    """Docking, status bar, menus and the remembered layout on Hello ImGui's runner parameters."""
    wp = rp.imgui_window_params
    wp.default_imgui_window_type = hello_imgui.DefaultImGuiWindowType.provide_full_screen_dock_space
    wp.enable_viewports = False
    wp.show_menu_bar = True
    wp.show_menu_app = False
    wp.show_menu_view = False  # ours (below) holds what a user needs: reset layout, keys
    wp.show_status_bar = True
    wp.show_status_fps = False  # ours says the view's frames per second beside the trainer's figures
    wp.remember_status_bar_settings = False
    wp.config_windows_move_from_title_bar_only = True
    rp.docking_params.docking_splits = docking_splits()
    rp.docking_params.dockable_windows = dockable_windows(app)
    rp.callbacks.show_status = lambda: status_bar(app)
    rp.callbacks.show_menus = lambda: menus(app)
    ini = layout_file()
    ini.parent.mkdir(parents=True, exist_ok=True)
    rp.ini_folder_type = hello_imgui.IniFolderType.absolute_path
    rp.ini_filename = str(ini)


def status_text(app) -> str:
    """The status bar's line: stage, state, iteration and total, it/s, time left, Gaussians, PSNR or loss, the
    view's frames per second, and how far the view is behind the trainer."""
    session = app.session
    status = session.status()
    bits = []
    if session.trainer is not None or status.stage:
        line = f"{status.stage or '-'}: {status.state}"
        if status.total:
            line += f" {status.step}/{status.total}"
        bits.append(line)
        bits.append(f"{status.steps_per_second:.1f} it/s")
        if status.seconds_left is not None and status.state == "running":
            bits.append(f"{status.seconds_left:.0f} s left")
        m = status.last_metrics
        if "psnr" in m and m["psnr"] == m["psnr"]:
            bits.append(f"PSNR {m['psnr']:.2f}")
        elif "loss" in m:
            bits.append(f"loss {m['loss']:.4g}")
        behind = status.step - app.training.shown_step if app.training.shown_step is not None else None
        if behind and behind > 0 and status.state == "running":
            bits.append(f"view {behind} steps behind")
    else:
        bits.append("idle")
    count = app.model_info.get("count")
    if count:
        bits.append(f"{count:,} Gaussians")
    bits.append(f"{app.window.fps:.0f} fps")
    return "   |   ".join(bits)


def status_bar(app) -> None:
    imgui.text(status_text(app))
    status = app.session.status()
    if status.total:
        imgui.same_line()
        imgui.progress_bar(status.step / status.total, imgui.ImVec2(160, 0))
    if app.error:
        imgui.same_line()
        imgui.text_colored(imgui.ImVec4(1.0, 0.4, 0.35, 1.0), app.error)


def menus(app) -> None:
    if imgui.begin_menu("File"):
        for label, attr in (("Open model...", "model"), ("Open dataset...", "data"), ("Open painting...", "style")):
            if imgui.menu_item(label, "", False)[0]:
                app.guarded("open", app.open_from_dialog, attr)
        if imgui.menu_item("Add model to scene...", "", False)[0]:
            from app.viewer.gizmo import add_from_dialog

            app.guarded("add model", add_from_dialog, app)
        imgui.separator()
        if imgui.menu_item("Open project...", "", False)[0]:
            app.guarded("open project", app.open_from_dialog, "project")
        if imgui.menu_item("Save project", "Ctrl+S", False)[0]:
            app.guarded("save project", app.save_project)
        imgui.separator()
        if imgui.menu_item("Quit", "", False)[0]:
            hello_imgui.get_runner_params().app_shall_exit = True
        imgui.end_menu()
    if imgui.begin_menu("View"):
        if imgui.menu_item("Reset layout", "", False)[0]:
            hello_imgui.get_runner_params().docking_params.layout_reset = True
        _, app.window.show_help = imgui.menu_item("Keys (H)", "", app.window.show_help)
        imgui.end_menu()
