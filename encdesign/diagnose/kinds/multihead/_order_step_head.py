"""The ``order_step`` view's rival form for its located time: a step of one head's reading
(issue 44 C, session 25).

The ``order_step`` view scans a change of the disk's order 1 (every head sees it, phase
shifted by its azimuth). A count jump, or any step of one head's reading, is a change of a
constant on that head alone; on a few heads and on part of a turn that constant is far from
orthogonal to the order-1 columns, so the view's scan takes part of it and finds an order
change, often far from the jump (session 24, fresh 6469 and 6470: the three ``order_step``
times located on `3+1` / `2+1` benches with a count jump were all outside their
intervals). Its located time describes a model that is not the one the data favour there.

Here the same change points are scanned for the best step of one head's constant (one
column per head: ``H(tau - t_s)`` on head ``k``, whitened, projected over the heads without a
reference, the base's columns projected out exactly as the view's), and its likelihood ratio
is compared with the order change's (:func:`head_step_gain`). Both are chi-square gains of a
fitted one-change model over the same base; the view keeps its located time only where the
order change's exceeds ``FinderSettings.order_step_head_ratio`` times the head step's; else the time
is the head step's, which the ``time`` view locates (its block means see a head's step).
"""

from __future__ import annotations

import numpy as np

from ...engine._views_sums import fingerprint, geometry
from ._order_step_bins import BIN_ROWS, base_columns

SINGULAR_RTOL = 1e-9
"""A head step's whitened norm squared left after the base's columns, relative to its own,
below which it counts as spanned by the base (gain 0: a change at a run's start is that
run's constant), as the order change's ``_step_gain``."""


def base_rows(prep, idx: np.ndarray, P: int) -> tuple[np.ndarray, np.ndarray]:
    """``(X, B)`` at the kept rows ``idx``: the whitened eccentricity columns ``X`` (rows, C,
    2), ``sin, cos (theta - alpha_k)``, and the base columns ``B`` (rows, C, P) a change must
    be told from (one constant per run and head, then ``X`` over whole turns, the base's own
    columns on part of a turn, :func:`._order_step_bins.order_step_width`); without a
    reference both projected over the heads (the head mean is projected out of the data)."""
    C, R = prep.n_channels, prep.ctx.n_runs
    th = np.asarray(prep.rows.take("theta", idx), float)
    d = th[:, None] - np.asarray(prep.consts["alpha"], float)[None, :]
    X = np.stack([np.sin(d), np.cos(d)], 2)  # (n, C, 2)
    B = np.zeros((idx.size, C, P))
    run = prep.run[idx]
    for k in range(C):
        B[np.arange(idx.size), k, run * C + k] = 1.0
    B[:, :, R * C :] = X if P == R * C + 2 else base_columns(prep, d, run)
    if prep.kd.project:  # without theta_ref the head mean is projected out (data and terms)
        X = X - X.mean(1, keepdims=True)
        B = B - B.mean(1, keepdims=True)
    w = 1.0 / np.asarray(prep.sigma, float)[None, :, None]
    return X * w, B * w


def _heads(prep) -> np.ndarray:
    """``H`` (C, C): row ``k`` is the whitened column of a constant on head ``k`` over the
    heads (``delta_kc / sigma_c``; without a reference less the head mean)."""
    C = prep.n_channels
    H = np.eye(C)
    if prep.kd.project:
        H = H - 1.0 / C
    return H / np.asarray(prep.sigma, float)[None, :]


def head_step_gain(
    prep, rw: np.ndarray, kidx: np.ndarray, P: int, edges: np.ndarray, e: np.ndarray, BBi, Br
) -> tuple[float, int, int]:
    """``(gain, head, edge)``: the largest whitened chi-square (1 dof) a step of one head's
    constant takes out over the change points ``edges[e]`` (kept-row positions; the
    ``order_step`` view's bins ``edges``), the base's columns (``BBi`` the pseudo-inverse of
    their Gram, ``Br`` their sums with the residual) refitted jointly; its head and the
    index into ``e``. The sums per bin of geometry are kept across scans
    (:func:`...engine._views_sums.geometry`)."""
    C = prep.n_channels
    nb = edges.size - 1
    H = _heads(prep)
    pos_bin = np.repeat(np.arange(nb), np.diff(edges))
    key = (
        "order_step_head",
        int(nb),
        int(P),
        bool(prep.kd.project),
        fingerprint(
            kidx,
            np.asarray(prep.rows.take("theta", kidx), float),
            prep.sigma,
            prep.consts["alpha"],
            prep.run[kidx],
        ),
    )

    def geo():
        hB = np.zeros((nb, C, P))
        for lo in range(0, kidx.size, BIN_ROWS):
            hi = min(kidx.size, lo + BIN_ROWS)
            _, B = base_rows(prep, kidx[lo:hi], P)
            hBi = np.einsum("kc,ncp->nkp", H, B)
            bi = pos_bin[lo:hi]
            st = np.flatnonzero(np.r_[True, bi[1:] != bi[:-1]])
            hB[bi[st]] += np.add.reduceat(hBi, st, axis=0)
        hh = np.diff(edges)[:, None] * np.sum(H**2, 1)[None, :]  # (nb, C)
        return hh, hB

    hh, hB = geometry(prep, key, geo)
    hr = np.zeros((nb, C))
    for lo in range(0, kidx.size, BIN_ROWS):
        hi = min(kidx.size, lo + BIN_ROWS)
        np.add.at(hr, pos_bin[lo:hi], np.asarray(rw[kidx[lo:hi]], float) @ H.T)

    def suffix(x):
        return np.cumsum(x[::-1], 0)[::-1]

    Shr, Shh, ShB = suffix(hr)[e], suffix(hh)[e], suffix(hB)[e]  # (n_e, C), (n_e, C, P)
    g = Shr - ShB @ (BBi @ Br)
    Gp = Shh - np.einsum("ekp,pq,ekq->ek", ShB, BBi, ShB)
    ok = Gp > SINGULAR_RTOL * Shh
    gain = np.where(ok, g**2 / np.where(ok, Gp, 1.0), 0.0)
    j, k = np.unravel_index(int(np.argmax(gain)), gain.shape)
    return float(gain[j, k]), int(k), int(j)
