"""Spatial style control: stylize only a selection of the Gaussians (a boolean mask), leave the rest bit-identical.

The Stylizer holds the mask; this module has the pieces that make "bit-identical" hold through every path that
touches colours (and, with ``params="all"``, geometry): the optimiser (gradients of unselected Gaussians are zeroed
and, after each Adam step, their trained parameters are copied back from a frozen copy, since Adam's momentum could
still move them after a mask change) and the pre/post colour transfer (applied with ``torch.where`` so unselected
rows keep their exact bits, and fitted on the pixels the selection covers rather than the whole image, so the
transfer suits the region it is applied to).

Which pixels the selection covers comes from a render of the model with every selected Gaussian white and every
other black: with the alpha-blending weights w_i of a pixel, that render is sum_i w_i [i selected], the share of
the pixel's colour that comes from the selection (0..1).
"""

from __future__ import annotations

import numpy as np
import torch

from training.core.errors import InputError
from training.model.gaussians import Gaussians, rgb_to_sh0

MIN_FIT_PIXELS = 64  # a colour transfer fitted on fewer covered pixels than this is noise; fit on all of them
COVER_THRESHOLD = 0.5  # a pixel belongs to the selection when at least half its colour comes from it


def as_mask(mask, n: int, name=None) -> torch.Tensor | None:
    """(N,) bool CPU tensor from a numpy/torch/list mask, or None when it selects everything (no masking needed).

    InputError naming ``name`` (the model) when the length is wrong or the mask is not boolean."""
    if mask is None:
        return None
    m = mask.detach().cpu() if isinstance(mask, torch.Tensor) else torch.from_numpy(np.asarray(mask))
    if m.dtype != torch.bool:
        raise InputError(name, f"the selection mask must be boolean, got {m.dtype}")
    if m.shape != (n,):
        raise InputError(name, f"the selection mask has shape {tuple(m.shape)}; the model has {n} Gaussians")
    return None if bool(m.all()) else m.clone()


def keep_unselected(new: Gaussians, old: Gaussians, mask: torch.Tensor | None) -> Gaussians:
    """``new``'s colours for the selected Gaussians, ``old``'s exact values for the others; geometry from ``new``."""
    if mask is None:
        return new
    m = mask.to(new.device)[:, None, None]
    sh0 = torch.where(m, new.sh0, old.sh0.to(new.sh0.dtype))
    shN = torch.where(m, new.shN, old.shN.to(new.shN.dtype))
    return Gaussians(means=new.means, log_scales=new.log_scales, quats=new.quats, opacity_logits=new.opacity_logits,
                     sh0=sh0.contiguous(), shN=shN.contiguous(), sh_degree=new.sh_degree)


def indicator_sh(mask: torch.Tensor, sh_degree: int, device, dtype) -> torch.Tensor:
    """(N, K, 3) SH colours: white for selected, black for the others, no view dependence."""
    k = (sh_degree + 1) ** 2
    sh = torch.zeros((len(mask), k, 3), dtype=dtype, device=device)
    sh[:, 0, :] = rgb_to_sh0(mask.to(device=device, dtype=dtype))[:, None]
    return sh


def coverage_from_render(image: np.ndarray, alpha: np.ndarray, background) -> np.ndarray:
    """(H, W) share of each pixel's colour that comes from the selection, from the indicator render.

    The render is sum_i w_i c_i + (1 - alpha) * background; the background's part is taken off."""
    return np.clip(image[..., 0] - float(background[0]) * (1.0 - alpha[..., 0]), 0.0, 1.0)


def covered_pixels(images: list[np.ndarray], coverages: list[np.ndarray], alphas: list[np.ndarray] | None = None
                   ) -> list[np.ndarray]:
    """(P, 3) colours of the pixels the selection covers in each image (un-premultiplied by ``alphas`` when given,
    as renders over a black background are); all pixels of every image when too few are covered in all."""
    out = []
    for i, (img, cov) in enumerate(zip(images, coverages)):
        keep = cov >= COVER_THRESHOLD
        if alphas is not None:
            a = alphas[i][..., 0]
            keep &= a >= COVER_THRESHOLD
            out.append(img[keep] / a[keep, None])
        else:
            out.append(img[keep])
    if sum(len(p) for p in out) >= MIN_FIT_PIXELS:
        return out
    if alphas is not None:
        return [img[a[..., 0] >= COVER_THRESHOLD] / a[a[..., 0] >= COVER_THRESHOLD][:, None]
                for img, a in zip(images, alphas)]
    return [img.reshape(-1, 3) for img in images]


def blend_content(original: np.ndarray, transferred: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    """The content image of a masked run: the colour-transferred photo where the selection shows, the photo
    elsewhere (the unselected Gaussians keep their colours, so their content target should too)."""
    w = coverage[..., None].astype(np.float32)
    return (w * transferred + (1.0 - w) * original).astype(np.float32)


def masked_step(optimizer: torch.optim.Optimizer, g: Gaussians, mask: torch.Tensor | None, frozen: Gaussians) -> None:
    """The Adam step with the selection honoured: no gradient reaches the unselected Gaussians, and their trained
    parameters are copied back from ``frozen`` afterwards (momentum from before a mask change could still move them;
    the copy is what makes them bit-identical). Trained: the colours always, the geometry (means, log_scales, quats,
    opacity_logits) when its tensors require gradients (``params="all"``); untrained geometry is never written."""
    if mask is None:
        optimizer.step()
        return
    off = ~mask.to(g.sh0.device)
    names = [name for name, p in g.parameters().items() if name in ("sh0", "shN") or p.requires_grad]
    for name in names:
        p = getattr(g, name)
        if p.grad is not None:
            p.grad[off] = 0
    optimizer.step()
    with torch.no_grad():
        for name in names:
            p = getattr(g, name)
            p[off] = getattr(frozen, name)[off].to(p.device)



def transfer_to_selection(gaussians: Gaussians, transform, mask: torch.Tensor | None) -> Gaussians:
    """The model with the colours of ``mask``'s Gaussians (None: all) moved by the colour map ``transform``."""
    from training.stylize.color_transfer import apply_to_gaussians

    return keep_unselected(apply_to_gaussians(gaussians, transform), gaussians, mask)


def pre_color_transfer(content_images: list[np.ndarray], style_image: np.ndarray, cover: list[np.ndarray] | None):
    """ARF's pre colour transfer of a run (``cover``: the selection's per-view coverage, None when every Gaussian is
    stylized): (the map fitted from the content images, where the selection shows, to the painting; the content
    images moved by it there)."""
    from training.stylize.color_transfer import apply_to_image, fit_color_transfer

    transform = fit_color_transfer(content_images if cover is None else covered_pixels(content_images, cover),
                                   style_image.reshape(-1, 3))
    moved = [apply_to_image(img, transform) for img in content_images]
    if cover is not None:
        moved = [blend_content(img, new, c) for img, new, c in zip(content_images, moved, cover)]
    return transform, moved


def post_color_transfer(renders: list[tuple[np.ndarray, np.ndarray]], style_image: np.ndarray,
                        cover: list[np.ndarray] | None):
    """ARF's post colour transfer's map, fitted from the stylized ``renders`` (image, alpha), where the selection
    shows (``cover`` as for ``pre_color_transfer``), to the painting; None when no pixel is covered."""
    from training.stylize.color_transfer import fit_color_transfer, foreground_pixels

    if cover is None:
        pixels = [foreground_pixels(img, a) for img, a in renders]
    else:
        pixels = covered_pixels([img for img, _ in renders], cover, [a for _, a in renders])
    pixels = [p for p in pixels if len(p)]
    return fit_color_transfer(pixels, style_image.reshape(-1, 3)) if pixels else None
