"""Adaptive density control of 3DGS as a separate strategy object (clone, split, prune, opacity reset).

The trainer calls ``DensifyStrategy.step_post_backward`` once per iteration, after ``loss.backward()`` and the
optimizer step, with the rasterizer's ``info``. The strategy owns its statistics and edits the model's parameter
tensors *and* the optimizer's Adam moments together, so the two never disagree in size.

Screen-space gradient. ``info["means2d"].grad`` is dL/d(pixel coordinates). 3DGS thresholds the gradient with
respect to normalised device coordinates, where x_ndc = 2 x_pix / W - 1, so dL/dx_ndc = dL/dx_pix * W / 2 (and
H / 2 for y). We scale by (0.5 W, 0.5 H) before taking the norm and compare against the paper's threshold 0.0002
unchanged; with that scaling the statistic does not depend on the image resolution.

The rules, as in 3DGS (steps count from 1):
- statistics (gradient norm, view count, largest screen radius) are accumulated while step < ``stop``;
- every ``interval`` steps with ``start`` < step < ``stop``: Gaussians whose mean gradient is >= threshold are
  cloned when their largest scale is <= ``percent_dense`` x extent, else split into two samples drawn from the
  Gaussian with scales / 1.6; then Gaussians are pruned when opacity < ``min_opacity``, and, after the first
  opacity reset, when their largest scale exceeds ``prune_world`` x extent or their largest screen radius since
  the last densification exceeds ``prune_screen`` x the image's long side (new Gaussians start at radius 0; 3DGS
  zeroes every radius there, which makes its screen-size test a no-op). The screen limit is a fraction, as gsplat's
  ``prune_scale2d``, not 3DGS's 20 pixels: a pixel limit prunes more the finer the training images;
- every ``reset_every`` steps with step < ``stop``, opacities are clamped to at most ``reset_opacity`` and their
  Adam moments zeroed.
New Gaussians start with zero Adam moments, removed ones take theirs with them (the 3DGS behaviour).
``max_gaussians`` (None = no limit) keeps the candidates with the largest gradients when growth would exceed it.
"""

from __future__ import annotations

import math
from typing import Callable

import torch

from training.model.gaussians import Gaussians
from training.model.rotation import quat_to_rotmat
from training.reconstruct.config import DensifyConfig

PARAM_NAMES = ("means", "log_scales", "quats", "opacity_logits", "sh0", "shN")


def _edit_params(model: Gaussians, optimizer: torch.optim.Optimizer,
                 param_fn: Callable[[str, torch.Tensor], torch.Tensor],
                 state_fn: Callable[[str, torch.Tensor], torch.Tensor]) -> None:
    """Replace every parameter p by param_fn(name, p) and its Adam moments m by state_fn(name, m), keeping the
    model's attributes, the optimizer's param groups and its state keyed by the new tensors."""
    for group in optimizer.param_groups:
        name = group["name"]
        old = group["params"][0]
        new = param_fn(name, old.detach()).contiguous().requires_grad_(True)
        state = optimizer.state.pop(old, None)
        if state:
            for key in ("exp_avg", "exp_avg_sq"):
                if key in state:
                    state[key] = state_fn(name, state[key]).contiguous()
            optimizer.state[new] = state
        group["params"][0] = new
        setattr(model, name, new)


def append_gaussians(model: Gaussians, optimizer: torch.optim.Optimizer, new: dict[str, torch.Tensor]) -> None:
    """Append rows ``new[name]`` (M, ...) to every parameter; their Adam moments start at zero."""
    _edit_params(model, optimizer,
                 lambda n, p: torch.cat([p, new[n].to(p)], dim=0),
                 lambda n, s: torch.cat([s, torch.zeros_like(new[n], dtype=s.dtype, device=s.device)], dim=0))


def keep_gaussians(model: Gaussians, optimizer: torch.optim.Optimizer, keep: torch.Tensor) -> None:
    """Keep the rows where the (N,) bool mask ``keep`` is True, in parameters and Adam moments alike."""
    _edit_params(model, optimizer, lambda n, p: p[keep], lambda n, s: s[keep])


class DensifyStrategy:
    """3DGS adaptive density control; see the module docstring. ``extent`` is the scene extent (world units)."""

    def __init__(self, extent: float, num_gaussians: int, device: torch.device | str = "cpu"):
        self.extent = float(extent)
        self.device = torch.device(device)
        self._reset_stats(num_gaussians)

    def _reset_stats(self, n: int) -> None:
        self.grad_accum = torch.zeros(n, device=self.device)
        self.count = torch.zeros(n, device=self.device)
        self.max_radii = torch.zeros(n, device=self.device)

    def state_dict(self) -> dict:
        return {"grad_accum": self.grad_accum.clone(), "count": self.count.clone(),
                "max_radii": self.max_radii.clone(), "radii_unit": "long_side", "extent": self.extent}

    def load_state_dict(self, state: dict) -> None:
        self.grad_accum = state["grad_accum"].clone().to(self.device)
        self.count = state["count"].clone().to(self.device)
        self.max_radii = state["max_radii"].clone().to(self.device)
        if state.get("radii_unit") != "long_side":
            # a checkpoint from before the radii were fractions holds pixels, which would prune everything; the
            # radii restart from zero at every densification anyway
            self.max_radii.zero_()
        self.extent = float(state["extent"])

    @torch.no_grad()
    def update_stats(self, info: dict, width: int, height: int) -> None:
        """Accumulate the NDC-scaled screen-space gradient norm and the screen radius of the visible Gaussians."""
        means2d = info["means2d"]
        grad = means2d.grad
        if grad is None:
            return
        radii = info["radii"]
        if radii.dim() > 1:  # per-axis radii: the larger one
            radii = radii.max(dim=-1).values
        visible = radii > 0
        g = grad.detach().reshape(-1, 2).clone()
        g[:, 0] *= 0.5 * width
        g[:, 1] *= 0.5 * height
        norm = g.norm(dim=-1)
        self.grad_accum[visible] += norm[visible]
        self.count[visible] += 1
        frac = radii[visible].to(self.max_radii.dtype) / float(max(width, height))
        self.max_radii[visible] = torch.maximum(self.max_radii[visible], frac)

    @torch.no_grad()
    def step_post_backward(self, cfg: DensifyConfig, step: int, model: Gaussians, optimizer: torch.optim.Optimizer,
                           info: dict, width: int, height: int, generator: torch.Generator | None = None) -> dict:
        """Run this iteration's share of density control; returns counts {"cloned", "split", "pruned", "reset"}."""
        out = {"cloned": 0, "split": 0, "pruned": 0, "reset": False}
        if not cfg.enabled or step >= cfg.stop:
            return out
        if self.grad_accum.shape[0] != len(model):  # the model was replaced outside the strategy
            self._reset_stats(len(model))
        self.update_stats(info, width, height)
        if step > cfg.start and step % cfg.interval == 0:
            out.update(self.densify_and_prune(cfg, step, model, optimizer, generator))
        if cfg.reset_every > 0 and step % cfg.reset_every == 0:
            self.reset_opacity(cfg, model, optimizer)
            out["reset"] = True
        return out

    @torch.no_grad()
    def densify_and_prune(self, cfg: DensifyConfig, step: int, model: Gaussians, optimizer: torch.optim.Optimizer,
                          generator: torch.Generator | None = None) -> dict:
        n = len(model)
        avg = self.grad_accum / self.count.clamp_min(1.0)
        high = avg >= cfg.grad_threshold
        smax = model.scales.max(dim=1).values
        small = smax <= cfg.percent_dense * self.extent
        if cfg.max_gaussians is not None:
            budget = max(int(cfg.max_gaussians) - n, 0)  # a clone or a split each adds one Gaussian net
            if int(high.sum()) > budget:
                keep_idx = torch.topk(torch.where(high, avg, torch.full_like(avg, -1.0)), budget).indices
                high = torch.zeros_like(high)
                high[keep_idx] = True
        clone = high & small
        split = high & ~small
        n_clone, n_split = int(clone.sum()), int(split.sum())

        params = model.parameters()
        new: dict[str, torch.Tensor] = {k: v.detach()[clone] for k, v in params.items()}
        if n_split:
            scales = model.scales.detach()[split].repeat(2, 1)
            rot = quat_to_rotmat(model.quats.detach()[split]).repeat(2, 1, 1)
            noise = torch.randn(scales.shape, generator=generator, dtype=scales.dtype).to(scales.device)
            offsets = torch.einsum("nij,nj->ni", rot, noise * scales)
            split_new = {k: v.detach()[split].repeat(2, *([1] * (v.dim() - 1))) for k, v in params.items()}
            split_new["means"] = split_new["means"] + offsets
            split_new["log_scales"] = torch.log(scales / (0.8 * 2))
            new = {k: torch.cat([new[k], split_new[k]], dim=0) for k in new}
        added = n_clone + 2 * n_split
        if added:
            append_gaussians(model, optimizer, new)
        # originals of the split Gaussians go; the appended rows are new and never pruned for screen size
        remove = torch.cat([split, torch.zeros(added, dtype=torch.bool, device=split.device)])
        max_radii = torch.cat([self.max_radii, torch.zeros(added, device=self.device)])
        remove |= model.opacities.detach() < cfg.min_opacity
        if cfg.reset_every > 0 and step > cfg.reset_every:
            remove |= model.scales.detach().max(dim=1).values > cfg.prune_world * self.extent
            if cfg.prune_screen > 0:
                remove |= max_radii > cfg.prune_screen
        n_pruned = int(remove.sum()) - n_split
        if bool(remove.any()):
            keep_gaussians(model, optimizer, ~remove)
        self._reset_stats(len(model))
        return {"cloned": n_clone, "split": n_split, "pruned": n_pruned}

    @torch.no_grad()
    def reset_opacity(self, cfg: DensifyConfig, model: Gaussians, optimizer: torch.optim.Optimizer) -> None:
        """Clamp opacities to <= cfg.reset_opacity and zero their Adam moments."""
        cap = math.log(cfg.reset_opacity / (1.0 - cfg.reset_opacity))
        _edit_params(model, optimizer,
                     lambda n, p: p.clamp_max(cap) if n == "opacity_logits" else p,
                     lambda n, s: torch.zeros_like(s) if n == "opacity_logits" else s)
