"""The Training panel: start a reconstruction, a stylization or both; pause, step, stop; how the view shares the CPU
with the trainer; status, progress and loss curves. During structure from motion (the photos pipeline) the status
is its phase (photos prepared, features, pairs matched, photos registered and points), the phase's time left, and
the points over the registrations; SfM cannot pause (COLMAP does the work), so Pause and Step are off then."""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui, implot

from app.viewer.display.view3d import RANGES
from app.viewer.files import open_model
from app.viewer.live.runs import start_reconstruction, start_stylization, stylize_progress
from app.viewer.live.sfm_run import phase_time_left
from app.viewer.panels.text_colours import RED
from training.stylize.terms import LOSS_KEYS

BALANCE_PLOT_H = 150.0


def training_panel(doc, session, ui) -> None:
    t = ui.training
    status = session.status()
    running = session.running
    imgui.begin_disabled(running)
    presets = ("quick", "standard", "paper")
    changed, i = imgui.combo("preset", presets.index(t.preset), list(presets))
    if changed:
        t.preset = presets[i]
    changed, iters = imgui.input_int("iterations (0: preset's)", t.recon_iters or 0, 100, 1000)
    if changed:
        t.recon_iters = iters if iters > 0 else None
    changed, down = imgui.input_int("downscale (0: preset's)", t.downscale or 0)
    if changed:
        t.downscale = down if down > 0 else None
    if imgui.button("Reconstruct"):
        ui.messages.guarded("reconstruct", start_reconstruction, doc, session, ui)
    imgui.same_line()
    if imgui.button("Stylize"):
        ui.messages.guarded("stylize", start_stylization, doc, session, ui)
    imgui.same_line()
    if imgui.button("Reconstruct + stylize"):
        ui.messages.guarded("run", start_reconstruction, doc, session, ui, then_stylize=True)
    imgui.begin_disabled(not t.runs)
    _, t.continue_last_run = imgui.checkbox("continue the last stylized run", t.continue_last_run)
    imgui.end_disabled()
    imgui.set_item_tooltip("off: Stylize starts from the model as opened or reconstructed (runs do not compound); "
                           "on: from the last run's output")
    imgui.end_disabled()
    sfm = status.stage == "sfm"
    imgui.begin_disabled(not running or status.state == "paused" or sfm)
    if imgui.button("Pause"):
        session.pause()
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(not running or status.state != "paused")
    if imgui.button("Resume"):
        session.resume()
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(not running or sfm)
    if imgui.button("Step"):
        session.single_step()
    imgui.end_disabled()
    imgui.same_line()
    imgui.begin_disabled(not running)
    if imgui.button("Stop"):
        session.stop()
    changed, t.pause_at = imgui.input_int("pause at", t.pause_at)
    if changed:
        session.pause_at(t.pause_at if t.pause_at > 0 else None)
    imgui.end_disabled()
    changed, share = imgui.slider_float("training share", ui.view.settings.training_share,
                                        *RANGES["training_share"])
    if changed:
        ui.view.settings.training_share = share
    imgui.set_item_tooltip("while a trainer runs, the view draws at most (1 - this) of the time: more leaves "
                           "the trainer more of the CPU, less makes the view smoother")
    changed, t.refresh_s = imgui.slider_float("view refresh (s)", t.refresh_s,
                                                         *RANGES["refresh_s"])
    imgui.set_item_tooltip("how often the view takes the trainer's latest model (each redraw costs it time)")
    s = ui.view.settings
    changed, s.training_scale = imgui.slider_float("live view resolution", s.training_scale,
                                                       *RANGES["training_scale"])
    ui.view.dirty |= changed
    changed, s.motion_lod = imgui.slider_float("detail while moving", s.motion_lod, *RANGES["motion_lod"])
    imgui.set_item_tooltip("the share of the Gaussians (the most opaque and largest) drawn while the camera moves")

    imgui.separator_text("Status")
    line = f"{status.stage}: {status.state}" if status.stage else status.state  # "idle" before any run
    if status.detail:  # SfM: its phase and count, in words
        line += f"  {status.detail}"
    elif status.total:
        line += f"  {status.step}/{status.total}"
    where = stylize_progress(session)
    if where:
        line += f"  ({where})"
    imgui.push_text_wrap_pos(0.0)
    imgui.text(line)
    imgui.pop_text_wrap_pos()
    m = status.last_metrics
    bits = [] if status.detail else [f"{status.steps_per_second:.1f} it/s"]
    if status.seconds_left is not None and status.state == "running":
        bits.append(phase_time_left(status.seconds_left) if status.detail else f"{status.seconds_left:.0f} s left")
    if "num_gaussians" in m:
        bits.append(f"{int(m['num_gaussians']):,} Gaussians")
    if "psnr" in m and np.isfinite(m["psnr"]):
        bits.append(f"PSNR {m['psnr']:.2f}")
    imgui.text("  ".join(bits))
    imgui.progress_bar(status.step / status.total if status.total else 0.0, imgui.ImVec2(-1, 0))
    if ui.messages.error:
        imgui.push_text_wrap_pos(0.0)
        imgui.text_colored(RED, ui.messages.error)
        imgui.pop_text_wrap_pos()
    loss_curves(session, ui)
    if t.runs:
        imgui.separator_text("Stylized runs")
        imgui.begin_disabled(session.running)
        for i, path in enumerate(t.runs):
            # the run's result as the opened model: the editor, gizmo, colour and export act on it
            if imgui.small_button(f"Open##run{i}"):
                ui.messages.guarded("open model", open_model, doc, session, ui, str(path))
            imgui.same_line()
            imgui.text(str(path))
        imgui.end_disabled()


CURVES = {"reconstruct": ("loss", "l1", "depth", "shape", "size"),
          "stylize": LOSS_KEYS,  # the style loss and each term of the objective (training/stylize/terms.py)
          "sfm": ("points",)}  # the sparse points over the photos registered


def loss_curves(session, ui) -> None:
    history = list(session.history)
    stage = session.status().stage
    sfm = stage == "sfm"
    if sfm:  # its registrations only: the other phases' steps count photos and pairs, not registrations
        history = [h for h in history if "points" in h]
    if len(history) < 2:
        return
    steps = np.array([h["step"] for h in history], dtype=np.float64)
    # the plot takes the panel's height left below it (the list of runs keeps its lines), never less than 170 px
    reserve = (len(ui.training.runs) + 2) * imgui.get_text_line_height_with_spacing() if ui.training.runs else 0.0
    if stage == "stylize":
        reserve += BALANCE_PLOT_H + imgui.get_style().item_spacing.y  # the gradient balance below the losses
    height = max(170.0, imgui.get_content_region_avail().y - reserve)
    if implot.begin_plot("sparse points###losses" if sfm else "losses", imgui.ImVec2(-1, height)):
        fit = implot.AxisFlags_.auto_fit.value  # the curves grow every step: keep them all in view
        implot.setup_axes(*(("photos registered", "points") if sfm else ("step", "loss")), fit, fit)
        # above the plot, in one row: inside it, the legend covered the curves of a 170 px plot
        implot.setup_legend(implot.Location_.north.value,
                            implot.LegendFlags_.outside.value | implot.LegendFlags_.horizontal.value)
        if not sfm:
            implot.setup_axis_scale(implot.ImAxis_.y1, implot.Scale_.log10)
        for key in CURVES.get(stage, ("loss",)):
            ys = np.array([h.get(key, np.nan) for h in history], dtype=np.float64)
            ys = np.where(ys > 0, ys, np.nan)
            if np.isfinite(ys).any():
                implot.plot_line(key, steps, ys)
        implot.end_plot()
    if stage == "stylize":
        balance_curve(steps, history)


def balance_curve(steps: np.ndarray, history: list[dict]) -> None:
    """The content term's gradient on the render over the style term's, step by step, with 1 (balanced) marked."""
    ratio = np.array([h.get("content_to_style", np.nan) for h in history], dtype=np.float64)
    measured = ratio > 0  # every balance_every-th step is measured: the curve joins those
    if not measured.any():
        return
    steps, ratio = steps[measured], ratio[measured]
    if implot.begin_plot("gradient balance", imgui.ImVec2(-1, BALANCE_PLOT_H)):
        fit = implot.AxisFlags_.auto_fit.value
        implot.setup_axes("step", "content / style", fit, fit)
        implot.setup_axis_scale(implot.ImAxis_.y1, implot.Scale_.log10)
        implot.setup_legend(implot.Location_.north.value,
                            implot.LegendFlags_.outside.value | implot.LegendFlags_.horizontal.value)
        implot.plot_line("content / style gradient", steps, ratio)
        implot.plot_line("balanced", np.array([steps[0], steps[-1]]), np.ones(2))
        implot.end_plot()


def messages_panel(doc, session, ui) -> None:
    """Every one-line message of the session, newest at the bottom (errors in red), scrolled to the newest."""
    lines = ui.messages.lines
    if not lines:
        imgui.text_disabled("messages from loading, runs and edits appear here")
        return
    for msg in lines:
        if msg.startswith("error:"):
            imgui.text_colored(RED, msg)
        else:
            imgui.text_wrapped(msg)
    if ui.window.messages_seen != len(lines):
        imgui.set_scroll_here_y(1.0)
        ui.window.messages_seen = len(lines)
