"""``--stop-when-flat``: when a reconstruction's held-out views have stopped improving (issue 42 item 7: on sparse
captures the later steps overfit), the iteration to stop at and the best-scoring model to keep."""

from __future__ import annotations

from typing import Callable


class FlatWatch:
    """After densification stops (before it the model grows and the opacity reset dips the curve), the iteration of
    the last rise by MIN_GAIN of the test views' PSNR and a copy of the best-scoring model; ``see`` says when
    ``patience`` iterations have passed without such a rise."""

    MIN_GAIN = 0.05  # dB

    def __init__(self, patience: int, after: int):
        self.patience, self.after = int(patience), int(after)
        self.best_psnr = self.rise_psnr = None
        self.best_iteration = self.rise_iteration = None
        self.best_params = None
        self.stopped_at = None

    def see(self, iteration: int, psnr: float | None, trainer) -> bool:
        """Take the test views' PSNR at ``iteration``; True when the run should end now."""
        if iteration <= self.after or psnr is None:
            return False
        if self.best_psnr is None or psnr > self.best_psnr:
            self.best_psnr, self.best_iteration = psnr, iteration
            self.best_params = {k: v.detach().clone() for k, v in trainer.gaussians.parameters().items()}
        if self.rise_psnr is None or psnr >= self.rise_psnr + self.MIN_GAIN:
            self.rise_psnr, self.rise_iteration = psnr, iteration
        if iteration - self.rise_iteration >= self.patience and not trainer.done:
            self.stopped_at = iteration
            return True
        return False

    def finish(self, trainer, curve: list, say: Callable[[str], None]) -> dict:
        """Keep the best-scoring model when the last one scored lower; the report's entry."""
        last = curve[-1] if curve else None
        kept = "last"
        if self.best_params is not None and last is not None and self.best_psnr > last["psnr"]:
            trainer.load_parameters(self.best_params)
            kept = "best"
        if self.stopped_at is not None:
            say(f"stopped at iteration {self.stopped_at} of {trainer.total_iters}: the test views' PSNR has not "
                f"risen by {self.MIN_GAIN} dB since iteration {self.rise_iteration} (--stop-when-flat "
                f"{self.patience})")
        if kept == "best":
            say(f"kept the model of iteration {self.best_iteration} (test PSNR {self.best_psnr:.2f} dB; iteration "
                f"{last['iteration']}: {last['psnr']:.2f} dB)")
        return {"patience": self.patience, "min_gain_db": self.MIN_GAIN, "stopped_at": self.stopped_at,
                "best_iteration": self.best_iteration, "best_test_psnr": self.best_psnr, "kept": kept,
                "chosen_on": "the test views"}
