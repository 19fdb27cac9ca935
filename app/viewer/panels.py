"""The viewer's panels (imgui-bundle): Scene, Training, Style, View order, and the help overlay.

Each panel reads the app's state and turns a user's action into one call on the app or its session; none of
them touches the trainer directly. Widget labels are stable: the GUI tests address them by name.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
from imgui_bundle import imgui, implot

from app.viewer.view3d import MODES, PHOTO_MODES
from training.stylize import defaults as D

KEYS = [("left drag", "orbit"), ("right / middle drag", "pan"), ("wheel", "zoom"), ("W A S D", "fly"),
        ("Q / E", "down / up"), ("Z / C", "roll"), ("N", "snap to the nearest dataset camera"), ("R", "reset view"),
        ("space", "pause / resume training"), ("Ctrl+Z / Ctrl+Y", "undo / redo an edit"),
        ("Delete", "delete the selection"), ("H or F1", "this help")]
RED = imgui.ImVec4(1.0, 0.4, 0.35, 1.0)
GREY = imgui.ImVec4(0.6, 0.6, 0.6, 1.0)
# Settings the stylizer fixes when it starts; the panel greys them during a run and says why.
RESTART = "fixed while a stylization runs: it shapes the run from its first step (stop and start again)"


def draw_all(app) -> None:
    from app.viewer.edit_panel import edit_panel

    from app.viewer.path_panel import path_panel

    scene_panel(app)
    edit_panel(app)
    path_panel(app)
    training_panel(app)
    style_panel(app)
    view_order_panel(app)
    if app.show_help:
        help_overlay(app)


def _window(name: str, pos, size) -> bool:
    imgui.set_next_window_pos(imgui.ImVec2(*pos), imgui.Cond_.first_use_ever)
    imgui.set_next_window_size(imgui.ImVec2(*size), imgui.Cond_.first_use_ever)
    expanded, _ = imgui.begin(name)
    return expanded


def _dialogs_available() -> bool:
    return any(shutil.which(t) for t in ("zenity", "kdialog", "qarma", "matedialog"))


def _path_row(app, label: str, attr: str, action, filters: list[str]) -> None:
    changed, value = imgui.input_text(f"##{label}", getattr(app.paths, attr))
    if changed:
        setattr(app.paths, attr, value)
    imgui.same_line()
    if imgui.button(f"Open {label}"):
        path = getattr(app.paths, attr)
        if not path and _dialogs_available():
            from imgui_bundle import portable_file_dialogs as pfd

            chosen = pfd.open_file(f"Open {label}", "", filters).result()
            path = chosen[0] if chosen else ""
        if path:
            app.guarded(f"open {label}", action, path)
        else:
            app.fail(f"type the {label}'s path in the field (no file dialog program on this system)")


# ---------------------------------------------------------------------------------------------------- scene
def scene_panel(app) -> None:
    if _window("Scene", (10, 10), (380, 520)):
        imgui.separator_text("Files")
        _path_row(app, "model", "model", app.open_model, ["Gaussians", "*.ply *.splat"])
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
            index = getattr(app, "photo_index", 0)
            changed, index = imgui.slider_int("camera", index, 0, n - 1)
            if changed:
                app.photo_index = index
            if imgui.button("Go to camera"):
                app.guarded("snap", app.snap_to_camera, app.photo_index if hasattr(app, "photo_index") else 0)
            imgui.same_line()
            if imgui.button("Nearest camera"):
                app.guarded("snap", app.snap_to_nearest)
            changed, photo = imgui.combo("photo", PHOTO_MODES.index(s.photo), list(PHOTO_MODES))
            if changed:
                s.photo = PHOTO_MODES[photo]
                if s.photo != "off":
                    app.guarded("photo", app.set_photo, getattr(app, "photo_index", 0))
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
    imgui.end()


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
    depth = app.view.renderer.render_arrays(cam, ("depth",))["depth"]
    out = app.out_dir() / f"depth_{time.strftime('%Y%m%d_%H%M%S')}.exr"
    write_image(out, depth[..., None].astype(np.float32))
    app.say(f"wrote {out}")
    app.view.dirty = True
    return out


# ------------------------------------------------------------------------------------------------- training
def training_panel(app) -> None:
    if _window("Training", (10, 540), (380, 420)):
        session = app.session
        status = session.status()
        running = session.running
        imgui.begin_disabled(running)
        presets = ("quick", "standard", "paper")
        changed, i = imgui.combo("preset", presets.index(app.preset), list(presets))
        if changed:
            app.preset = presets[i]
        changed, iters = imgui.input_int("iterations (0: preset's)", app.recon_iters or 0, 100, 1000)
        if changed:
            app.recon_iters = iters if iters > 0 else None
        changed, down = imgui.input_int("downscale (0: preset's)", app.downscale or 0)
        if changed:
            app.downscale = down if down > 0 else None
        if imgui.button("Reconstruct"):
            app.guarded("reconstruct", app.start_reconstruction)
        imgui.same_line()
        if imgui.button("Stylize"):
            app.guarded("stylize", app.start_stylization)
        imgui.same_line()
        if imgui.button("Reconstruct + stylize"):
            app.guarded("run", app.start_reconstruction, then_stylize=True)
        imgui.end_disabled()
        imgui.begin_disabled(not running or status.state == "paused")
        if imgui.button("Pause"):
            session.pause()
        imgui.end_disabled()
        imgui.same_line()
        imgui.begin_disabled(not running or status.state != "paused")
        if imgui.button("Resume"):
            session.resume()
        imgui.end_disabled()
        imgui.same_line()
        imgui.begin_disabled(not running)
        if imgui.button("Step"):
            session.single_step()
        imgui.same_line()
        if imgui.button("Stop"):
            session.stop()
        changed, app.pause_at_value = imgui.input_int("pause at", getattr(app, "pause_at_value", 0))
        if changed:
            session.pause_at(app.pause_at_value if app.pause_at_value > 0 else None)
        imgui.end_disabled()
        changed, share = imgui.slider_float("training share", app.view.settings.training_share, 0.05, 0.95)
        if changed:
            app.view.settings.training_share = share
        imgui.set_item_tooltip("while a trainer runs, the view draws at most (1 - this) of the time: more leaves "
                               "the trainer more of the CPU, less makes the view smoother")
        changed, app.refresh_s = imgui.slider_float("view refresh (s)", app.refresh_s, 0.05, 5.0)
        imgui.set_item_tooltip("how often the view takes the trainer's latest model (each redraw costs it time)")
        s = app.view.settings
        changed, s.training_scale = imgui.slider_float("live view resolution", s.training_scale, 0.25, 1.0)
        app.view.dirty |= changed
        changed, s.motion_lod = imgui.slider_float("detail while moving", s.motion_lod, 0.05, 1.0)
        imgui.set_item_tooltip("the share of the Gaussians (the most opaque and largest) drawn while the camera moves")

        imgui.separator_text("Status")
        line = f"{status.stage or '-'}: {status.state}"
        if status.total:
            line += f"  {status.step}/{status.total}"
        imgui.text(line)
        m = status.last_metrics
        bits = [f"{status.steps_per_second:.1f} it/s"]
        if status.seconds_left is not None and status.state == "running":
            bits.append(f"{status.seconds_left:.0f} s left")
        if "num_gaussians" in m:
            bits.append(f"{int(m['num_gaussians']):,} Gaussians")
        if "psnr" in m and np.isfinite(m["psnr"]):
            bits.append(f"PSNR {m['psnr']:.2f}")
        imgui.text("  ".join(bits))
        imgui.progress_bar(status.step / status.total if status.total else 0.0, imgui.ImVec2(-1, 0))
        if app.error:
            imgui.push_text_wrap_pos(0.0)
            imgui.text_colored(RED, app.error)
            imgui.pop_text_wrap_pos()
        loss_curves(app)
        if app.messages:
            imgui.separator_text("Messages")
            for msg in app.messages[-4:]:
                imgui.text_wrapped(msg)
    imgui.end()


CURVES = {"reconstruct": ("loss", "l1", "depth", "shape", "size"),
          "stylize": ("loss", "style_loss", "content_loss")}


def loss_curves(app) -> None:
    history = list(app.session.history)
    if len(history) < 2:
        return
    stage = app.session.status().stage
    steps = np.array([h["step"] for h in history], dtype=np.float64)
    if implot.begin_plot("losses", imgui.ImVec2(-1, 170)):
        implot.setup_axes("step", "loss")
        implot.setup_axis_scale(implot.ImAxis_.y1, implot.Scale_.log10)
        for key in CURVES.get(stage, ("loss",)):
            ys = np.array([h.get(key, np.nan) for h in history], dtype=np.float64)
            ys = np.where(ys > 0, ys, np.nan)
            if np.isfinite(ys).any():
                implot.plot_line(key, steps, ys)
        implot.end_plot()


# ---------------------------------------------------------------------------------------------------- style
def style_panel(app) -> None:
    if _window("Style", (930, 10), (340, 620)):
        painting(app)
        cfg = app.stylize_config
        live = app.session.running and app.session.status().stage == "stylize"
        regions = ("all", "selection", "unselected")
        changed, i = imgui.combo("stylize", regions.index(app.style_region), ["every Gaussian", "only the selection",
                                                                             "all but the selection"])
        if changed:
            app.guarded("region", app.set_style_region, regions[i])
        imgui.set_item_tooltip("the others keep their colours exactly (select in the Edit panel)")
        losses = list(D.LOSSES)
        changed, i = imgui.combo("loss", losses.index(cfg.loss), losses)
        if changed:
            app.set_stylize(loss=losses[i])
        # (label, field, min, max, log scale)
        floats = [("tau", "tau", 0.01, 10.0, True), ("epsilon", "epsilon", 0.005, 0.5, True),
                  ("lambda_guide", "lambda_guide", 0.0, 10.0, False),
                  ("lambda_content", "lambda_content", 0.0, 0.1, False)]
        for label, name, lo, hi, log in floats:
            flags = imgui.SliderFlags_.logarithmic if log else 0
            changed, value = imgui.slider_float(label, float(getattr(cfg, name)), lo, hi, "%.4g", flags)
            if changed:
                app.set_stylize(**{name: value})
        changed, k = imgui.slider_int("K", cfg.k, 1, 64)
        if changed:
            app.set_stylize(k=k)
        changed, value = imgui.slider_float("lambda_style", cfg.style_weight, 0.0, 100.0, "%.3g")
        if changed:
            app.set_stylize(lambda_style=value)
        changed, value = imgui.slider_float("learning rate", cfg.learning_rate, 0.001, 0.1, "%.4f",
                                            imgui.SliderFlags_.logarithmic)
        if changed:
            app.set_stylize(lr=value)
        per_view = cfg.iters_per_view or 0
        changed, per_view = imgui.slider_int("iterations per view", per_view, 0, 100,
                                             "%d" if per_view else "paper's")
        if changed:
            app.set_stylize(iters_per_view=per_view or None)
        imgui.separator_text("Fixed at the start")
        imgui.begin_disabled(live)
        presets = list(D.PRESETS)
        changed, i = imgui.combo("stylize preset", presets.index(cfg.preset), presets)
        if changed:
            app.set_stylize(preset=presets[i])
        imgui.set_item_tooltip(f"paper: the paper's schedule at up to {D.PAPER_MAX_SIDE} px; quick: "
                               f"{D.QUICK_MAX_SIDE} px renders and {D.QUICK_ITER_FRACTION:g} of the iterations")
        orders = list(D.VIEW_ORDERS)
        changed, i = imgui.combo("view order", orders.index(cfg.view_order), orders)
        if changed:
            app.set_stylize(view_order=orders[i])
        changed, n = imgui.slider_int("virtual views", cfg.virtual_views, 0, 4)
        if changed:
            app.set_stylize(virtual_views=n)
        changed, ct = imgui.checkbox("colour transfer", cfg.color_transfer)
        if changed:
            app.set_stylize(color_transfer=ct)
        imgui.end_disabled()
        if live:
            imgui.text_colored(GREY, "greyed: " + RESTART)
        trainer = app.session.trainer
        if live and trainer is not None:
            u = trainer.utilisation()
            if u:
                imgui.separator_text("Style use (last plan)")
                imgui.text(f"utilisation {u.get('utilisation', float('nan')):.3f}   "
                           f"column entropy {u.get('column_entropy', float('nan')):.3f}")
    imgui.end()


def painting(app) -> None:
    """The painting, with the live capacity map (column mass of the last transport plan) over it."""
    if app.style_image is None:
        imgui.text_colored(GREY, "no painting: open one in the Scene panel")
        return
    ctx = app.ctx
    img = app.style_image
    if app.style_texture is None:
        rgba = np.concatenate([img, np.ones(img.shape[:2] + (1,), np.float32)], axis=2)
        app.style_texture = ctx.texture((img.shape[1], img.shape[0]), 4, np.ascontiguousarray(rgba).tobytes(),
                                        dtype="f4")
    width = imgui.get_content_region_avail().x
    size = imgui.ImVec2(width, width * img.shape[0] / img.shape[1])
    pos = imgui.get_cursor_screen_pos()
    imgui.image(imgui.ImTextureRef(app.style_texture.glo), size)
    trainer = app.session.trainer
    capacity = trainer.capacity_map() if trainer is not None and hasattr(trainer, "capacity_map") else None
    changed, app.show_capacity = imgui.checkbox("capacity map", getattr(app, "show_capacity", True))
    if capacity is not None and app.show_capacity:
        heat = heatmap(capacity)
        if app.capacity_texture is None or app.capacity_texture.size != (heat.shape[1], heat.shape[0]):
            if app.capacity_texture is not None:
                app.capacity_texture.release()
            app.capacity_texture = ctx.texture((heat.shape[1], heat.shape[0]), 4, dtype="f4")
        app.capacity_texture.write(np.ascontiguousarray(heat).tobytes())
        imgui.get_window_draw_list().add_image(imgui.ImTextureRef(app.capacity_texture.glo), pos,
                                               imgui.ImVec2(pos.x + size.x, pos.y + size.y))
        imgui.text(f"capacity: {capacity.shape[1]}x{capacity.shape[0]} style features, "
                   f"max {capacity.max() * capacity.size:.1f}x the fair share")


def heatmap(mass: np.ndarray) -> np.ndarray:
    """(h, w) column mass -> (h, w, 4) RGBA over the painting: red to yellow where a style feature gets more than its
    fair share (1 / count; log scale up to the map's own maximum, so the most used patterns always stand out),
    blue where it gets less (fully blue: unused), clear at the fair share. Tau's effect is the balance of the two."""
    fair = 1.0 / max(mass.size, 1)
    ratio = mass / fair
    rgba = np.zeros(mass.shape + (4,), np.float32)
    over = ratio > 1.0
    top = max(float(np.log2(max(float(ratio.max()), 1.0))), 0.5)
    t = np.clip(np.log2(np.maximum(ratio, 1.0)) / top, 0.0, 1.0)
    rgba[..., 0] = np.where(over, 1.0, 0.1)
    rgba[..., 1] = np.where(over, t, 0.35)
    rgba[..., 2] = np.where(over, 0.0, 1.0)
    rgba[..., 3] = np.where(over, 0.75 * t, 0.6 * np.clip(1.0 - ratio, 0.0, 1.0))
    return rgba


# ----------------------------------------------------------------------------------------------- view order
def view_order_panel(app) -> None:
    if _window("View order", (930, 640), (340, 330)):
        items = app.trajectory()
        if not items:
            imgui.text_colored(GREY, "open a dataset to see the camera trajectory")
            imgui.end()
            return
        current = app.current_view_index()
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
                app.snap_to_camera(items[pos][0])
        app.drawn_order = [source for source, _, virtual in items if not virtual]
        imgui.text(f"{len(items)} views in order" + (f", now at {current}" if current is not None else "")
                   + "; click a camera to go there")
    imgui.end()


def plane_coordinates(points: np.ndarray) -> np.ndarray:
    """(P, 3) -> (P, 2): coordinates on the best-fit plane (the two main axes of the camera centres)."""
    centred = points - points.mean(axis=0)
    if len(points) < 3:
        return np.stack([centred[:, 0], centred[:, 1]], axis=1)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return centred @ vt[:2].T


def help_overlay(app) -> None:
    io = imgui.get_io()
    imgui.set_next_window_pos(imgui.ImVec2(io.display_size.x / 2, io.display_size.y / 2), imgui.Cond_.always,
                              imgui.ImVec2(0.5, 0.5))
    imgui.set_next_window_bg_alpha(0.85)
    flags = imgui.WindowFlags_.always_auto_resize | imgui.WindowFlags_.no_collapse
    expanded, app.show_help = imgui.begin("Keys", True, flags)
    if expanded:
        for key, what in KEYS:
            imgui.text(f"{key:<22}{what}")
    imgui.end()
