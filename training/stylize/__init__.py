"""Stylization after a painting: the trainer (``trainer.Stylizer``), the paper's defaults (``defaults``), the CCFT
loss and its Sinkhorn, the NNFM and Gram baselines, VGG-16 features and where their weights come from, colour
transfer, view order and virtual views, and the painting's checks. ``pipeline`` runs the whole stage for the CLI.

May import ``training.core``, ``training.scene``, ``training.model``, ``training.raster`` and
``training.reconstruct`` (PSNR and views for reports).
"""
