"""How far a stylization moved the Gaussians' colours, per SH coefficient: the DC term (one colour for every view)
and the bands above 0 (the view-dependent part). With the geometry fixed, the bands above 0 are the only way a
colour-only stylization can make two views of the same Gaussian disagree, so their change bounds what cross-view
guidance and view order can act on (docs/RESULTS.md, issue 22). Both colour transfers (pre and post, linear maps of
every band) are part of the change: a DC-only run's band change is theirs alone.
"""

from __future__ import annotations

from training.model.gaussians import Gaussians


def colour_shift(before: Gaussians, after: Gaussians) -> dict[str, float]:
    """Mean absolute change of the DC coefficients (``dc_shift``) and of the coefficients of the bands above 0
    (``shn_shift``), with the bands' mean size before (``shn_size``), in SH units; {} when the two models do not
    pair row for row (another number of Gaussians or SH degree)."""
    if len(before) != len(after) or before.sh_degree != after.sh_degree:
        return {}
    out = {"dc_shift": float((after.sh0 - before.sh0).abs().mean())}
    if before.shN.numel():
        out["shn_shift"] = float((after.shN - before.shN).abs().mean())
        out["shn_size"] = float(before.shN.abs().mean())
    return out
