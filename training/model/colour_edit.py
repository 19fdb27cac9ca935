"""Colour adjustments and style strength on a model's SH coefficients, per region: what the viewer shows live and
what an export bakes (numpy; torch tensors accepted and given back as tensors).

**Colour adjustments.** Each of brightness, contrast, saturation, hue and temperature is an affine map of the
rendered base colour ``C = SH_C0 * dc + 0.5`` (RGB, before the renderer's clamp at 0): ``C' = M C + o``. One
``ColourAdjustment`` applies them in a fixed order, temperature, hue, saturation, contrast, brightness::

    temperature t   T = diag(1 + 0.2 t, 1, 1 - 0.2 t)                 (warmer: more red, less blue)
    hue h (deg)     H = rotation by h about the grey axis (1,1,1)/sqrt3 (Rodrigues): greys stay grey
    saturation s    S = (1 + s) I - s 1 w^T, w = Rec. 709 luma weights  (s = -1: grey at the same luma)
    contrast c      k = 1 + c, around mid-grey: C' = k (C - 0.5) + 0.5
    brightness b    C' = C + b

so ``M = k S H T`` and ``o = 0.5 (1 - k) + b`` (on every channel).

**Why the higher bands take M alone.** A Gaussian's colour seen along ``d`` is
``C(d) = SH_C0 dc + 0.5 + sum_k Y_k(d) c_k`` (k over degrees 1..3). Asking for ``C'(d) = M C(d) + o`` for every
``d`` and matching the constant and the ``Y_k`` terms (the basis functions are linearly independent) gives

    SH_C0 dc' + 0.5 = M (SH_C0 dc + 0.5) + o      ->   dc' = (M (SH_C0 dc + 0.5) + o - 0.5) / SH_C0
    c_k'            = M c_k                        (the view-dependent residual takes the linear part only)

which is exact for every view direction, not only for the DC colour. The one place it is not exact is the
renderer's clamp at 0: where ``M C(d) + o`` is negative the shown colour is 0, as it would be for any model.

**Regions.** An adjustment applies to a region, an (N,) bool mask over the model's rows, or to everything
(``None``); a list of them composes in order. Rows outside a region keep their coefficients bit for bit, and an
adjustment with identity parameters is skipped (an exact no-op, not a round trip through floating point).

**Style strength.** Per Gaussian ``s`` in [0, 1]: ``coeffs = original + s (stylized - original)`` on all SH
coefficients (0: the photo model, 1: the stylized one). Both ends are selected, not computed, so 0 gives the
original's values and 1 the stylized ones bit for bit. A global strength with regions that override it, later
regions over earlier ones, gives each Gaussian its ``s``. ``ColourEdits.apply`` blends first, then adjusts.

Arithmetic is in the coefficients' precision (float32 for models as read, float64 for float64 input).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Sequence

import numpy as np

from training.model.sh_constants import SH_C0

LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 weights: saturation keeps this luma
TEMPERATURE_GAIN = 0.2  # red and blue gains at temperature +-1

# Each parameter's useful span (low, high) and the rule a value must meet: what a slider offers and validate checks
RANGES: dict[str, tuple[float, float]] = {"brightness": (-1.0, 1.0), "contrast": (-1.0, 2.0),
                                          "saturation": (-1.0, 2.0), "hue": (-180.0, 180.0),
                                          "temperature": (-1.0, 1.0)}


@dataclass(frozen=True)
class ColourAdjustment:
    """Colour parameters, 0 each for no change (module docstring: the maps and their order)."""

    brightness: float = 0.0  # added to every channel of the rendered colour
    contrast: float = 0.0  # gain (1 + contrast) around mid-grey; -1 flattens to grey
    saturation: float = 0.0  # (1 + saturation) away from the luma grey; -1 is grey
    hue: float = 0.0  # degrees about the grey axis
    temperature: float = 0.0  # -1 cool .. 1 warm

    def validate(self) -> None:
        """ValueError naming the parameter for a value outside its range (or not a finite number)."""
        for f in fields(self):
            value = getattr(self, f.name)
            lo, hi = RANGES[f.name]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"{f.name} must be a finite number, got {value!r}")
            if not lo <= value <= hi:
                raise ValueError(f"{f.name} must be in [{lo:g}, {hi:g}], got {value:g}")

    @property
    def is_identity(self) -> bool:
        return all(getattr(self, f.name) == 0 for f in fields(self))

    def to_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}

    def affine(self) -> tuple[np.ndarray, np.ndarray]:
        """(M (3, 3), o (3,)) float64 with ``C' = M C + o`` on rendered RGB."""
        t = TEMPERATURE_GAIN * self.temperature
        temperature = np.diag([1.0 + t, 1.0, 1.0 - t])
        theta = math.radians(self.hue)
        u = np.full(3, 1.0 / math.sqrt(3.0))
        cross = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
        hue = math.cos(theta) * np.eye(3) + math.sin(theta) * cross + (1.0 - math.cos(theta)) * np.outer(u, u)
        s = self.saturation
        saturation = (1.0 + s) * np.eye(3) - s * np.outer(np.ones(3), LUMA)
        k = 1.0 + self.contrast
        m = k * saturation @ hue @ temperature
        o = np.full(3, 0.5 * (1.0 - k) + self.brightness)
        return m, o

    def on_colours(self, rgb: np.ndarray) -> np.ndarray:
        """The map on rendered colours (..., 3): the reference the SH transform is checked against."""
        m, o = self.affine()
        return np.asarray(rgb, np.float64) @ m.T + o


# --------------------------------------------------------------------------------------------- array plumbing
def _as_numpy(x):
    """(float64 numpy copy source, a function giving the result back in x's kind and dtype)."""
    try:
        import torch
    except ImportError:  # pragma: no cover  (the project always has torch; numpy callers need not)
        torch = None
    if torch is not None and isinstance(x, torch.Tensor):
        dtype, device = x.dtype, x.device
        return x.detach().cpu().numpy(), lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(device, dtype)
    x = np.asarray(x)
    return x, lambda a: a.astype(x.dtype, copy=False)


def _mask(region, n: int) -> np.ndarray | None:
    if region is None:
        return None
    m = np.asarray(region)
    if m.dtype != bool or m.shape != (n,):
        raise ValueError(f"a region must be an ({n},) bool mask, got {m.dtype} {m.shape}")
    return m


def adjust_sh(sh, adjustments: Sequence[tuple[object, ColourAdjustment]]):
    """``sh`` (N, K, 3), DC first, after each (region or None, adjustment) in order. Rows outside every region are
    bit for bit the input's; with no effective adjustment the input itself is returned."""
    work = [(r, a) for r, a in adjustments if not a.is_identity]
    if not work:
        return sh
    src, back = _as_numpy(sh)
    if src.ndim != 3 or src.shape[2] != 3:
        raise ValueError(f"SH coefficients must be (N, K, 3), got {src.shape}")
    # in the coefficients' own precision (float32 models: float32, a 2-D matrix product, 4x faster than float64)
    dtype = np.result_type(src.dtype, np.float32)
    out = src.astype(dtype, copy=True)
    for region, adj in work:
        adj.validate()
        m, o = adj.affine()
        mt, o = m.T.astype(dtype), o.astype(dtype)
        mask = _mask(region, len(out))
        rows = out if mask is None else out[mask]
        new = (rows.reshape(-1, 3) @ mt).reshape(rows.shape)  # every band: the linear part
        new[:, 0] = ((rows[:, 0] * dtype.type(SH_C0) + dtype.type(0.5)) @ mt + o - dtype.type(0.5)) \
            / dtype.type(SH_C0)
        if mask is None:
            out = new
        else:
            out[mask] = new
    return back(out.astype(src.dtype, copy=False))


def strength_per_gaussian(n: int, strength: float = 1.0, regions: Sequence[tuple[object, float]] = ()) -> np.ndarray:
    """(N,) float64: ``strength`` everywhere, then each (region, strength) over its rows, in order."""
    s = np.full(n, float(strength))
    for region, value in regions:
        mask = _mask(region, n)
        s[mask if mask is not None else slice(None)] = float(value)
    if not np.all((s >= 0) & (s <= 1)):
        raise ValueError("style strength must be in [0, 1]")
    return s


def blend_style(original, stylized, strength):
    """``original + s (stylized - original)`` per Gaussian (``strength`` a number or (N,)), on (N, K, 3) arrays or
    tensors; 0 selects the original's values and 1 the stylized ones exactly."""
    a, back = _as_numpy(stylized)
    b, _ = _as_numpy(original)
    if a.shape != b.shape:
        raise ValueError(f"the stylized and original models differ in shape: {a.shape} and {b.shape}")
    s = np.broadcast_to(np.asarray(strength, np.float64), (a.shape[0],))
    if np.all(s == 1):
        return stylized
    if np.all(s == 0):
        return back(b.copy())
    dtype = np.result_type(a.dtype, np.float32)
    w = s.astype(dtype)[:, None, None]
    out = b.astype(dtype) + w * (a.astype(dtype) - b)
    for end, values in ((0, b), (1, a)):  # the ends are the models' own values, not a round trip through the blend
        rows = s == end
        if rows.any():
            out[rows] = values[rows]
    return back(out.astype(a.dtype, copy=False))


# --------------------------------------------------------------------------------------------- one model's edits
@dataclass
class ColourEdits:
    """A model's colour edits, regions as (N,) bool masks over its rows as read from its file (rows stay valid
    through deletions; ``apply(rows=...)`` picks the ones still there)."""

    adjustments: list[tuple[np.ndarray | None, ColourAdjustment]] = field(default_factory=list)
    strength: float = 1.0  # style strength everywhere (1: the stylized model as trained)
    strength_regions: list[tuple[np.ndarray | None, float]] = field(default_factory=list)

    @property
    def uses_original(self) -> bool:
        """The edits blend towards the original (photo) model somewhere."""
        return self.strength != 1.0 or any(float(v) != 1.0 for _, v in self.strength_regions)

    @property
    def is_identity(self) -> bool:
        return not self.uses_original and all(a.is_identity for _, a in self.adjustments)

    def apply(self, sh, original_sh=None, rows=None):
        """The SH coefficients to show or write: ``sh`` (the stylized or only model's (M, K, 3)) blended with
        ``original_sh`` (same shape) by the style strength, then colour-adjusted. ``rows`` (M,) are the file rows
        ``sh``'s rows are (the viewer editor's ``index``); None: all of them, in order. Returns ``sh`` itself when
        nothing changes."""
        if self.is_identity:
            return sh
        n = len(sh)
        total = n if rows is None else None
        pick = (lambda m: m) if rows is None else (lambda m: None if m is None else np.asarray(m)[rows])
        if total is None:
            lengths = {len(m) for m, _ in self.adjustments + self.strength_regions if m is not None}
            if len(lengths) > 1:
                raise ValueError("the regions of one model differ in length")
            total = lengths.pop() if lengths else int(np.max(rows)) + 1 if len(rows) else 0
        out = sh
        if self.uses_original:
            if original_sh is None:
                raise ValueError("style strength below 1 needs the original (unstylized) model")
            s = strength_per_gaussian(total, self.strength, self.strength_regions)
            out = blend_style(original_sh, out, s if rows is None else s[np.asarray(rows)])
        return adjust_sh(out, [(pick(m), a) for m, a in self.adjustments])
