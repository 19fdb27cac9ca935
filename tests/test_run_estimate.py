"""The time estimates: said once the model is ready, said again only when they move by more than 20 %, recorded
for the report; the reconstruction's Gaussian count follows the preset's densification schedule."""

from __future__ import annotations

import pytest
import torch

from training.core.messages import Stepped
from training.core.run_estimate import RunEstimate, UniformSteps, format_duration
from training.reconstruct.densify import DensifyConfig
from training.reconstruct.time_estimate import mean_planned_gaussians, planned_gaussians


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def run_steps(estimate: RunEstimate, clock: Clock, step_seconds, total: int, start: int = 0) -> None:
    estimate.begin(start)
    for step in range(start + 1, total + 1):
        clock.t += step_seconds(step)
        estimate(Stepped("test", step, {"total_iters": total}))


def test_uniform_steps_say_one_estimate_when_the_time_holds():
    clock, said = Clock(), []
    est = RunEstimate(UniformSteps(warmup=2, timed=8), say=said.append, clock=clock)
    run_steps(est, clock, lambda s: 5.0 if s <= 2 else 1.0, total=200)
    assert len(said) == 1 and said[0].startswith("estimated training time: about")
    rec = est.record()
    # said after step 10: 10 s elapsed (two 5 s warm-up steps) + 190 steps at 1 s
    assert rec["first_estimate_at_iteration"] == 10 and rec["first_estimate_s"] == pytest.approx(208.0)
    assert rec["actual_s"] == pytest.approx(208.0) and rec["actual_over_first_estimate"] == pytest.approx(1.0)
    assert rec["revisions"] == [] and rec["from_iteration"] == 0


def test_a_slowdown_beyond_20_percent_is_said_again_and_a_small_one_is_not():
    clock, said = Clock(), []
    est = RunEstimate(UniformSteps(warmup=2, timed=8, window=20, review_every=10), say=said.append, clock=clock)
    # 10 % slower from step 50: no revision; three times slower from step 100: one (or a few) revisions
    run_steps(est, clock, lambda s: 1.0 if s < 50 else (1.1 if s < 100 else 3.0), total=400)
    revised = [line for line in said if line.startswith("revised estimate")]
    assert revised, said
    rec = est.record()
    first_revision = rec["revisions"][0]
    assert first_revision["iteration"] > 100
    assert abs(first_revision["estimate_s"] - rec["first_estimate_s"]) > 0.2 * rec["first_estimate_s"]
    # each revision differs from the one said before it by more than 20 %
    said_totals = [rec["first_estimate_s"]] + [r["estimate_s"] for r in rec["revisions"]]
    assert all(abs(b - a) > 0.2 * a for a, b in zip(said_totals, said_totals[1:]))
    # every look is kept, said or not: the first, the revisions and the ones that moved too little
    assert len(rec["looks"]) > 1 + len(rec["revisions"])
    assert {r["iteration"] for r in rec["revisions"]} < {look["iteration"] for look in rec["looks"]}
    assert rec["actual_s"] == pytest.approx(49 + 50 * 1.1 + 301 * 3.0)


def test_a_resumed_run_times_only_its_own_steps():
    clock, said = Clock(), []
    est = RunEstimate(UniformSteps(warmup=2, timed=8), say=said.append, clock=clock)
    run_steps(est, clock, lambda s: 0.5, total=100, start=60)
    rec = est.record()
    assert rec["from_iteration"] == 60 and "for 40 iterations" in said[0]
    assert rec["actual_s"] == pytest.approx(20.0) and rec["first_estimate_s"] == pytest.approx(20.0)


def test_format_duration():
    assert format_duration(30) == "30 s" and format_duration(98) == "1 min 38 s" and format_duration(126.5) == \
        "2 min 06 s"
    assert format_duration(600) == "10 min" and format_duration(7200) == "2.0 h"


def test_planned_gaussians_follow_the_schedule_to_the_cap():
    d = DensifyConfig(start=250, stop=2500, interval=167, max_gaussians=60_000)
    assert planned_gaussians(100, 5000, 50, d, 5000) == 5000  # before densification starts
    assert planned_gaussians(250, 5000, 50, d, 5000) == 5000
    assert planned_gaussians(1375, 5000, 50, d, 5000) == pytest.approx(32_500)  # half way: half the growth
    assert planned_gaussians(2500, 5000, 50, d, 5000) == 60_000
    assert planned_gaussians(4000, 5000, 50, d, 5000) == 60_000
    # from the middle of densification: a straight line from the count now
    assert planned_gaussians(2000, 30_000, 1500, d, 5000) == pytest.approx(45_000)
    # after densification stopped the count stays
    assert planned_gaussians(4000, 59_000, 3000, d, 5000) == 59_000
    # mean over the rest of a quick run from step 250: 2250 steps of the line, 2500 at the cap
    mean = mean_planned_gaussians(250, 5000, 5000, d, 5000)
    assert mean == pytest.approx((2250 * 32_500 + 2500 * 60_000) / 4750, rel=1e-3)
    # the exact mean of the per-step counts
    brute = sum(planned_gaussians(s, 5000, 250, d, 5000) for s in range(251, 5001)) / 4750
    assert mean == pytest.approx(brute, rel=1e-3)


def test_planned_gaussians_without_a_cap_assume_ten_fold_growth():
    d = DensifyConfig(start=500, stop=15_000, interval=100, max_gaussians=None)
    assert planned_gaussians(20_000, 100_000, 500, d, 30_000) == pytest.approx(1_000_000)
    assert planned_gaussians(20_000, 100_000, 500, DensifyConfig(enabled=False), 30_000) == 100_000


class FakeTrainer:
    """What ReconstructSteps reads of a Reconstructor: its config's schedule, its step count and model size."""

    def __init__(self, total: int, densify: DensifyConfig, n: int):
        from types import SimpleNamespace

        self.total_iters, self.step_count = total, 0
        self.config = SimpleNamespace(densify=densify)
        self.gaussians = [None] * n


def test_reconstruction_estimate_waits_a_tenth_of_the_run_and_adds_the_planned_gaussians():
    from training.reconstruct.time_estimate import ReconstructSteps

    d = DensifyConfig(start=250, stop=2500, interval=167, max_gaussians=60_000)
    trainer = FakeTrainer(5000, d, 5000)
    model = ReconstructSteps(trainer, probe=False)
    model._measure_per_gaussian = lambda: 2e-6  # what the probe would measure: 2 us per Gaussian per step
    clock, said = Clock(), []
    est = RunEstimate(model, say=said.append, clock=clock)
    est.begin(0)
    n = 5000
    for step in range(1, 502):
        clock.t += 0.6 if step < 300 else 0.1  # a random start's slow first steps
        est(Stepped("reconstruct", step, {"total_iters": 5000, "num_gaussians": n}))
    rec = est.record()
    assert rec["first_estimate_at_iteration"] == 500  # a tenth of the run, not the slow start
    elapsed = 299 * 0.6 + 201 * 0.1
    mean_n = mean_planned_gaussians(500, 5000, 5000, d, 5000)
    assert rec["first_estimate_s"] == pytest.approx(elapsed + 4500 * (0.1 + 2e-6 * (mean_n - 5000)))
    assert "60,000" in said[0]


def test_the_probe_measures_a_positive_cost_per_gaussian_on_a_real_model():
    from assets.demo.scene import make_demo_scene
    from training.reconstruct.time_estimate import probe_per_gaussian
    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
    from training.scene.scene import Scene

    demo = make_demo_scene(num_views=3, width=48, height=36, num_points=300, supersample=1)
    scene = Scene(cameras=demo.cameras, images=demo.images, points=demo.points, point_colors=demo.point_colors)
    trainer = Reconstructor(scene, ReconstructConfig.from_preset("quick", iterations=50))
    before = {k: v.detach().clone() for k, v in trainer.gaussians.parameters().items()}
    per_gaussian = probe_per_gaussian(trainer, 20_000, steps=2)
    assert 0 <= per_gaussian < 1e-3  # seconds per Gaussian per step: microseconds (no timing claim: a loaded machine)
    # the trainer's model is untouched
    assert all(torch.equal(before[k], v) for k, v in trainer.gaussians.parameters().items())
    assert trainer.step_count == 0
