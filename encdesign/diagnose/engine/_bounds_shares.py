"""Rules 4 and 5 of the detection bounds (:mod:`._bounds`): the share of the structure at
the places an effect's own error is located that is its own, and what its signature views
keep, beside the final residual's findings; the smallest size that passes them."""

from __future__ import annotations

import math

import numpy as np

from ._select import _reaches
from ._views import locate

VIEW_DOUBLINGS = 12
"""Doublings of the size beyond the criterion's before a view is called blind to it."""


def _own_shares(prep, resid, views, scan, a: float, sig: set[str], ref) -> tuple[float, float]:
    """``(share, left)`` of rules 4 and 5 for the effect at size ``a`` (``resid`` its
    noise-free unit residual) beside the final findings ``ref``: at each place its own error
    is located, weighted by its power there, the share of the structure there that is its
    own (what its fit clears), and in its signature views the share it leaves (a place where
    the final findings keep ``untouched_share`` or more is another effect's and set aside):
    the rules of stage 4 (``_select.own_share``) on a record that holds it and that structure."""
    s = prep.settings
    num = den = num_s = den_s = 0.0
    for g in locate(prep, resid, views, scan, scale=a, reuse=True):
        w = float(g.power)
        if w <= 0:
            continue
        other = sum(max(float(f.power) - float(f.dof), 0.0) for f in ref if _reaches(f, (g,)))
        num += w * w / (w + other)
        den += w
        if g.view in sig and other < s.untouched_share * (w + other):
            num_s += w * other / (w + other)
            den_s += w
    return (num / den if den > 0 else 0.0), (num_s / den_s if den_s > 0 else 0.0)


def _share_size(prep, resid, views, scan, a0: float, sig: set[str], ref):
    """``(size, i)``: the smallest size from ``a0`` up at which the effect passes rules 4 and
    5 of the module doc beside the final findings ``ref`` (:func:`_own_shares`), and the
    index of the rule that asked most at ``a0``: its share grows with the size squared while
    the structure beside it dominates, so a few rescalings reach it; ``(None, i)`` when no
    view locates it within :data:`VIEW_DOUBLINGS` doublings."""
    s = prep.settings
    sh, sl = s.located_share_min, s.signature_left_max
    a, first = a0, None
    for _ in range(VIEW_DOUBLINGS):
        share, left = _own_shares(prep, resid, views, scan, a, sig, ref)
        ratios = [
            sh / share if share > 0 else math.inf,
            left / sl if sl > 0 else (math.inf if left > 0 else 0.0),
        ]
        if first is None:
            first = int(np.argmax(ratios))
        worst = max(ratios)
        if worst <= 1 + SHARE_TOL:
            return a, first
        a *= 2.0 if not math.isfinite(worst) else math.sqrt(worst)
    return None, first or 0


SHARE_TOL = 0.02
"""Relative shortfall of the located excess accepted when rescaling to the share rules'
size (the power is quadratic in the size: about 1 % of the size)."""
