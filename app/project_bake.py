"""Bake a project into one model: what ``splatstyler export --project`` writes and what the viewer shows.

Per model, in this order (each step is the one the viewer applies live, so the file is what was on screen):

1. read the model file (the stylized one, when there was a stylization) and, when the style strength is below 1
   anywhere, the original (unstylized) model it was stylized from; both must have the same rows;
2. style strength and colour adjustments on the SH coefficients (training/model/colour_edit.py), regions over
   the file's rows;
3. keep the rows the edits kept (deletions, crops), in the editor's order; hidden Gaussians are kept too (hiding
   is a view setting) unless ``drop_hidden``;
4. the model's transform, then the scene's (up axis and scale), both similarities: centres, rotations, scales and
   the SH bands, rotated (training/model/transform.py).

Several models are concatenated in the project's order; one with fewer SH bands is padded with zero bands.
"""

from __future__ import annotations

import numpy as np
import torch

from app.project import ModelEntry, Project
from training.core.errors import InputError
from training.model.gaussians import Gaussians, num_sh_coeffs
from training.model.transform import transform_gaussians


def model_problem(entry: ModelEntry) -> str | None:
    """The line saying why this model cannot be baked (a file missing or changed), or None."""
    refs = [(entry.file, "model")]
    if entry.colour.uses_original:
        refs.append((entry.original, "original model"))
    for ref, what in refs:
        if ref.missing:
            return f"{ref.path}: {what} of the project not found"
        if ref.changed:
            return f"{ref.path}: {what} changed since the project was saved (content hash differs); its edits " \
                   "refer to the rows it had"
    return None


def with_colour(g: Gaussians, original: Gaussians | None, entry: ModelEntry, name) -> Gaussians:
    """``g`` with the entry's style strength and colour adjustments baked into its SH."""
    edits = entry.colour
    if edits.is_identity:
        return g
    for region, _ in edits.adjustments + edits.strength_regions:
        if region is not None and len(region) != len(g):
            raise InputError(name, f"a colour region of model '{entry.name}' has {len(region)} rows; the model has "
                                   f"{len(g)}")
    original_sh = None
    if edits.uses_original:
        if len(original) != len(g) or original.sh_degree != g.sh_degree:
            raise InputError(entry.original.path, f"does not match the stylized model '{entry.name}' "
                                                  f"({len(original)} Gaussians of SH degree {original.sh_degree}, "
                                                  f"the stylized {len(g)} of degree {g.sh_degree})")
        original_sh = original.sh
    sh = edits.apply(g.sh, original_sh=original_sh)
    params = g.parameters()
    params["sh0"], params["shN"] = sh[:, :1].contiguous(), sh[:, 1:].contiguous()
    return Gaussians(**params, sh_degree=g.sh_degree)


def bake_model(project: Project, entry: ModelEntry, drop_hidden: bool = False) -> Gaussians:
    """One model of the project with its edits applied (module docstring: the order). InputError for a file
    missing or changed, or edits that do not fit the model."""
    problem = model_problem(entry)
    if problem is not None:
        raise InputError(None, problem)
    name = project.source
    g = project.open_model(entry.file)
    original = project.open_model(entry.original) if entry.colour.uses_original else None
    g = with_colour(g, original, entry, name)
    rows = entry.kept
    if rows is not None and len(rows) and rows.max() >= len(g):
        raise InputError(name, f"model '{entry.name}' keeps row {int(rows.max())}; it has {len(g)} Gaussians")
    if drop_hidden and entry.hidden is not None:
        rows = np.arange(len(g)) if rows is None else rows
        if len(entry.hidden) != len(rows):
            raise InputError(name, f"model '{entry.name}': {len(entry.hidden)} hidden flags for {len(rows)} rows")
        rows = rows[~entry.hidden]
    if rows is not None and not (len(rows) == len(g) and np.array_equal(rows, np.arange(len(g)))):
        g = g.subset(torch.as_tensor(rows, dtype=torch.long))
    return transform_gaussians(g, np.asarray(project.world) @ np.asarray(entry.transform))


def merge(models: list[Gaussians]) -> Gaussians:
    """The union of several models, in order; SH bands padded with zeros to the highest degree."""
    if len(models) == 1:
        return models[0]
    degree = max(g.sh_degree for g in models)
    k = num_sh_coeffs(degree) - 1
    parts = {name: [] for name in models[0].parameters()}
    for g in models:
        for name, value in g.parameters().items():
            if name == "shN" and value.shape[1] < k:
                value = torch.cat([value, value.new_zeros(len(g), k - value.shape[1], 3)], dim=1)
            parts[name].append(value)
    return Gaussians(**{name: torch.cat(values) for name, values in parts.items()}, sh_degree=degree)


def bake_project(project: Project, drop_hidden: bool = False) -> Gaussians:
    """Every model of the project baked and merged into one model."""
    if not project.models:
        raise InputError(project.source, "the project holds no model")
    return merge([bake_model(project, m, drop_hidden) for m in project.models])
