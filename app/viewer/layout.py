"""The window's layout: Hello ImGui's docking with the 3D view as the central node (nothing floats over it), the
panels docked left and right with tabs where they share a side, a status bar that is always visible, a menu, and
the keys overlay. The one module that knows every panel: each is a function of (document, session, UI state) that
imports no other panel.

The layout is remembered per user (``$XDG_CONFIG_HOME/splatstyler/viewer.ini``, default ``~/.config``) and
"View > Reset layout" puts it back. Fonts and panels follow the monitor's content scale (Hello ImGui's DPI
handling); the window opens at the monitor's work area unless a size is asked for.
"""

from __future__ import annotations

import os
from pathlib import Path

from imgui_bundle import hello_imgui, imgui

from app.viewer.dialogs import choose_photos_folder, open_from_dialog, save_project_as
from app.viewer.files import save_project, unless_unsaved
from app.viewer.live.sfm_run import phase_time_left
from app.viewer.panels import edit_panel, export_panel, gizmo_panel, select_tools_panel
from app.viewer.panels.colour_panel import colour_panel
from app.viewer.panels.measure_panel import measure_panel
from app.viewer.panels.path_panel import path_panel
from app.viewer.panels.photos_panel import photos_dialog
from app.viewer.panels.scene_panel import scene_panel
from app.viewer.panels.style_panel import style_panel
from app.viewer.panels.text_colours import RED
from app.viewer.panels.training_panel import messages_panel, training_panel
from app.viewer.panels.view_order_panel import view_order_panel
from app.viewer.panels.view_panel import VIEW_WINDOW, view_window

LEFT, LEFT_BOTTOM, RIGHT, RIGHT_BOTTOM = "LeftSpace", "LeftBottomSpace", "RightSpace", "RightBottomSpace"
MAIN = "MainDockSpace"
STYLE = "Style"  # the painting, its capacity map and the live sliders: in front while a stylization runs


def layout_file() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "splatstyler" / "viewer.ini"


def docking_splits() -> list:
    split = hello_imgui.DockingSplit
    return [split(MAIN, LEFT, imgui.Dir.left, 0.25), split(MAIN, RIGHT, imgui.Dir.right, 0.31),
            # the View order panel's plot reads well small; the Style panel above it holds the painting and sliders
            split(LEFT, LEFT_BOTTOM, imgui.Dir.down, 0.25), split(RIGHT, RIGHT_BOTTOM, imgui.Dir.down, 0.28)]


def dockable_windows(doc, session, ui) -> list:
    """Every panel, by name (the GUI tests address them so), in the dock it starts in; the first of a dock is the
    tab in front. A window lists its panel functions, drawn one below the other."""
    def window(label, dock, *panels):
        def gui():
            # labels keep about 25 characters beside the widgets, however narrow the dock
            imgui.push_item_width(-imgui.get_font_size() * 12.5)
            for panel in panels:
                ui.messages.guarded(label, panel, doc, session, ui)
            imgui.pop_item_width()

        return hello_imgui.DockableWindow(label, dock, gui, True, False)

    view = hello_imgui.DockableWindow(VIEW_WINDOW, MAIN, lambda: view_window(doc, session, ui), True, False)
    view.call_begin_end = False
    view.include_in_view_menu = False
    edit = (edit_panel.selection_section, select_tools_panel.more_selections, gizmo_panel.gizmo_section,
            edit_panel.edits_section, export_panel.export_section)
    return [view,
            window("Scene", LEFT, scene_panel), window("Edit", LEFT, *edit),
            window("Colour", LEFT, colour_panel),
            window("Scale and up", LEFT, measure_panel),  # the measure and up tools
            window("Camera path", LEFT, path_panel), window("Messages", LEFT_BOTTOM, messages_panel),
            window("Training", RIGHT, training_panel), window(STYLE, RIGHT, style_panel),
            window("View order", RIGHT_BOTTOM, view_order_panel)]


def configure(rp, doc, session, ui) -> None:
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
    rp.docking_params.dockable_windows = dockable_windows(doc, session, ui)
    rp.callbacks.show_status = lambda: status_bar(session, ui)
    rp.callbacks.show_menus = lambda: menus(doc, session, ui)
    rp.callbacks.confirm_exit = lambda: confirm_exit(doc, session, ui)
    ini = layout_file()
    ini.parent.mkdir(parents=True, exist_ok=True)
    rp.ini_folder_type = hello_imgui.IniFolderType.absolute_path
    rp.ini_filename = str(ini)


def status_text(session, ui) -> str:
    """The status bar's line: stage, state, iteration and total, it/s, time left, Gaussians, PSNR or loss, the
    view's frames per second, and how far the view is behind the trainer."""
    status = session.status()
    bits = []
    if status.detail:  # a stage whose steps are no iterations (SfM): its phase, in words
        bits += [f"{status.stage}: {status.state}", status.detail]
        if status.seconds_left is not None and status.state == "running":
            bits.append(phase_time_left(status.seconds_left))  # the phase's: SfM's phases differ in kind
    elif session.has_trainer or status.stage:
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
        shown = ui.training.shown_step
        behind = status.step - shown if shown is not None else None
        if behind and behind > 0 and status.state == "running":
            bits.append(f"view {behind} steps behind")
    else:
        bits.append("idle")
    count = ui.window.model_info.get("count")
    if count and status.stage != "sfm":  # SfM shows its points, which its line counts
        bits.append(f"{count:,} Gaussians")
    bits.append(f"{ui.window.fps:.0f} fps")
    return "   |   ".join(bits)


def status_bar(session, ui) -> None:
    imgui.text(status_text(session, ui))
    status = session.status()
    if status.total:
        imgui.same_line()
        imgui.progress_bar(status.step / status.total, imgui.ImVec2(160, 0))
    if ui.messages.error:
        imgui.same_line()
        imgui.text_colored(RED, ui.messages.error)


def menus(doc, session, ui) -> None:
    guarded = ui.messages.guarded
    if imgui.begin_menu("File"):
        if imgui.menu_item("New from photos...", "", False)[0]:
            guarded("new from photos", choose_photos_folder, ui)
        imgui.separator()
        for label, what in (("Open model...", "model"), ("Open dataset...", "data"), ("Open painting...", "style")):
            if imgui.menu_item(label, "", False)[0]:
                guarded("open", open_from_dialog, doc, session, ui, what)
        if imgui.menu_item("Add model to scene...", "", False)[0]:
            guarded("add model", open_from_dialog, doc, session, ui, "add")
        imgui.separator()
        if imgui.menu_item("Open project...", "", False)[0]:
            guarded("open project", open_from_dialog, doc, session, ui, "project")
        if imgui.menu_item("Save project", "Ctrl+S", False)[0]:
            guarded("save project", save_project, doc, session, ui)
        if imgui.menu_item("Save project as...", "Ctrl+Shift+S", False)[0]:
            guarded("save project as", save_project_as, doc, session, ui)
        imgui.separator()
        if imgui.menu_item("Quit", "Ctrl+Q", False)[0]:
            quit_app(doc, session, ui)
        imgui.end_menu()
    if imgui.begin_menu("View"):
        if imgui.menu_item("Reset layout", "", False)[0]:
            hello_imgui.get_runner_params().docking_params.layout_reset = True
        _, ui.window.show_help = imgui.menu_item("Keys (H)", "", ui.window.show_help)
        imgui.end_menu()


def floating_windows(doc, session, ui) -> None:
    """The windows over the layout: the New from photos dialog, while it is open, and the question the window asks
    (over everything, as a modal)."""
    ui.messages.guarded("new from photos", photos_dialog, doc, session, ui)
    question_modal(ui)


def question_modal(ui) -> None:
    """The first of ``ui.questions`` as a modal: its text and a button per answer; an answer runs its action (a
    failure is one line in the window) and the question goes."""
    if not ui.questions:
        return
    q = ui.questions[0]
    if not imgui.is_popup_open(q.title):
        imgui.open_popup(q.title)
    io = imgui.get_io()
    imgui.set_next_window_pos(imgui.ImVec2(io.display_size.x / 2, io.display_size.y / 2), imgui.Cond_.appearing,
                              imgui.ImVec2(0.5, 0.5))
    opened, _ = imgui.begin_popup_modal(q.title, None, imgui.WindowFlags_.always_auto_resize)
    if not opened:
        return
    imgui.push_text_wrap_pos(imgui.get_font_size() * 32)
    imgui.text_wrapped(q.text)
    imgui.pop_text_wrap_pos()
    imgui.spacing()
    for i, (label, action) in enumerate(q.answers):
        if i:
            imgui.same_line()
        if imgui.button(label):
            imgui.close_current_popup()
            ui.questions.remove(q)
            if action is not None:
                ui.messages.guarded(label.lower(), action)
    imgui.end_popup()


def quit_app(doc, session, ui) -> None:
    """File > Quit and Ctrl+Q: as the window's close button (the trainer stops and saves, the layout is kept),
    once unsaved edits are saved or discarded (``unless_unsaved``)."""
    unless_unsaved(doc, session, ui, "quitting", exit_now)


def exit_now() -> None:
    hello_imgui.get_runner_params().app_shall_exit = True


def confirm_exit(doc, session, ui) -> bool:
    """The window's close button (and Alt-F4): True to close now; with unsaved edits False, and the question is
    asked in the next frame (its Save and Discard close the window). A signal (SIGTERM, Ctrl-C) closes without
    asking: the recovery project keeps the edits then."""
    if not doc.unsaved():
        return True
    quit_app(doc, session, ui)
    return False


def window_title(doc, ui) -> str:
    """splatstyler, the project (or the model) the scene is, and "*" while it has unsaved edits."""
    name = Path(ui.project.path).name if ui.project.path else Path(ui.paths.model).name if ui.paths.model else ""
    return "splatstyler" + (f" - {name}" if name else "") + (" *" if doc.unsaved() else "")


KEYS = [("left drag", "orbit"), ("right / middle drag", "pan"), ("wheel", "zoom"), ("W A S D", "fly"),
        ("Q / E", "down / up"), ("Z / C", "roll"), ("N", "snap to the nearest dataset camera"), ("R", "reset view"),
        ("space", "pause / resume training"), ("Ctrl+Z / Ctrl+Y", "undo / redo an edit"),
        ("Delete", "delete the selection"), ("G / T / Y", "gizmo: move / turn / scale (again: off)"),
        ("Ctrl+S", "save the project"), ("Ctrl+Shift+S", "save the project as..."),
        ("Ctrl+Q", "quit (a run saves, as on closing the window; unsaved edits: Save, Discard or Cancel)"),
        ("H or F1", "this help")]


def help_overlay(ui) -> None:
    """The keys, over the middle of the window (H or F1), in two columns (a table: the font is proportional, so
    padding the keys with spaces did not line the descriptions up)."""
    io = imgui.get_io()
    imgui.set_next_window_pos(imgui.ImVec2(io.display_size.x / 2, io.display_size.y / 2), imgui.Cond_.always,
                              imgui.ImVec2(0.5, 0.5))
    imgui.set_next_window_bg_alpha(0.85)
    flags = imgui.WindowFlags_.always_auto_resize | imgui.WindowFlags_.no_collapse
    expanded, ui.window.show_help = imgui.begin("Keys", True, flags)
    if expanded and imgui.begin_table("keys", 2, imgui.TableFlags_.sizing_fixed_fit):
        for key, what in KEYS:
            imgui.table_next_row()
            imgui.table_next_column()
            imgui.text(key)
            imgui.table_next_column()
            imgui.text(what)
        imgui.end_table()
    pos, size = imgui.get_window_pos(), imgui.get_window_size()
    ui.window.help_rect = (int(pos.x), int(pos.y), int(size.x), int(size.y))  # where it is on screen (tests look)
    imgui.end()


def front_tab(name: str) -> str:
    """The window in front of the dock that holds window ``name``: what the screen shows there ("" while it is not
    docked, as in the first frames, before the layout is applied)."""
    window = imgui.internal.find_window_by_name(name)
    node = None if window is None else window.dock_node
    if node is None or node.visible_window is None:
        return ""
    return node.visible_window.name


def bring_to_front(name: str) -> None:
    """Put window ``name``'s tab in front of its dock, as a click on the tab does. The keyboard stays where it is
    (the 3D view keeps its fly keys) unless it is in that dock (a click on the Training panel's Stylize button): imgui
    keeps the focused window's tab in front, so the window comes forward with the focus."""
    window = imgui.internal.find_window_by_name(name)
    if window is None or window.dock_node is None or window.dock_node.tab_bar is None:
        return
    focused = imgui.get_current_context().nav_window
    if focused is not None and focused.root_window is not None and focused.root_window.dock_id == window.dock_id:
        imgui.set_window_focus(name)
    else:
        window.dock_node.tab_bar.next_selected_tab_id = window.tab_id


def style_forward(ui) -> None:
    """A stylization began: the Style tab (the painting, its capacity map, the live sliders) is to come to the
    front (at the next frame where the layout is in place: a run started with the window may begin before)."""
    ui.window.style_tab = "wanted"
    ui.window.style_covers = ""


def watch_style_tab(ui) -> None:
    """Each frame: bring the Style tab forward when wanted, remembering the tab it covers; once the user puts
    another tab in front during the run, the tabs are theirs (nothing comes back at the end)."""
    w = ui.window
    if not w.style_tab:
        return
    front = front_tab(STYLE)
    if not front:
        return
    if w.style_tab == "wanted":
        w.style_covers = "" if front == STYLE else front
        w.style_tab = "asked" if w.style_covers else ""
        if w.style_covers:
            bring_to_front(STYLE)
    elif front == STYLE:
        w.style_tab = "shown"
    elif w.style_tab == "shown":
        w.style_tab, w.style_covers = "", ""


def style_back(ui) -> None:
    """The stylization ended: the tab the Style tab covered comes back, unless the user chose a tab meanwhile."""
    covered = ui.window.style_covers
    ui.window.style_tab, ui.window.style_covers = "", ""
    if covered and front_tab(STYLE) == STYLE:
        bring_to_front(covered)
