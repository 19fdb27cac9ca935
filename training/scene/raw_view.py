"""A view as a scene file describes it, before its image is resolved: file name, pose and lens (with distortion).

Both scene formats (COLMAP models and transforms.json) read into this; ``scene_loader`` then finds the image,
applies ``--downscale`` and removes the distortion, producing pinhole ``Camera`` objects.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class RawView:
    name: str  # image path relative to the scene's image folder (may contain sub-folders)
    world_to_camera: np.ndarray  # (4, 4) float64, OpenCV convention
    lens: object  # pycolmap.Camera: model, distortion and intrinsics for an image of lens.width x lens.height


def copy_lens(lens):
    """An independent copy of a pycolmap.Camera (rescale and friends modify in place)."""
    import pycolmap

    return pycolmap.Camera(model=lens.model, width=lens.width, height=lens.height, params=list(lens.params))
