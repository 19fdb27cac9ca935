"""The deliberately inconsistent reference: every view stylized on its own, in 2D, as a per-view image method would.

Each image's pixels are optimised directly (Adam) against the painting with the stylizer's own losses: the style
loss (CCFT by default, ``training.stylize.style_losses``) on VGG-16 relu3 features of the image and of the painting
(resized to the stylizer's stroke size, its long side ``style_scale`` times the image's, both halved as the stylizer
does) weighted by the stylizer's lambda_style, plus lambda_content times the stylizer's content term
(``training.stylize.objective``) to the features of the image before stylization. A fresh loss, so a
fresh CCFT guide, for every view: nothing ties one view's stylization to another's. Optionally (default on) the
images first get the stylizer's pre colour transfer, one linear map fitted to all of them pooled, so that the
colour statistics start where the 3D stylizer's do and the only difference is the per-view optimisation.

Cost: ``iters`` VGG forward/backward passes (and CCFT's transport) per view; 60 iterations at 256 x 192 took
5.2 s per view on this machine's 2 shared CPU cores (20 views: 105 s).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

DEFAULT_ITERS = 60
DEFAULT_PIXEL_LR = 0.005  # Adam on pixel values in [0, 1]; 0.02 (the stylizer's SH rate) inflates contrast into noise


def stylize_images_independently(images: Sequence[np.ndarray], painting: np.ndarray, iters: int = DEFAULT_ITERS,
                                 loss: str = "ccft", vgg=None, lr: float = DEFAULT_PIXEL_LR,
                                 lambda_style: float | None = None, lambda_content: float | None = None,
                                 color_transfer: bool = True, device: str | torch.device = "cpu",
                                 cancel=None) -> list[np.ndarray]:
    """Stylize each (H, W, 3) image in [0, 1] independently toward ``painting``; returns float32 (H, W, 3) images.

    ``vgg``: a ``training.stylize.vgg_features.VGGFeatures`` (loaded when None); ``lambda_style`` and
    ``lambda_content`` default to the stylizer's (``StylizeConfig``); ``cancel()`` is asked before each view."""
    from training.core.messages import check_cancel
    from training.stylize.color_transfer import apply_to_image, fit_color_transfer
    from training.stylize.config import StylizeConfig
    from training.stylize.objective import content_loss
    from training.stylize.style_image import check_style_array, halve, painting_side, style_for_render
    from training.stylize.style_losses import make_style_loss

    painting = check_style_array(painting)
    cfg = StylizeConfig(loss=loss)
    cfg.validate()
    w_style = cfg.style_weight if lambda_style is None else float(lambda_style)
    w_content = cfg.lambda_content if lambda_content is None else float(lambda_content)
    device = torch.device(device)
    if vgg is None:
        from training.stylize.vgg_features import load_vgg16_features

        vgg = load_vgg16_features()
    vgg = vgg.to(device)
    images = [np.clip(np.asarray(img, dtype=np.float32)[..., :3], 0, 1) for img in images]
    if color_transfer and images:
        transform = fit_color_transfer(images, painting.reshape(-1, 3))
        images = [apply_to_image(img, transform) for img in images]

    style_cache: dict[int, torch.Tensor] = {}
    out = []
    for image in images:
        check_cancel(cancel)
        h, w = image.shape[:2]
        side = max(h, w)
        if side not in style_cache:
            with torch.no_grad():
                style_cache[side] = vgg(halve(style_for_render(painting, painting_side(side, cfg.style_scale))
                                              .to(device)))
        style = style_cache[side]
        start = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)[None].to(device)
        with torch.no_grad():
            content = vgg(halve(start))
        style_loss = make_style_loss(loss)  # a fresh guide for every view
        x = start.clone().requires_grad_(True)
        opt = torch.optim.Adam([x], lr=lr)
        for _ in range(int(iters)):
            feats = vgg(halve(x))
            s_loss, _ = style_loss(feats, style)
            total = w_style * s_loss + w_content * content_loss(feats, content, cfg.content_norm)
            opt.zero_grad(set_to_none=True)
            total.backward()
            opt.step()
            with torch.no_grad():
                x.clamp_(0, 1)
        out.append(x.detach()[0].permute(1, 2, 0).cpu().numpy().astype(np.float32))
    return out
