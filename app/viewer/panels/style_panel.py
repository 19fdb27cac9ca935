"""The Style panel: the painting with the live capacity map over it, and the stylization's settings (live where the
running stylizer takes them, greyed where they shape a run from its start)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from imgui_bundle import imgui

from app.viewer.live.runs import set_style_region, stylizing
from app.viewer.panels.text_colours import GREY
from app.viewer.state import REGIONS
from training.core.status import StylizeStatus
from training.stylize import defaults as D
from training.stylize.config import RANGES, recipe_departures, recipe_settings

# Settings the stylizer fixes when it starts; the panel greys them during a run and says why.
RESTART = "fixed while a stylization runs: it shapes the run from its first step (stop and start again)"
# The painting gives way to the settings below it (all in view without scrolling, 1920x1080 included) down to this
# many text lines high.
MIN_PAINTING_LINES = 6


def set_stylize(session, ui, **changes) -> None:
    """A slider moved: the settings are validated here, where they enter (StylizeConfig.validate), then handed to
    the running stylizer (it takes them between two steps) and kept as the next run's."""
    candidate = replace(ui.training.stylize, **changes)
    try:
        candidate.validate()
    except ValueError as exc:
        ui.messages.fail(str(exc))
        return
    if stylizing(session):
        refusal = session.update_config(**changes)
        if refusal:
            ui.messages.fail(refusal)
            return
    ui.training.stylize = candidate
    if any(k in changes for k in ("view_order", "virtual_views", "seed")):
        ui.training.order_preview = None
        ui.requests.overlays = True


def style_panel(doc, session, ui) -> None:
    below_painting = painting(doc, session, ui)
    cfg = ui.training.stylize
    status = session.status()
    live = session.running and status.stage == "stylize"
    changed, i = imgui.combo("stylize", REGIONS.index(ui.edit.region), ["every Gaussian", "only the selection",
                                                                        "all but the selection"])
    if changed:
        ui.messages.guarded("region", set_style_region, doc, session, ui, REGIONS[i])
    imgui.set_item_tooltip("the others keep their colours exactly (select in the Edit panel)")
    losses = list(D.LOSSES)
    changed, i = imgui.combo("loss", losses.index(cfg.loss), losses)
    if changed:
        set_stylize(session, ui, loss=losses[i])
    balance_slider(session, ui, cfg)
    recipe_line(cfg)
    lo, hi, _ = RANGES["style_scale"]
    changed, scale = imgui.slider_float("stroke size", float(cfg.style_scale), lo, hi, "%.2gx",
                                        imgui.SliderFlags_.logarithmic)
    if changed:
        set_stylize(session, ui, style_scale=scale)
    imgui.set_item_tooltip("the painting's size against the render's (style scale): larger gives larger strokes and "
                           "fewer whole motifs of the painting")
    # (label, config field, its current value): the spans come with the config (RANGES)
    floats = [("tau", "tau", cfg.tau), ("epsilon", "epsilon", cfg.epsilon), ("lambda_guide", "lambda_guide",
              cfg.lambda_guide), ("style weight", "lambda_style", cfg.style_weight),
              ("learning rate", "lr", cfg.learning_rate)]
    for label, name, value in floats:
        lo, hi, log = RANGES[name]
        flags = imgui.SliderFlags_.logarithmic if log else 0
        changed, value = imgui.slider_float(label, float(value), lo, hi, "%.4g", flags)
        if changed:
            set_stylize(session, ui, **{name: value})
    changed, k = imgui.slider_int("K", cfg.k, *map(int, RANGES["k"][:2]))
    if changed:
        set_stylize(session, ui, k=k)
    per_view = cfg.iters_per_view or 0
    changed, per_view = imgui.slider_int("iterations per view", per_view, *map(int, RANGES["iters_per_view"][:2]),
                                         "%d" if per_view else "paper's")
    if changed:
        set_stylize(session, ui, iters_per_view=per_view or None)
    # the settings fixed at the start: folded while a run goes (greyed there, and the sliders above are the ones that
    # act), with the run's in the header; open again when it ends; the user may open or fold it any time
    if ui.window.fixed_folded != live:
        imgui.set_next_item_open(not live, imgui.Cond_.always)
        ui.window.fixed_folded = live
    summary = f": {cfg.preset}, {cfg.view_order} order, {cfg.schedule}" if live else ""
    if imgui.collapsing_header(f"Fixed at the start{summary}###fixed at the start"):
        fixed_settings(session, ui, cfg, live)
    # this stage's stylizer's: while the stylization loads, the trainer held is still the stage before's (a
    # reconstruction, or the last run's stylizer)
    run = session.trainer_status(StylizeStatus) if live and status.state != "loading" else None
    plan = run.utilisation if run is not None else {}
    if "utilisation" in plan:
        imgui.text(f"last plan: utilisation {plan['utilisation']:.3f}, "
                   f"column entropy {plan.get('column_entropy', float('nan')):.3f}")
    balance = run.gradient_balance if run is not None else None
    if balance is not None:
        imgui.text(f"content/style gradient: {balance:.3g} "
                   f"({'the scene leads' if balance > 1 else 'the painting leads'})")
    if run is not None and run.structure_drift is not None and run.content_weight is not None \
            and run.config.structure_budget > 0:
        imgui.text(f"structure drift {run.structure_drift:.3f} of {run.config.structure_budget:.3g}: "
                   f"content weight {run.content_weight:.3g}")
        imgui.set_item_tooltip("the structure budget steers the content weight: up while the drift is over the "
                               "budget, down while it is under")
    ui.window.style_settings_h = imgui.get_cursor_pos_y() - below_painting  # the painting leaves them room


def balance_slider(session, ui, cfg) -> None:
    """Scene <-> painting, the scene at the left end, the painting at the right. Under a structure budget (the
    balanced recipe) it sets the budget: how far the renders' structure may drift from the scene's, the content weight
    following by itself; without one (the paper's recipe) it sets the content weight, on a logarithmic scale."""
    if cfg.structure_budget > 0:
        lo, hi = D.STRUCTURE_BUDGET_SPAN
        budget = min(max(float(cfg.structure_budget), lo), hi)
        changed, toward_painting = imgui.slider_float("scene <-> painting", (budget - lo) / (hi - lo), 0.0, 1.0,
                                                      f"structure drift {cfg.structure_budget:.3g}")
        if changed:
            set_stylize(session, ui, structure_budget=float(lo + (hi - lo) * toward_painting))
        imgui.set_item_tooltip("how far the scene's structure may drift toward the painting's (the structure budget; "
                               f"the default is {D.STRUCTURE_BUDGET:g}): left keeps the scene, right gives the "
                               "painting more of it. The content weight follows by itself as the run goes; a "
                               "line under the sliders says where it is")
        return
    lo, hi, _ = RANGES["lambda_content"]  # the span where each end leads: content, style
    weight = min(max(float(cfg.lambda_content), lo), hi)
    toward_painting = math.log(hi / weight) / math.log(hi / lo)
    changed, toward_painting = imgui.slider_float("scene <-> painting", toward_painting, 0.0, 1.0,
                                                  f"content weight {cfg.lambda_content:.3g}")
    if changed:
        set_stylize(session, ui, lambda_content=float(hi * (lo / hi) ** toward_painting))
    imgui.set_item_tooltip("left keeps the scene's structure (a larger content weight), right gives the painting "
                           f"more of it; the default is {D.LAMBDA_CONTENT:g}. The Training tab plots the balance of "
                           "the two terms' gradients as the run goes")


def recipe_line(cfg) -> None:
    """Which recipe the settings come from and where they leave it; its tooltip lists every setting the two recipes
    set differently, with where the paper's come from (training/stylize/defaults.py)."""
    changed = recipe_departures(cfg)
    imgui.text(f"{cfg.recipe} recipe" + (": changed " + ", ".join(f"{k} {v:g}" if isinstance(v, float) else
                                                                    f"{k} {v}" for k, (_, v) in changed.items())
                                         if changed else ""))
    if imgui.is_item_hovered():
        lines = [f"{name}: " + ", ".join(f"{r} {v}" for r, v in row.items() if r != "value")
                 + f" ({D.RECIPE_SOURCES[name]})" for name, row in recipe_settings(cfg).items()]
        imgui.set_tooltip("the settings the two recipes set differently:\n" + "\n".join(lines))


def fixed_settings(session, ui, cfg, live: bool) -> None:
    """Recipe, preset, view order, schedule, virtual views, colour transfer: greyed during a run."""
    imgui.begin_disabled(live)
    recipes = list(D.RECIPES)
    changed, i = imgui.combo("recipe", recipes.index(cfg.recipe), recipes)
    if changed:
        set_stylize(session, ui, recipe=recipes[i], **D.RECIPE_SETTINGS[recipes[i]])
    imgui.set_item_tooltip("the settings to start from: balanced (this project's) or paper (the paper's stated "
                           "objective and settings); the sliders change them from there")
    presets = list(D.PRESETS)
    changed, i = imgui.combo("stylize preset", presets.index(cfg.preset), presets)
    if changed:
        set_stylize(session, ui, preset=presets[i])
    imgui.set_item_tooltip(f"paper: the paper's schedule at up to {D.PAPER_MAX_SIDE} px; quick: "
                           f"{D.QUICK_MAX_SIDE} px renders and {D.QUICK_ITER_FRACTION:g} of the iterations")
    orders = list(D.VIEW_ORDERS)
    changed, i = imgui.combo("view order", orders.index(cfg.view_order), orders)
    if changed:
        set_stylize(session, ui, view_order=orders[i])
    schedules = list(D.SCHEDULES)
    changed, i = imgui.combo("schedule", schedules.index(cfg.schedule), schedules)
    if changed:
        set_stylize(session, ui, schedule=schedules[i])
    imgui.set_item_tooltip("interleaved (the paper's): a new view of the order at every iteration, in passes along "
                           "it, so the guide map comes from the previous iteration's view; block: the iterations "
                           "per view on one view, then the next")
    changed, n = imgui.slider_int("virtual views", cfg.virtual_views, *map(int, RANGES["virtual_views"][:2]))
    if changed:
        set_stylize(session, ui, virtual_views=n)
    changed, ct = imgui.checkbox("colour transfer", cfg.color_transfer)
    if changed:
        set_stylize(session, ui, color_transfer=ct)
    imgui.end_disabled()
    if live:
        imgui.push_text_wrap_pos(0.0)
        imgui.text_colored(GREY, "greyed: " + RESTART)
        imgui.pop_text_wrap_pos()


def painting(doc, session, ui) -> float:
    """The painting, with the live capacity map (column mass of the last transport plan) over it, as large as the
    panel's width allows and as high as the settings below it leave room for (the last frame's height of them);
    returns the cursor's height below the picture."""
    if doc.painting is None:
        imgui.text_colored(GREY, "no painting: open one in the Scene panel")
        return imgui.get_cursor_pos_y()
    ctx = ui.view.ctx
    tex = ui.textures
    img = doc.painting.image
    if tex.painting_of is not img:  # a painting opened since: its own texture
        if tex.painting is not None:
            tex.painting.release()
        rgba = np.concatenate([img, np.ones(img.shape[:2] + (1,), np.float32)], axis=2)
        tex.painting = ctx.texture((img.shape[1], img.shape[0]), 4, np.ascontiguousarray(rgba).tobytes(), dtype="f4")
        tex.painting.build_mipmaps()  # shown smaller than it is (it yields to the settings): filtered, not aliased
        tex.painting_of = img
    avail = imgui.get_content_region_avail()
    room = max(avail.y - ui.window.style_settings_h, MIN_PAINTING_LINES * imgui.get_text_line_height_with_spacing())
    height = min(avail.x * img.shape[0] / img.shape[1], room)
    # whole pixels: a picture placed between pixels is filtered twice (blurred) on screen
    size = imgui.ImVec2(float(int(height * img.shape[1] / img.shape[0])), float(int(height)))
    imgui.set_cursor_pos_x(float(int(imgui.get_cursor_pos_x() + (avail.x - size.x) / 2)))  # a narrower one is centred
    pos = imgui.get_cursor_screen_pos()
    imgui.image(imgui.ImTextureRef(tex.painting.glo), size)
    below = imgui.get_cursor_pos_y()
    ui.window.painting_rect = (int(pos.x), int(pos.y), int(size.x), int(size.y))  # where it is on screen (tests look)
    run = session.trainer_status(StylizeStatus)
    capacity = run.capacity if run is not None else None
    changed, ui.window.show_capacity = imgui.checkbox("capacity map", ui.window.show_capacity)
    imgui.set_item_tooltip("the column mass of the last transport plan at each style feature's place: red to yellow "
                           "where a pattern gets more than its fair share, blue where it gets less")
    if capacity is not None and ui.window.show_capacity:
        heat = heatmap(capacity)
        if tex.capacity is None or tex.capacity.size != (heat.shape[1], heat.shape[0]):
            if tex.capacity is not None:
                tex.capacity.release()
            tex.capacity = ctx.texture((heat.shape[1], heat.shape[0]), 4, dtype="f4")
        tex.capacity.write(np.ascontiguousarray(heat).tobytes())
        imgui.get_window_draw_list().add_image(imgui.ImTextureRef(tex.capacity.glo), pos,
                                               imgui.ImVec2(pos.x + size.x, pos.y + size.y))
        imgui.same_line()  # one line with the checkbox: the height goes to the painting
        imgui.text(f"{capacity.shape[1]}x{capacity.shape[0]} style features, "
                   f"max {capacity.max() * capacity.size:.1f}x the fair share")
    return below


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
