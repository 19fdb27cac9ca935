"""The Colour panel: brightness, contrast, saturation, hue and temperature, and the style strength, on the selection
or on everything; live in the 3D view, undoable (one step per slider drag), exported and saved as shown
(colour_view.py holds the logic).

Adjustments are layers: the sliders show and set the top layer while its region is the one chosen (the current
selection, or all); another selection starts a new layer on top, so earlier adjustments stay where they were made.
"""

from __future__ import annotations

from dataclasses import replace

from imgui_bundle import imgui

from app.viewer.edit import colour_view as cv
from app.viewer.panels.text_colours import GREY
from training.model.colour_edit import RANGES
from training.core.status import StylizeStatus

REGION_LABELS = {"selection": "the selection", "all": "every Gaussian"}
PARAMETERS = (("brightness", "%.3f"), ("contrast", "%.3f"), ("saturation", "%.3f"), ("hue", "%.1f deg"),
              ("temperature", "%.3f"))


def colour_panel(doc, session, ui) -> None:
    ed = doc.editor
    if ed is None:
        imgui.text_colored(GREY, "open a model to adjust its colours")
        return
    state = ui.colour
    regions = list(REGION_LABELS)
    changed, i = imgui.combo("apply to", regions.index(state.region), list(REGION_LABELS.values()))
    if changed:
        state.region = regions[i]
    try:
        region = cv.region_mask(doc, state.region)
    except ValueError as exc:
        imgui.text_colored(GREY, str(exc))
        region, usable = None, False
    else:
        usable = True
    edits = doc.colour
    imgui.separator_text("Colour")
    imgui.begin_disabled(not usable)
    adjustment = cv.current_adjustment(edits, region)
    for name, fmt in PARAMETERS:
        lo, hi = RANGES[name]
        changed, value = imgui.slider_float(name, getattr(adjustment, name), lo, hi, fmt,
                                            imgui.SliderFlags_.always_clamp)
        if imgui.is_item_activated():
            state.drag += 1
        if changed and usable:
            new = replace(adjustment, **{name: float(value)})
            ui.messages.guarded("colour", doc.set_colour, cv.with_adjustment(edits, region, new),
                                ("colour", name, state.drag))
            edits, adjustment = doc.colour, new
    if imgui.button("Reset these sliders"):
        ui.messages.guarded("colour", doc.set_colour, cv.with_adjustment(edits, region, type(adjustment)()))
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(not edits.adjustments)
    if imgui.button("Remove all colour edits"):
        ui.messages.guarded("colour", doc.set_colour, replace(edits, adjustments=[],
                                                              strength_regions=list(edits.strength_regions)))
    imgui.end_disabled()
    layers = sum(not a.is_identity for _, a in edits.adjustments)
    imgui.text_colored(GREY, f"{layers} adjustment layer{'s' if layers != 1 else ''}")
    strength_section(doc, session, ui, region, usable)


def strength_section(doc, session, ui, region, usable: bool) -> None:
    state = ui.colour
    imgui.separator_text("Style strength")
    problem = cv.strength_problem(doc, session)
    edits = doc.colour
    imgui.begin_disabled(problem is not None or not usable)
    changed, value = imgui.slider_float("style strength", cv.current_strength(edits, region), 0.0, 1.0, "%.3f",
                                        imgui.SliderFlags_.always_clamp)
    if imgui.is_item_activated():
        state.drag += 1
    if changed and problem is None and usable:
        ui.messages.guarded("style strength", doc.set_colour, cv.with_strength(edits, region, float(value)),
                            ("strength", state.drag))
    imgui.end_disabled()
    imgui.set_item_tooltip("0: the photo model's colours, 1: the stylized ones (each Gaussian's SH blended)")
    if problem is not None:
        imgui.push_text_wrap_pos(0.0)
        imgui.text_colored(GREY, problem)
        imgui.pop_text_wrap_pos()
    if session.trainer_status(StylizeStatus) is None and doc.source is not None:
        if not state.original_input:
            state.original_input = str(doc.original.ref.path) if doc.original is not None else doc.stylized_from
        _, state.original_input = imgui.input_text("original model", state.original_input)
        imgui.set_item_tooltip("the model the opened one was stylized from (same Gaussians, row for row)")
        if imgui.button("Pair original"):
            ui.messages.guarded("pair original", pair_original, doc, ui, state.original_input)


def pair_original(doc, ui, path: str) -> None:
    doc.pair_original(path)
    ui.messages.say(f"paired {path} as the original of {doc.models.files[0].path} ({len(doc.original.sh):,} rows)")
