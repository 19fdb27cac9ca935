"""Photos to a stylized scene in one window: the photos pipeline, started in the live session by `splatstyler view
PHOTOS`, File > New from photos... or a folder of photos dropped on the window (both open the New from photos
dialog first), and what its end makes of the window.

The pipeline is three stages of one run, each the same code and settings as its console command and each writing
what that command writes as it ends, into the output folder: structure from motion (`splatstyler sfm`: OUT/scene,
a COLMAP folder that appears only whole), the reconstruction (`splatstyler reconstruct`: OUT/reconstruction, with
its report and renders) and, with a painting, the stylization (`splatstyler stylize`: OUT/stylized, with its report
and renders); each folder is claimed (created) as the run starts, and a name that an earlier run or another window
took gets a number (scene_2, ...); the SfM folder stays empty until the scene is complete. When it has finished, the last model is
opened as the scene (the reconstruction paired as its original, for the style strength) and a project recording
them, the dataset and the painting is written to OUT (project.splatproj, or the first free name). Without a
painting the run ends after the reconstruction, and a line says how to stylize it.

Each function runs on the UI thread.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from training.core.errors import InputError


def is_scene(path: Path) -> bool:
    """A folder that holds cameras already: a COLMAP model or transforms.json."""
    from training.scene.loader import find_model_folder

    return path.is_dir() and ((path / "transforms.json").is_file() or find_model_folder(path) is not None)


def photos_folder(path: str | Path) -> Path | None:
    """The folder of photos ``path`` names (photos directly in it, or in its images/) when it is no scene yet (no
    COLMAP model, no transforms.json), else None."""
    from training.scene.image_io import is_image_file

    path = Path(path)
    if not path.is_dir() or is_scene(path):
        return None
    for folder in (path, path / "images"):
        if folder.is_dir() and any(is_image_file(p) for p in folder.iterdir()):
            return folder
    return None


def ask_for_photos(ui, folder: str = "") -> None:
    """Open the New from photos dialog (photos_panel.py), with ``folder`` in it when given (and the painting open
    in the window, when the dialog names none yet)."""
    if folder:
        ui.photos.folder = str(folder)
    if not ui.photos.painting and ui.paths.style:
        ui.photos.painting = ui.paths.style
    ui.photos.dialog = True


def open_dropped(doc, session, ui, path: str) -> None:
    """A file or folder dropped on the window: a folder of photos opens the New from photos dialog with it;
    anything else opens as files.open_dropped says (a model, a painting, a dataset, a project)."""
    from app.viewer.files import open_dropped as open_file

    if photos_folder(path) is not None:
        ask_for_photos(ui, path)
    else:
        open_file(doc, session, ui, path)


def start_photos(doc, session, ui) -> None:
    """Start the photos pipeline with the dialog's settings (ui.photos, and the Training panel's preset, iterations
    and downscale): a new scene, the three stages in the live session."""
    from app.viewer.files import unless_unsaved
    from training.scene.sfm import CAMERA_MODELS, list_photos

    p, t = ui.photos, ui.training
    if session.running:
        raise ValueError("a run is going: stop it (Training panel) before starting from photos")
    if not p.folder:
        raise InputError(None, "choose the folder that holds the photos")
    folder = photos_folder(p.folder)
    if folder is None:
        if is_scene(Path(p.folder)):
            raise InputError(p.folder, "already a scene (it has cameras): open it as the dataset (File > Open "
                                       "dataset...)")
        list_photos(Path(p.folder))  # says what is wrong: no such folder, not a folder, no photos
    count = len(list_photos(folder))  # at least two
    if p.max_size < 16:
        raise InputError(None, f"the photos' long side must be at least 16 pixels, got {p.max_size}")
    if p.camera_model not in CAMERA_MODELS:
        raise InputError(None, f"unknown camera model {p.camera_model!r} ({', '.join(CAMERA_MODELS)})")
    if p.painting:
        doc.open_painting(p.painting)  # a bad painting stops here, before minutes of work
        ui.paths.style = p.painting
    painting = doc.painting.path if p.painting else None
    unless_unsaved(doc, session, ui, "starting a new scene from photos",
                   lambda: _begin_photos(doc, session, ui, folder, count, painting))


def _begin_photos(doc, session, ui, folder: Path, count: int, painting: str | None) -> None:
    """The pipeline started (the photos and painting checked): its folders claimed, a new scene, the stages."""
    from app.settings import sfm as sfm_settings
    from app.stage_outputs import StageOutputs
    from app.viewer.live.runs import claimed_for, settings_now
    from app.viewer.live.stages import reconstruct_stage, sfm_stage, stylize_stage

    p, t = ui.photos, ui.training
    out = ui.out_dir()
    folders = {"scene": claimed_for(ui, out, "scene"), "reconstruction": claimed_for(ui, out, "reconstruction")}
    if painting:
        folders["stylized"] = claimed_for(ui, out, "stylized")
    outputs = StageOutputs(folders["scene"], painting, out)
    overrides = {} if t.recon_iters is None else {"iterations": int(t.recon_iters)}
    sfm = sfm_settings.options_from_flags(["--max-size", str(int(p.max_size)), "--camera-model", p.camera_model])
    stages = [sfm_stage(folder, folders["scene"], sfm),
              reconstruct_stage(folders["scene"], folders["reconstruction"], preset=t.preset, downscale=t.downscale,
                                outputs=outputs.reconstruction, **overrides)]
    if painting:
        t.stylize = replace(t.stylize, preset=t.preset)  # one preset for the run (quick: minutes on a CPU)
        stages.append(stylize_stage(folders["scene"], painting, folders["stylized"], config=settings_now(ui),
                                    outputs=outputs.stylization))

    # a new scene: nothing of the last one is shown, edited or saved into the next project
    session.release()
    doc.new_scene()
    t.before, t.shown_step, t.base_model, t.runs, t.order_preview = None, None, "", [], None
    ui.edit.shown_version = None
    ui.paths.model = ui.paths.data = ""
    ui.project.path = ""
    ui.window.model_info = {}
    view = ui.view
    if view is not None:
        view.clear(0)
        view.clear(1)
        view.overlays = None
        view.camera = None  # placed on the first registered cameras
    p.out, p.folders, p.ended, p.ending, p.dialog = str(out), {k: str(v) for k, v in folders.items()}, False, "", False
    ui.messages.error = ""
    ui.messages.say(f"from {count} photos in {folder}: structure from motion into "
                    f"{folders['scene']}, then " + ("reconstruction and stylization" if painting else
                                                     "reconstruction") + f", into {out}")
    session.start(stages)


def note_state(ui, state: str) -> None:
    """The session's run reached ``state``: the pipeline's end is taken care of once its thread is gone."""
    if state in ("finished", "stopped", "error") and not ui.photos.ended:
        ui.photos.ending = state


def end_when_done(doc, session, ui) -> None:
    """Each frame: the pipeline's end (``photos_run_ended``) once the run's thread has ended (the session's last
    state comes a moment before, and a model cannot open while a run goes)."""
    if ui.photos.ending and not session.running:
        state, ui.photos.ending = ui.photos.ending, ""
        photos_run_ended(doc, session, ui, state)


def photos_run_ended(doc, session, ui, state: str) -> None:
    """The pipeline's run ended (``state``: finished, stopped or error). Finished: the last model opened as the
    scene, paired with the reconstruction when stylized, and the project written. Stopped or failed: what the
    stages saved stays where they said (a stopped SfM: nothing), and the window goes on."""
    from app.viewer.files import open_model, save_project

    p = ui.photos
    p.ended = True
    if state != "finished":
        return
    recon = Path(p.folders["reconstruction"]) / "point_cloud.ply"
    stylized = Path(p.folders["stylized"]) / "point_cloud.ply" if "stylized" in p.folders else None
    final = stylized if stylized is not None else recon
    # the scene the user started from the photos: what was edited meanwhile (keyframes) goes into its project
    open_model(doc, session, ui, str(final), ask=False)
    if stylized is not None:
        doc.pair_original(recon)  # the Colour panel's style strength, and the project's record of the original
    written = save_project(doc, session, ui)
    if stylized is None:
        ui.messages.say(f"reconstructed {final}; to stylize it, open a painting (File > Open painting..., or drop one "
                        "on the window) and press Stylize (Training tab)")
    else:
        ui.messages.say(f"photos to a stylized scene: {p.folders['scene']}, {recon.parent}, {stylized.parent} "
                        f"and {written}")
