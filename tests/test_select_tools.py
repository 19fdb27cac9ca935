"""The selection tools' geometry on the demo scene's model, without a window: the weights colour pick chooses by
are the renderer's compositing (their sum is the rendered alpha and their colour mix the rendered colour at each
pixel tried), and the surface test keeps the centres at the rendered depth."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from app.render_inputs import load_model_arrays
from app.viewer.edit import select_tools as st
from renderer_gl import SplatRenderer, create_context
from tests.viewer_harness import make_demo_scene


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    from training.scene.loader import load_scene

    scene_dir, _, model = make_demo_scene(tmp_path_factory)
    arrays = load_model_arrays(model)
    camera = load_scene(scene_dir, load_images=False).cameras[5]
    ctx = create_context()
    try:
        renderer = SplatRenderer(ctx, sort_tolerance_deg=0.0)
        renderer.set_splats(*arrays)
        out = renderer.render_arrays(camera, ("rgb", "alpha", "depth"), max_sh_degree=0)
    finally:
        ctx.release()
    means, scales, quats, opacities, sh, _ = arrays
    return SimpleNamespace(means=means, scales=scales, quats=quats, opacities=opacities, sh=sh), camera, out


def test_pick_weights_are_the_renderers_compositing(rendered):
    model, camera, out = rendered
    colours = st.base_colours(model.sh)
    rng = np.random.default_rng(0)
    for x, y in zip(rng.integers(0, camera.width, 12), rng.integers(0, camera.height, 12)):
        w = st.weights_at(model, camera, x + 0.5, y + 0.5)  # the pixel's centre
        assert w.sum() == pytest.approx(out["alpha"][y, x], abs=2e-3)
        assert np.allclose(w @ colours, out["rgb"][y, x], atol=3e-3)
        if out["alpha"][y, x] > 0.5:
            assert st.pick(model, camera, x + 0.5, y + 0.5) == int(np.argmax(w))


def test_the_surface_test_keeps_the_front_layer(rendered):
    model, camera, out = rendered
    depth = out["depth"]
    on = st.on_surface(model.means, camera, depth, 0.1)
    z = st.camera_depths(model.means, camera)
    assert 0 < on.sum() < len(z)
    uv, front = camera.project(model.means)
    inside = front & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    px, py = np.floor(uv[inside]).astype(int).T
    ratio = z[inside] / np.where(depth[py, px] > 0, depth[py, px], np.nan)
    kept = on[inside]
    assert np.all(np.abs(ratio[kept] - 1) <= 0.1 + 1e-9)
    assert np.nanmedian(ratio[~kept]) > 1.1  # what it leaves out lies behind the drawn surface
