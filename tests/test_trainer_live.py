"""The trainers driven as the viewer drives them: snapshots read from another thread, config changes from another
thread applied at the next step (and refused for settings fixed at the start), events, cancellation."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from assets.demo.scene import make_demo_scene
from training.core.messages import Cancelled, Finished, Stepped, StructureChanged, TrainerEvent, ViewMoved
from training.model.gaussian_init import gaussians_from_points
from training.reconstruct.densify import DensifyConfig
from training.reconstruct.trainer import ReconstructConfig, Reconstructor
from training.scene.scene import Scene
from training.stylize.style_distance import style_distance
from training.stylize.trainer import StylizeConfig, Stylizer


@pytest.fixture(scope="module")
def scene():
    d = make_demo_scene(num_views=16, width=64, height=48, num_points=1000)
    return Scene(d.cameras, d.images, points=d.points, point_colors=d.point_colors)


def recon_config(**overrides) -> ReconstructConfig:
    # densification every 20 steps from step 40, an opacity reset at 150: several structure changes in 300 steps
    dens = DensifyConfig(start=40, stop=250, interval=20, reset_every=150, grad_threshold=0.0001)
    return ReconstructConfig(**{"iterations": 300, "sh_interval": 100, "device": "cpu", "densify": dens,
                                **overrides})


def check_snapshot(snap) -> None:
    n = len(snap)
    k = (snap.sh_degree + 1) ** 2
    assert snap.means.shape == (n, 3) and snap.scales.shape == (n, 3) and snap.quats.shape == (n, 4)
    assert snap.opacities.shape == (n,) and snap.sh.shape == (n, k, 3)
    for a in (snap.means, snap.scales, snap.quats, snap.opacities, snap.sh):
        assert a.dtype == np.float32 and not a.flags.writeable
        assert np.isfinite(a).all()
    assert np.allclose(np.linalg.norm(snap.quats, axis=1), 1.0, atol=1e-5)
    assert ((snap.opacities > 0) & (snap.opacities < 1)).all() and (snap.scales > 0).all()


@pytest.mark.slow
def test_snapshots_are_never_torn_while_training_densifies_and_config_changes(scene):
    trainer = Reconstructor(scene, recon_config())
    seen: list = []
    errors: list[BaseException] = []
    stop = threading.Event()
    config_changed = threading.Event()
    structure_steps: list[int] = []
    trainer.add_listener(lambda e: structure_steps.append(e.step) if isinstance(e, StructureChanged) else None)

    def reader() -> None:
        try:
            changed = False
            while not stop.is_set():
                snap = trainer.snapshot()
                check_snapshot(snap)
                if seen and snap.version == seen[-1].version:
                    assert snap is seen[-1]  # same version: the same arrays, not another copy
                else:
                    seen.append(snap)
                if not changed and snap.step >= 100:
                    trainer.update_config(use_shape=False, use_size=False)  # live, from this thread
                    changed = True
                    config_changed.set()
        except BaseException as exc:  # noqa: BLE001  (reported by the main thread)
            errors.append(exc)

    thread = threading.Thread(target=reader)
    thread.start()
    try:
        steps_after_change = 0
        while not trainer.done:
            applies = config_changed.is_set()  # changed before this step started: this step must use it
            result = trainer.step()
            if applies and not result["recovered"]:
                assert result["shape"] == 0.0 and result["size"] == 0.0  # the live change reached the loss
                steps_after_change += 1
    finally:
        stop.set()
        thread.join()
    assert not errors, errors[0]
    assert trainer.step_count == 300
    assert trainer.config.use_shape is False and trainer.config.use_size is False and steps_after_change > 100
    assert structure_steps, "densification never changed the model: the test would not exercise swaps"
    versions = [s.version for s in seen]
    assert versions == sorted(versions) and len(set(versions)) == len(versions)
    counts = {len(s) for s in seen}
    assert len(counts) > 1, "every snapshot had the same size: densification was not seen from the reader"
    final = trainer.snapshot()
    assert np.array_equal(final.means, trainer.gaussians.means.detach().numpy())
    assert len(final) == len(trainer.gaussians)


def test_reconstruct_update_config_is_validated_and_fixed_settings_are_refused(scene):
    trainer = Reconstructor(scene, recon_config(iterations=5))
    with pytest.raises(ValueError, match="lambda_shape must be at least 0"):
        trainer.update_config(lambda_shape=-1.0)
    with pytest.raises(ValueError, match="background can only be set before the reconstruction starts"):
        trainer.update_config(background="white")
    with pytest.raises(ValueError, match="has no setting tau"):
        trainer.update_config(tau=0.1)
    trainer.update_config(background="black", lr_opacity=0.01)  # an unchanged fixed setting is not a change
    assert trainer.config.lr_opacity == 0.05  # not yet: at the start of the next step
    trainer.step()
    assert trainer.config.lr_opacity == 0.01
    lrs = {g["name"]: g["lr"] for g in trainer.optimizer.param_groups}
    assert lrs["opacity_logits"] == 0.01


def test_reconstruct_config_is_validated_at_construction(scene):
    with pytest.raises(ValueError, match="iterations must be at least 1"):
        Reconstructor(scene, recon_config(iterations=0))
    with pytest.raises(ValueError, match="unknown depth 'lidar'"):
        Reconstructor(scene, recon_config(depth="lidar"))


def test_reconstruct_events_drive_a_progress_count(scene):
    trainer = Reconstructor(scene, recon_config(iterations=6))
    events: list[TrainerEvent] = []
    trainer.add_listener(events.append)
    while not trainer.done:
        trainer.step()
    steps = [e for e in events if isinstance(e, Stepped)]
    assert [e.step for e in steps] == [1, 2, 3, 4, 5, 6]
    assert all(e.stage == "reconstruct" and e.metrics["total_iters"] == 6 for e in steps)
    assert all(np.isfinite(e.metrics["loss"]) and "times/rasterize" in e.metrics for e in steps)
    assert isinstance(events[-1], Finished) and events[-1].step == 6


# ------------------------------------------------------------------------------------------------ stylizer
@pytest.fixture(scope="module")
def tiny():
    demo = make_demo_scene(num_views=4, width=64, height=48, num_points=1500, supersample=1)
    scene = Scene(cameras=demo.cameras, images=demo.images, points=demo.points, point_colors=demo.point_colors)
    g = gaussians_from_points(demo.points, demo.point_colors, sh_degree=1)
    g.opacity_logits = torch.full_like(g.opacity_logits, 2.0)
    return scene, g


def stylizer(tiny, vgg, **overrides) -> Stylizer:
    from assets.demo.painting import make_style_image

    scene, g = tiny
    cfg = StylizeConfig(**{"preset": "quick", "max_side": 64, "device": "cpu", "iters_per_view": 2, **overrides})
    return Stylizer(g, scene, np.asarray(make_style_image(size=128, seed=1), dtype=np.float32), cfg, vgg=vgg)


def test_stylize_update_config_reaches_the_next_plan(tiny, vgg, monkeypatch):
    s = stylizer(tiny, vgg)
    s.step()
    used: list[float] = []
    import training.stylize.ccft as ccft

    real = ccft.semi_balanced_sinkhorn  # (cost, indices, reachable, tau, ...): the plan's tau, and its k columns
    monkeypatch.setattr(ccft, "semi_balanced_sinkhorn",
                        lambda *a, **kw: (used.append((a[3], a[1].shape[1])), real(*a, **kw))[1])
    done = threading.Event()
    threading.Thread(target=lambda: (s.update_config(tau=0.01, k=4), done.set())).start()
    assert done.wait(10)
    s.step()
    assert used == [(0.01, 4)] and s.config.tau == 0.01


def test_stylize_fixed_settings_are_refused_with_a_reason(tiny, vgg):
    s = stylizer(tiny, vgg)
    for name, value in (("view_order", "random"), ("virtual_views", 2), ("preset", "paper"), ("device", "cuda"),
                        ("color_transfer", False), ("scene_kind", "forward"), ("background", (1.0, 1.0, 1.0))):
        with pytest.raises(ValueError, match=f"{name} can only be set before the stylization starts"):
            s.update_config(**{name: value})
    with pytest.raises(ValueError, match="epsilon must be positive"):
        s.update_config(epsilon=0.0)
    assert s.config.epsilon > 0 and s._pending_config is None  # a refused change leaves nothing pending


def test_stylize_snapshot_copies_only_colours_and_tracks_versions(tiny, vgg):
    s = stylizer(tiny, vgg)
    first = s.snapshot()
    check_snapshot(first)
    assert s.snapshot() is first
    s.step()
    second = s.snapshot()
    assert second.version > first.version and second.geometry_version == first.geometry_version
    assert second.means is first.means and second.opacities is first.opacities  # geometry not copied again
    assert not np.array_equal(second.sh, first.sh)
    assert np.array_equal(second.sh, s.gaussians.sh.detach().numpy())


def test_stylize_status_is_published_whole_after_each_step_and_each_deletion(tiny, vgg):
    """What the viewer's panels read (through the session): the status the stylizer built after its last step,
    a new object each time, never one being written; a listener of the step event already sees that step's."""
    s = stylizer(tiny, vgg)
    first = s.status()
    assert first.stage == "stylize" and first.step == 0 and first.capacity is None and first.losses == {}
    seen = []
    s.add_listener(lambda e: seen.append((e.step, s.status().step)) if isinstance(e, Stepped) else None)
    for _ in range(3):
        s.step()
    st = s.status()
    assert st is not first and seen == [(1, 1), (2, 2), (3, 3)]
    assert st.trajectory_position == s.trajectory_position and st.pass_progress == s.pass_progress()
    assert [stop.source_index for stop in st.trajectory] == [item.source_index for item in s.trajectory]
    assert st.capacity is not None and st.capacity.ndim == 2 and st.num_gaussians == len(s.gaussians)
    assert st.losses["loss"] == s.last_stats["loss"]
    # the balance is measured every balance_every steps (the first, of these three): the status keeps the last one
    assert s.last_stats["content_to_style"] is None and st.gradient_balance is not None
    assert st.gradient_balance == s.history[0]["grad_content"] / s.history[0]["grad_style"]
    assert st.utilisation == s.utilisation() and st.colour_only
    keep = np.arange(len(s.gaussians)) % 2 == 0
    s.keep(keep)
    after = s.status()
    assert after.num_gaussians == int(keep.sum()) and after.structure_version == s.structure_version
    assert after.structure_version != st.structure_version


def test_stylize_events_and_cancelled_finish(tiny, vgg):
    s = stylizer(tiny, vgg)
    events: list[TrainerEvent] = []
    s.add_listener(events.append)
    s.run()
    assert sum(isinstance(e, Stepped) for e in events) == s.total_iters and isinstance(events[-1], Finished)
    views = [e.trajectory_position for e in events if isinstance(e, ViewMoved)]
    assert views[:3] == [1.0, 2.0, 3.0]
    before = s.gaussians.sh.detach().clone()
    calls = []
    with pytest.raises(Cancelled):
        s.finish(cancel=lambda: calls.append(1) or len(calls) > 2)  # cancelled after two views
    assert torch.equal(s.gaussians.sh, before) and not s.finished
    with pytest.raises(Cancelled):
        style_distance(s, cancel=lambda: True)


def test_stylize_keep_removes_gaussians_between_steps(tiny, vgg):
    s = stylizer(tiny, vgg)
    s.step()
    before = s.snapshot()
    n = len(before)
    keep = np.ones(n, dtype=bool)
    keep[::3] = False  # a deletion from another thread, as the viewer's Edit panel makes it
    events: list[TrainerEvent] = []
    s.add_listener(events.append)
    done = threading.Event()
    threading.Thread(target=lambda: (s.keep(keep), done.set())).start()
    assert done.wait(10)
    after = s.snapshot()
    assert len(after) == keep.sum() and after.geometry_version > before.geometry_version
    assert np.array_equal(after.means, before.means[keep]) and np.array_equal(after.sh, before.sh[keep])
    assert any(isinstance(e, StructureChanged) and e.num_gaussians == keep.sum() for e in events)
    s.step()  # the next step trains the smaller model
    assert s.snapshot().sh.shape[0] == keep.sum()
    with pytest.raises(ValueError, match="every Gaussian"):
        s.keep(np.zeros(len(after), dtype=bool))


def test_reconstruct_keep_removes_gaussians_with_their_optimizer_state(scene):
    trainer = Reconstructor(scene, recon_config(iterations=20))
    for _ in range(3):
        trainer.step()
    before = trainer.snapshot()
    n = len(before)
    keep = np.ones(n, dtype=bool)
    keep[1::4] = False
    trainer.keep(keep)
    after = trainer.snapshot()
    assert len(after) == keep.sum() and after.geometry_version > before.geometry_version
    assert np.array_equal(after.means, before.means[keep])
    state = trainer.optimizer.state[trainer.gaussians.means]
    assert state["exp_avg"].shape[0] == keep.sum()  # the moments went with their Gaussians
    assert trainer.strategy.grad_accum.shape[0] == keep.sum()
    result = trainer.step()  # trains on, densification statistics and all
    assert result["num_gaussians"] == keep.sum() and not result["recovered"]
