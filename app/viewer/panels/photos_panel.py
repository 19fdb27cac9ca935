"""The New from photos dialog: the settings a photos pipeline starts with (the photos, the output folder, the
preset, the photos' long side for SfM, the camera model, the optional painting, the reconstruction's iterations),
then Start. File > New from photos... and a folder of photos dropped on the window open it (app/viewer/live/photos.py)."""

from __future__ import annotations

from imgui_bundle import imgui

from app.viewer.dialogs import DIALOG_FILTERS, choose_file, choose_folder
from app.viewer.live.photos import start_photos
from app.viewer.panels.text_colours import GREY
from training.scene.sfm import CAMERA_MODELS

PRESETS = ("quick", "standard", "paper")


def photos_dialog(doc, session, ui) -> None:
    p, t = ui.photos, ui.training
    if not p.dialog:
        return
    io = imgui.get_io()
    imgui.set_next_window_pos(imgui.ImVec2(io.display_size.x / 2, io.display_size.y / 2), imgui.Cond_.appearing,
                              imgui.ImVec2(0.5, 0.5))
    flags = imgui.WindowFlags_.always_auto_resize | imgui.WindowFlags_.no_collapse
    expanded, p.dialog = imgui.begin("New from photos", p.dialog, flags)
    if expanded:
        guarded = ui.messages.guarded
        width = imgui.get_font_size() * 28
        imgui.set_next_item_width(width)
        _, p.folder = imgui.input_text("photos", p.folder)
        imgui.same_line()
        if imgui.button("Choose...##photos"):
            guarded("choose photos", _choose_photos, ui)
        imgui.set_next_item_width(width)
        _, ui.paths.out = imgui.input_text("output folder", ui.paths.out)
        imgui.set_item_tooltip("the scene (COLMAP folder), the reconstruction, the stylization and the project go "
                               "here, each in a folder of its own")
        imgui.set_next_item_width(width)
        changed, i = imgui.combo("preset", PRESETS.index(t.preset), list(PRESETS))
        if changed:
            t.preset = PRESETS[i]
        imgui.set_item_tooltip("the reconstruction's and the stylization's: quick takes minutes on a CPU, paper is "
                               "for a GPU")
        imgui.set_next_item_width(width)
        changed, iters = imgui.input_int("reconstruction iterations (0: preset's)", t.recon_iters or 0, 100, 1000)
        if changed:
            t.recon_iters = iters if iters > 0 else None
        imgui.set_next_item_width(width)
        _, p.max_size = imgui.input_int("photos' long side at most (px)", p.max_size, 100, 400)
        imgui.set_item_tooltip("structure from motion works on the photos shrunk to this (`splatstyler sfm "
                               "--max-size`)")
        imgui.set_next_item_width(width)
        models = list(CAMERA_MODELS)
        changed, i = imgui.combo("camera model", models.index(p.camera_model), models)
        if changed:
            p.camera_model = models[i]
        imgui.set_item_tooltip("SIMPLE_RADIAL: most photos; OPENCV: wide or strongly distorted lenses; PINHOLE: "
                               "photos already undistorted")
        imgui.set_next_item_width(width)
        _, p.painting = imgui.input_text("painting (optional)", p.painting)
        imgui.same_line()
        if imgui.button("Choose...##painting"):
            guarded("choose painting", _choose_painting, ui)
        imgui.push_text_wrap_pos(width * 1.6)
        then = "reconstruction, then stylization after the painting" if p.painting else \
            "reconstruction (no painting: stylize later from the Training tab)"
        imgui.text_colored(GREY, f"structure from motion, then {then}, into {ui.paths.out}")
        imgui.pop_text_wrap_pos()
        imgui.begin_disabled(session.running or not p.folder)
        if imgui.button("Start"):
            guarded("from photos", start_photos, doc, session, ui)
        imgui.end_disabled()
        imgui.same_line()
        if imgui.button("Cancel"):
            p.dialog = False
        if session.running:
            imgui.same_line()
            imgui.text_colored(GREY, "a run is going: stop it first")
    imgui.end()


def _choose_photos(ui) -> None:
    folder = choose_folder("The folder of photos", ui.photos.folder)
    if folder:
        ui.photos.folder = folder


def _choose_painting(ui) -> None:
    path = choose_file("The painting", DIALOG_FILTERS["style"])
    if path:
        ui.photos.painting = path
