"""What the console's reconstruct and stylize write besides the model, written by a window's stages as each ends
(``Stage.outputs``, on the viewer's training thread, the window live meanwhile).

``StageOutputs.reconstruction`` writes the reconstruction's report.json, renders and contact sheet: the reconstruct
command's job (training/reconstruct/pipeline.py ``reconstruct_to_folder``) resumed from the checkpoint the stage
saved at its end, so no step is taken; ``stylization`` the stylization's renders, report.json (its metrics) and
before/after sheet: the stylize command's job (training/stylize/pipeline.py ``stylize_to_folder``) resumed from a
checkpoint of the finished stylizer, with the settings it ended with (the sliders may have moved them). Each line is
said in the window and printed in the console. The demo's window adds its own files (app/commands/demo.py), the
photos pipeline uses these as they are (app/viewer/live/photos.py).
"""

from __future__ import annotations

from pathlib import Path


class StageOutputs:
    """The console's outputs of a reconstruction of ``data`` and a stylization after ``style`` (see the module
    docstring); ``out`` is the run's output folder."""

    def __init__(self, data: Path, style: Path | None, out: Path):
        self.data, self.style, self.out = Path(data), None if style is None else Path(style), Path(out)

    def reconstruction(self, trainer, ply, say) -> None:
        from training.reconstruct.pipeline import reconstruct_to_folder, summary_line

        folder = Path(ply).parent
        tell(say, f"writing {folder / 'report.json'}, renders and contact sheet (as `splatstyler reconstruct`)")
        report = reconstruct_to_folder(self.data, folder, None, resume=True, log=print,
                                       warn=lambda line: tell(say, f"warning: {line}"))
        tell(say, summary_line(report, folder))

    def stylization(self, trainer, ply, say) -> None:
        from app.settings.stylize import METRIC_PAIRS
        from training.evaluate.measure import Measure, summary_line
        from training.stylize.checkpoint import CHECKPOINT_NAME, save_stylize_checkpoint, stylize_fingerprint
        from training.stylize.pipeline import stylize_to_folder

        ply = Path(ply)
        folder, model = ply.parent, Path(trainer.model_name)
        tell(say, f"measuring and rendering every view for {folder / 'report.json'} (as `splatstyler stylize`)")
        steps = sum(s for name, s in trainer.times.totals.items() if name.startswith("stylize/"))
        save_stylize_checkpoint(folder / CHECKPOINT_NAME, trainer, stylize_fingerprint(
            model, self.data, self.style, trainer.config, trainer.mask), {"stylize_seconds": steps})
        report = stylize_to_folder(model, self.data, self.style, folder, trainer.config, mask=trainer.mask,
                                   metrics=Measure(METRIC_PAIRS), resume=True, log=print)
        tell(say, f"wrote {folder / 'report.json'}, {len(report['renders'])} renders in {folder / 'renders'}, "
                  f"{folder / report['contact_sheet']}")
        if report.get("metrics"):
            tell(say, summary_line(report["metrics"]))


def tell(say, line: str) -> None:
    """A line in the window (``say``) and in the console."""
    print(line, flush=True)
    say(line)
