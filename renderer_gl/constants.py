"""The numbers renderer_gl shares with the training rasterizer, so that both draw the same picture: read from the
engine's torch-free constant modules (one source of defaults), never redefined here."""

from training.model.sh_constants import SH_C0, SH_C1, SH_C2, SH_C3
from training.raster.constants import ALPHA_MAX, ALPHA_MIN, EPS2D, FAR_PLANE, FOV_CLAMP_MARGIN, NEAR_PLANE, T_MIN

__all__ = ["ALPHA_MAX", "ALPHA_MIN", "EPS2D", "FAR_PLANE", "FOV_CLAMP_MARGIN", "NEAR_PLANE", "SH_C0", "SH_C1",
           "SH_C2", "SH_C3", "T_MIN"]
