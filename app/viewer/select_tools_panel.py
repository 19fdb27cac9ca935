"""The Edit panel's "More selections" section and the two view tools it adds: "colour pick" (click a splat: the
Gaussians of a similar colour) and "surface brush" (a brush that takes only the visible surface). Each selection
combines with the current one by the selection mode and is one undo step; grow and shrink replace the selection
with the grown or shrunk one (the mode has no meaning for them). The masks come from select_tools.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from imgui_bundle import imgui

from app.viewer import select_tools as st

VIEW_TOOLS = ("surface brush", "colour pick")  # the tools of the Edit panel's list that this module handles
GREY = imgui.ImVec4(0.6, 0.6, 0.6, 1.0)


@dataclass
class SelectToolSettings:
    colour_tolerance: float = 0.12  # RGB distance (0..1 per channel)
    picked: tuple[float, float, float] | None = None  # the last picked Gaussian's base colour
    opacity: list[float] = field(default_factory=lambda: [0.0, 0.5])
    size: list[float] | None = None  # [lo, hi] world units; the model's span at first use
    neighbours: int = 8
    surface_tolerance: float = 0.1  # fraction of the depth at the pixel
    neighbour_cache: st.Neighbours = field(default_factory=st.Neighbours)


def shown_sh(app) -> np.ndarray:
    """The colours the view shows for the editor's rows (after the colour edits)."""
    from app.viewer.colour_view import displayed

    return displayed(app, app.editor.model).sh


def render_depth(app, camera) -> np.ndarray:
    """(H, W) depth the renderer composites for ``camera`` (0 where nothing is drawn), top row first."""
    return app.view.render_arrays(camera, ("depth",))["depth"]


def gesture(app, points: list[tuple[float, float]]) -> None:
    """A finished drag or click of one of VIEW_TOOLS over the view (points in the view camera's pixels)."""
    from app.viewer.edit_panel import view_camera

    ed, s = app.editor, app.select_tools
    cam = view_camera(app)
    if app.edit.tool == "surface brush":
        scale = imgui.get_io().display_framebuffer_scale.x
        picked = st.surface_brush(ed.model.means, cam, points, app.edit.brush_radius * scale,
                                  render_depth(app, cam), s.surface_tolerance)
        ed.select(picked, app.edit.select_mode)
        return
    x, y = points[-1]
    row = st.pick(ed.model, cam, x, y, visible=~ed.hidden)
    if row is None:
        app.say("colour pick: no Gaussian under the cursor")
        return
    sh = shown_sh(app)
    s.picked = tuple(float(c) for c in st.base_colours(sh[row:row + 1])[0])
    ed.select(st.similar_colour(sh, s.picked, s.colour_tolerance), app.edit.select_mode)
    app.say(f"colour pick: RGB {s.picked[0]:.2f} {s.picked[1]:.2f} {s.picked[2]:.2f}, "
            f"{int(ed.selected.sum()):,} selected")


def more_selections(app) -> None:
    ed, s = app.editor, app.select_tools
    imgui.separator_text("By colour, opacity, size, neighbours")
    if app.edit.tool == "surface brush":
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
            app.guarded("select", lambda: ed.select(st.similar_colour(shown_sh(app), s.picked, s.colour_tolerance),
                                                    app.edit.select_mode))
    _, lo, hi = imgui.drag_float_range2("opacity range", s.opacity[0], s.opacity[1], 0.005, 0.0, 1.0)
    s.opacity = [lo, hi]
    if imgui.button("Select by opacity"):
        app.guarded("select", lambda: ed.select(st.in_range(ed.model.opacities, *s.opacity), app.edit.select_mode))
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
        app.guarded("select", lambda: ed.select(st.in_range(sizes, *s.size), app.edit.select_mode))
    _, s.neighbours = imgui.slider_int("neighbours", s.neighbours, 1, 32)
    imgui.begin_disabled(not ed.selected.any())
    if imgui.button("Grow"):
        app.guarded("grow", grow_or_shrink, app, True)
    imgui.same_line()
    if imgui.button("Shrink"):
        app.guarded("shrink", grow_or_shrink, app, False)
    imgui.end_disabled()
    imgui.set_item_tooltip("add each selected Gaussian's nearest neighbours, or drop the selected ones that have "
                           "an unselected neighbour")


def grow_or_shrink(app, grow: bool) -> None:
    ed, s = app.editor, app.select_tools
    rows = np.nonzero(ed.selected)[0]
    if len(rows) == 0:
        raise ValueError("nothing is selected")
    model = ed.model
    neighbours = s.neighbour_cache.of(model.means, (id(model.means), model.geometry_version), rows, s.neighbours)
    picked = (st.grow if grow else st.shrink)(ed.selected, neighbours, rows)
    ed.select(picked, "set")
