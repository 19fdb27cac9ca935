"""Evaluation metrics of a stylized scene (GitHub issue 13, "Metrics"; formulas in docs/evaluation.md).

- ``consistency``: multi-view consistency by depth warping of one stylized render into another view (RMSE, masked
  LPIPS-VGG, valid fraction), short range (neighbouring views of the trajectory) and long range (7 apart);
- ``style_metrics``: Gram and sliced Wasserstein distances between VGG-16 features of renders and of the painting;
- ``content_metrics``: self-similarity structure distance (VGG-16) and blurred-luminance PSNR against the original;
- ``baseline_2d``: the deliberately inconsistent reference, every view stylized on its own in 2D;
- ``measure``: the entry points (``measure_images``, ``measure_stylizer``, ``summary_line``);
- ``vgg_taps``: VGG-16 relu1_1 .. relu4_1 from the offline LPIPS weights.

Layering: this package may import training.core, scene, model, raster, reconstruct and stylize; nothing imports
it from below, and it takes nothing from app or renderer_gl (tests/test_import_layers.py).
"""
