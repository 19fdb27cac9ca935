"""How long a reconstruction will take on this machine: the cost model behind ``RunEstimate``
(training/core/run_estimate.py), from the run's own timed steps, a probe of what more Gaussians cost, and the
preset's densification schedule.

A step costs ``t = t_now + per_gaussian * (N - N_now)``: what the latest steps took, plus what each Gaussian that
densification adds costs per step (projection, SH, sorting, the regularizers, the gradient, Adam's update, the
finiteness checks). The pixel work is taken to stay as it is: densification splits large Gaussians into smaller
ones, so the Gaussian-tile pairs a step composites do not grow with N (fox, quick: 254k over steps 701-800 with
6.5k Gaussians, 147k-193k from step 1400 to the end with 21k-59k; docs/reconstruction.md).

- ``per_gaussian`` is measured, at the first estimate, by ``probe_per_gaussian``: a few training steps'
  work (render, loss, backward, Adam) on the model as it is, and on the same model with as many small Gaussians
  added as densification will add, at the schedule's final SH degree; the difference over the added count.
- ``N(step)`` follows the schedule: the current count until densification starts, then a straight line to the cap
  (``max_gaussians``) at the step densification stops, flat after. Every quick run we measured ended at 97-99 % of
  the cap (fox, fern, flower, and the facade of issue 33); without a cap (the paper preset) it assumes ten-fold
  growth and says so.
- When: the first Gaussians are large, from a random start (the fox) or from sparse SfM points (the fern), and a
  step costs two to five times a later one until training and the first splits have shrunk them, over the first
  few hundred steps. So the first estimate waits for a tenth of the run (quick: step 500 of 5000, about 40 s on a
  quiet machine), and not before densification starts.
- After each densification, and every 5 % of the run after the last one, the estimate is made again from the
  latest window of steps; RunEstimate prints it when it moved by more than 20 %.
"""

from __future__ import annotations

import time
from collections import deque

import torch

WARMUP_STEPS = 2  # the first step compiles numba kernels and fills caches
CALIBRATE_AT = 0.1  # of the run
TIMED_STEPS = 8  # at least this many timed steps behind any estimate
WINDOW = 50  # the latest steps' mean is the current step time (shorter windows follow every burst of other jobs)
PROBE_STEPS = 3
NO_CAP_GROWTH = 10.0


def planned_gaussians(step: int, n_now: int, step_now: int, densify, iterations: int) -> float:
    """The Gaussian count the schedule leads to at ``step`` (> step_now), from ``n_now`` at ``step_now``."""
    if not densify.enabled or step_now >= densify.stop:
        return float(n_now)
    n_end = densify.max_gaussians if densify.max_gaussians is not None else NO_CAP_GROWTH * n_now
    n_end = max(float(n_end), float(n_now))
    begin = max(step_now, densify.start)
    if step <= begin:
        return float(n_now)
    if step >= densify.stop:
        return n_end
    return n_now + (n_end - n_now) * (step - begin) / max(1, densify.stop - begin)


def mean_planned_gaussians(step_now: int, total: int, n_now: int, densify, iterations: int) -> float:
    """Mean of planned_gaussians over the steps step_now+1 .. total (the line and the flat parts, exactly)."""
    if total <= step_now:
        return float(n_now)
    # the planned count is piecewise linear in the step: sum it piece by piece (trapezoids over whole steps)
    points = sorted({step_now, total, *(s for s in (densify.start, densify.stop) if step_now < s < total)})
    acc = 0.0
    for a, b in zip(points, points[1:]):
        na = planned_gaussians(a + 1, n_now, step_now, densify, iterations)
        nb = planned_gaussians(b, n_now, step_now, densify, iterations)
        acc += 0.5 * (na + nb) * (b - a)
    return acc / (total - step_now)


def probe_per_gaussian(trainer, added: int, steps: int = PROBE_STEPS) -> float:
    """Seconds per step each of ``added`` more Gaussians costs, measured on ``trainer``'s model and scene without
    touching either: the model as it is, then with ``added`` small Gaussians (inside random existing ones, a
    hundredth of their size) at the schedule's final SH degree; each timed over ``steps`` training steps' work
    (render, L1 + SSIM and the regularizers, backward, Adam)."""
    from training.model.gaussians import Gaussians

    if added <= 0:
        return 0.0
    base = trainer.gaussians.detached()
    g = torch.Generator().manual_seed(0)
    pick = torch.randint(len(base), (added,), generator=g).to(base.device)
    params = base.parameters()
    grown = {k: torch.cat([v, v[pick]], dim=0) for k, v in params.items()}
    grown["log_scales"][len(base):] += torch.log(torch.tensor(0.01))
    big = Gaussians(**grown, sh_degree=base.sh_degree)
    degree = min(trainer.config.sh_degree, base.sh_degree)
    views = [trainer.scene.train_indices[i % len(trainer.scene.train_indices)] for i in range(steps + 1)]
    t_small = _time_steps(trainer, base, views, degree)
    t_big = _time_steps(trainer, big, views, degree)
    return max(0.0, (t_big - t_small) / added)


def _time_steps(trainer, model, views, degree: int) -> float:
    """Mean seconds of a training step's work on ``model`` over ``views`` (the first one untimed: a warm-up)."""
    from training.reconstruct.metrics import render_view
    from training.reconstruct.regularizers import shape_loss, size_loss
    from training.reconstruct.ssim import ssim

    from training.model.gaussians import Gaussians
    from training.reconstruct.trainer import FUSED_ADAM, all_finite

    cfg = trainer.config
    leaves = {k: v.detach().clone().requires_grad_(True) for k, v in model.parameters().items()}
    live = Gaussians(**leaves, sh_degree=model.sh_degree)
    opt = torch.optim.Adam(list(leaves.values()), lr=1e-6, eps=1e-15, fused=FUSED_ADAM)
    total = 0.0
    for i, view in enumerate(views):
        t = time.perf_counter()
        cam = trainer.scene.cameras[view]
        image, _, info = render_view(live, cam, sh_degree=degree, backend=cfg.backend)
        target = trainer.images[view][..., :3]
        rgb = image[..., :3]
        loss = 0.8 * (rgb - target).abs().mean() + 0.2 * (1.0 - ssim(rgb, target))
        s = live.scales / trainer.extent
        loss = loss + shape_loss(s, cfg.lambda_s) + size_loss(s, cfg.beta1, cfg.beta2)
        loss.backward()
        opt.step()
        opt.zero_grad(set_to_none=True)
        all_finite(leaves.values())  # the trainer checks twice a step
        all_finite(leaves.values())
        if i:
            total += time.perf_counter() - t
    return total / max(1, len(views) - 1)


class ReconstructSteps:
    """The cost model (see the module docstring) for ``trainer`` (a Reconstructor)."""

    def __init__(self, trainer, warmup: int = WARMUP_STEPS, timed: int = TIMED_STEPS, window: int = WINDOW,
                 probe: bool = True):
        self.trainer = trainer
        self.warmup, self.timed, self.window, self.probe = warmup, timed, window, probe
        self.seen = 0
        self.recent: deque[float] = deque(maxlen=window)
        self.since_change = 0  # timed steps since the last densification
        self.per_gaussian: float | None = None
        self.n_now = len(trainer.gaussians)
        self.step_now = trainer.step_count
        self._review = False
        self._last_review_step = 0

    # ------------------------------------------------------------------ measurements
    def calibration_step(self) -> int:
        """The step of the first estimate: a tenth into the run, and not before densification starts."""
        total = self.trainer.total_iters
        densify = self.trainer.config.densify
        at = CALIBRATE_AT * total
        if densify.enabled:
            at = max(at, densify.start)
        return max(int(at), self.warmup + 1)

    def observe(self, step: int, seconds: float, metrics: dict[str, float]) -> None:
        self.seen += 1
        self.step_now = step
        n = int(metrics.get("num_gaussians", self.n_now))
        densified = any(metrics.get(k, 0) for k in ("cloned", "split", "pruned")) or n != self.n_now
        self.n_now = n
        if densified:
            # the model changed: look again once a whole window of steps has timed the new one
            self.since_change = 0
            self._review = True
        if self.seen <= self.warmup:
            return
        self.recent.append(seconds)
        self.since_change += 1
        if self.per_gaussian is None and step >= self.calibration_step() and len(self.recent) >= self.timed:
            self.per_gaussian = self._measure_per_gaussian()

    def _measure_per_gaussian(self) -> float:
        densify = self.trainer.config.densify
        n_end = planned_gaussians(self.trainer.total_iters, self.n_now, self.step_now, densify,
                                  self.trainer.total_iters)
        added = int(n_end - self.n_now)
        if not self.probe or added <= 0:
            return 0.0
        return probe_per_gaussian(self.trainer, added)

    def mean(self) -> float:
        return sum(self.recent) / len(self.recent)

    # ------------------------------------------------------------------ the CostModel protocol
    def ready(self, step: int) -> bool:
        return self.per_gaussian is not None and len(self.recent) >= self.timed

    def seconds_left(self, step: int, total: int) -> float:
        densify = self.trainer.config.densify
        n_mean = mean_planned_gaussians(step, total, self.n_now, densify, total)
        per_step = self.mean() + (self.per_gaussian or 0.0) * (n_mean - self.n_now)
        return per_step * max(0, total - step)

    def basis(self) -> str:
        densify = self.trainer.config.densify
        text = f"steps at {1000 * self.mean():.0f} ms with {self.n_now:,} Gaussians"
        if self.per_gaussian and self.step_now < densify.stop:
            n_end = planned_gaussians(self.trainer.total_iters, self.n_now, self.step_now, densify,
                                      self.trainer.total_iters)
            cost = self.mean() + self.per_gaussian * (n_end - self.n_now)
            cap = "" if densify.max_gaussians is not None else f", {NO_CAP_GROWTH:g}x with no cap: a guess"
            text += f", {1000 * cost:.0f} ms at the {n_end:,.0f} densification grows to by iteration " \
                    f"{densify.stop}{cap}"
        return text

    def review(self, step: int) -> bool:
        """After a densification, once a window of the new model's steps is timed; every 5 % of the run else."""
        if self._review and self.since_change >= self.window:
            self._review = False
            self._last_review_step = step
            return True
        if step - self._last_review_step >= max(self.window, self.trainer.total_iters // 20):
            self._last_review_step = step
            return True
        return False
