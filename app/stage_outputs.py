"""What the console's reconstruct and stylize write besides the model, written by a window's stages as each ends
(``Stage.outputs``, on the viewer's training thread, the window live meanwhile): the same library steps the commands
end with, on the stage's finished trainer (training/reconstruct/pipeline.py ``write_reconstruction``,
training/stylize/pipeline.py ``write_stylization``), with what the stage measured at its start. Each line is said
in the window and printed in the console. The demo's window adds its own files (app/commands/demo.py), the photos
pipeline uses these as they are (app/viewer/live/photos.py).
"""

from __future__ import annotations

from pathlib import Path


class StageOutputs:
    """The console's outputs of a reconstruction of ``data`` and a stylization after ``style`` (see the module
    docstring); ``out`` is the run's output folder."""

    def __init__(self, data: Path, style: Path | None, out: Path):
        self.data, self.style, self.out = Path(data), None if style is None else Path(style), Path(out)

    def reconstruction(self, trainer, ply, say, seconds: float, report_extra: dict, fingerprint: dict) -> None:
        from training.reconstruct.pipeline import summary_line, write_reconstruction

        folder = Path(ply).parent
        tell(say, f"writing {folder / 'report.json'}, renders and contact sheet (as `splatstyler reconstruct`)")
        report = write_reconstruction(trainer, trainer.export_gaussians(), folder, self.data, seconds, report_extra,
                                      fingerprint, log=print)
        tell(say, summary_line(report, folder))

    def stylization(self, trainer, ply, say, record) -> None:
        from app.settings.stylize import METRIC_PAIRS
        from training.evaluate.measure import Measure, summary_line
        from training.stylize.pipeline import write_stylization

        folder = Path(ply).parent
        tell(say, f"measuring and rendering every view for {folder / 'report.json'} (as `splatstyler stylize`)")
        report = write_stylization(trainer, folder, record, metrics=Measure(METRIC_PAIRS))
        tell(say, f"wrote {folder / 'report.json'}, {len(report['renders'])} renders in {folder / 'renders'}, "
                  f"{folder / report['contact_sheet']}")
        if report.get("metrics"):
            tell(say, summary_line(report["metrics"]))


def tell(say, line: str) -> None:
    """A line in the window (``say``) and in the console."""
    print(line, flush=True)
    say(line)
