"""What the console's reconstruct and stylize write besides the model, written by a window's stages as each ends
(``Stage.outputs``, on the viewer's training thread, the window live meanwhile), and the stylize report's metrics.

``StageOutputs.reconstruction`` writes the reconstruction's report.json, renders and contact sheet, made by
``reconstruct --resume`` from the checkpoint the stage saved at its end (no step is taken); ``stylization`` the
stylization's renders, report.json (its metrics) and before/after sheet, made by the stylize pipeline from a
checkpoint of the finished stylizer, with the settings it ended with (the sliders may have moved them). Each line is
said in the window and printed in the console. The demo's window adds its own files (app/commands/demo.py), the
photos pipeline uses these as they are (app/viewer/photos.py).
"""

from __future__ import annotations

from pathlib import Path

# Pairs of views per range (neighbours, 7 apart) for the consistency metric: evenly spaced along the trajectory.
METRIC_PAIRS = 20


class Measure:
    """The report's metrics (training/evaluate): consistency, style and content of the finished stylization;
    ``version`` goes into the report beside them."""

    def __init__(self, max_pairs: int = METRIC_PAIRS):
        from training.evaluate.measure import METRICS_VERSION

        self.max_pairs = max_pairs
        self.version = METRICS_VERSION

    def __call__(self, stylizer) -> dict:
        from training.evaluate.measure import measure_stylizer

        return measure_stylizer(stylizer, original=stylizer.input_gaussians(), max_pairs=self.max_pairs)


class StageOutputs:
    """The console's outputs of a reconstruction of ``data`` and a stylization after ``style`` (see the module
    docstring); ``out`` is the run's output folder."""

    def __init__(self, data: Path, style: Path | None, out: Path):
        self.data, self.style, self.out = Path(data), None if style is None else Path(style), Path(out)

    def reconstruction(self, trainer, ply, say) -> None:
        folder = Path(ply).parent
        tell(say, f"writing {folder / 'report.json'}, renders and contact sheet (as `splatstyler reconstruct`)")
        run_command(["reconstruct", str(self.data), "-o", str(folder), "--resume", "--no-progress"])
        tell(say, f"wrote {folder / 'report.json'}, {folder / 'renders'}, {folder / 'contact_sheet.png'}")

    def stylization(self, trainer, ply, say) -> None:
        from training.evaluate.measure import summary_line
        from training.stylize.checkpoint import CHECKPOINT_NAME, save_stylize_checkpoint, stylize_fingerprint
        from training.stylize.pipeline import stylize_to_folder

        ply = Path(ply)
        folder, model = ply.parent, Path(trainer.model_name)
        tell(say, f"measuring and rendering every view for {folder / 'report.json'} (as `splatstyler stylize`)")
        steps = sum(s for name, s in trainer.times.totals.items() if name.startswith("stylize/"))
        save_stylize_checkpoint(folder / CHECKPOINT_NAME, trainer, stylize_fingerprint(
            model, self.data, self.style, trainer.config, trainer.mask), {"stylize_seconds": steps})
        report = stylize_to_folder(model, self.data, self.style, folder, trainer.config, mask=trainer.mask,
                                   metrics=Measure(), resume=True, log=print)
        tell(say, f"wrote {folder / 'report.json'}, {len(report['renders'])} renders in {folder / 'renders'}, "
                  f"{folder / report['contact_sheet']}")
        if report.get("metrics"):
            tell(say, summary_line(report["metrics"]))


def tell(say, line: str) -> None:
    """A line in the window (``say``) and in the console."""
    print(line, flush=True)
    say(line)


def run_command(argv: list[str]) -> None:
    """A subcommand as the console runs it, here on the viewer's training thread: the window owns SIGTERM and
    Ctrl-C (cli.main's handlers can only go in on the main thread), and a failure is one line in the window."""
    from app.cli import build_parser

    args = build_parser().parse_args(argv)
    code = args.func(args)
    if code:
        raise RuntimeError(f"splatstyler {argv[0]} exited with status {code}")
