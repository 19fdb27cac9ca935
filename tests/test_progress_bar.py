"""The CLI's progress bar: live on a terminal, a few lines in a log file (SLURM, `> run.log`, the eval grid's job
logs), where every redraw is kept."""

import io
import sys
import time

from app.progress import ProgressBar
from training.core.messages import Scored, Stepped


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _run(stream, monkeypatch, steps: int = 120, seconds: float = 1.2) -> str:
    monkeypatch.setattr(sys, "stderr", stream)
    bar = ProgressBar(desc="stylizing", postfix={"loss": "loss"})
    for i in range(1, steps + 1):
        bar(Stepped("stylize", i, {"loss": 1.0 / i, "total_iters": steps}))
        time.sleep(seconds / steps)
    bar.close()
    return stream.getvalue()


def test_a_log_file_gets_a_few_redraws_and_the_final_count(monkeypatch):
    log = _run(io.StringIO(), monkeypatch)
    assert log.count("\r") <= 3, log
    assert "120/120" in log


def test_a_terminal_still_sees_the_bar_move(monkeypatch):
    shown = _run(_Terminal(), monkeypatch)
    assert shown.count("\r") >= 5
    assert "120/120" in shown


def test_the_line_keeps_the_test_views_last_score(monkeypatch):
    """A "test" event (the run scored its held-out views) stays in the line beside each later step's metrics."""
    stream = _Terminal()
    monkeypatch.setattr(sys, "stderr", stream)
    bar = ProgressBar(desc="reconstruct", postfix={"loss": "loss"})
    bar(Stepped("reconstruct", 1, {"loss": 0.5, "total_iters": 3}))
    bar(Scored("reconstruct", 1, psnr=21.234, ssim=0.7))
    for i in (2, 3):
        bar(Stepped("reconstruct", i, {"loss": 0.25, "total_iters": 3}))
    bar.close()
    assert "test=21.23 dB" in stream.getvalue().rsplit("\r", 1)[-1]
