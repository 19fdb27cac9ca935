"""Virtual cameras between consecutive views, so that sparse captures still give the guidance overlapping views.

The paper (supplementary, view order) names camera interpolation as the remedy for sparse or irregular trajectories.
Between two consecutive cameras of the stylization order we insert N cameras (training/scene/pose.py's
``interpolate_camera``): rotation by slerp of the camera-to-world rotations, centre by linear interpolation,
intrinsics (and image size) by linear interpolation. A virtual view has no photo; its content target is the scene
rendered before stylization.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from training.scene.pose import interpolate_camera
from training.scene.scene import Camera


@dataclass
class ViewItem:
    """One entry of the stylization trajectory: a camera and, for a real view, the index of its photo."""

    camera: Camera
    source_index: int | None  # index into Scene.cameras/images; None for a virtual view

    @property
    def is_virtual(self) -> bool:
        return self.source_index is None


def trajectory(cameras: Sequence[Camera], order: Sequence[int], virtual_views: int = 0) -> list[ViewItem]:
    """The views in ``order`` with ``virtual_views`` interpolated cameras between each consecutive pair."""
    items: list[ViewItem] = []
    for pos, idx in enumerate(order):
        items.append(ViewItem(cameras[idx], int(idx)))
        if virtual_views > 0 and pos + 1 < len(order):
            nxt = order[pos + 1]
            for k in range(1, virtual_views + 1):
                t = k / (virtual_views + 1)
                cam = interpolate_camera(cameras[idx], cameras[nxt], t,
                                         name=f"virtual_{idx:04d}_{int(nxt):04d}_{k}")
                items.append(ViewItem(cam, None))
    return items
