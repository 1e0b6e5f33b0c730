"""Disk orders that every head of a layout sees alike (no ``theta_ref``): the head
differences cannot determine them, so the base holds them and no view or profile tests
them (the multihead kind's base and views, the ``order_step`` zero profile)."""

from __future__ import annotations

import numpy as np

from ...engine._protocol import Prepared


def _pattern_spread(alpha: np.ndarray, m: int) -> float:
    """Mean square over the heads of the head pattern ``exp(-i m alpha_k)`` about its mean
    (0: every head sees order ``m`` alike; 1: it cancels in the heads' mean)."""
    v = np.exp(-1j * m * alpha)
    return float(np.sum(np.abs(v - v.mean()) ** 2) / alpha.size)


def _symmetric_orders(prep: Prepared, M: int, limit: float | None = None) -> list[int]:
    """Without ``theta_ref`` (and more than one head): the disk orders 1..M whose head
    pattern varies over the heads by at most ``limit`` (mean square; default
    ``FinderSettings.symmetric_order_max``: exactly alike, up to the rounding of the
    azimuths): the head differences cannot determine them (multiples of the symmetry of
    equally spaced heads). Empty with a reference or one head."""
    if prep.ctx.has_ref or prep.n_channels < 2:
        return []
    lim = prep.settings.symmetric_order_max if limit is None else limit
    alpha = np.asarray(prep.consts["alpha"], float)
    return [m for m in range(1, M + 1) if _pattern_spread(alpha, m) <= lim]
