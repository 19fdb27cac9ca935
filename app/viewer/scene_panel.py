"""The Scene panel: the files (model, dataset, painting, output folder), how the view renders, the dataset's cameras
and their photos, and pictures of the view (screenshot, depth EXR)."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
from imgui_bundle import imgui

from app.viewer.view3d import MODES, PHOTO_MODES


def _dialogs_available() -> bool:
    return any(shutil.which(t) for t in ("zenity", "kdialog", "qarma", "matedialog"))


def choose_file(title: str, filters: list[str]) -> str:
    """A path from the system's file dialog ('' when cancelled); an error when no dialog program exists."""
    if not _dialogs_available():
        raise ValueError("no file dialog program on this system (zenity or kdialog): type the path in the Scene "
                         "panel, or drop the file on the window")
    from imgui_bundle import portable_file_dialogs as pfd

    chosen = pfd.open_file(title, "", filters).result()
    return chosen[0] if chosen else ""


def _path_row(app, label: str, attr: str, action, filters: list[str]) -> None:
    button = f"Open {label}"
    width = imgui.calc_text_size(button).x + 2 * imgui.get_style().frame_padding.x + imgui.get_style().item_spacing.x
    imgui.set_next_item_width(max(imgui.get_content_region_avail().x - width, 40.0))
    changed, value = imgui.input_text_with_hint(f"##{label}", f"{label} path", getattr(app.paths, attr))
    if changed:
        setattr(app.paths, attr, value)
    imgui.same_line()
    if imgui.button(button):
        path = getattr(app.paths, attr) or app.guarded(f"open {label}", choose_file, f"Open {label}", filters)
        if path:
            app.guarded(f"open {label}", action, path)


DISPLAY_CHOICES = ("auto", "gl-cpu-sort", "gl-cpu-sort/f2", "gl-gpu-sort", "gl-gpu-sort/f2", "cuda", "cuda/pinned",
                   "cuda/interop")


def display_path_row(app) -> None:
    """How the view draws: the path chosen by timing on this machine (or set here), and why."""
    view = app.view
    current = view.display_override if view.display_override in DISPLAY_CHOICES else "auto"
    changed, i = imgui.combo("display path", DISPLAY_CHOICES.index(current), list(DISPLAY_CHOICES))
    if changed:
        view.set_display_override(DISPLAY_CHOICES[i])
    choice = view.display
    if choice is not None:
        imgui.text_disabled(f"drawing with {choice.label()}")
        imgui.set_item_tooltip("\n".join([choice.reason] + [f"{k}: {v}" for k, v in choice.skipped.items()]))
        note = choice.interop_note(view.cuda)
        if note:
            imgui.text_disabled(note)


def scene_panel(app) -> None:
    imgui.separator_text("Files")
    from training.model.model_io import FILE_DIALOG_PATTERN

    _path_row(app, "model", "model", app.open_model, ["Gaussians", FILE_DIALOG_PATTERN])
    _path_row(app, "dataset", "data", app.open_data, ["Scenes", "transforms.json cameras.bin images.bin"])
    _path_row(app, "painting", "style", app.open_style, ["Images", "*.jpg *.jpeg *.png *.exr *.tif"])
    changed, out = imgui.input_text("output folder", app.paths.out)
    if changed:
        app.paths.out = out
    info = app.model_info
    if info.get("count"):
        lo, hi = info["min"], info["max"]
        imgui.text(f"{info['count']:,} Gaussians, SH degree {info['sh_degree']}")
        imgui.text(f"bounds {np.array2string(lo, precision=2)} .. {np.array2string(hi, precision=2)}")
    if app.scene.cameras:
        imgui.text(f"{len(app.scene.cameras)} dataset cameras")
    imgui.separator_text("Render")
    s = app.view.settings
    changed, mode = imgui.combo("mode", MODES.index(s.mode), list(MODES))
    if changed:
        s.mode = MODES[mode]
        app.view.dirty = True
    display_path_row(app)
    changed, bg = imgui.color_edit3("background", list(s.background))
    if changed:
        s.background = tuple(bg)
        app.view.dirty = True
    changed, deg = imgui.slider_int("max SH degree", s.max_sh_degree, 0, 3)
    if changed:
        s.max_sh_degree = deg
        app.view.dirty = True
    imgui.begin_disabled(app.original is None)
    changed, s.split = imgui.checkbox("split: before | after stylization", s.split)
    app.view.dirty |= changed
    if s.split:
        changed, s.split_position = imgui.slider_float("divider", s.split_position, 0.0, 1.0)
        app.view.dirty |= changed
    imgui.end_disabled()
    if app.original is None:
        imgui.set_item_tooltip("the split view compares a model before and after stylization")
    for label, attr in (("frustums", "show_frustums"), ("stylization path", "show_path")):
        changed, value = imgui.checkbox(label, getattr(s, attr))
        if changed:
            setattr(s, attr, value)
            app.update_overlays()
    if app.view.camera is not None:
        changed, fov = imgui.slider_float("field of view", app.view.camera.fov_y_degrees, 10.0, 120.0)
        if changed:
            app.view.camera.set_fov(fov)
            app.view.moved()
    imgui.separator_text("Cameras")
    if app.scene.cameras:
        n = len(app.scene.cameras)
        index = app.window.photo_index
        changed, index = imgui.slider_int("camera", index, 0, n - 1)
        if changed:
            app.window.photo_index = index
        if imgui.button("Go to camera"):
            app.guarded("snap", app.snap_to_camera, app.window.photo_index if True else 0)
        imgui.same_line()
        if imgui.button("Nearest camera"):
            app.guarded("snap", app.snap_to_nearest)
        changed, photo = imgui.combo("photo", PHOTO_MODES.index(s.photo), list(PHOTO_MODES))
        if changed:
            s.photo = PHOTO_MODES[photo]
            if s.photo != "off":
                app.guarded("photo", app.set_photo, app.window.photo_index)
            app.view.dirty = True
        if s.photo == "blend":
            changed, s.photo_alpha = imgui.slider_float("photo opacity", s.photo_alpha, 0.0, 1.0)
            app.view.dirty |= changed
    if imgui.button("Reset view"):
        app.reset_camera()
    imgui.separator_text("Pictures")
    if imgui.button("Screenshot"):
        app.guarded("screenshot", screenshot, app)
    imgui.same_line()
    if imgui.button("Depth EXR"):
        app.guarded("depth", depth_exr, app)


def screenshot(app) -> Path:
    from training.scene.image_io import write_image

    img = app.view.read()
    if img is None:
        raise ValueError("nothing drawn yet")
    out = app.out_dir() / f"screenshot_{time.strftime('%Y%m%d_%H%M%S')}.png"
    write_image(out, img.astype(np.float32) / 255.0)
    app.say(f"wrote {out}")
    return out


def depth_exr(app) -> Path:
    from training.scene.image_io import write_image

    if app.view.camera is None or not app.view.has_model(0):
        raise ValueError("nothing to render")
    io = imgui.get_io()
    cam = app.view.camera.camera(int(io.display_size.x), int(io.display_size.y))
    depth = app.view.render_arrays(cam, ("depth",))["depth"]
    out = app.out_dir() / f"depth_{time.strftime('%Y%m%d_%H%M%S')}.exr"
    write_image(out, depth[..., None].astype(np.float32))
    app.say(f"wrote {out}")
    app.view.dirty = True
    return out
