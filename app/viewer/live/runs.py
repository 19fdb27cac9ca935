"""The viewer's runs: starting a reconstruction, a stylization or both in the live session, what a stage's saved model
becomes, the region a stylization may change, the view order it follows, and the commands handed to a running
trainer (through the session: nothing here holds a trainer). Every function takes the document, the session and the
UI state, and runs on the UI thread."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from training.core.status import StylizeStatus
from training.core.trainer import Keep, SetRegion
from app.viewer.live.stages import reconstruct_stage, stylize_stage


def claim_run_dir(out: Path, name: str = "stylized") -> Path:
    """Make and return ``out/stylized`` for the first stylization, then ``stylized_2``, ``stylized_3``...: each run
    claims its folder when it starts, by creating it (a folder another run made first, in this window or another
    writing to the same output folder, is that run's: the next name is tried), so no run writes over another's."""
    out.mkdir(parents=True, exist_ok=True)
    candidate, n = out / name, 1
    while True:
        try:
            candidate.mkdir()
            return candidate
        except FileExistsError:
            n += 1
            candidate = out / f"{name}_{n}"


def claimed_for(ui, out: Path, name: str) -> Path:
    """``claim_run_dir``, noted in the UI state: a folder the run never wrote to is given back when it ends."""
    folder = claim_run_dir(out, name)
    ui.training.claimed.append(folder)
    return folder


def give_back_unused(session, ui) -> None:
    """Each frame: once a run's thread is gone, the folders it claimed and left empty (stopped or failed before its
    stage began) are removed, so the output folder holds only what runs wrote."""
    if session.running or not ui.training.claimed:
        return
    for folder in ui.training.claimed:
        try:
            folder.rmdir()  # only an empty folder goes
        except OSError:
            pass
    ui.training.claimed = []


def settings_now(ui):
    """The stylization settings as the Style panel holds them when a stylization stage begins (a function the stage
    calls then): what the user changed during the stages before it is what the run uses."""
    return lambda: replace(ui.training.stylize)


def record_saved(doc, ui, stage: str, path: str) -> None:
    """A stage saved its model: structure from motion's scene opens as the dataset (its cameras in the view, the
    scene the next stages read); a reconstruction becomes the model later stylizations start from; a stylization
    is listed as a run (and starts the next one only when the user asks to continue)."""
    if stage == "sfm":
        from app.viewer.files import open_data

        ui.messages.say(f"saved {path}")
        open_data(doc, None, ui, path)  # opening a dataset asks nothing of the session
        return
    if stage == "stylize":
        ui.training.runs.append(Path(path))
    else:
        ui.training.base_model = path
        ui.paths.model = path
        doc.stylized_from = path  # a stylization started from it offers it as the original
    ui.messages.say(f"saved {path}")


def start_reconstruction(doc, session, ui, then_stylize: bool = False) -> None:
    if doc.dataset is None:
        raise ValueError("open a dataset first (COLMAP folder or transforms.json)")
    t = ui.training
    if then_stylize and doc.painting is None:
        raise ValueError("open a painting first")
    if session.running:
        raise ValueError("a run is going: stop it (Training panel) before starting another")
    overrides = {} if t.recon_iters is None else {"iterations": int(t.recon_iters)}
    # each run in a folder of its own (reconstruction, reconstruction_2...): a later run never overwrites a model
    # that a project or a stylization refers to
    outputs = t.outputs
    stages = [reconstruct_stage(doc.dataset.path, claimed_for(ui, ui.out_dir(), "reconstruction"), preset=t.preset,
                                downscale=t.downscale, outputs=outputs and outputs.reconstruction, **overrides)]
    if then_stylize:
        stages.append(stylize_stage(doc.dataset.path, doc.painting.path, claimed_for(ui, ui.out_dir(), "stylized"),
                                    config=settings_now(ui), outputs=outputs and outputs.stylization))
    t.before = None
    ui.messages.error = ""
    session.start(stages)


def start_stylization(doc, session, ui) -> None:
    t = ui.training
    if doc.dataset is None:
        raise ValueError("open the dataset the model was reconstructed from")
    if doc.painting is None:
        raise ValueError("open a painting first")
    # from the model as opened or reconstructed, not the last stylized output (a run on top of a run would
    # compound the style), unless the user asks to continue the last run
    if t.continue_last_run and t.runs:
        model = str(t.runs[-1])
    else:
        model = t.base_model or ui.paths.model or None
    if model is None:
        raise ValueError("open a model (PLY) or reconstruct first")
    if session.running:
        raise ValueError("a run is going: stop it (Training panel) before starting another")
    run = claimed_for(ui, ui.out_dir(), "stylized")
    if doc.edited() and not (t.continue_last_run and t.runs):
        from training.model.ply_io import write_ply

        # the stylization starts from what the user sees: the model after the deletes and crops, with the models
        # added to the scene, as one model kept in the run's own folder (it is that run's original, for style
        # strength; a later run writes its own); the region's mask is over these rows
        model = run / "edited_model.ply"
        write_ply(model, doc.edited_gaussians())
    t.before = doc.in_file_frame(doc.model)  # the run works in the file's (dataset's) frame
    doc.stylized_from = str(model)  # the Colour panel offers it as the result's original
    ui.messages.error = ""
    session.start([stylize_stage(doc.dataset.path, doc.painting.path, run, config=settings_now(ui), model=model,
                                 mask=region_mask(doc, ui), outputs=t.outputs and t.outputs.stylization)])


def stylizing(session) -> bool:
    """A stylization stage is running or loading (its settings change live; while it loads they are kept for the
    stylizer being built, not given to the trainer of the stage before it)."""
    return session.running and session.status().stage == "stylize"


def region_mask(doc, ui) -> np.ndarray | None:
    """The Gaussians a stylization may change, over the edited model (None: all)."""
    if ui.edit.region == "all" or doc.editor is None:
        return None
    return doc.editor.selected.copy() if ui.edit.region == "selection" else ~doc.editor.selected


def set_style_region(doc, session, ui, region: str) -> None:
    """Which Gaussians the stylization changes; a running stylizer takes it at its next step."""
    ui.edit.region = region
    # while the stylization loads, the trainer held is the stage before's: the stylizer starts with the region
    if stylizing(session) and session.trainer_status(StylizeStatus) is not None:
        submit_to_trainer(session, ui, "stylize region", SetRegion(region_mask(doc, ui)))


def submit_to_trainer(session, ui, what: str, command, done=None) -> None:
    """``command`` (session.py's Keep, SetRegion, UseModel) on the training thread between steps
    (session.submit); its error, or ``done(result)``, comes back at a later frame (``finish_pending``)."""
    ui.training.pending.append((what, session.submit(command), done))


def finish_pending(ui) -> None:
    still = []
    for what, future, done in ui.training.pending:
        if not future.done():
            still.append((what, future, done))
        elif future.exception() is not None:
            ui.messages.fail(f"{what}: {future.exception()}")
        elif done is not None:
            ui.messages.guarded(what, done, future.result())
    ui.training.pending = still


def keep_live(session, ui):
    """The deletions and crops of a live edit, for the document's editor: each applied between two of the trainer's
    steps, and only to the Gaussians the selection was made on (densification in between would shift the rows)."""
    def on_keep(keep: np.ndarray, structure_version: int) -> None:
        submit_to_trainer(session, ui, "delete", Keep(np.array(keep, dtype=bool), structure_version))

    return on_keep


def edit_live(doc, session, ui) -> None:
    """Select and delete in the model a running trainer trains; deletions reach it at its next step."""
    status = session.trainer_status()
    if status is None or not status.editable or not session.running:
        raise ValueError("no running trainer to edit")
    doc.edit_live(session.snapshot(), keep_live(session, ui))
    ui.messages.say("editing the running trainer's model: deletions and crops apply to it and cannot be undone")


def trajectory(doc, session, ui) -> list[tuple[int, np.ndarray, bool]]:
    """(source camera index, centre, is virtual) in optimisation order: the running stylizer's, or the order the
    next stylization would follow."""
    running = session.trainer_status(StylizeStatus)
    if session.status().stage == "stylize" and running is not None:
        return [(stop.source_index, stop.center, stop.is_virtual) for stop in running.trajectory]
    cams = doc.cameras
    if not cams:
        return []
    if ui.training.order_preview is None:
        from training.scene.scene import camera_normalization
        from training.stylize.view_order import view_order
        from training.stylize.virtual_views import trajectory as with_virtual_views

        cfg = ui.training.stylize
        # the extent the stylizer passes (the scene's), so the preview is the order the run will follow
        order = view_order(cams, cfg.view_order, seed=cfg.seed, extent=camera_normalization(cams)[1])
        ui.training.order_preview = [(item.source_index, item.camera.center, item.is_virtual)
                                     for item in with_virtual_views(cams, order, cfg.virtual_views)]
    return ui.training.order_preview


def current_view_index(session) -> int | None:
    """Trajectory position of the view the stylizer optimises now (None when no stylizer runs)."""
    running = session.trainer_status(StylizeStatus)
    return running.trajectory_position if session.status().stage == "stylize" and running is not None else None


def current_camera_index(session) -> int | None:
    """The dataset camera the stylizer optimises now (None when none runs or the view is a virtual one)."""
    running = session.trainer_status(StylizeStatus)
    if session.status().stage != "stylize" or running is None:
        return None
    stop = running.trajectory[running.trajectory_position]
    return None if stop.is_virtual else stop.source_index


def stylize_progress(session) -> str:
    """"pass p of P, view v" while a stylization runs (v: the trajectory position the View order panel numbers,
    the view the next step optimises; under the interleaved schedule it moves at every step), else "". From the
    status the stylizer published after its last step."""
    running = session.trainer_status(StylizeStatus)
    if not session.running or session.status().stage != "stylize" or running is None:
        return ""
    position = running.trajectory_position
    done, passes = running.pass_progress
    virtual = " (virtual)" if running.trajectory[position].is_virtual else ""
    return f"pass {done} of {passes}, view {position}{virtual}"
