"""The gradient balance the progress line, the report and the Training tab show: measured or not, the step's gradient
is the same, and the measured norms are those of each term's own gradient on the render."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from training.stylize.objective import content_loss, render_gradients, total_variation

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
PHOTO = SHARED / "scenes" / "fox" / "images_8" / "0001.jpg"
PAINTING = SHARED / "styles" / "starry_night.jpg"


def _image(path: Path, size: tuple[int, int]) -> torch.Tensor:
    if not path.exists():
        pytest.skip(f"{path} is not beside this checkout")
    img = Image.open(path).convert("RGB").resize(size, Image.BICUBIC)
    return torch.from_numpy(np.asarray(img, dtype=np.float32) / 255.0)


def _terms(render: torch.Tensor, vgg, content_img: torch.Tensor, painting: torch.Tensor) -> dict:
    feats = vgg(render.permute(2, 0, 1)[None])
    with torch.no_grad():
        content = vgg(content_img.permute(2, 0, 1)[None])
        style = vgg(painting.permute(2, 0, 1)[None]).flatten(2)[0]
    # a style term through the same features: each rendered feature's cosine distance to its nearest painting one
    f = torch.nn.functional.normalize(feats.flatten(2)[0], dim=0)
    s = torch.nn.functional.normalize(style, dim=0)
    style_term = (1 - (f.T @ s).max(dim=1).values).mean()
    return {"style": 30 * style_term, "content": 8 * content_loss(feats, content, "relative"),
            "tv": 40 * total_variation(render)}


def test_measuring_the_balance_leaves_the_gradient_alone_and_measures_each_term(vgg):
    photo = _image(PHOTO, (128, 72))
    painting = _image(PAINTING, (128, 100))
    # a render some way from the photo: the photo darkened with noise (the content term has a gradient)
    render0 = (0.6 * photo + 0.1 * torch.rand(photo.shape, generator=torch.Generator().manual_seed(0))).clamp(0, 1)

    def gradients(measure: bool):
        render = render0.clone().requires_grad_(True)
        return render, _terms(render, vgg, photo, painting), measure

    render, terms, _ = gradients(False)
    plain = render_gradients(render, terms, False)
    assert plain.style_norm is None and plain.content_to_style is None
    render, terms, _ = gradients(True)
    measured = render_gradients(render, terms, True)
    # the step's gradient does not depend on whether (or how often) the balance is measured
    assert torch.equal(plain.total, measured.total)

    # each norm against that term's gradient taken alone
    alone = {}
    for name in ("style", "content", "tv"):
        render, terms, _ = gradients(True)
        (alone[name],) = torch.autograd.grad(terms[name], render)
    assert measured.style_norm == pytest.approx(float(alone["style"].norm()), rel=1e-4)
    assert measured.content_norm == pytest.approx(float(alone["content"].norm()), rel=1e-6)
    assert measured.tv_norm == pytest.approx(float(alone["tv"].norm()), rel=1e-6)
    assert float((measured.total - sum(alone.values())).norm()) <= 1e-5 * float(measured.total.norm())
    assert 0 < measured.content_to_style < np.inf
