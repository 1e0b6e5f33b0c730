"""Multihead: the runs' angle zeros ``delta_r`` of the base model (their start, and which
runs' own low orders can judge them; issue 44, records of less than one turn).

Each run's disk error orders fitted alone give the low-order phases the start aligns to run 0
(:func:`low_order_phases`). On a run of part of a turn those orders are not separable (their
columns against the run's constants are ill-conditioned over the arc it covers), so their
phases say nothing about the run's zero: such a run's start is the zero at which its
observations match run 0's at the same disk angle (:func:`match_offset`), or, where no zero
makes the runs share an arc, at which the base fitted to both explains the most
(:func:`profile_offset`), and :func:`resolved_runs` tells the issue-41 hold which runs'
low orders may judge a fitted zero at all.
"""

from __future__ import annotations

import numpy as np

from ...engine._protocol import Prepared
from ...engine._rowshare import summed_items
from ...engine._views import run_spans

ALIGN_GRID = 720
"""Angle zeros tried per run by :func:`profile_offset` (0.5 degree steps; the nearest is then
refined on a grid as fine again around it, and the fit refines it further)."""


RUN_NORMAL_ROWS = 1 << 14
"""Rows per block of :func:`run_normals` (bounded temporaries; the blocks are the work
items its sums are split over the processes by)."""


def run_normals(prep: Prepared, Mf: int):
    """Per run, the normal equations ``(G, h)`` of the disk error's orders ``1..Mf`` (columns
    ``cos, sin`` of each order in turn) and one constant per head (last ``C`` columns), in the
    run's own angle ``theta_raw`` (head differences without ``theta_ref``), accumulated in
    blocks of :data:`RUN_NORMAL_ROWS` rows (the design is never built whole), the blocks
    split over the processes (``engine._rowshare.summed_items``: the same sums on any
    number of them)."""
    R, C = prep.ctx.n_runs, prep.n_channels
    alpha = prep.consts["alpha"]
    P = 2 * Mf + C
    spans = dict(run_spans(prep.run))
    blocks = [
        (r, a, min(b0, a + RUN_NORMAL_ROWS))
        for r in range(R)
        for a0, b0 in [spans.get(r, (0, 0))]
        for a in range(a0, b0, RUN_NORMAL_ROWS)
    ]

    def add(sums, i):
        r, a, b = blocks[i]
        kb = prep.keep[a:b]
        th = prep.rows.column("theta_raw", a, b)[kb]
        y = prep.y[a:b][kb]
        cols = []
        for k in range(C):
            ck = []
            for mm in range(1, Mf + 1):
                ck += [np.cos(mm * (th - alpha[k])), np.sin(mm * (th - alpha[k]))]
            cols.append(np.stack(ck, 1))
        X = np.stack(cols, 1)  # (n, C, 2Mf)
        const = np.broadcast_to(np.eye(C)[None], (th.size, C, C))
        X = np.concatenate([X, const], 2)
        if prep.kd.project:
            X = X - X.mean(1, keepdims=True)
            y = y - y.mean(1, keepdims=True)
        Xf = X.reshape(-1, P)
        sums[0][r] += Xf.T @ Xf
        sums[1][r] += Xf.T @ y.ravel()

    G, h = summed_items(len(blocks), [np.zeros((R, P, P)), np.zeros((R, P))], add)
    return [(G[r], h[r]) for r in range(R)]


def resolved(G: np.ndarray, project: bool, coverage_min: float) -> bool:
    """Whether a run's orders are separable from each other and from its constants: the
    smallest eigenvalue of its normal matrix scaled to unit diagonal is at least
    ``coverage_min`` (``FinderSettings.coverage_min``, the test of the circle's coverage),
    over the columns the data see at all (orders alike on equally spaced heads cancel in
    head differences, and so does the heads' common constant without ``theta_ref``)."""
    d = np.diag(G)
    live = d > np.finfo(float).eps * max(float(d.max(initial=0.0)), 1e-300)
    if not live.any():
        return False
    dg = np.sqrt(d[live])
    lam = np.linalg.eigvalsh(G[np.ix_(live, live)] / dg[:, None] / dg[None, :])
    skip = int(project)  # the heads' common constant: exactly zero in head differences
    return bool(lam[min(skip, lam.size - 1)] >= coverage_min)


def low_order_phases(prep: Prepared, M: int, M_fit: int = 0):
    """Each run's orders ``1..max(Mz, M_fit)`` fitted alone, ``Mz`` =
    ``settings.run_offset_start_orders`` (or ``M``): ``(Z, V, m, ok)``, per run the complex
    coefficients ``a - i b`` of the disk error's low orders ``m = 1..Mz`` in the run's own
    angle ``theta_raw`` (their phases advance by ``m delta`` with the run's angle zero
    ``delta``), their variances (white noise at the mean ``sigma``) and whether the run's
    orders are separable at all (:func:`resolved`); the orders above ``Mz`` are fitted so
    that they do not leak into the low ones (a run of part turns)."""
    Mz = int(min(M, prep.settings.run_offset_start_orders))
    Mf = max(Mz, int(M_fit))
    s2 = float(np.mean(np.asarray(prep.sigma, float) ** 2))
    Z, V, ok = [], [], []
    for G, h in run_normals(prep, Mf):
        coef = np.linalg.lstsq(G, h, rcond=None)[0]
        a, b = coef[0 : 2 * Mz : 2], coef[1 : 2 * Mz : 2]
        Z.append(a - 1j * b)
        d = np.diag(np.linalg.pinv(G))
        V.append(s2 * (d[0 : 2 * Mz : 2] + d[1 : 2 * Mz : 2]))
        ok.append(resolved(G, prep.kd.project, prep.settings.coverage_min))
    return Z, V, np.arange(1, Mz + 1), ok


def _explained(G0, h0, Gr, hr, Mf: int, deltas: np.ndarray) -> np.ndarray:
    """``h . G^+ h`` of run 0 and run ``r`` fitted together (one disk error, each run its
    own constants) with run ``r``'s angle shifted by each of ``deltas``: its orders' columns
    rotate, ``cos m(th + d), sin m(th + d) = [cos, sin] [[cos md, sin md], [-sin md, cos md]]``."""
    C = G0.shape[0] - 2 * Mf
    P = 2 * Mf + 2 * C
    out = np.empty(deltas.size)
    m = np.arange(1, Mf + 1)
    for i, dl in enumerate(deltas):
        T = np.eye(2 * Mf + C)
        c, s = np.cos(m * dl), np.sin(m * dl)
        T[2 * m - 2, 2 * m - 2], T[2 * m - 2, 2 * m - 1] = c, s
        T[2 * m - 1, 2 * m - 2], T[2 * m - 1, 2 * m - 1] = -s, c
        Gt, ht = T.T @ Gr @ T, T.T @ hr
        G = np.zeros((P, P))
        h = np.zeros(P)
        i0 = np.r_[np.arange(2 * Mf), 2 * Mf + np.arange(C)]
        ir = np.r_[np.arange(2 * Mf), 2 * Mf + C + np.arange(C)]
        G[np.ix_(i0, i0)] += G0
        G[np.ix_(ir, ir)] += Gt
        h[i0] += h0
        h[ir] += ht
        x = np.linalg.lstsq(G, h, rcond=None)[0]
        out[i] = float(h @ x)
    return out


def profile_offset(normals, r: int, Mf: int) -> float:
    """Run ``r``'s angle zero (rad, against run 0) at which orders ``1..Mf`` fitted to both
    runs together explain the most (the same disk error on both arcs): the start where a
    run's own orders are not separable (part of a turn)."""
    (G0, h0), (Gr, hr) = normals[0], normals[r]
    grid = np.linspace(-np.pi, np.pi, ALIGN_GRID, endpoint=False)
    e = _explained(G0, h0, Gr, hr, Mf, grid)
    d0 = grid[int(np.argmax(e))]
    step = grid[1] - grid[0]
    fine = d0 + np.linspace(-step, step, 41)
    ef = _explained(G0, h0, Gr, hr, Mf, fine)
    return float(fine[int(np.argmax(ef))])


def _kept(prep: Prepared, r: int) -> tuple[np.ndarray, np.ndarray]:
    """Run ``r``'s kept rows: its angle ``theta_raw`` (rad) and observations ``y``."""
    a, b = dict(run_spans(prep.run)).get(r, (0, 0))
    kb = prep.keep[a:b]
    return prep.rows.column("theta_raw", a, b)[kb], np.asarray(prep.y[a:b])[kb]


def match_offset(prep: Prepared, r: int, M: int) -> float | None:
    """Run ``r``'s angle zero (rad, against run 0) at which its observations best match run
    0's at the same disk angle (run 0's interpolated there, each head's constant free; the
    mismatch's chi-square per degree of freedom in the noise), over the zeros where the two
    runs share an arc of at least half the period of the base's highest order ``M`` (a
    shorter one cannot tell a zero); ``None`` where no zero makes them share one."""
    th0, y0 = _kept(prep, 0)
    thr, yr = _kept(prep, r)
    if th0.size < 2 or thr.size < 2:
        return None
    o = np.argsort(th0)
    xp, fp = th0[o], y0[o]
    w = 1.0 / (2.0 * np.asarray(prep.sigma, float) ** 2)
    C = fp.shape[1]

    def mismatch(d: float) -> float:
        x = xp[0] + np.mod(thr + d - xp[0], 2 * np.pi)
        on = x <= xp[-1]
        if on.sum() <= C or np.ptp(x[on]) < np.pi / max(M, 1):
            return np.inf
        e = yr[on] - np.stack([np.interp(x[on], xp, fp[:, k]) for k in range(C)], 1)
        e -= e.mean(0)
        return float(np.sum(e**2 * w) / (e.size - C))

    grid = np.linspace(-np.pi, np.pi, ALIGN_GRID, endpoint=False)
    g = np.array([mismatch(d) for d in grid])
    if not np.isfinite(g).any():
        return None
    step = grid[1] - grid[0]
    fine = grid[int(np.argmin(g))] + np.linspace(-step, step, 41)
    return float(fine[int(np.argmin([mismatch(d) for d in fine]))])


def run_offsets_start(prep: Prepared, M: int) -> np.ndarray:
    """Start for ``delta_r``: each run's low orders (:func:`low_order_phases`) aligned to run
    0; a run whose own orders (or run 0's) are not separable is matched to run 0 at the same
    disk angle (:func:`match_offset`), or where it shares no arc with it gets
    :func:`profile_offset`."""
    if prep.ctx.n_runs < 2:
        return np.zeros(0)
    Z, _, mm, ok = low_order_phases(prep, M)
    normals = None if all(ok) else run_normals(prep, M)
    grid = np.linspace(-np.pi, np.pi, 7200, endpoint=False)
    out = []
    for r in range(1, len(Z)):
        if normals is not None and not (ok[r] and ok[0]):
            d = match_offset(prep, r, M)
            out.append(profile_offset(normals, r, M) if d is None else d)
            continue
        score = np.real(
            (Z[r] * np.conj(Z[0]))[None, :] * np.exp(-1j * mm[None, :] * grid[:, None])
        ).sum(1)
        out.append(grid[int(np.argmax(score))])
    return np.asarray(out)
