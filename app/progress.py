"""The console's view of a trainer: a tqdm progress bar fed by the trainer's events, the same stream the viewer
reads. (The trainers' warnings also go through Python's warnings, which the CLI prints as one line each.)"""

from __future__ import annotations

import sys

from training.core.messages import Scored, Stepped, TrainerEvent

# A bar redrawn ten times a second is right on a terminal; in a log file (SLURM, `> run.log`, an eval grid's job
# logs) every redraw is kept, and a run's log grows by hundreds of KB. Off a terminal the bar is written at most
# this often: a run's log keeps its progress, a line's worth every half minute.
LOG_INTERVAL_S = 30.0


def redraw_timing(stream=None) -> dict[str, float]:
    """tqdm's ``mininterval`` and ``maxinterval`` for a bar written to ``stream`` (default: stderr)."""
    stream = sys.stderr if stream is None else stream
    try:
        tty = stream.isatty()
    except (AttributeError, ValueError):  # a closed or file-less stream
        tty = False
    return {"mininterval": 0.1, "maxinterval": 10.0} if tty else {"mininterval": LOG_INTERVAL_S,
                                                                    "maxinterval": LOG_INTERVAL_S}


class ProgressBar:
    """A listener (``trainer.add_listener(bar)``): "step" events advance the bar and show the metrics named in
    ``postfix`` (event metric -> label; ``psnr`` is smoothed) with the last "test" event's PSNR. The bar appears with the first step, so an error
    before training leaves no empty bar behind, counting from the step before that one's (a resumed run's bar starts
    where it resumed); its total follows the trainer's (a schedule may change live)."""

    def __init__(self, desc: str = "", postfix: dict[str, str] | None = None, disable: bool = False):
        self.desc, self.disable = desc, disable
        self.postfix = postfix or {}
        self.bar = None
        self._psnr_ema: float | None = None
        self._test: dict[str, str] = {}  # the test views' last score, kept beside each step's metrics
        self._shown: dict[str, str | int] = {}

    def __call__(self, event: TrainerEvent) -> None:
        if isinstance(event, Scored) and event.psnr is not None:
            self._test = {"test": f"{event.psnr:.2f} dB"}
        if not isinstance(event, Stepped):
            return
        m = event.metrics
        total = int(m.get("total_iters", 0)) or None
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=max(0, event.step - 1), desc=self.desc, unit="it", disable=self.disable,
                            dynamic_ncols=True, **redraw_timing())
        elif total is not None and total != self.bar.total:
            self.bar.total = total
        if not m.get("recovered", 0.0):
            shown = self._shown  # a metric a step did not measure keeps the value it last had (or is left out)
            for key, label in self.postfix.items():
                if m.get(key) is not None:
                    value = m[key]
                    if key == "psnr":
                        self._psnr_ema = value if self._psnr_ema is None else 0.9 * self._psnr_ema + 0.1 * value
                        value = self._psnr_ema
                    shown[label] = int(value) if float(value).is_integer() else f"{value:.4g}"
            self.bar.set_postfix({**shown, **self._test}, refresh=False)
        self.bar.update(max(0, event.step - self.bar.n))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class CountBar:
    """A bar over a count of finished items, told by ``update(done, total)`` (an eval grid's jobs), with lines
    printed above it by ``write``. It shows no remaining time of its own: jobs differ too much in length for a rate,
    and the caller's lines say the time left from what jobs of each kind took."""

    def __init__(self, desc: str, unit: str, disable: bool = False):
        self.desc, self.unit, self.disable = desc, unit, disable
        self.bar = None

    def update(self, done: int, total: int) -> None:
        if self.disable:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=self.desc, unit=self.unit, dynamic_ncols=True,
                            bar_format="{desc}: {n_fmt}/{total_fmt} " + self.unit + "s |{bar}| {elapsed}",
                            **redraw_timing())
        self.bar.total = total
        self.bar.update(max(0, done - self.bar.n))

    def write(self, line: str) -> None:
        if self.bar is None:
            print(line, flush=True)
        else:
            self.bar.write(line, file=sys.stdout)
            sys.stdout.flush()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def say_above_bars(line: str) -> None:
    """Print a line on stderr without tearing a progress bar that is being drawn there."""
    from tqdm import tqdm

    tqdm.write(line, file=sys.stderr)
    sys.stderr.flush()
