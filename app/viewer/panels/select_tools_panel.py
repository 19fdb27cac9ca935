"""The Edit panel's "More selections" section: by colour, opacity, size and neighbours (the two view tools it adds,
"colour pick": a click for the Gaussians of a similar colour, and "surface brush": a brush that takes only the
visible surface, are gestures in the 3D view, gestures.py). Each selection combines with the current one by the
selection mode and is one undo step; grow and shrink replace the selection with the grown or shrunk one (the mode
has no meaning for them). The masks come from select_tools.py.
"""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.viewer.display.gestures import shown_sh
from app.viewer.edit import select_tools as st
from app.viewer.panels.text_colours import GREY


def more_selections(doc, session, ui) -> None:
    ed, s = doc.editor, ui.select_tools
    if ed is None:
        return
    mode = ui.edit.select_mode
    imgui.separator_text("By colour, opacity, size, neighbours")
    if ui.edit.tool == "surface brush":
        changed, s.surface_tolerance = imgui.slider_float("surface tolerance", s.surface_tolerance, 0.005, 0.5,
                                                          "%.3f", imgui.SliderFlags_.logarithmic)
        imgui.set_item_tooltip("how far behind or before the drawn surface (a fraction of its depth) a centre "
                               "may be and still be taken")
    _, s.colour_tolerance = imgui.slider_float("colour tolerance", s.colour_tolerance, 0.0, 1.0, "%.3f")
    if s.picked is None:
        imgui.text_colored(GREY, "tool 'colour pick': click a splat in the view")
    else:
        imgui.color_button("picked colour", imgui.ImVec4(*s.picked, 1.0))
        imgui.same_line()
        if imgui.button("Select similar colour"):
            ui.messages.guarded("select", lambda: ed.select(
                st.similar_colour(shown_sh(doc, session), s.picked, s.colour_tolerance), mode))
    _, lo, hi = imgui.drag_float_range2("opacity range", s.opacity[0], s.opacity[1], 0.005, 0.0, 1.0)
    s.opacity = [lo, hi]
    if imgui.button("Select by opacity"):
        ui.messages.guarded("select", lambda: ed.select(st.in_range(ed.model.opacities, *s.opacity), mode))
    sizes = st.sizes(ed.model.scales) if len(ed.model) else np.ones(1)
    top = float(sizes.max()) if sizes.size else 1.0
    bottom = max(float(sizes.min()), top * 1e-6, 1e-9)
    if s.size is None:
        s.size = [bottom, float(np.median(sizes))]
    flags = imgui.SliderFlags_.logarithmic
    _, s.size[0] = imgui.slider_float("size min", s.size[0], bottom, top, "%.4g", flags)
    _, s.size[1] = imgui.slider_float("size max", s.size[1], bottom, top, "%.4g", flags)
    imgui.set_item_tooltip("a Gaussian's size: its largest standard deviation (world units)")
    if imgui.button("Select by size"):
        ui.messages.guarded("select", lambda: ed.select(st.in_range(sizes, *s.size), mode))
    _, s.neighbours = imgui.slider_int("neighbours", s.neighbours, 1, 32)
    imgui.begin_disabled(not ed.selected.any())
    if imgui.button("Grow"):
        ui.messages.guarded("grow", grow_or_shrink, doc, ui, True)
    imgui.same_line()
    if imgui.button("Shrink"):
        ui.messages.guarded("shrink", grow_or_shrink, doc, ui, False)
    imgui.end_disabled()
    imgui.set_item_tooltip("add each selected Gaussian's nearest neighbours, or drop the selected ones that have "
                           "an unselected neighbour")


def grow_or_shrink(doc, ui, grow: bool) -> None:
    ed, s = doc.editor, ui.select_tools
    rows = np.nonzero(ed.selected)[0]
    if len(rows) == 0:
        raise ValueError("nothing is selected")
    model = ed.model
    if s.neighbour_cache is None:
        s.neighbour_cache = st.Neighbours()
    neighbours = s.neighbour_cache.of(model.means, (id(model.means), model.geometry_version), rows, s.neighbours)
    picked = (st.grow if grow else st.shrink)(ed.selected, neighbours, rows)
    ed.select(picked, "set")
