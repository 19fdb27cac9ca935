"""Reconstruction: the 3DGS trainer (``trainer.Reconstructor``, its settings ``config.ReconstructConfig``) with the
paper's depth, shape and size regularizers, adaptive density control as a strategy object, depth targets,
SSIM/PSNR, and checkpoints.

May import ``training.core``, ``training.scene``, ``training.model`` and ``training.raster``.
"""
