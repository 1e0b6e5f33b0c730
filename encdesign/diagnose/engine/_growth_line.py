"""Issue 44: the signal-period line beside the orders the base's growth would add.

A base kept below a disk's highest order leaves the missing orders in its residual; seen
through the phase within one signal period (the ``line_phase`` view) they leak into a line
that can hold a few percent of what every view located. A real line at the signal period
(``interpolation_error``), aliased, can pose as integer orders instead. The two are told
apart by fitting them jointly, per channel, on the whitened residual of the base: harmonics
1 and 2 of the phase ``psi`` within a signal period (the view's four columns) and cos / sin of
every order the growth would add (``theta``, rotation locked over all runs), and beside both
the base's own orders ``1 .. order`` (refitted there: the grown base refits them too). The
line that stays significant beside those orders (at the view's own threshold, ``alpha`` over
the channels) is real and vetoes the growth; where it does not, the growth goes on when the
added orders stay significant beside the line and the base's own orders (``alpha`` over the
channels, ``2 k`` degrees of freedom for ``k`` orders).

The base's own orders are in the joint fit since session 37: in a sparse record the missing
orders alias onto the base's own, whose fitted coefficients then hold part of them, and the
residual's remainder of that part (not a shaft order once the base took its share) leaked into
the line's four columns, which kept the line significant beside the added orders alone
(training seed 6713 record 5 of ``benchmarks/finder_variations.py --set high``, clean, 4
heads, about 6 samples per turn, disk orders 1-17: line chi-square 59.5 beside orders 13-24
at a 21.5 threshold, 0.7 beside orders 1-24; the growth vetoed and a false ``vibration``
named).
"""

from __future__ import annotations

import numpy as np

from ._views import _blocks, _col, chi2_threshold
from ._views_sums import Whitened


def _power(G: np.ndarray, B: np.ndarray, idx: np.ndarray) -> float:
    """Chi-square the columns ``idx`` of Gram ``G`` take out of a channel with sums ``B``."""
    g, b = G[np.ix_(idx, idx)], B[idx]
    coef = np.linalg.lstsq(g, b, rcond=None)[0]
    return float(max(b @ coef, 0.0))


def line_beside_orders(
    prep, resid: np.ndarray, orders: list[int], held: list[int] | None = None
) -> dict:
    """The joint fit of the signal-period line (harmonics 1 and 2 of ``psi``) and the integer
    shaft ``orders`` on the base residual ``resid`` (n, C), whitened by the noise, beside the
    integer orders ``held`` (the base's own, refitted in every fit: neither group's).

    Returns ``{"orders", "held_orders", "line_chi2", "orders_chi2", "line_threshold",
    "orders_threshold", "line_significant", "orders_significant"}``: per channel, the largest
    chi-square each group takes beyond the other and the held orders (dimensionless), the
    thresholds, and whether each exceeds its own."""
    rw = Whitened(resid, prep.sigma)
    C = rw.shape[1]
    m = np.asarray(sorted(set(orders)), float)
    h = np.asarray(sorted(set(held or ()) - set(orders)), float)
    q = 4 + 2 * m.size + 2 * h.size
    G = np.zeros((C, q, q))
    B = np.zeros((C, q))
    keep = prep.keep
    name = "theta_eff" if "theta_eff" in prep.rows else "theta"
    n_kept = 0
    for a, b in _blocks(keep.size):
        kb = keep[a:b]
        if not kb.any():
            continue
        psi = np.asarray(_col(prep, "psi", a, b))[kb]
        th = np.asarray(_col(prep, name, a, b), float)[kb]
        ang = th[:, None] * np.concatenate([m, h])[None, :]
        Xo = np.concatenate([np.cos(ang), np.sin(ang)], axis=1)
        r = rw[a:b][kb]
        n_kept += int(kb.sum())
        for k in range(C):
            ph = psi[:, k]
            X = np.concatenate(
                [np.stack([np.cos(ph), np.sin(ph), np.cos(2 * ph), np.sin(2 * ph)], 1), Xo], 1
            )
            G[k] += X.T @ X
            B[k] += X.T @ r[:, k]
    # columns: the line's 4, then cos of (orders, held), then sin of (orders, held)
    n_o = m.size + h.size
    is_held = np.concatenate([np.zeros(m.size, bool), np.ones(h.size, bool)])
    cols = np.arange(4, q)
    own = cols[~np.concatenate([is_held, is_held])]  # the orders' cos and sin
    base = cols[np.concatenate([is_held, is_held])]  # the held orders' cos and sin
    line = np.arange(4)
    both = np.arange(q)
    lp, op = np.zeros(C), np.zeros(C)
    if n_kept > q:
        for k in range(C):
            full = _power(G[k], B[k], both)
            lp[k] = full - _power(G[k], B[k], cols) if n_o else full
            op[k] = full - _power(G[k], B[k], np.concatenate([line, base])) if own.size else 0.0
    s = prep.settings
    lthr = chi2_threshold(s.alpha, 4, C)
    dof = 2 * m.size  # cos and sin of each order
    othr = chi2_threshold(s.alpha, dof, C) if m.size else np.inf
    return {
        "orders": [int(x) for x in m],
        "held_orders": [int(x) for x in h],
        "line_chi2": float(lp.max(initial=0.0)),
        "orders_chi2": float(op.max(initial=0.0)),
        "line_threshold": float(lthr),
        "orders_threshold": float(othr),
        "line_significant": bool(lp.max(initial=0.0) > lthr),
        "orders_significant": bool(m.size > 0 and op.max(initial=0.0) > othr),
    }


def growth_beside_line(
    prep, resid: np.ndarray, order: int, M: int, L: int, base_info: dict
) -> bool:
    """Whether the base's growth from ``order`` to ``M`` goes on beside a ``line_phase``
    line over ``settings.growth_veto_share``: the orders ``order + 1 .. M`` (less ``L`` and
    ``2 L``, the line's own) fitted jointly with the line, beside the base's own orders
    ``1 .. order`` (:func:`line_beside_orders`); the growth goes on where the line is not
    significant beside them and they are beside it. Records the test in
    ``base_info["growth_line"]``."""
    own = {L, 2 * L} if L > 0 else set()  # the line's own orders
    add = [m for m in range(order + 1, M + 1) if m not in own]
    held = [m for m in range(1, order + 1) if m not in own]
    got = line_beside_orders(prep, resid, add, held)
    ok = got["orders_significant"] and not got["line_significant"]
    base_info["growth_line"] = {**got, "grows": bool(ok)}
    return bool(ok)


__all__ = ["growth_beside_line", "line_beside_orders"]
