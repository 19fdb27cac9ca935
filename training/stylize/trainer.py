"""Scene stylization after a painting: the paper's capacity-controlled stylization, one iteration per ``step()``.

Per iteration, on the current view of the trajectory: render the Gaussians; VGG-16 relu3 features of the render and of the content image (the photo after the pre colour
transfer, or the pre-stylization render for a virtual view), both halved first as ARF does; the style loss (CCFT with
the guide map carried from iteration to iteration, or the NNFM / Gram baselines) against the style image's features
(resized so that its long side matches the render's, then halved); content loss = MSE of the features; Adam on the
SH colour coefficients only (``params="colour"``, the default and the paper's method): geometry (means, scales,
rotations, opacities) is then never optimised and never written, it stays bit-identical. ``params="all"`` (the
paper's ablation) also optimises the means, log-scales, quaternions and opacity logits, at the original 3DGS
learning rates (training/stylize/defaults.py), activated afresh at every render. Before the first step, the content
images and the Gaussians' colours get the linear colour transfer toward the painting; ``finish()`` re-renders every
view, refits the transfer from those renders to the painting and applies it to the Gaussians (ARF's pre and post
colour transfer).

Which view an iteration renders (``config.schedule``): "interleaved", the default and the paper's, takes the next view
of the trajectory at every iteration (iteration t renders trajectory position t mod N), so the guide map each
iteration uses was built by the previous iteration on the previous view (paper, Cross-view Matching Guidance:
"the viewpoint of previous iteration"); the total, ``max(iters_per_view * N, min_total)``, is spread over passes along
the trajectory. "block" stays on a view for ``iters_per_view`` iterations in a row before moving on. The content
features of every view are kept (up to ``CONTENT_CACHE_BYTES``), so a new view every step costs no extra VGG pass.

The config may change between steps (the viewer's sliders): ``update_config(**changes)`` from any thread is
validated at once and applied at the start of the next step; loss parameters, weights, learning rate, iterations per
view and even the loss itself may change, while the settings that shape the run (``FIXED_AT_START``) are refused.
``snapshot()`` gives a viewer a consistent copy of the model from any thread (only the colours are copied anew while
stylizing colours alone; under ``params="all"`` the geometry too, after every step); ``add_listener`` delivers the
trainer's events (training/core/messages.py).
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from training.stylize.color_transfer import (ColorTransform, apply_to_gaussians, apply_to_image, fit_color_transfer,
                                     foreground_pixels)
from training.core.errors import InputError
from training.core.live_trainer import LiveTrainer
from training.core.messages import check_cancel
from training.model.gaussians import Gaussians
from training.raster.rasterize import resolve_device
from training.scene.correspondence import MIN_CELLS, cell_correspondence, label_agreement
from training.scene.scene import Camera, Scene, over_background
from training.stylize.objective import content_loss, render_gradients, total_variation
from training.stylize.region import (as_mask, blend_content, coverage_from_render, covered_pixels, indicator_sh,
                                     keep_unselected, masked_step)
from training.stylize.style_image import check_style_array, halve, painting_side, style_for_render
from training.stylize.defaults import MEANS_LR, OPACITY_LR, QUATS_LR, SCALES_LR, SHN_LR_FACTOR
from training.stylize.config import (DEFAULT_LAMBDA_STYLE, DEFAULT_LR, StylizeConfig,  # noqa: F401  (re-exported)
                                     paper_schedule, render_camera, schedule)
from training.stylize.scene_match import MATCH_MIN_ALPHA, check_model_matches_scene  # noqa: F401
from training.stylize.view_order import scene_kind, view_order
from training.stylize.virtual_views import ViewItem, trajectory

# Settings that shape the run when the Stylizer is built (the cameras, the trajectory, the colour transfer, the
# device, which parameters the optimiser holds): update_config refuses them rather than ignore them.
FIXED_AT_START = ("view_order", "virtual_views", "preset", "device", "color_transfer", "background", "scene_kind",
                  "max_side", "seed", "params", "schedule", "content_source")
GEOMETRY = ("means", "log_scales", "quats", "opacity_logits")
# The content features of the views, kept so that a new view at every iteration costs no VGG pass of its photo:
# about 2.4 MB a view at 256 px, 40-60 MB at 1600 px. Beyond this the least recently used view is dropped and
# computed again when its turn comes.
CONTENT_CACHE_BYTES = 1 << 30


@dataclass
class StageTimes:
    """Seconds spent per stage, accumulated."""

    totals: dict[str, float] = field(default_factory=dict)

    def add(self, name: str, seconds: float) -> None:
        self.totals[name] = self.totals.get(name, 0.0) + seconds


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
        self.scene = scene
        self.style_image = check_style_array(style_image)
        self.model_name = model_name

        if vgg is None:
            from training.stylize.vgg_features import load_vgg16_features

            vgg = load_vgg16_features(vgg_weights)
        self.vgg = vgg.to(self.device)

        geometry = {k: getattr(gaussians, k).detach().to(self.device)
                    for k in ("means", "log_scales", "quats", "opacity_logits")}
        colour = {k: getattr(gaussians, k).detach().to(self.device).clone() for k in ("sh0", "shN")}
        self.gaussians = Gaussians(**geometry, **colour, sh_degree=gaussians.sh_degree)
        self._mask = as_mask(mask, len(self.gaussians), model_name)
        if self._mask is not None and not bool(self._mask.any()):
            raise InputError(model_name, "the selection mask selects no Gaussians: nothing to stylize")
        self._trains_geometry = self.config.params == "all"
        if self._trains_geometry:
            # activated from the trained parameters at every render (``_render_geometry``); the input model's
            # geometry is kept for what must be rendered as before stylization (virtual views' content)
            self._scales = self._opacities = None
            self._input_geometry = {k: getattr(self.gaussians, k).clone() for k in GEOMETRY}  # raw parameters
            self._geometry_lrs = {"means": MEANS_LR * float(scene.extent), "log_scales": SCALES_LR,
                                  "quats": QUATS_LR, "opacity_logits": OPACITY_LR}
        else:
            # Activated geometry, computed once: it never changes and needs no gradient.
            self._scales = self.gaussians.scales.detach()
            self._opacities = self.gaussians.opacities.detach()
            self._input_geometry = None

        # Views: all cameras of the scene, at the stylization resolution.
        max_side = self.config.render_max_side
        self.cameras = [render_camera(c, max_side) for c in scene.cameras]
        if check_match:
            check_model_matches_scene(self.gaussians, self.cameras, model_name)
        self.kind = scene_kind(scene.cameras, self.config.scene_kind)
        self.order = view_order(scene.cameras, self.config.view_order, seed=self.config.seed, extent=scene.extent)
        self.trajectory: list[ViewItem] = trajectory(self.cameras, self.order, self.config.virtual_views)
        # RGBA photos are compared over the same background as the renders
        bg = np.asarray(self.config.background, dtype=np.float32)
        self.content_images = [self._resize(over_background(img, mask, bg), cam)
                               for img, mask, cam in zip(scene.images, scene.masks, self.cameras)]
        self.times.add("load", time.perf_counter() - t0)

        t0 = time.perf_counter()
        if check_match:
            self._check_renders_not_empty()
        self.pre_transform: ColorTransform | None = None
        self.post_transform: ColorTransform | None = None
        if self.config.color_transfer:
            style_px = self.style_image.reshape(-1, 3)
            cover = None if self._mask is None else self._coverage()
            fit_px = self.content_images if cover is None else covered_pixels(self.content_images, cover)
            self.pre_transform = fit_color_transfer(fit_px, style_px)
            moved = [apply_to_image(img, self.pre_transform) for img in self.content_images]
            self.content_images = moved if cover is None else [
                blend_content(img, new, c) for img, new, c in zip(self.content_images, moved, cover)]
            self.gaussians = keep_unselected(apply_to_gaussians(self.gaussians, self.pre_transform), self.gaussians,
                                             self._mask)
        # The pre-stylization model: the content of virtual views.
        self._initial_sh = self.gaussians.sh.detach().clone()
        self._frozen = self.gaussians.detached()  # the colours unselected Gaussians are held to
        self.times.add("pre_color_transfer", time.perf_counter() - t0)
        self.original_sh = torch.cat([colour["sh0"], colour["shN"]], dim=1)  # the input model's colours

        self.iteration = 0
        self._position = 0  # index into the trajectory
        self._iters_on_view = 0
        self._style_cache: dict[int, torch.Tensor] = {}
        self._content_cache: OrderedDict[int, torch.Tensor] = OrderedDict()  # trajectory position -> features
        self._loss_name: str | None = None
        self.style_loss = None
        self._optimizer: torch.optim.Optimizer | None = None
        self._dc_only: bool | None = None
        self.last_stats: dict[str, Any] = {}
        self._previous_plan = None  # (position, camera, labels, depth, alpha) of the last step, for its agreement
        self._agreements: list[float] = []
        self.history: list[dict[str, float]] = []
        self.finished = False
        # Threads: step() runs on one; snapshot() and update_config() may come from another. The lock covers every
        # write to the model's tensors (and their replacement), so a snapshot never sees half an update.
        self._init_live("stylization", "stylize")
        self._capacity: np.ndarray | None = None

    # ------------------------------------------------------------------ schedule
    @property
    def iters_per_view(self) -> int:
        return schedule(self.config, self.kind, len(self.scene.cameras))[0]

    @property
    def total_iters(self) -> int:
        """Iterations of the whole schedule: every trajectory view ``iters_per_view`` times, at least the minimum."""
        per_view, min_total = schedule(self.config, self.kind, len(self.scene.cameras))
        return max(per_view * len(self.trajectory), min_total)

    @property
    def iters_per_pass(self) -> int:
        """Iterations of one pass along the trajectory: one a view (interleaved) or ``iters_per_view`` a view."""
        per_view = 1 if self.config.schedule == "interleaved" else self.iters_per_view
        return per_view * len(self.trajectory)

    def pass_progress(self) -> tuple[int, int]:
        """(pass, passes): the pass along the trajectory the next step belongs to (1-based, at most ``passes``) and
        how many the schedule makes (the last one may stop part-way: the total need not be a whole number of
        passes)."""
        per_pass = self.iters_per_pass
        passes = max(1, math.ceil(self.total_iters / per_pass))
        return min(self.iteration // per_pass + 1, passes), passes

    @property
    def done(self) -> bool:
        return self.iteration >= self.total_iters

    @property
    def current_view(self) -> ViewItem:
        return self.trajectory[self._position]

    @property
    def trajectory_position(self) -> int:
        """Index into ``trajectory`` of the view the next step optimises."""
        return self._position

    def capacity_map(self) -> np.ndarray | None:
        """(h, w) float32: the column mass of the last CCFT plan at each style feature's place on the painting's
        feature grid (sums to about 1; None before the first CCFT step). Any thread."""
        return self._capacity

    # ------------------------------------------------------------------ rendering
    def _resize(self, image: np.ndarray, camera: Camera) -> np.ndarray:
        if image.shape[:2] == (camera.height, camera.width):
            return np.ascontiguousarray(image, dtype=np.float32)
        from training.scene.image_io import resize_image

        return resize_image(image, camera.width, camera.height)

    def _render_geometry(self, input_geometry: bool = False):
        """(means, quats, scales, opacities) to render with: the current geometry (under "all" activated from the
        trained leaves, so gradients reach them), or with ``input_geometry`` the input model's."""
        if input_geometry and self._input_geometry is not None:
            raw = self._input_geometry
            return raw["means"], raw["quats"], torch.exp(raw["log_scales"]), torch.sigmoid(raw["opacity_logits"])
        g = self.gaussians
        if self._trains_geometry:
            return g.means, g.quats, g.scales, g.opacities
        return g.means, g.quats, self._scales, self._opacities

    def render(self, camera: Camera, sh: torch.Tensor | None = None, input_geometry: bool = False,
               render_mode: str = "RGB") -> tuple[torch.Tensor, torch.Tensor]:
        """Render at ``camera`` with the current colours (or ``sh`` (N, K, 3)) -> image (H, W, 3), alpha (H, W, 1).
        ``input_geometry``: with the input model's geometry (differs from the current one only under "all");
        ``render_mode`` "RGB+ED": the image's fourth channel is the expected depth."""
        from training.raster.rasterize import rasterize

        g = self.gaussians
        colors = g.sh if sh is None else sh
        dt = g.means.dtype
        means, quats, scales, opacities = self._render_geometry(input_geometry)
        image, alpha, _ = rasterize(
            means, quats, scales, opacities, colors,
            torch.as_tensor(camera.world_to_camera, dtype=dt, device=self.device),
            torch.as_tensor(camera.K, dtype=dt, device=self.device), camera.width, camera.height,
            sh_degree=g.sh_degree, background=torch.tensor(self.config.background, dtype=dt, device=self.device),
            render_mode=render_mode, backend=self.config.backend)
        return image, alpha

    def render_views(self, cameras: list[Camera] | None = None, cancel=None, sh: torch.Tensor | None = None,
                     input_geometry: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
        """(image (H, W, 3), alpha (H, W, 1)) numpy renders of ``cameras`` (default: every scene view) with the
        current colours (or ``sh``) and geometry (or the input model's: ``input_geometry``); ``cancel()`` is asked
        before each view (Cancelled). The input model as it was: ``sh=original_sh, input_geometry=True``."""
        out = []
        with torch.no_grad():
            for cam in cameras if cameras is not None else self.cameras:
                check_cancel(cancel)
                img, alpha = self.render(cam, sh=sh, input_geometry=input_geometry)
                out.append((img.clamp(0, 1).float().cpu().numpy(), alpha.float().cpu().numpy()))
        return out

    def _check_renders_not_empty(self) -> None:
        picks = sorted({0, len(self.cameras) // 2, len(self.cameras) - 1})
        small = [render_camera(self.cameras[i], 96) for i in picks]
        with torch.no_grad():
            coverage = [float(self.render(cam)[1].mean()) for cam in small]
        if max(coverage) < MATCH_MIN_ALPHA:
            raise InputError(self.model_name, f"renders of the scene's views are empty (coverage at most "
                                              f"{max(coverage):.1%}): the model does not match this scene")

    # ------------------------------------------------------------------ features
    def features(self, image_hwc: torch.Tensor) -> torch.Tensor:
        """(H, W, 3) image -> (1, 768, h, w) VGG features of the image halved (ARF)."""
        x = image_hwc.permute(2, 0, 1)[None].float()
        return self.vgg(halve(x))

    def style_features(self, camera: Camera) -> torch.Tensor:
        """(1, 768, h, w) features of the painting resized so its long side is ``style_scale`` times the render's,
        then halved."""
        side = painting_side(max(camera.width, camera.height), self.config.style_scale)
        if side not in self._style_cache:
            with torch.no_grad():
                style = style_for_render(self.style_image, side).to(self.device)
                self._style_cache[side] = self.vgg(halve(style))
        return self._style_cache[side]

    def content_features(self) -> torch.Tensor:
        """(1, 768, h, w) content features of the current view (kept for every view, ``CONTENT_CACHE_BYTES``)."""
        cache = self._content_cache
        if self._position in cache:
            cache.move_to_end(self._position)
            return cache[self._position]
        view = self.current_view
        with torch.no_grad():
            if view.is_virtual or self.config.content_source == "render":
                content, _ = self.render(view.camera, sh=self._initial_sh, input_geometry=True)
                content = content.clamp(0, 1)
            else:
                content = torch.from_numpy(self.content_images[view.source_index]).to(self.device)
            feats = self.features(content)
        cache[self._position] = feats
        size = feats.numel() * feats.element_size()
        while len(cache) > 1 and len(cache) * size > CONTENT_CACHE_BYTES:
            cache.popitem(last=False)
        return feats

    # ------------------------------------------------------------------ config sync
    def _sync(self) -> None:
        """Apply the (possibly changed) config: loss object and its parameters, optimiser, learning rate. The config
        was validated where it entered (construction, ``update_config``, the viewer's settings)."""
        self._take_pending_config()
        cfg = self.config
        if self.style_loss is None or cfg.loss != self._loss_name:
            from training.stylize.style_losses import make_style_loss

            self.style_loss = make_style_loss(cfg.loss)
            self._loss_name = cfg.loss
        for name, value in (("k", cfg.k), ("epsilon", cfg.epsilon), ("tau", cfg.tau),
                            ("lambda_guide", cfg.lambda_guide), ("iters", cfg.sinkhorn_iters)):
            if hasattr(self.style_loss, name):
                setattr(self.style_loss, name, value)
        if self._optimizer is None or cfg.dc_only != self._dc_only:
            with self._model_lock:
                self._make_optimizer()
        for group in self._optimizer.param_groups:
            if group["lr_scale"] is not None:  # the geometry's rates (params="all") are fixed
                group["lr"] = self._lr_now() * group["lr_scale"]

    def _lr_now(self) -> float:
        """The colours' learning rate at this iteration: ``lr`` decayed exponentially to ``lr * lr_final`` at the
        last iteration of the schedule (constant with lr_final 1)."""
        cfg = self.config
        progress = min(1.0, self.iteration / max(1, self.total_iters - 1))
        return cfg.learning_rate * cfg.lr_final ** progress

    def _make_optimizer(self) -> None:
        g = self.gaussians
        sh0 = g.sh0.detach().clone().requires_grad_(True)
        shN = g.shN.detach().clone().requires_grad_(not self.config.dc_only)
        g.sh0, g.shN = sh0, shN
        lr = self.config.learning_rate
        groups = [{"params": [sh0], "lr_scale": 1.0, "lr": lr, "name": "sh0"}]
        if not self.config.dc_only and shN.numel() > 0:
            groups.append({"params": [shN], "lr_scale": SHN_LR_FACTOR, "lr": lr * SHN_LR_FACTOR, "name": "shN"})
        if self._trains_geometry:  # new leaves: the caller's (shared) tensors are never written
            for name in GEOMETRY:
                leaf = getattr(g, name).detach().clone().requires_grad_(True)
                setattr(g, name, leaf)
                groups.append({"params": [leaf], "lr_scale": None, "lr": self._geometry_lrs[name], "name": name})
        self._optimizer = torch.optim.Adam(groups, eps=1e-15)
        self._dc_only = self.config.dc_only

    # ------------------------------------------------------------------ one iteration
    def step(self) -> dict[str, Any]:
        """One stylization iteration on the current view; returns losses, the view and a timing breakdown (s)."""
        self._sync()
        cfg = self.config
        view = self.current_view
        timings: dict[str, float] = {}
        sync = (lambda: torch.cuda.synchronize()) if self.device.type == "cuda" else (lambda: None)

        t = time.perf_counter()
        rendered, alpha = self.render(view.camera, render_mode="RGB+ED")  # the depth: for the step's agreement
        rendered, depth = rendered[..., :3], rendered[..., 3:].detach()
        # the objective's gradient on the render is taken first (its terms apart, for the balance), then pushed
        # through the rasterizer: two timed backward stages
        image = rendered.detach().requires_grad_(True)
        sync()
        timings["rasterize"] = time.perf_counter() - t

        t = time.perf_counter()
        feats = self.features(image)
        content = self.content_features()
        style = self.style_features(view.camera)
        sync()
        timings["vgg_forward"] = time.perf_counter() - t

        t = time.perf_counter()
        style_loss, stats = self.style_loss(feats, style, source=self._position)
        last = getattr(self.style_loss, "last_result", None)
        if last is not None and getattr(last, "column_mass", None) is not None:
            # swapped in whole: a reader on another thread sees the previous map or this one
            self._capacity = last.column_mass.detach().to("cpu", torch.float32).numpy().reshape(style.shape[2:])
        content_term = content_loss(feats, content, cfg.content_norm)
        terms = {"style": cfg.style_weight * style_loss, "content": cfg.lambda_content * content_term}
        if cfg.lambda_tv > 0:
            terms["tv"] = cfg.lambda_tv * total_variation(image)
        loss = sum(terms.values())
        sync()
        timings["loss"] = time.perf_counter() - t
        t = time.perf_counter()
        agreement = self._step_agreement(last, feats.shape[2:], view.camera, depth, alpha.detach())
        timings["agreement"] = time.perf_counter() - t
        for key, value in stats.items():  # the loss's own breakdown: similarity_topk_s, sinkhorn_s, guide_s
            if key.endswith("_s"):
                timings[key[:-2]] = float(value)

        t = time.perf_counter()
        grads = render_gradients(image, terms, cfg.measure_balance)
        sync()
        timings["vgg_backward"] = time.perf_counter() - t
        t = time.perf_counter()
        self._optimizer.zero_grad(set_to_none=True)
        rendered.backward(grads.total)
        sync()
        timings["raster_backward"] = time.perf_counter() - t

        t = time.perf_counter()
        with self._model_lock:
            masked_step(self._optimizer, self.gaussians, self._mask, self._frozen)
            self._version += 1
            if self._trains_geometry:  # positions moved: a viewer must upload them again
                self._geometry_version += 1
        sync()
        timings["optimizer"] = time.perf_counter() - t
        for key, value in timings.items():
            self.times.add(f"stylize/{key}", value)

        result = {
            "iteration": self.iteration,
            "loss": float(loss.detach()),
            "style_loss": float(style_loss.detach()),
            "content_loss": float(content_term.detach()),
            # the norms of the style and content terms' gradients on the render (None: not measured)
            "grad_style": grads.style_norm, "grad_content": grads.content_norm,
            "content_to_style": grads.content_to_style,
            "view": view.camera.name,
            "view_index": view.source_index,
            "trajectory_position": self._position,
            "virtual": view.is_virtual,
            # the trajectory position whose features built the guide map this step used (None: no guidance)
            "guide_view": getattr(self.style_loss, "used_guide_source", None),
            # share of the cells this view and the previous step's (another view) both see that the two steps'
            # plans gave the same style feature (None: same view, no CCFT plan, or too few shared cells)
            "match_agreement": agreement,
            "pass": self.pass_progress()[0],
            "coverage": float(alpha.detach().mean()),
            "timings": timings,
            # the settings this step used: a live change shows in the first step that applied it
            "tau": cfg.tau, "k": cfg.k, "epsilon": cfg.epsilon, "lambda_guide": cfg.lambda_guide,
            "lambda_style": cfg.style_weight, "lambda_content": cfg.lambda_content, "lr": self._lr_now(),
            "style_scale": cfg.style_scale,
        }
        result.update({k: _plain(v) for k, v in stats.items()
                       if k not in ("loss",) and not k.endswith("_s") and _is_scalar(v)})
        self.last_stats = result
        self.history.append({k: result[k] for k in ("iteration", "loss", "style_loss", "content_loss", "grad_style",
                                                    "grad_content")})

        self.iteration += 1
        self._iters_on_view += 1
        self.events.emit("step", self.iteration, {**result, "total_iters": self.total_iters})
        if cfg.schedule == "interleaved" or self._iters_on_view >= self.iters_per_view:
            self._iters_on_view = 0
            self._position = (self._position + 1) % len(self.trajectory)
            self.events.emit("view", self.iteration, {"trajectory_position": self._position,
                                                      "view_index": self.current_view.source_index,
                                                      "virtual": self.current_view.is_virtual})
        if self.iteration == self.total_iters:
            self.events.emit("finished", self.iteration)
        return result

    def _step_agreement(self, result, cells: tuple[int, int], camera: Camera, depth: torch.Tensor,
                        alpha: torch.Tensor) -> float | None:
        """Match agreement of this step's plan with the previous step's, where the previous step rendered another
        view: the share of this view's feature cells that see what a cell of the previous view saw (depth warp,
        training/scene/correspondence.py) and whose largest plan entry is the same style feature there. What
        cross-view guidance acts on, measured as the run goes; ``step_agreement()`` averages it."""
        if result is None or getattr(result, "plan", None) is None:
            self._previous_plan = None
            return None
        plan = result.plan
        labels = plan.indices.gather(1, plan.values.argmax(dim=1, keepdim=True))[:, 0].reshape(cells).cpu()
        previous, self._previous_plan = self._previous_plan, (self._position, camera, labels, depth, alpha)
        if previous is None or previous[0] == self._position:
            return None
        _, p_camera, p_labels, p_depth, p_alpha = previous
        landing, valid = cell_correspondence(depth, alpha, camera, cells, p_depth, p_alpha, p_camera,
                                             tuple(p_labels.shape))
        same, n = label_agreement(labels, p_labels, landing, valid)
        if n < MIN_CELLS:
            return None
        self._agreements.append(same / n)
        return same / n

    def step_agreement(self) -> float | None:
        """Mean over the steps so far of their match agreement with the step before (the steps that changed view
        and had enough shared cells); None before any."""
        return float(np.mean(self._agreements)) if self._agreements else None

    @property
    def mask(self) -> np.ndarray | None:
        """(N,) bool copy of the selection being stylized; None when every Gaussian is."""
        m = self._mask
        return None if m is None else m.numpy().copy()

    def set_mask(self, mask) -> None:
        """Stylize only ``mask``'s Gaussians from the next step on (None: all); any thread. Gaussians leaving the
        selection keep the colours they have now; the snapshot version moves on. ValueError for a wrong shape."""
        try:
            new = as_mask(mask, len(self.gaussians))
        except InputError as exc:
            raise ValueError(exc.problem) from None
        with self._model_lock:
            self._mask = new
            self._frozen = self.gaussians.detached()
            self._version += 1

    def _coverage(self, cancel=None) -> list[np.ndarray]:
        """Per view, (H, W) share of each pixel's colour that comes from the selection."""
        g = self.gaussians
        ind = indicator_sh(self._mask, g.sh_degree, self.device, g.means.dtype)
        return [coverage_from_render(img, a, self.config.background)
                for img, a in self.render_views(sh=ind, cancel=cancel)]

    def run(self, cancel=None) -> None:
        """Step until the schedule is done (or ``cancel()`` turns true between steps: raises Cancelled)."""
        while not self.done:
            check_cancel(cancel)
            self.step()

    # ------------------------------------------------------------------ the viewer's copy and edits
    def _snapshot_step(self) -> int:
        return self.iteration

    def _snapshot_geometry(self):
        g = self.gaussians
        if self._trains_geometry:
            return g.means, g.scales, g.rotations, g.opacities
        return g.means, self._scales, g.rotations, self._opacities

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
        index = keep_t.nonzero()[:, 0].to(self.device)
        with self._model_lock:
            self.gaussians = self.gaussians.detached().subset(index)
            if self._trains_geometry:
                self._input_geometry = {k: t[index] for k, t in self._input_geometry.items()}
            else:
                self._scales, self._opacities = self._scales[index], self._opacities[index]
            self._initial_sh, self.original_sh = self._initial_sh[index], self.original_sh[index]
            self._frozen = self._frozen.subset(index)
            self._mask = None if self._mask is None else self._mask[keep_t]
            self._optimizer = None
            self._content_cache.clear()  # a virtual view's content is a render of the model
            self._version += 1
            self._geometry_version += 1
            self._structure_changed()
        self.events.emit("structure", self.iteration, {"num_gaussians": len(self.gaussians)})

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
        if self._mask is None:
            pixels = [foreground_pixels(img, a) for img, a in renders]
        else:  # fitted where the selection shows: the map is applied to the selection alone
            cover = self._coverage(cancel)
            pixels = covered_pixels([img for img, _ in renders], cover, [a for _, a in renders])
        pixels = [p for p in pixels if len(p)]
        if not pixels:
            return None
        self.post_transform = fit_color_transfer(pixels, self.style_image.reshape(-1, 3))
        with self._model_lock:
            current = self.gaussians.detached()
            self.gaussians = keep_unselected(apply_to_gaussians(current, self.post_transform), current, self._mask)
            self._frozen = self.gaussians.detached()
            self._optimizer = None  # the colour tensors were replaced: a later step() starts a fresh optimiser
            self._version += 1
        self.finished = True
        self.times.add("post_color_transfer", time.perf_counter() - t0)
        return self.post_transform

    def style_distance(self, sh: torch.Tensor | None = None, max_views: int | None = 8,
                       cancel=None) -> dict[str, float]:
        """Mean over the scene's views (at most ``max_views`` of them, evenly spaced: the report's figure should not
        cost as much as the stylization itself) of the Gram distance between the render's features and the painting's (both
        prepared as for the loss): ``gram`` on the raw relu3 features, ``gram_normalised`` on features scaled to
        unit length per position (blind to overall activation strength, i.e. contrast, which cosine-based losses
        leave free). ``sh``: colours to render with (default: the current ones)."""
        from training.stylize.ccft import l2_normalise

        totals = {"gram": 0.0, "gram_normalised": 0.0}
        cameras = self.cameras
        if max_views is not None and len(cameras) > max_views:
            cameras = [cameras[int(i)] for i in np.linspace(0, len(cameras) - 1, max_views).round()]
        with torch.no_grad():
            for cam in cameras:
                check_cancel(cancel)
                image, _ = self.render(cam, sh=sh)
                f, fs = self.features(image.clamp(0, 1)), self.style_features(cam)
                totals["gram"] += gram_distance(f, fs)
                unit = lambda x: l2_normalise(x[0].flatten(1).t()).t().reshape(x.shape)  # noqa: E731
                totals["gram_normalised"] += gram_distance(unit(f), unit(fs))
        return {k: v / len(cameras) for k, v in totals.items()}

    def stylized_gaussians(self) -> Gaussians:
        """The current model, detached, on the CPU (under "all" with the optimised geometry)."""
        return self.gaussians.detached().to("cpu")

    def input_gaussians(self) -> Gaussians:
        """The input model as given (its geometry and colours, the rows ``keep`` left), detached, on the CPU: what
        a before/after comparison renders as "before" (under "all" the current geometry is no longer the input's)."""
        g = self.gaussians
        raw = self._input_geometry or {k: getattr(g, k) for k in GEOMETRY}
        sh = self.original_sh
        return Gaussians(**{k: v.detach().clone() for k, v in raw.items()}, sh0=sh[:, :1].clone(),
                         shN=sh[:, 1:].clone(), sh_degree=g.sh_degree).to("cpu")

    def utilisation(self) -> dict[str, float]:
        """Style-feature utilisation of the last iteration (whatever the loss reported)."""
        keys = ("utilisation", "column_entropy", "column_entropy_normalised", "reachable_fraction",
                "distinct_fraction", "distinct_count")
        return {k: self.last_stats[k] for k in keys if k in self.last_stats}

    def config_dict(self) -> dict[str, Any]:
        return asdict(replace(self.config))

    # ------------------------------------------------------------------ checkpoints (training/stylize/checkpoint.py)
    def state_dict(self) -> dict[str, Any]:
        """What a resumed run needs beyond its inputs: the place in the schedule, the colours (and under "all" the
        geometry), the optimiser's moments, the CCFT guide carried from step to step, the losses so far, and
        whether the post colour transfer was applied. Tensors on the CPU; plain values otherwise."""
        with self._model_lock:
            g = self.gaussians.detached().to("cpu")
            optimizer = None if self._optimizer is None else self._optimizer.state_dict()
        names = ("sh0", "shN") + (GEOMETRY if self._trains_geometry else ())
        guide = getattr(self.style_loss, "guide", None)
        return {
            "iteration": self.iteration, "position": self._position, "iters_on_view": self._iters_on_view,
            "num_gaussians": len(g), "model": {k: getattr(g, k) for k in names},
            "optimizer": optimizer, "dc_only": self._dc_only, "loss": self._loss_name,
            "guide": None if guide is None else guide.detach().to("cpu"),
            "guide_source": getattr(self.style_loss, "guide_source", None),
            "agreements": list(self._agreements),
            "history": [dict(h) for h in self.history],
            "last_stats": {k: v for k, v in self.last_stats.items() if isinstance(v, (bool, int, float, str))},
            "finished": self.finished,
            "post_transform": None if self.post_transform is None else self.post_transform.to_dict(),
            "times": dict(self.times.totals),
        }

    def load_state(self, state: dict[str, Any]) -> None:
        """Continue from ``state_dict()`` of a run on the same inputs (this Stylizer built as that one was); the
        live settings (loss, weights, learning rate) stay this config's. InputError when the model differs."""
        if int(state["num_gaussians"]) != len(self.gaussians):
            raise InputError(self.model_name, f"the checkpoint holds {state['num_gaussians']} Gaussians, this "
                                              f"model {len(self.gaussians)}")
        with self._model_lock:
            for name, value in state["model"].items():
                setattr(self.gaussians, name, value.to(self.device, getattr(self.gaussians, name).dtype))
            self.iteration = int(state["iteration"])
            self._position = int(state["position"])
            self._iters_on_view = int(state["iters_on_view"])
            self._content_cache.clear()
            self.finished = bool(state["finished"])
            if state["post_transform"] is not None:
                t = state["post_transform"]
                self.post_transform = ColorTransform(np.asarray(t["A"], dtype=np.float64),
                                                     np.asarray(t["b"], dtype=np.float64))
            if self.finished:
                self._frozen = self.gaussians.detached()
            self._optimizer = None
            self._version += 1
            if self._trains_geometry:
                self._geometry_version += 1
        self.history = [dict(h) for h in state["history"]]
        self.last_stats = dict(state["last_stats"])
        for name, seconds in state["times"].items():
            self.times.add(name, float(seconds))
        if state["loss"] is not None:
            from training.stylize.style_losses import make_style_loss

            self.style_loss, self._loss_name = make_style_loss(state["loss"]), state["loss"]
            if state["guide"] is not None and hasattr(self.style_loss, "guide"):
                self.style_loss.guide = state["guide"].to(self.device)
                self.style_loss.guide_source = state.get("guide_source")
        self._agreements = [float(a) for a in state.get("agreements", [])]
        if state["optimizer"] is not None and state["dc_only"] == self.config.dc_only:
            with self._model_lock:
                self._make_optimizer()
            saved = [group.get("name") for group in state["optimizer"]["param_groups"]]
            if saved == [group["name"] for group in self._optimizer.param_groups]:
                self._optimizer.load_state_dict(state["optimizer"])


def _is_scalar(value: Any) -> bool:
    if isinstance(value, (int, float, bool, str)):
        return True
    return isinstance(value, torch.Tensor) and value.numel() == 1


def _plain(value: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return value.item()
    return value


def gram_distance(features: torch.Tensor, style_features: torch.Tensor) -> float:
    """The Gram loss (Gatys; ``training.stylize.style_losses.GramStyleLoss``) between two (1, C, h, w) feature maps: the
    style distance of the acceptance figures."""
    from training.stylize.style_losses import GramStyleLoss

    return float(GramStyleLoss()(features, style_features)[0])
