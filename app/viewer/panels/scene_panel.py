"""The Scene panel: the files (model, dataset, painting, output folder), how the view renders, the dataset's cameras
and their photos, and pictures of the view (screenshot, depth EXR)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from imgui_bundle import imgui

from app.viewer.display.view3d import MODES, PHOTO_MODES
from app.viewer.dialogs import DIALOG_FILTERS, choose_file
from app.viewer.files import open_data, open_model, open_style


def _path_row(doc, session, ui, label: str, attr: str, action) -> None:
    button = f"Open {label}"
    width = imgui.calc_text_size(button).x + 2 * imgui.get_style().frame_padding.x + imgui.get_style().item_spacing.x
    imgui.set_next_item_width(max(imgui.get_content_region_avail().x - width, 40.0))
    changed, value = imgui.input_text_with_hint(f"##{label}", f"{label} path", getattr(ui.paths, attr))
    if changed:
        setattr(ui.paths, attr, value)
    imgui.same_line()
    if imgui.button(button):
        path = getattr(ui.paths, attr) or ui.messages.guarded(f"open {label}", choose_file, f"Open {label}",
                                                               DIALOG_FILTERS[attr])
        if path:
            ui.messages.guarded(f"open {label}", action, doc, session, ui, path)


DISPLAY_CHOICES = ("auto", "gl-cpu-sort", "gl-cpu-sort/f2", "gl-gpu-sort", "gl-gpu-sort/f2", "cuda", "cuda/pinned",
                   "cuda/interop")


def display_path_row(ui) -> None:
    """How the view draws: the path chosen by timing on this machine (or set here), and why."""
    view = ui.view
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


def scene_panel(doc, session, ui) -> None:
    imgui.separator_text("Files")
    _path_row(doc, session, ui, "model", "model", open_model)
    _path_row(doc, session, ui, "dataset", "data", open_data)
    _path_row(doc, session, ui, "painting", "style", open_style)
    changed, out = imgui.input_text("output folder", ui.paths.out)
    if changed:
        ui.paths.out = out
    info = ui.window.model_info
    view = ui.view
    if info.get("count"):
        lo, hi = info["min"], info["max"]
        if session.status().stage == "sfm":  # structure from motion's sparse points, drawn as small round splats
            imgui.text(f"{info['count']:,} sparse points (structure from motion)")
        else:
            imgui.text(f"{info['count']:,} Gaussians, SH degree {info['sh_degree']}")
        imgui.text(f"bounds {np.array2string(lo, precision=2)} .. {np.array2string(hi, precision=2)}")
    if doc.cameras:
        imgui.text(f"{len(doc.cameras)} dataset cameras")
    imgui.separator_text("Render")
    s = view.settings
    changed, mode = imgui.combo("mode", MODES.index(s.mode), list(MODES))
    if changed:
        s.mode = MODES[mode]
        view.dirty = True
    display_path_row(ui)
    changed, bg = imgui.color_edit3("background", list(s.background))
    if changed:
        s.background = tuple(bg)
        view.dirty = True
    changed, deg = imgui.slider_int("max SH degree", s.max_sh_degree, 0, 3)
    if changed:
        s.max_sh_degree = deg
        view.dirty = True
    before = ui.training.before
    imgui.begin_disabled(before is None)
    changed, s.split = imgui.checkbox("split: before | after stylization", s.split)
    view.dirty |= changed
    if s.split:
        changed, s.split_position = imgui.slider_float("divider", s.split_position, 0.0, 1.0)
        view.dirty |= changed
    imgui.end_disabled()
    if before is None:
        imgui.set_item_tooltip("the split view compares a model before and after stylization")
    for label, attr in (("frustums", "show_frustums"), ("stylization path", "show_path")):
        changed, value = imgui.checkbox(label, getattr(s, attr))
        if changed:
            setattr(s, attr, value)
            ui.requests.overlays = True
    if view.camera is not None:
        changed, fov = imgui.slider_float("field of view", view.camera.fov_y_degrees, 10.0, 120.0)
        if changed:
            view.camera.set_fov(fov)
            view.moved()
    imgui.separator_text("Cameras")
    if doc.cameras:
        n = len(doc.cameras)
        index = ui.window.photo_index
        changed, index = imgui.slider_int("camera", index, 0, n - 1)
        if changed:
            ui.window.photo_index = index
        if imgui.button("Go to camera"):
            ui.requests.camera = ui.window.photo_index
        imgui.same_line()
        if imgui.button("Nearest camera"):
            ui.requests.nearest = True
        changed, photo = imgui.combo("photo", PHOTO_MODES.index(s.photo), list(PHOTO_MODES))
        if changed:
            s.photo = PHOTO_MODES[photo]
            if s.photo != "off":
                ui.requests.photo = ui.window.photo_index
            view.dirty = True
        if s.photo == "blend":
            changed, s.photo_alpha = imgui.slider_float("photo opacity", s.photo_alpha, 0.0, 1.0)
            view.dirty |= changed
    if imgui.button("Reset view"):
        ui.requests.reset = True
    imgui.separator_text("Pictures")
    if imgui.button("Screenshot"):
        ui.messages.guarded("screenshot", screenshot, ui)
    imgui.same_line()
    if imgui.button("Depth EXR"):
        ui.messages.guarded("depth", depth_exr, ui)


def screenshot(ui) -> Path:
    from training.scene.image_io import write_image

    img = ui.view.read()
    if img is None:
        raise ValueError("nothing drawn yet")
    out = ui.out_dir() / f"screenshot_{time.strftime('%Y%m%d_%H%M%S')}.png"
    write_image(out, img.astype(np.float32) / 255.0)
    ui.messages.say(f"wrote {out}")
    return out


def depth_exr(ui) -> Path:
    from training.scene.image_io import write_image

    view = ui.view
    if view.camera is None or not view.has_model(0):
        raise ValueError("nothing to render")
    io = imgui.get_io()
    cam = view.camera.camera(int(io.display_size.x), int(io.display_size.y))
    depth = view.render_arrays(cam, ("depth",))["depth"]
    out = ui.out_dir() / f"depth_{time.strftime('%Y%m%d_%H%M%S')}.exr"
    write_image(out, depth[..., None].astype(np.float32))
    ui.messages.say(f"wrote {out}")
    view.dirty = True
    return out
