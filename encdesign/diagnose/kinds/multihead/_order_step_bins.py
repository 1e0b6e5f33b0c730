"""The ``order_step`` view's sums per bin of kept rows (issue 43): geometry kept, the
residual's linear part alone per scan.

The view (:func:`._multihead_terms.view_order_step`) needs per bin of kept rows the sums
``X^T r`` (2,), ``X^T X`` (2, 2) and ``X^T B`` (2, P) of the whitened eccentricity columns
``X`` and base columns ``B`` (a constant per run and head, then ``X``), and over the record
``B^T B`` and ``B^T r``. All but ``X^T r`` and ``B^T r`` are geometry: they depend on the
kept rows, the angle, the head angles and the noise weights, not on the residual, and are
kept across scans (:func:`...engine._views_sums.geometry`; building ``B`` per row and its
products were most of the view's cost). ``B^T r`` follows from ``X^T r`` and the residual's
sums per run and head.
"""

from __future__ import annotations

import numpy as np

from ...engine._views_sums import fingerprint, geometry, linear

BIN_ROWS = 1 << 14
"""Kept rows per block of the pass (bounded temporaries)."""


def _layout(prep) -> tuple[int, np.ndarray | None]:
    """``(M, ab)``: the disk orders ``1..M`` the ``order_step`` view projects out beside the
    run constants, and the base's fitted disk coefficients ``ab`` (2, M) (cos, sin) where
    the runs' angle zeros are fitted (their columns, the error's slope in each run, are
    projected out too), else ``None``. See :func:`order_step_width`."""
    base = next((t for t in prep.base_terms or () if t.cand.name == "base"), None)
    if prep.part_turn_span is None or base is None or "fourier_cos_rad" not in base.values:
        return 1, None
    a = np.ravel(np.asarray(base.values["fourier_cos_rad"], float))
    b = np.ravel(np.asarray(base.values["fourier_sin_rad"], float))
    off = "run_angle_offset_rad"
    ab = np.stack([a, b]) if prep.ctx.n_runs > 1 and off in base.values else None
    return max(1, int(a.size)), ab


def order_step_width(prep) -> int:
    """Columns beside the run constants that the ``order_step`` view projects out (issue
    44, session 22). Where every run covers less than one turn (``Prepared.part_turn_span``)
    the base's own: its disk orders ``1..M`` and, with several runs, each later run's angle
    zero (the disk error's slope on that run's rows, at the base's fitted coefficients);
    else order 1 alone. On part of a turn those columns are far from orthogonal to a step of
    order 1 in time: fitted before the scan they take part of the step and move its best
    change point (training ``short_arcs.py --set effects --seed 6215`` record 1: a shift in
    the pause between runs located 0.32 s into the later run; a run's angle zero takes a
    step at the run's start, and the change was put some rows into the run); projected
    out, the scan's gain is the step's chi-square with the base refitted jointly. Over
    whole turns orders 2..M are orthogonal to it but for the turn the step falls in, and
    their sums would cost rows x heads x M^2."""
    M, ab = _layout(prep)
    return 2 * M + (prep.ctx.n_runs - 1 if ab is not None else 0)


def base_columns(prep, d: np.ndarray, run: np.ndarray) -> np.ndarray:
    """The columns :func:`order_step_width` counts (rows, C, E) at the head arguments ``d =
    theta - alpha_k`` (rows, C) of rows of runs ``run``: ``sin, cos (m d)`` for ``m = 1..M``,
    then per run after the first the slope ``sum_m m (b_m cos m d - a_m sin m d)`` on its
    rows (the base's run angle zero, ``_multihead._base_candidate``)."""
    M, ab = _layout(prep)
    m = np.arange(1, M + 1, dtype=float)
    md = d[:, :, None] * m
    sn, cs = np.sin(md), np.cos(md)
    out = [np.stack([sn, cs], 3).reshape(d.shape[0], d.shape[1], 2 * M)]
    if ab is not None:
        slope = np.einsum("ncm,m->nc", cs, m * ab[1]) - np.einsum("ncm,m->nc", sn, m * ab[0])
        on = run[:, None] == np.arange(1, prep.ctx.n_runs)[None, :]  # (rows, R - 1)
        out.append(slope[:, :, None] * on[:, None, :])
    return np.concatenate(out, 2)


def _row_sums(prep, idx: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``X^T r`` per row (rows, 2) of the whitened (and, without a reference, projected over
    the heads) eccentricity columns ``X = sin, cos (theta - alpha_k)`` and the whitened
    residual ``r`` (rows, C), by the difference formulas: ``sin (theta - alpha) = sin theta
    cos alpha - cos theta sin alpha``, so the heads enter through two weighted sums of ``r``
    per row (no per-head column is formed)."""
    th = np.asarray(prep.rows.take("theta", idx), float)
    al = np.asarray(prep.consts["alpha"], float)
    ca, sa = np.cos(al), np.sin(al)
    if prep.kd.project:
        ca, sa = ca - ca.mean(), sa - sa.mean()
    w = 1.0 / np.asarray(prep.sigma, float)
    P, Q = r @ (ca * w), r @ (sa * w)
    c, s = np.cos(th), np.sin(th)
    return np.stack([s * P - c * Q, c * P + s * Q], 1)


def order_step_bins(prep, rw, kidx: np.ndarray, P: int, nb: int, sums_of) -> tuple:
    """``(a, G, XB, BB, Br)``: per bin (``nb`` equal-count bins of ``kidx``, in order) the
    sums ``X^T r``, ``X^T X``, ``X^T B``, and over the record ``B^T B``, ``B^T r``;
    ``sums_of(prep, rw, idx, P)``: the view's own per-row sums (used for the geometry)."""
    C, R = prep.n_channels, prep.ctx.n_runs
    edges = np.linspace(0, kidx.size, nb + 1).astype(int)
    pos_bin = np.repeat(np.arange(nb), np.diff(edges))
    th = np.asarray(prep.rows.take("theta", kidx), float)
    key = (
        "order_step",
        int(nb),
        int(P),
        bool(prep.kd.project),
        fingerprint(kidx, th, prep.sigma, prep.consts["alpha"], prep.run[kidx]),
    )
    del th

    def bins(x, bi, st):
        return bi[st], np.add.reduceat(x, st, axis=0)

    def geo():
        G, XB, BB = np.zeros((nb, 2, 2)), np.zeros((nb, 2, P)), np.zeros((P, P))
        for lo in range(0, kidx.size, BIN_ROWS):
            hi = min(kidx.size, lo + BIN_ROWS)
            _, _, Gi, XBi, BBc, _ = sums_of(prep, rw, kidx[lo:hi], P)
            bi = pos_bin[lo:hi]  # kept rows in time order: a block's bins ascend
            st = np.flatnonzero(np.r_[True, bi[1:] != bi[:-1]])
            G[bi[st]] += np.add.reduceat(Gi, st, axis=0)
            XB[bi[st]] += np.add.reduceat(XBi, st, axis=0)
            BB += BBc
        return G, XB, BB

    G, XB, BB = geometry(prep, key, geo)

    def lin():
        a, Br = np.zeros((nb, 2)), np.zeros(P)
        w = 1.0 / np.asarray(prep.sigma, float)
        for lo in range(0, kidx.size, BIN_ROWS):
            hi = min(kidx.size, lo + BIN_ROWS)
            idx = kidx[lo:hi]
            r = np.asarray(rw[idx], float)
            ai = _row_sums(prep, idx, r)
            bi = pos_bin[lo:hi]
            st = np.flatnonzero(np.r_[True, bi[1:] != bi[:-1]])
            a[bi[st]] += np.add.reduceat(ai, st, axis=0)
            if P > R * C + 2:  # the base's own columns (part of a turn): as they are built
                Br += sums_of(prep, rw, idx, P)[5]
                continue
            # the run and head constants: B = (delta_ck - 1/C [projected]) w_c
            v = r * w[None, :]
            if prep.kd.project:
                v = v - (r @ w)[:, None] / C
            run = prep.run[idx]
            for k in range(C):
                Br[k : R * C : C] += np.bincount(run, weights=v[:, k], minlength=R)
            Br[R * C :] += ai.sum(0)
        return [a, Br]

    a, Br = linear(prep, key, lin)
    return a, G, XB, BB, Br, edges
