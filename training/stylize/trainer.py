"""Scene stylization after a painting: the paper's capacity-controlled stylization, one iteration per ``step()``.

An iteration (step.py) renders the view the schedule picks (view_schedule.py), compares VGG-16 features of the
render with the content's and the painting's (feature_cache.py, objective.py; the style loss reads the live config at
each call) and takes an Adam step (optimizer.py) on the SH colours (``params="colour"``, the paper's method: the
geometry stays bit-identical), or on the geometry too (``params="all"``, the paper's ablation). ARF's colour transfer
goes before the first step and after the last (``finish()``), honouring a selection (region.py). The model and its
renders are stylized_model.py's; a checkpoint's state is checkpoint.py's; the report's style distance is
style_distance.py's.

The config may change between steps (the viewer's sliders, through its session): ``update_config(**changes)`` from
any thread is validated at once and applied at the start of the next step; the settings that shape the run
(``FIXED_AT_START``) are refused. ``snapshot()`` (the model) and ``status()`` (status.py) serve a viewer from any
thread; ``add_listener`` delivers the trainer's events (training/core/messages.py).
"""

from __future__ import annotations

import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from training.core.errors import InputError
from training.core.live_trainer import LiveTrainer
from training.core import stop
from training.core.messages import Finished, Stepped, StructureChanged, ViewMoved, check_cancel
from training.model.gaussians import Gaussians
from training.raster.rasterize import resolve_device
from training.scene.scene import Camera, Scene, over_background
from training.stylize.color_transfer import ColorTransform, apply_to_render, colour_stats
from training.stylize.config import (DEFAULT_LAMBDA_STYLE, DEFAULT_LR, FIXED_AT_START,  # noqa: F401  (re-exported)
                                     StylizeConfig, iteration_schedule, paper_schedule, render_camera)
from training.stylize.feature_cache import FeatureCache, vgg_in_bfloat16
from training.stylize.optimizer import (colour_learning_rate, geometry_learning_rates, make_optimizer,
                                        set_colour_learning_rate)
from training.stylize.plan_readouts import StepAgreement
from training.stylize.region import (as_mask, coverage_from_render, indicator_sh, masked_step, post_color_transfer,
                                     pre_color_transfer, transfer_to_selection)
from training.stylize.scene_match import check_model_matches_scene, check_renders_not_empty
from training.stylize.style_image import check_style_array
from training.stylize.status import UTILISATION, stylize_status
from training.stylize.structure_budget import StructureBudget, structure_drift
from training.stylize.terms import LOSS_KEYS
from training.stylize.step import StageTimes, StepTimer, gradient_step
from training.stylize.stylized_model import StylizedModel
from training.stylize.view_schedule import ViewSchedule


class Stylizer(LiveTrainer):
    """Stylize ``gaussians`` (a reconstruction of ``scene``) after ``style_image``, one ``step()`` at a time.

    ``style_image``: float32 (H, W, 3) in [0, 1] (see ``training.stylize.style_image.load_style_image``).
    ``vgg``: a ``VGGFeatures`` to share; loaded (with ``config``'s weights source) when None.
    The caller's Gaussians are not modified: ``self.gaussians`` is a new model sharing the geometry tensors
    (detached) with new colour tensors; under ``config.params == "all"`` the optimiser gets copies of the geometry.
    ``mask``: (N,) bool, the Gaussians to stylize (None: all); the others' colours (and geometry, under "all") stay
    bit-identical through the steps and both colour transfers (training/stylize/region.py); ``set_mask`` changes it
    between steps.
    """

    FIXED_AT_START = FIXED_AT_START

    def __init__(self, gaussians: Gaussians, scene: Scene, style_image: np.ndarray, config: StylizeConfig | None = None,
                 vgg: torch.nn.Module | None = None, vgg_weights: str | None = None,
                 model_name: str | Path | None = None, check_match: bool = True, mask=None):
        self.config = config or StylizeConfig()
        self.config.validate()
        self.device = resolve_device(self.config.device, self.config.backend)
        self.times = StageTimes()
        t0 = time.perf_counter()
        if not scene.cameras:
            raise InputError(scene.source, "the scene has no cameras")
        if len(scene.images) != len(scene.cameras):
            raise InputError(scene.source, "the scene's images are not loaded (load_scene(..., load_images=True))")
        self.scene, self.style_image, self.model_name = scene, check_style_array(style_image), model_name
        if vgg is None:
            from training.stylize.vgg_features import load_vgg16_features

            vgg = load_vgg16_features(vgg_weights)
            stop.check()
        self.vgg = vgg.to(self.device)
        self.feature_cache = FeatureCache(self.vgg, self.style_image, self.device,
                                          vgg_in_bfloat16(self.config.vgg_precision, self.device))

        mask = as_mask(mask, len(gaussians), model_name)
        if mask is not None and not bool(mask.any()):
            raise InputError(model_name, "the selection mask selects no Gaussians: nothing to stylize")
        trains_geometry = self.config.params == "all"
        self.model = StylizedModel(gaussians, self.device, trains_geometry, mask)
        self._geometry_lrs = geometry_learning_rates(scene.extent) if trains_geometry else None

        self.cameras = [render_camera(c, self.config.render_max_side) for c in scene.cameras]
        if check_match:
            check_model_matches_scene(self.model.gaussians, self.cameras, model_name)
        self.views = ViewSchedule.for_scene(scene.cameras, self.cameras, self.config, scene.extent)
        self.kind, self.order, self.trajectory = self.views.kind, self.views.order, self.views.trajectory
        bg = np.asarray(self.config.background, dtype=np.float32)  # RGBA photos over the renders' background
        self.content_images = [_resize(over_background(img, m, bg), cam)
                               for img, m, cam in zip(scene.images, scene.masks, self.cameras)]
        self.times.add("load", time.perf_counter() - t0)

        t0 = time.perf_counter()
        if check_match:
            check_renders_not_empty(self.render, self.cameras, model_name)
            stop.check()
        self.pre_transform: ColorTransform | None = None
        self.post_transform: ColorTransform | None = None
        if self.config.color_transfer:
            cover = None if mask is None else self._coverage()
            self.pre_transform, self.content_images = pre_color_transfer(self.content_images, self.style_image, cover)
            self.model.gaussians = transfer_to_selection(self.model.gaussians, self.pre_transform, mask)
            self.model.settle()
        self.times.add("pre_color_transfer", time.perf_counter() - t0)

        # the per-run state (checkpoint.py writes and reads it)
        self.iteration = 0
        self.style_loss = None
        self.optimizer: torch.optim.Optimizer | None = None
        self.optimizer_dc_only: bool | None = None  # the dc_only the optimiser was made for
        self.agreement = StepAgreement()
        self.budget = StructureBudget()  # the content weight's multiplier (structure_budget.py)
        self._painting_colours = None  # the painting's colour mean and covariance, for the "output" measure
        self.last_stats: dict[str, Any] = {}
        self.history: list[dict[str, float]] = []
        self.finished = False
        self.capacity: np.ndarray | None = None  # the last CCFT plan's (plan_readouts.py), swapped in whole
        # Threads: step() runs on one; snapshot() and update_config() may come from another. The lock covers every
        # write to the model's tensors (and their replacement), so a snapshot never sees half an update.
        self._init_live("stylization", "stylize")
        self._publish_status()

    # ------------------------------------------------------------------ where the run is (view_schedule.py)
    iters_per_view = property(lambda self: self.views.iters_per_view(self.config))
    total_iters = property(lambda self: self.views.total_iters(self.config))
    done = property(lambda self: self.iteration >= self.total_iters)
    current_view = property(lambda self: self.views.current)
    trajectory_position = property(lambda self: self.views.position,
                                   doc="Index into ``trajectory`` of the view the next step optimises.")

    def pass_progress(self) -> tuple[int, int]:
        """(pass, passes): the pass the next step belongs to (1-based) and how many the schedule makes."""
        return self.views.pass_progress(self.iteration, self.config)

    _build_status = stylize_status

    # ------------------------------------------------------------------ rendering and features
    # the model being stylized; stylized_model.py holds it with the input model and the selection
    gaussians = property(lambda self: self.model.gaussians, lambda self, g: setattr(self.model, "gaussians", g))
    original_sh = property(lambda self: self.model.original_sh)  # the input model's colours

    def render(self, camera: Camera, **options) -> tuple[torch.Tensor, torch.Tensor]:
        """``StylizedModel.render`` with this run's background and backend."""
        return self.model.render(camera, self.config, **options)

    def render_views(self, cameras: list[Camera] | None = None, **options) -> list[tuple[np.ndarray, np.ndarray]]:
        """``StylizedModel.render_views`` of ``cameras`` (default: every scene view). The input model as it was:
        ``sh=original_sh, input_geometry=True``."""
        return self.model.render_views(self.cameras if cameras is None else cameras, self.config, **options)

    def features(self, image_hwc: torch.Tensor) -> torch.Tensor:
        """(H, W, 3) image -> (1, 768, h, w) VGG features of the image halved (ARF)."""
        return self.feature_cache.features(image_hwc)

    def style_features(self, camera: Camera) -> torch.Tensor:
        """(1, 768, h, w) features of the painting at ``style_scale`` times the render's long side, halved."""
        return self.feature_cache.style_features(camera.width, camera.height, self.config.style_scale)

    def content_features(self) -> torch.Tensor:
        """(1, 768, h, w) content features of the current view (kept for every view, feature_cache.py)."""
        view = self.views.current

        def content_image() -> torch.Tensor:
            if view.is_virtual or self.config.content_source == "render":
                return self.render(view.camera, sh=self.model.initial_sh, input_geometry=True)[0].clamp(0, 1)
            return torch.from_numpy(self.content_images[view.source_index]).to(self.device)

        return self.feature_cache.content_features(self.views.position, content_image)

    def measured_drift(self, image: torch.Tensor, alpha: torch.Tensor, feats: torch.Tensor,
                       content: torch.Tensor) -> float:
        """The structure drift of the current view's render (image and alpha, detached) that the budget holds, by
        the config's ``structure_measure`` (structure_budget.py); ``feats`` and ``content`` are the step's."""
        if self.config.structure_measure == "render":
            return structure_drift(feats, content)
        colours = self.budget.colours
        colours.update(image, alpha)
        if self._painting_colours is None:
            self._painting_colours = colour_stats(self.style_image.reshape(-1, 3))
        transform = colours.transfer(self._painting_colours) if self.config.color_transfer else None
        mapped = image if transform is None else apply_to_render(image, alpha, transform)
        camera = self.views.current.camera

        def original_image() -> torch.Tensor:  # the input model in its own colours
            return self.render(camera, sh=self.original_sh, input_geometry=True)[0][..., :3].clamp(0, 1)

        with torch.no_grad():
            original = self.feature_cache.original_features(self.views.position, original_image)
            return structure_drift(self.features(mapped), original)

    # ------------------------------------------------------------------ one iteration
    def _sync(self) -> None:
        """Apply the (possibly changed) config: the loss object, the optimiser, the learning rate. The loss reads
        its parameters from the config at each call; the config was validated where it entered."""
        self._take_pending_config()
        cfg = self.config
        if self.style_loss is None or cfg.loss != self.style_loss.name:
            from training.stylize.style_losses import make_style_loss

            self.style_loss = make_style_loss(cfg.loss)
        if self.optimizer is None or cfg.dc_only != self.optimizer_dc_only:
            with self._model_lock:
                self.restart_optimizer()
        set_colour_learning_rate(self.optimizer, colour_learning_rate(cfg, self.iteration, self.total_iters))

    def restart_optimizer(self) -> None:
        """A fresh optimiser over new leaves of the current model (under the model lock)."""
        self.optimizer = make_optimizer(self.model.gaussians, self.config, self._geometry_lrs)
        self.optimizer_dc_only = self.config.dc_only

    def step(self) -> dict[str, Any]:
        """One stylization iteration on the current view (step.py); returns losses, the view, the settings it used
        and a timing breakdown (s)."""
        self._sync()
        timer = StepTimer(self.device)
        result, capacity = gradient_step(self, timer)
        self.capacity = self.capacity if capacity is None else capacity  # kept until the next plan
        timer.start()
        m = self.model
        with self._model_lock:
            masked_step(self.optimizer, m.gaussians, m.mask, m.frozen)
            self._model_changed(geometry=m.trains_geometry)  # moved positions: a viewer uploads them again
        timer.stop("optimizer")
        for key, value in timer.timings.items():
            self.times.add(f"stylize/{key}", value)
        self.last_stats = result
        self.history.append({k: result[k] for k in ("iteration", *LOSS_KEYS, "grad_style", "grad_content",
                                                    "structure_drift", "content_weight")})
        self.iteration += 1
        moved = self.views.advance(self.config)
        self._publish_status()
        self.events.emit(Stepped, self.iteration, metrics={**result, "total_iters": self.total_iters})
        if moved:
            self.events.emit(ViewMoved, self.iteration, trajectory_position=self.views.position,
                             view_index=self.views.current.source_index, virtual=self.views.current.is_virtual)
        if self.iteration == self.total_iters:
            self.events.emit(Finished, self.iteration)
        return result

    def run(self, cancel=None) -> None:
        """Step until the schedule is done (or ``cancel()`` turns true between steps: raises Cancelled)."""
        while not self.done:
            check_cancel(cancel)
            self.step()

    # ------------------------------------------------------------------ the selection and the viewer's edits
    @property
    def mask(self) -> np.ndarray | None:
        """(N,) bool copy of the selection being stylized; None when every Gaussian is."""
        return None if self.model.mask is None else self.model.mask.numpy().copy()

    def set_mask(self, mask) -> None:
        """Stylize only ``mask``'s Gaussians from the next step on (None: all); any thread. Gaussians leaving the
        selection keep the colours they have now; the snapshot version moves on. ValueError for a wrong shape."""
        try:
            new = as_mask(mask, len(self.gaussians))
        except InputError as exc:
            raise ValueError(exc.problem) from None
        with self._model_lock:
            self.model.mask, self.model.frozen = new, self.gaussians.detached()
            self._model_changed()

    def set_region(self, mask) -> None:
        """The Viewer's SetRegion: ``set_mask``, refused for a selection made on another model."""
        if mask is not None and len(mask) != len(self.gaussians):
            raise ValueError("the selection belongs to another model than the one being stylized")
        self.set_mask(mask)

    def whole_model(self) -> Gaussians:
        return self.stylized_gaussians()

    def input_colours(self) -> torch.Tensor:
        return self.original_sh.detach().cpu()

    def _coverage(self, cancel=None) -> list[np.ndarray]:
        """Per view, (H, W) share of each pixel's colour that comes from the selection."""
        g = self.gaussians
        ind = indicator_sh(self.model.mask, g.sh_degree, self.device, g.means.dtype)
        return [coverage_from_render(img, a, self.config.background)
                for img, a in self.render_views(sh=ind, cancel=cancel)]

    def _snapshot_step(self) -> int:
        return self.iteration

    def _snapshot_geometry(self):
        return self.model.snapshot_geometry()

    def _snapshot_colours(self):
        return self.gaussians.sh, self.gaussians.sh_degree

    def keep(self, keep) -> None:
        """Keep only the Gaussians where ``keep`` (N,) bool (the viewer deleted or cropped the others); any thread,
        effective from the next step. The optimiser restarts (its moments belonged to the old rows)."""
        keep_t = torch.as_tensor(np.asarray(keep, dtype=bool))
        if keep_t.shape != (len(self.gaussians),):
            raise ValueError(f"keep must have {len(self.gaussians)} entries, got {tuple(keep_t.shape)}")
        if not bool(keep_t.any()):
            raise ValueError("that would remove every Gaussian")
        with self._model_lock:
            self.model.keep_rows(keep_t)
            self.optimizer = None
            self.feature_cache.forget_renders()  # a virtual view's content is a render of the model
            self._model_changed(geometry=True)
            self._structure_changed()
        self._publish_status()
        self.events.emit(StructureChanged, self.iteration, num_gaussians=len(self.gaussians))

    # ------------------------------------------------------------------ after
    def finish(self, cancel=None) -> ColorTransform | None:
        """ARF's post colour transfer: render every view, fit the map from those renders to the painting, apply it
        to the Gaussians' colours. Returns the map (None when colour transfer is off). ``cancel()`` is asked between
        views; when it turns true, Cancelled is raised and the colours are left as they were."""
        t0 = time.perf_counter()
        if not self.config.color_transfer:
            self.finished = True
            return None
        renders = self.render_views(cancel=cancel)
        cover = None if self.model.mask is None else self._coverage(cancel)  # the map is applied to the selection alone
        transform = post_color_transfer(renders, self.style_image, cover)
        if transform is None:
            return None
        self.post_transform = transform
        with self._model_lock:
            self.gaussians = transfer_to_selection(self.gaussians.detached(), transform, self.model.mask)
            self.model.frozen = self.gaussians.detached()
            self.optimizer = None  # the colour tensors were replaced: a later step() starts a fresh optimiser
            self._model_changed()
        self.finished = True
        self.times.add("post_color_transfer", time.perf_counter() - t0)
        return self.post_transform

    def stylized_gaussians(self) -> Gaussians:
        """The current model, detached, on the CPU (under "all" with the optimised geometry)."""
        return self.gaussians.detached().to("cpu")

    def input_gaussians(self) -> Gaussians:
        """The input model as given (the rows ``keep`` left), detached, on the CPU: what a before/after comparison
        renders as "before" (under "all" the current geometry is no longer the input's)."""
        return self.model.input_gaussians()

    def utilisation(self) -> dict[str, float]:
        """Style-feature utilisation of the last iteration (whatever the loss reported)."""
        return {k: self.last_stats[k] for k in UTILISATION if k in self.last_stats}

    def config_dict(self) -> dict[str, Any]:
        return asdict(replace(self.config))

    # ------------------------------------------------------------------ checkpoints (training/stylize/checkpoint.py)
    def state_dict(self) -> dict[str, Any]:
        """What a resumed run needs beyond its inputs (``checkpoint.trainer_state``)."""
        from training.stylize.checkpoint import trainer_state

        with self._model_lock:  # the model and the optimiser's moments as one step left them
            return trainer_state(self)

    def load_state(self, state: dict[str, Any]) -> None:
        """Continue from ``state_dict()`` of a run on the same inputs (this Stylizer built as that one was); the
        live settings (loss, weights, learning rate) stay this config's. InputError when the model differs."""
        from training.stylize.checkpoint import restore_trainer

        with self._model_lock:
            restore_trainer(self, state)
            self.feature_cache.forget_renders()
            if self.finished:
                self.model.frozen = self.gaussians.detached()
            self._model_changed(geometry=self.model.trains_geometry)
        self._publish_status()


def _resize(image: np.ndarray, camera: Camera) -> np.ndarray:
    if image.shape[:2] == (camera.height, camera.width):
        return np.ascontiguousarray(image, dtype=np.float32)
    from training.scene.image_io import resize_image

    return resize_image(image, camera.width, camera.height)

