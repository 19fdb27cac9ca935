"""The reconstruction trainer: 3DGS with the paper's depth, shape and size regularizers, one step at a time.

``Reconstructor(scene, config)`` (the settings: training/reconstruct/config.py) owns a Gaussian model, its Adam
optimizer and a density-control strategy; ``step()`` runs one iteration on a random training view and returns its
metrics. Live settings (the viewer's, through its session) come by ``update_config(**changes)``, from any thread:
validated at once, applied at the start of the next step, refusing the settings only construction may set
(``FIXED_AT_START``). ``snapshot()`` gives a viewer a consistent copy of the model and ``status()`` where the run is
(training/core/status.py), both from any thread; ``add_listener`` delivers the trainer's events
(training/core/messages.py).

Recipe (3DGS 2023 plus the paper):
- Adam (eps 1e-15) with per-parameter learning rates; the means' rate is scaled by the scene extent and decays
  log-linearly from 1.6e-4 to 1.6e-6 over ``iterations``; sh0 2.5e-3, shN 2.5e-3 / 20, opacity 0.05,
  log-scales 5e-3, quaternions 1e-3;
- the active SH degree starts at 0 and rises by one every ``sh_interval`` steps up to ``sh_degree``;
- L = 0.8 L1 + 0.2 (1 - SSIM) + lambda_depth L_depth + lambda_shape L_shape + lambda_size L_size
  (see training/reconstruct/regularizers.py for the units), lambda_depth decaying from 1 to 0.01 over ``iterations``;
- views are visited in shuffled epochs (every training view once per epoch, as 3DGS's viewpoint stack);
- density control by training/reconstruct/densify.py after the optimizer step.

Safety: a step whose loss, gradients-turned-parameters or inputs are not finite is undone: the model, optimizer and
density statistics return to the last good snapshot (taken every ``snapshot_every`` steps), a warning is issued,
and training continues with the next step.
"""

from __future__ import annotations

import copy
import math
import time
import warnings

import torch

from training.core.live_trainer import LiveTrainer
from training.core.messages import Finished, Stepped, StructureChanged, Warned
from training.core.status import ReconstructStatus, scalars

from training.reconstruct.config import FIXED_AT_START, ReconstructConfig
from training.reconstruct.densify import PARAM_NAMES, DensifyStrategy
from training.model.gaussians import Gaussians
from training.reconstruct.metrics import evaluate_views, psnr, render_view
from training.raster.rasterize import resolve_device
from training.reconstruct.regularizers import depth_loss, depth_weight, shape_loss, size_loss
from training.scene.scene import Scene, over_background
from training.reconstruct.ssim import ssim

MAX_CONSECUTIVE_RECOVERIES = 20
LOSSES = ("loss", "l1", "ssim", "psnr", "depth", "shape", "size")  # a step's figures its status carries


# One pass over each parameter instead of Adam's eight (same update; at 60k Gaussians 14 -> 2 ms of CPU a step).
FUSED_ADAM = True


def all_finite(tensors) -> bool:
    """Whether every element of every tensor is finite. A NaN or an infinity makes a sum non-finite, so a finite
    sum answers in one reduction (no mask allocated); a non-finite one (or an overflowing sum) asks element by
    element. At 60k Gaussians: about 0.6 ms for the model, against 13 ms for isfinite().all()."""
    return all(bool(torch.isfinite(t.sum())) or bool(torch.isfinite(t).all()) for t in tensors)


def _load_optimizer(optimizer: torch.optim.Adam, state: dict) -> None:
    """load_state_dict, keeping this optimizer's implementation: a checkpoint's param groups carry the flags of the
    Adam that saved them (unfused before the fused one), which would otherwise replace ours."""
    optimizer.load_state_dict(state)
    for group in optimizer.param_groups:
        group["fused"], group["foreach"] = FUSED_ADAM, None


# The phases of a step, in order (see Reconstructor.step).
PHASES = ("checks", "rasterize", "loss", "ssim", "depth", "shape", "size", "backward", "optimizer", "densify")


class _Clock:
    """Adds the time since the last lap to ``times[name]``."""

    def __init__(self, times: dict):
        self.times, self.t = times, time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.times[name] += now - self.t
        self.t = now


def means_lr(cfg: ReconstructConfig, step: int, extent: float) -> float:
    """3DGS's exponential position learning rate at ``step`` (1-based), scaled by the scene extent."""
    t = min(max(step / max(cfg.iterations, 1), 0.0), 1.0)
    lr = math.exp((1 - t) * math.log(cfg.lr_means_init) + t * math.log(cfg.lr_means_final))
    return lr * extent



def initial_gaussians(scene: Scene, cfg: ReconstructConfig) -> tuple[Gaussians, str]:
    """SfM points when the scene has them, else random Gaussians in the view volume; and which it was."""
    from training.model.gaussian_init import gaussians_from_points, gaussians_random

    if scene.num_points > 0:
        return gaussians_from_points(scene.points, scene.point_colors, cfg.sh_degree, scene.source), "sfm"
    return gaussians_random(scene, cfg.random_init_points, cfg.sh_degree, seed=cfg.seed), "random"


class Reconstructor(LiveTrainer):
    """3DGS trainer. ``gaussians`` is the live model (leaf tensors that require grad); ``step()`` advances it."""

    FIXED_AT_START = FIXED_AT_START

    def __init__(self, scene: Scene, config: ReconstructConfig, gaussians: Gaussians | None = None):
        from training.reconstruct.depth_targets import compute_depth_targets

        if not scene.images:
            raise ValueError("Reconstructor needs a scene with its images loaded")
        if not scene.train_indices:
            raise ValueError("the scene has no training views")
        config.validate()
        self.scene = scene
        self.config = config
        self.extent = float(scene.extent)
        if gaussians is None:
            gaussians, self.init_source = initial_gaussians(scene, config)
        else:
            self.init_source = "given"
        self.gaussians = gaussians.detached().to(resolve_device(config.device, config.backend))
        for t in self.gaussians.parameters().values():
            t.requires_grad_(True)
        self.device = self.gaussians.device
        self.images = [torch.as_tensor(im, device=self.device) for im in scene.images]
        self.masks = [None if m is None else torch.as_tensor(m, device=self.device) for m in scene.masks]
        targets, self.depth_mode = compute_depth_targets(scene, config.depth, config.mono_depth_model)
        self.depth_targets: list[tuple[torch.Tensor, torch.Tensor] | None] | None = None
        if targets is not None:
            self.depth_targets = [
                None if t is None else (torch.as_tensor(t.depth / self.extent, device=self.device),
                                        torch.as_tensor(t.valid, device=self.device))
                for t in targets
            ]
        self.optimizer = self._make_optimizer()
        self.strategy = DensifyStrategy(self.extent, len(self.gaussians), self.device)
        self.generator = torch.Generator(device="cpu").manual_seed(int(config.seed))
        self.step_count = 0
        self.active_sh_degree = 0
        self._order: list[int] = []
        self.recoveries = 0
        self._consecutive_recoveries = 0
        self.last_timings: dict[str, float] = {}
        # Threads: step() runs on one; snapshot() and update_config() may come from another. The lock covers every
        # write to the model's tensors (optimizer step, densification, restore), so a snapshot is never torn.
        self._init_live("reconstruction", "reconstruct")
        self._snapshot = self._take_snapshot()
        self._last_losses: dict[str, float] = {}
        self._publish_status()

    @property
    def total_iters(self) -> int:
        return int(self.config.iterations)

    @property
    def done(self) -> bool:
        return self.step_count >= self.total_iters

    # ------------------------------------------------------------------------------- the viewer's copy, edits
    def _snapshot_step(self) -> int:
        return self.step_count

    def _snapshot_geometry(self):
        g = self.gaussians
        return g.means, g.scales, g.rotations, g.opacities

    def _snapshot_colours(self):
        return self.gaussians.sh, self.gaussians.sh_degree

    def _build_status(self) -> ReconstructStatus:
        return ReconstructStatus("reconstruct", self.step_count, self.total_iters, str(self.device),
                                 len(self.gaussians), self._structure_version, self.config, editable=True,
                                 losses=self._last_losses)

    def _model_changed(self) -> None:
        """Call with the lock held after any write to the model: every step moves the geometry too."""
        self._version += 1
        self._geometry_version += 1

    def whole_model(self) -> Gaussians:
        return self.export_gaussians()

    def keep(self, keep) -> None:
        """Keep only the Gaussians where ``keep`` (N,) bool (a deletion or crop in the viewer); any thread, effective
        from the next step. Their Adam moments and density statistics go with them, as a prune's do."""
        import numpy as np

        from training.reconstruct.densify import keep_gaussians

        keep_t = torch.as_tensor(np.array(keep, dtype=bool))
        if keep_t.shape != (len(self.gaussians),):
            raise ValueError(f"keep must have {len(self.gaussians)} entries, got {tuple(keep_t.shape)}")
        if not bool(keep_t.any()):
            raise ValueError("that would remove every Gaussian")
        keep_t = keep_t.to(self.device)
        with self._model_lock:
            keep_gaussians(self.gaussians, self.optimizer, keep_t)
            st = self.strategy
            st.grad_accum, st.count, st.max_radii = st.grad_accum[keep_t], st.count[keep_t], st.max_radii[keep_t]
            self._model_changed()
            self._structure_changed()
            self._snapshot = self._take_snapshot()  # a NaN restore must not bring the removed ones back
        self._publish_status()
        self.events.emit(StructureChanged, self.step_count, num_gaussians=len(self.gaussians))

    def load_parameters(self, params: dict) -> None:
        """Make copies of ``params`` (a ``Gaussians.parameters()`` dict, e.g. an earlier step's) the model; Adam's
        moments and the density statistics start afresh. Any thread; effective from the next step."""
        gaussians = Gaussians(**{k: v.detach().clone().to(self.device) for k, v in params.items()},
                              sh_degree=self.gaussians.sh_degree)
        for t in gaussians.parameters().values():
            t.requires_grad_(True)
        with self._model_lock:
            self.gaussians = gaussians
            self.optimizer = self._make_optimizer()
            self.strategy = DensifyStrategy(self.extent, len(gaussians), self.device)
            self._model_changed()
            self._structure_changed()
            self._snapshot = self._take_snapshot()
        self._publish_status()
        self.events.emit(StructureChanged, self.step_count, num_gaussians=len(self.gaussians))

    # ----------------------------------------------------------------------------------------------- set-up
    def _make_optimizer(self) -> torch.optim.Adam:
        cfg = self.config
        lrs = {"means": means_lr(cfg, 0, self.extent), "log_scales": cfg.lr_scales, "quats": cfg.lr_quats,
               "opacity_logits": cfg.lr_opacity, "sh0": cfg.lr_sh0, "shN": cfg.lr_shN}
        params = self.gaussians.parameters()
        groups = [{"params": [params[n]], "lr": lrs[n], "name": n} for n in PARAM_NAMES]
        return torch.optim.Adam(groups, lr=0.0, eps=1e-15, fused=FUSED_ADAM)

    def _set_learning_rates(self, step: int) -> None:
        cfg = self.config
        lrs = {"means": means_lr(cfg, step, self.extent), "log_scales": cfg.lr_scales, "quats": cfg.lr_quats,
               "opacity_logits": cfg.lr_opacity, "sh0": cfg.lr_sh0, "shN": cfg.lr_shN}
        for g in self.optimizer.param_groups:
            g["lr"] = lrs[g["name"]]

    def _next_view(self) -> int:
        if not self._order:
            train = self.scene.train_indices
            perm = torch.randperm(len(train), generator=self.generator).tolist()
            self._order = [train[i] for i in perm]
        return self._order.pop()

    def _background(self) -> torch.Tensor | None:
        bg = self.config.background
        if bg == "white":
            return torch.ones(3, device=self.device)
        if bg == "random":
            return torch.rand(3, generator=self.generator).to(self.device)
        return None

    def eval_background(self) -> torch.Tensor | None:
        return torch.ones(3, device=self.device) if self.config.background == "white" else None

    # ---------------------------------------------------------------------------------------------- training
    def _params_finite(self) -> bool:
        return all_finite(self.gaussians.parameters().values())

    def step(self) -> dict:
        """One training iteration. Returns {"step", "loss", "l1", "ssim", "psnr", "depth", "shape", "size",
        "lambda_depth", "num_gaussians", "sh_degree", "view", "cloned", "split", "pruned", "reset",
        "recovered", "times", "raster_times"}. "times" (seconds) splits the step into disjoint phases that sum to
        it: rasterize (the forward render), loss (L1 and the sum), ssim, depth, shape, size (each term's forward),
        backward (all of it: the loss terms' and the rasterizer's), optimizer (Adam), checks (the two finiteness
        checks of the parameters), densify (statistics and density control). "raster_times": the cpu
        rasterizer's own stages (training/raster/cpu.py), the backward's among them (empty on other backends)."""
        self._take_pending_config()
        cfg = self.config
        self.step_count += 1
        i = self.step_count
        times = dict.fromkeys(PHASES, 0.0)
        self._set_learning_rates(i)
        self.active_sh_degree = min(cfg.sh_degree, self.gaussians.sh_degree, i // max(cfg.sh_interval, 1))
        view = self._next_view()
        cam = self.scene.cameras[view]
        background = self._background()
        target = over_background(self.images[view], self.masks[view], background)
        lam_depth = depth_weight(i, cfg.iterations, cfg.lambda_depth_start, cfg.lambda_depth_end)
        depth_t = None
        if cfg.use_depth and self.depth_targets is not None and lam_depth > 0:
            depth_t = self.depth_targets[view]

        clock = _Clock(times)
        if not self._params_finite():
            return self._recover(i, view, "the model's parameters are not finite", times)
        clock.lap("checks")

        image, alpha, info = render_view(self.gaussians, cam, sh_degree=self.active_sh_degree,
                                         background=background, backend=cfg.backend,
                                         render_mode="RGB+ED" if depth_t is not None else "RGB")
        clock.lap("rasterize")
        rgb = image[..., :3]
        l1 = (rgb - target).abs().mean()
        clock.lap("loss")
        ssim_val = ssim(rgb, target)
        clock.lap("ssim")
        loss = (1.0 - cfg.lambda_dssim) * l1 + cfg.lambda_dssim * (1.0 - ssim_val)
        terms = {"depth": 0.0, "shape": 0.0, "size": 0.0}
        if depth_t is not None:
            # expected depth is ill-defined where the render is mostly transparent: supervise only covered pixels
            valid = depth_t[1] & (alpha[..., 0].detach() > 0.5)
            ld = depth_loss(image[..., 3] / self.extent, depth_t[0], valid)
            loss = loss + lam_depth * ld
            terms["depth"] = float(ld.detach())
            clock.lap("depth")
        if cfg.use_shape or cfg.use_size:
            s_norm = self.gaussians.scales / self.extent
            if cfg.use_shape:
                ls = shape_loss(s_norm, cfg.lambda_s)
                loss = loss + cfg.lambda_shape * ls
                terms["shape"] = float(ls.detach())
                clock.lap("shape")
            if cfg.use_size:
                lz = size_loss(s_norm, cfg.beta1, cfg.beta2)
                loss = loss + cfg.lambda_size * lz
                terms["size"] = float(lz.detach())
                clock.lap("size")
        if not bool(torch.isfinite(loss)):
            return self._recover(i, view, "the loss is not finite", times)
        clock.lap("loss")
        loss.backward()
        clock.lap("backward")
        with self._model_lock:
            self.optimizer.step()
            self.optimizer.zero_grad(set_to_none=True)
            clock.lap("optimizer")
            if not self._params_finite():
                # restore while still holding the lock: no snapshot may see the non-finite update
                return self._recover(i, view, "the update made parameters non-finite", times, locked=True)
            clock.lap("checks")
            n_before = len(self.gaussians)
            counts = self.strategy.step_post_backward(cfg.densify, i, self.gaussians, self.optimizer, info,
                                                      cam.width, cam.height, self.generator)
            self._model_changed()
            # under the lock with the change itself: a snapshot taken in between would pair the new Gaussians
            # with the old structure version, and every edit made on it would be refused until the next step
            restructured = len(self.gaussians) != n_before or any(counts.get(k) for k in ("cloned", "split", "pruned"))
            if restructured:
                self._structure_changed()
        clock.lap("densify")
        self.last_timings = times
        self._consecutive_recoveries = 0
        if cfg.snapshot_every > 0 and i % cfg.snapshot_every == 0:
            self._snapshot = self._take_snapshot()
        result = {"step": i, "loss": float(loss.detach()), "l1": float(l1.detach()),
                "ssim": float(ssim_val.detach()),
                "psnr": psnr(rgb.clamp(0, 1), target), "lambda_depth": lam_depth if depth_t is not None else 0.0,
                **terms, "num_gaussians": len(self.gaussians), "sh_degree": self.active_sh_degree, "view": view,
                **counts, "recovered": False, "times": times, "raster_times": dict(info.get("timings", {}))}
        self._last_losses = scalars(result, LOSSES)
        self._publish_status()
        self.events.emit(Stepped, i, metrics={**result, "total_iters": self.total_iters})
        if restructured:
            self.events.emit(StructureChanged, i, num_gaussians=len(self.gaussians), counts=counts)
        if i == self.total_iters:
            self.events.emit(Finished, i)
        return result

    # ------------------------------------------------------------------------------------------ NaN recovery
    def _take_snapshot(self) -> dict:
        return {
            "params": {k: v.detach().clone() for k, v in self.gaussians.parameters().items()},
            "optimizer": copy.deepcopy(self.optimizer.state_dict()),
            "strategy": self.strategy.state_dict(),
            "step": self.step_count,
        }

    def _restore(self, snap: dict) -> None:
        """Call with the model lock held."""
        for name, t in snap["params"].items():
            setattr(self.gaussians, name, t.clone().requires_grad_(True))
        self.optimizer = self._make_optimizer()
        _load_optimizer(self.optimizer, copy.deepcopy(snap["optimizer"]))
        self.strategy.load_state_dict(snap["strategy"])
        self._model_changed()

    def _recover(self, step: int, view: int, why: str, times: dict, locked: bool = False) -> dict:
        self.optimizer.zero_grad(set_to_none=True)
        self._consecutive_recoveries += 1
        self.recoveries += 1
        if self._consecutive_recoveries > MAX_CONSECUTIVE_RECOVERIES:
            raise RuntimeError(f"training diverged: {MAX_CONSECUTIVE_RECOVERIES} steps in a row were not finite "
                               f"(last: {why}); lower the learning rates or check the input")
        message = f"step {step}: {why}; restored the model from step {self._snapshot['step']} and continuing"
        warnings.warn(message, RuntimeWarning, stacklevel=3)
        if locked:
            self._restore(self._snapshot)
            self._structure_changed()
        else:
            with self._model_lock:
                self._restore(self._snapshot)
                self._structure_changed()
        self.last_timings = times
        result = {"step": step, "loss": float("nan"), "psnr": float("nan"), "num_gaussians": len(self.gaussians),
                  "sh_degree": self.active_sh_degree, "view": view, "recovered": True, "times": times}
        self._publish_status(locked=locked)
        self.events.emit(Warned, step, message=message)
        self.events.emit(StructureChanged, step, num_gaussians=len(self.gaussians))
        self.events.emit(Stepped, step, metrics={**result, "total_iters": self.total_iters})
        return result

    # ------------------------------------------------------------------------------------------- evaluation
    def evaluate(self, indices) -> dict:
        """{"psnr", "ssim", "views"} of the current model on the scene's views at ``indices``."""
        return evaluate_views(self.gaussians, self.scene, list(indices), sh_degree=self.active_sh_degree,
                              background=self.eval_background(), backend=self.config.backend)

    def export_gaussians(self) -> Gaussians:
        """A detached copy of the model, ready for write_ply (the full SH degree it holds)."""
        return self.gaussians.detached()

    # ------------------------------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        return {
            "step": self.step_count,
            "params": {k: v.detach().clone() for k, v in self.gaussians.parameters().items()},
            "sh_degree": self.gaussians.sh_degree,
            "active_sh_degree": self.active_sh_degree,
            "optimizer": self.optimizer.state_dict(),
            "strategy": self.strategy.state_dict(),
            "rng": self.generator.get_state(),
            "order": list(self._order),
            "config": self.config.to_dict(),
            "init_source": self.init_source,
            "recoveries": self.recoveries,
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore a state_dict() (the config is left as this trainer's; build it from state["config"])."""
        params = {k: v.to(self.device) for k, v in state["params"].items()}
        gaussians = Gaussians(**params, sh_degree=int(state["sh_degree"]))
        for t in gaussians.parameters().values():
            t.requires_grad_(True)
        with self._model_lock:
            self.gaussians = gaussians
            self.optimizer = self._make_optimizer()
            self._model_changed()
        _load_optimizer(self.optimizer, state["optimizer"])
        self.strategy.load_state_dict(state["strategy"])
        self.generator.set_state(state["rng"])
        self._order = list(state["order"])
        self.step_count = int(state["step"])
        self.active_sh_degree = int(state["active_sh_degree"])
        self.init_source = state.get("init_source", self.init_source)
        self.recoveries = int(state.get("recoveries", 0))
        self._snapshot = self._take_snapshot()
        self._publish_status()
