"""The stages a live session runs: structure from motion, reconstruction and stylization, built and saved as the CLI
builds and saves them.

An SfM stage runs `splatstyler sfm`'s run_sfm (app/viewer/live/sfm_run.py) into OUT, a COLMAP folder that appears only
whole: stopped or failed, it leaves nothing, and says so in one line (``Stage.stopped``); it hands OUT to the next
stage, and its outputs are the lines the console prints at the end (the summary, the photos left out).

A reconstruction stage writes OUT/checkpoint.pt (resumable with ``splatstyler reconstruct --resume``; kept when it
finished, as the CLI keeps it) and OUT/point_cloud.ply, whether it finished or was stopped; a stylization stage
writes OUT/point_cloud.ply, after the post colour transfer when it finished, as it stands when stopped (a stop
during the colour transfer keeps the finished stylization without the transfer), and then also
OUT/stylize_checkpoint.pt (resumable with ``splatstyler stylize ... --resume``). Both hand the PLY's path to the
next stage. The checkpoints hold the fingerprint of their inputs (training/scene/fingerprint.py), which a resume
checks.

``outputs`` writes the rest of what the command line writes once a stage has finished (the demo's window:
report.json, renders, contact sheets), through the same library steps the commands end with
(training/reconstruct/pipeline.py ``write_reconstruction``, training/stylize/pipeline.py ``write_stylization``): for
it a stage measures at its start what the command measures before its first step (a reconstruction its first
scores, a stylization its start style distances) and hands that over with the finished trainer.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from app.viewer.live.session import Stage


def sfm_stage(photos: str | Path, out: str | Path, options: dict | None = None) -> Stage:
    """Structure from motion of the photos in ``photos`` into the scene folder ``out`` (``options``: run_sfm's
    settings, as app/settings/sfm.py gives them; default `splatstyler sfm`'s)."""
    from app.settings import sfm as settings
    from app.viewer.live.sfm_run import SfmRun

    out = Path(out)

    def build(_previous):
        return SfmRun(Path(photos), out, settings.options_from_flags() if options is None else options)

    def save(trainer, finished: bool, cancel) -> Path | None:
        return out if finished else None  # run_sfm put the whole folder in place, or nothing

    def outputs(trainer, saved, say) -> None:
        from training.scene.sfm import result_lines

        lines, notes = result_lines(trainer.result)
        for line in lines + [f"note: {n}" for n in notes]:
            say(line)

    def stopped(trainer) -> str:
        return f"structure from motion stopped: nothing written ({out} appears only once complete)"

    return Stage("sfm", build, save, outputs, stopped)


def reconstruct_stage(data: str | Path, out: str | Path, preset: str = "quick", downscale: int | None = None,
                      outputs=None, iterations: int | None = None) -> Stage:
    """3DGS with the paper's regularizers on DATA, with the settings `splatstyler reconstruct --preset PRESET
    [--iters ITERATIONS] [--downscale DOWNSCALE]` takes (app/settings/reconstruct.py)."""
    import time

    out = Path(out)
    report_extra: dict[str, Any] = {}  # what the CLI's report measures before the first step (with ``outputs``)
    started: list[float] = []
    fingerprint: dict[str, Any] = {}  # the data as the run read it (a save must not read the data folder again)

    def build(_previous):
        from app.settings import parse_flags
        from app.settings import reconstruct as settings
        from training.reconstruct.resolution import training_downscale
        from training.reconstruct.trainer import Reconstructor
        from training.scene.fingerprint import dataset_fingerprint, make_fingerprint
        from training.scene.loader import load_scene

        # at the start, as the CLI takes it: the checkpoint names the data the run was made from, and a save (Stop,
        # window close) still works when the data folder has moved or gone since
        fingerprint.update(make_fingerprint(dataset=dataset_fingerprint(data)))
        flags = (["--preset", preset] + ([] if iterations is None else ["--iters", str(int(iterations))])
                 + ([] if downscale is None else ["--downscale", str(int(downscale))]))
        cfg = settings.config_from_args(parse_flags(settings.add_arguments, flags, "reconstruct flags"))
        cfg.downscale = training_downscale(data, cfg.max_side, cfg.downscale)
        scene = load_scene(data, downscale=cfg.downscale)
        trainer = Reconstructor(scene, cfg)
        if outputs is not None:
            from training.reconstruct.metrics import constant_color_psnr

            views = scene.test_indices or scene.train_indices
            first = trainer.evaluate(views)
            report_extra.update(initial_psnr=first["psnr"], initial_ssim=first["ssim"],
                                constant_color_psnr=constant_color_psnr(scene, scene.train_indices, views))
        started.append(time.perf_counter())
        return trainer

    def save(trainer, finished: bool, cancel) -> Path:
        from training.model.ply_io import write_ply
        from training.reconstruct.checkpoint import CHECKPOINT_NAME, save_checkpoint

        out.mkdir(parents=True, exist_ok=True)
        # the data's fingerprint, as the CLI's checkpoints hold it: `reconstruct --resume` checks it; the time and
        # the first measures, which its report gives
        save_checkpoint(out / CHECKPOINT_NAME,
                        {**trainer.state_dict(), "fingerprint": dict(fingerprint),
                         "elapsed": time.perf_counter() - started[0], "report_extra": dict(report_extra)})
        write_ply(out / "point_cloud.ply", trainer.export_gaussians())
        return out / "point_cloud.ply"

    def stage_outputs(trainer, saved, say) -> None:
        outputs(trainer, saved, say, seconds=time.perf_counter() - started[0], report_extra=dict(report_extra),
                fingerprint=dict(fingerprint))

    return Stage("reconstruct", build, save, None if outputs is None else stage_outputs)


def stylize_stage(data: str | Path, style: str | Path, out: str | Path, config=None, model: str | Path | None = None,
                  vgg_weights: str | None = None, mask=None, outputs=None) -> Stage:
    """Stylize ``model`` (or the previous stage's PLY) after the painting ``style``; ``config`` a StylizeConfig, or a
    function giving the one to use, called when the stage begins (the window's settings as they are then: a run
    that reconstructs first stylizes with what the user set meanwhile); ``mask`` (N,) bool: only those Gaussians
    change."""
    import time

    out = Path(out)
    records: list = []  # what the report keeps beyond the stylizer (with ``outputs``): measured as the CLI does

    def build(previous):
        from training.model.model_io import read_model
        from training.scene.loader import load_scene
        from training.stylize.checkpoint import stylize_fingerprint
        from training.stylize.pipeline import StylizationRecord, choose_downscale, start_distances
        from training.stylize.style_image import load_style_image
        from training.stylize.config import StylizeConfig
        from training.stylize.trainer import Stylizer

        t0 = time.perf_counter()
        source = Path(model) if model is not None else previous
        if source is None:
            raise ValueError("nothing to stylize: open a model or reconstruct first")
        cfg = replace(config() if callable(config) else config or StylizeConfig(preset="quick"))
        painting = load_style_image(style)
        scene = load_scene(data, downscale=choose_downscale(Path(data), cfg.render_max_side))
        stylizer = Stylizer(read_model(source), scene, painting, cfg, vgg_weights=vgg_weights, model_name=source,
                            mask=mask)
        if outputs is not None:
            loaded = time.perf_counter() - t0
            records[:] = [StylizationRecord(source, Path(data), Path(style),
                                            stylize_fingerprint(source, data, style, cfg, mask),
                                            *start_distances(stylizer), load_seconds=loaded, started=t0)]
        return stylizer

    def save(trainer, finished: bool, cancel) -> Path:
        from training.core.messages import Cancelled
        from training.model.ply_io import write_ply

        if finished and not trainer.finished:
            try:
                trainer.finish(cancel=cancel)
            except Cancelled:
                # stopped during the post colour transfer: the stylization itself is done and is kept, as the
                # model without the transfer and a checkpoint (`stylize --resume` applies the transfer)
                finished = False
        out.mkdir(parents=True, exist_ok=True)
        write_ply(out / "point_cloud.ply", trainer.stylized_gaussians())
        if not finished:  # stopped: `splatstyler stylize ... --resume` can continue it, as it continues the CLI's
            from training.stylize.checkpoint import CHECKPOINT_NAME, save_stylize_checkpoint, stylize_fingerprint

            save_stylize_checkpoint(out / CHECKPOINT_NAME, trainer, stylize_fingerprint(
                trainer.model_name, data, style, trainer.config, trainer.mask))
        return out / "point_cloud.ply"

    def stage_outputs(trainer, saved, say) -> None:
        record = records[0]
        record.loop_seconds = sum(s for name, s in trainer.times.totals.items() if name.startswith("stylize/"))
        outputs(trainer, saved, say, record)

    def began(trainer) -> str:
        from training.stylize.config import recipe_line

        line = f"stylizing after {Path(style).name}: {recipe_line(trainer.config)}; {trainer.total_iters} steps"
        if outputs is not None:  # a window that writes the console's outputs also prints the console's lines
            print(line, flush=True)
        return line

    def stopped(trainer) -> str:
        if trainer is None:
            return f"stylization stopped before its first step: nothing written to {out}"
        return (f"stylization stopped at step {trainer.status().step} of {trainer.total_iters}: the model so far "
                f"and its checkpoint in {out} (`splatstyler stylize ... --resume` continues it)")

    return Stage("stylize", build, save, None if outputs is None else stage_outputs, stopped, began)
