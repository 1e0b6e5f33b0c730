"""The multihead ``beam_tilt_axial`` term's runout orders: which ones the record supports
(before its fit) and which ones its fit found (reported), issue 44 B."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg as sla

from ...engine._candidates import Context
from ...engine._rowshare import gathered_groups, my_groups, row_groups
from ...engine._views import chi2_threshold

RUNOUT_ORDERS = (1.0, 2.0, 3.0)
"""Runout orders of the axial beam tilt."""


def _qr_apply(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, Q^T Y)`` of the reduced QR factorisation ``X = Q R`` (``X`` (n, q), ``Y`` (n, C)),
    with ``Q`` applied by its reflectors and never formed (issue 43: forming it and its product
    were most of the vibration start's line search; ``R`` is LAPACK's same, ``Q^T Y`` equal to
    rounding)."""
    if X.shape[0] < X.shape[1] or X.shape[1] == 0:  # (a short block: Q formed, it is small)
        Q, R = np.linalg.qr(X)
        return R, Q.T @ Y
    QtY, R = sla.qr_multiply(X, np.ascontiguousarray(Y.T), mode="right")
    return R, np.asarray(QtY).T


def _gain(rw: np.ndarray, X: np.ndarray) -> float:
    """Whitened chi-square that regressors ``X`` (n, q) take out of ``rw`` (n, C)."""
    if X.shape[0] <= X.shape[1]:
        return 0.0
    return float(np.sum(_qr_apply(X, rw)[1] ** 2))


SPLIT_ROWS = 1 << 14
"""Rows per block of :func:`split_gains` (the work items its rows are split over the
processes by)."""


def split_gains(n: int, sets: Callable[[int, int], list[np.ndarray]], rw: np.ndarray) -> list:
    """:func:`_gain` of ``rw`` (n, C) and each regressor set ``sets(a, b)`` gives rows
    ``a:b`` of (each (b - a, q_s)), the rows split over the processes: the blocks of
    :data:`SPLIT_ROWS` rows in the fixed groups of ``engine._rowshare``, each group's QR
    ``(R, Q^T rw)`` gathered and the groups' stacked ``R`` factored again (a tall-skinny QR:
    its basis spans the whole design), so the gains are the same on any number of
    processes."""
    blocks = [(a, min(n, a + SPLIT_ROWS)) for a in range(0, n, SPLIT_ROWS)]
    groups, C = row_groups(len(blocks)), rw.shape[1]
    qs = [X.shape[1] for X in sets(0, 0)]
    parts = []
    for grp in my_groups(len(groups)):
        i0, i1 = groups[grp]
        a, b = (blocks[i0][0], blocks[i1 - 1][1]) if i1 > i0 else (0, 0)
        flat = []
        for X, q in zip(sets(a, b), qs):
            R, T = np.zeros((q, q)), np.zeros((q, C))
            if b > a:
                Rg, QtY = _qr_apply(X, rw[a:b])
                R[: Rg.shape[0]], T[: QtY.shape[0]] = Rg, QtY
            flat += [R.ravel(), T.ravel()]
        parts.append(np.concatenate(flat) if flat else np.zeros(0))
    every = gathered_groups(parts, len(groups), sum(q * q + q * C for q in qs))
    out, at = [], 0
    for q in qs:
        Rs = every[:, at : at + q * q].reshape(-1, q)
        Ts = every[:, at + q * q : at + q * q + q * C].reshape(-1, C)
        at += q * q + q * C
        out.append(float(np.sum((np.linalg.qr(Rs)[0].T @ Ts) ** 2)) if n > q else 0.0)
    return out


def _bt_orders_supported(ctx: Context, resid: np.ndarray, cand: np.ndarray) -> np.ndarray:
    """Of the runout orders ``cand`` (a mask over :data:`RUNOUT_ORDERS`), those the record
    supports: fitted together per head (cos, sin of each order, less a constant per run) on
    the whitened residual, every order whose conditional chi-square over the heads (``2 C``
    dof, given the other orders) passes ``FinderSettings.alpha`` (Bonferroni over the orders
    tested); the weakest order that fails is dropped and the rest refitted. A strong order's
    leakage into its neighbours over a few turns is taken by the strong order itself in the
    joint fit, so no share of the strongest order's power is needed to tell a weak order
    from a leak (issue 44 B: an order 3 at a tenth of order 1's power was left unexplained)."""
    th = np.asarray(ctx.rows["theta"], float)
    oh = np.asarray(ctx.rows["run_onehot"], float)
    rw = np.asarray(resid, float).reshape(th.size, -1) / np.asarray(ctx.noise, float)[None, :]
    rw = rw - oh @ np.linalg.lstsq(oh, rw, rcond=None)[0]
    C = rw.shape[1]
    on = np.asarray(cand, bool).copy()
    n_tests = max(int(on.sum()), 1)
    thr = chi2_threshold(ctx.settings.alpha, 2 * C, n_tests)
    while on.any():
        idx = np.flatnonzero(on)
        X = np.concatenate(
            [
                np.stack([np.cos(RUNOUT_ORDERS[j] * th), np.sin(RUNOUT_ORDERS[j] * th)], 1)
                for j in idx
            ],
            1,
        )
        X = X - oh @ np.linalg.lstsq(oh, X, rcond=None)[0]
        full = _gain(rw, X)
        cond = []
        for i in range(idx.size):
            rest = np.delete(X, [2 * i, 2 * i + 1], axis=1)
            cond.append(full - (_gain(rw, rest) if rest.shape[1] else 0.0))
        i_min = int(np.argmin(cond))
        if cond[i_min] > thr:
            break
        on[idx[i_min]] = False
    return on


def _bt_orders_significant(ctx: Context, amp: np.ndarray, on: np.ndarray) -> list[int]:
    """The fitted runout orders (``on``) whose head-specific part ``amp`` (C, orders) is
    significant against the noise: ``sum_k amp_k^2 / (2 sigma_k^2 / n)`` over the heads (the
    variance of a cos / sin pair's amplitude fitted to ``n`` rows of white noise), chi-square
    with ``2 C`` dof at ``FinderSettings.alpha``, Bonferroni over the orders fitted."""
    n = int(np.asarray(ctx.rows["theta"]).shape[0])
    var = 2.0 * np.asarray(ctx.noise, float) ** 2 / max(n, 1)
    C = amp.shape[0]
    thr = chi2_threshold(ctx.settings.alpha, 2 * C, max(int(np.sum(on > 0)), 1))
    return [
        int(m)
        for j, m in enumerate(RUNOUT_ORDERS)
        if on[j] and float(np.sum(amp[:, j] ** 2 / np.maximum(var, 1e-300))) > thr
    ]
