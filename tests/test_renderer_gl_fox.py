"""renderer_gl against the training rasterizer on a real reconstruction: the fox from ../shared, reconstructed
here for a few steps at 1/16 resolution (no reconstruction is stored), rendered from its held-out cameras."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.gl_scenes import psnr, reference_render

FOX = Path(__file__).resolve().parents[2] / "shared" / "data" / "scenes" / "fox"


@pytest.mark.slow
@pytest.mark.skipif(not FOX.is_dir(), reason="needs ../shared/data/scenes/fox")
def test_fox_reconstruction_matches_the_training_rasterizer():
    from renderer_gl import SplatRenderer, create_context, orbit, view
    from training.reconstruct.trainer import ReconstructConfig, Reconstructor
    from training.scene.loader import load_scene

    scene = load_scene(FOX, downscale=16)
    cfg = ReconstructConfig.from_preset("quick", depth="none", random_init_points=4000, seed=0)
    # Densify early so the model holds split and cloned Gaussians, not only its random start (about 15 s on 2 quiet cores).
    cfg = replace(cfg, iterations=120, densify=replace(cfg.densify, start=40, interval=40, stop=110))
    rec = Reconstructor(scene, cfg)
    for _ in range(cfg.iterations):
        rec.step()
    snap = rec.snapshot()
    arrays = (snap.means, snap.scales, snap.quats, snap.opacities, snap.sh)
    assert len(snap) > 4000  # densification ran

    ctx = create_context("egl")
    r = SplatRenderer(ctx)
    r.set_splats(*arrays, snap.sh_degree)
    r2 = SplatRenderer(ctx, accum_dtype="f2")  # the format a GPU blends at full rate (docs/gpu.md)
    r2.set_splats(*arrays, snap.sh_degree)
    cams = [scene.cameras[i].scaled(2.0) for i in scene.test_indices[:2]]
    # and one view no training camera saw, from further out
    c = scene.cameras[0]
    w2c = orbit(np.asarray(scene.center), 1.5 * float(scene.extent), 8, up=-c.world_to_camera[1, :3],
                start=c.center - np.asarray(scene.center))[3]
    cams.append(view(world_to_camera=w2c, K=c.scaled(2.0).K, width=c.width * 2, height=c.height * 2))
    try:
        for cam in cams:
            out = r.render_arrays(cam, ("rgb",), background=(0.0, 0.0, 0.0))["rgb"]
            ref, ref_alpha = reference_render(*arrays, snap.sh_degree, cam.world_to_camera, cam.K, cam.width,
                                              cam.height, background=(0.0, 0.0, 0.0))
            assert ref_alpha.mean() > 0.1  # the view sees the model
            value = psnr(out, ref)
            print(f"{cam.width}x{cam.height}: {value:.1f} dB")
            assert value >= 35.0
            half = r2.render_arrays(cam, ("rgb",), background=(0.0, 0.0, 0.0))["rgb"]
            print(f"  f2: {psnr(half, ref):.1f} dB against the rasterizer, {psnr(half, out):.1f} dB against f4")
            assert psnr(half, ref) >= 40.0 and psnr(half, out) >= 40.0  # 46 dB measured
    finally:
        r.release()
        r2.release()
        ctx.release()
