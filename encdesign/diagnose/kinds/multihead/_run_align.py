"""Multihead: the runs' angle zeros ``delta_r`` of the base model (their start, and which
runs' own low orders can judge them; issue 44, records of less than one turn).

Each run's disk error orders fitted alone give the low-order phases the start aligns to run 0
(:func:`low_order_phases`). On a run of part of a turn those orders are not separable (their
columns against the run's constants are ill-conditioned over the arc it covers), so their
phases say nothing about the run's zero: such a run's start is the zero at which its
observations match run 0's at the same disk angle (:func:`match_offset`), or, where no zero
makes the runs share an arc, or where the observations contradict the match and the base
fitted to both runs prefers another zero (:func:`matched_zero_refused`: the true zero may
make the runs share no shaft arc while each head's arc overlaps other heads' arcs of the
other run), at which the base fitted to both explains the most (:func:`profile_offset`),
and :func:`resolved_runs` tells the issue-41 hold which runs' low orders may judge a fitted
zero at all.
"""

from __future__ import annotations

import numpy as np

from ...engine._protocol import Prepared
from ...engine._rowshare import summed_items
from ...engine._views import chi2_threshold, run_spans

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
    found = _match(prep, r, M)
    return None if found is None else found[0]


def _match(prep: Prepared, r: int, M: int) -> tuple[float, float, int] | None:
    """:func:`match_offset`'s zero (rad) with its mismatch: the chi-square (in the noise of
    both runs) and its degrees of freedom."""
    th0, y0 = _kept(prep, 0)
    thr, yr = _kept(prep, r)
    if th0.size < 2 or thr.size < 2:
        return None
    o = np.argsort(th0)
    xp, fp = th0[o], y0[o]
    w = 1.0 / (2.0 * np.asarray(prep.sigma, float) ** 2)
    C = fp.shape[1]

    def mismatch(d: float) -> tuple[float, int]:
        x = xp[0] + np.mod(thr + d - xp[0], 2 * np.pi)
        on = x <= xp[-1]
        if on.sum() <= C or np.ptp(x[on]) < np.pi / max(M, 1):
            return np.inf, 0
        e = yr[on] - np.stack([np.interp(x[on], xp, fp[:, k]) for k in range(C)], 1)
        e -= e.mean(0)
        return float(np.sum(e**2 * w)), int(e.size - C)

    def per_dof(d: float) -> float:
        chi, dof = mismatch(d)
        return chi / dof if dof > 0 else np.inf

    grid = np.linspace(-np.pi, np.pi, ALIGN_GRID, endpoint=False)
    g = np.array([per_dof(d) for d in grid])
    if not np.isfinite(g).any():
        return None
    step = grid[1] - grid[0]
    fine = grid[int(np.argmin(g))] + np.linspace(-step, step, 41)
    best = float(fine[int(np.argmin([per_dof(d) for d in fine]))])
    return (best, *mismatch(best))


def _sum_squares(prep: Prepared, r: int) -> tuple[float, int]:
    """Run ``r``'s kept observations: their sum of squares (rad^2; head differences without
    ``theta_ref``, as :func:`run_normals` sees them) and how many values they hold."""
    _, y = _kept(prep, r)
    if prep.kd.project:
        y = y - y.mean(1, keepdims=True)
    return float(np.sum(y**2)), int(y.shape[0] * (y.shape[1] - int(prep.kd.project)))


def matched_zero_refused(prep: Prepared, normals, r: int, Mf: int, match) -> float | None:
    """The profile's zero (:func:`profile_offset`) where run ``r``'s matched zero (``match``:
    :func:`_match`'s zero, chi-square and degrees of freedom) is refused for it, else
    ``None``. Both must say so: the observations contradict the match (its mismatch chi-square over
    ``chi2_threshold(settings.alpha, dof, 1)``: the runs differ at the same disk angle by
    more than the noise), and the base fitted to run 0 and run ``r`` together (orders
    ``1..Mf``, each run its head constants) leaves a residual sum of squares at the matched
    zero that exceeds the profile's by more than ``chi2_threshold(settings.alpha, 1,
    ALIGN_GRID)`` times the profile's own residual per degree of freedom (a quasi-likelihood
    ratio: the same parameters at both zeros, the profile's the best of the grid's zeros, and
    the dispersion its own, so orders the base leaves out or an effect it does not model
    cannot by themselves refuse the match). The match compares a run's heads with run 0's
    at the same shaft angle only: where the true zero makes the runs share no shaft arc it
    cannot see it, and takes the best of the zeros that do, at a short shared arc (issue 44,
    ``short_arcs.py --set effects --seed 6215`` record 1: a zero 0.92 rad off, the base 29x
    the noise), while the profile sees the heads' arcs overlap across the runs. With one head
    there is no other head's arc: the profile knows no more than the match, and where the
    base leaves orders out it favours zeros that keep the runs' arcs apart (one sensor, three
    runs of 0.73 turn, orders to 13 over the base's 12: ``finder_variations.py --set high
    --seed 6290`` record 0, the match right and the profile 1.4 rad off), so the match
    stands."""
    matched, chi, dof_m = match
    if prep.n_channels < 2:  # (one head: no other head's arc, the match sees all there is)
        return None
    if dof_m <= 0 or chi <= chi2_threshold(prep.settings.alpha, dof_m, 1):
        return None
    prof = profile_offset(normals, r, Mf)
    (G0, h0), (Gr, hr) = normals[0], normals[r]
    y0, n0 = _sum_squares(prep, 0)
    yr, nr = _sum_squares(prep, r)
    res = y0 + yr - _explained(G0, h0, Gr, hr, Mf, np.array([matched, prof]))
    dof = n0 + nr - G0.shape[0] - Gr.shape[0] + 2 * Mf
    if dof <= 0:
        return None
    disp = max(float(res[1]), 0.0) / dof
    drop = float(res[0] - res[1])
    thr = chi2_threshold(prep.settings.alpha, 1, ALIGN_GRID)
    return prof if (drop > thr * disp if disp > 0 else drop > 0) else None


def run_offsets_start(prep: Prepared, M: int) -> np.ndarray:
    """Start for ``delta_r``: each run's low orders (:func:`low_order_phases`) aligned to run
    0; a run whose own orders (or run 0's) are not separable is matched to run 0 at the same
    disk angle (:func:`match_offset`), unless the observations contradict that zero and the
    base fitted to both runs prefers another (:func:`matched_zero_refused`), or where it
    shares no arc with it gets :func:`profile_offset`."""
    if prep.ctx.n_runs < 2:
        return np.zeros(0)
    Z, _, mm, ok = low_order_phases(prep, M)
    normals = None if all(ok) else run_normals(prep, M)
    grid = np.linspace(-np.pi, np.pi, 7200, endpoint=False)
    out = []
    for r in range(1, len(Z)):
        if normals is not None and not (ok[r] and ok[0]):
            d = _match(prep, r, M)
            if d is None:
                out.append(profile_offset(normals, r, M))
                continue
            p = matched_zero_refused(prep, normals, r, M, d)
            out.append(d[0] if p is None else p)
            continue
        score = np.real(
            (Z[r] * np.conj(Z[0]))[None, :] * np.exp(-1j * mm[None, :] * grid[:, None])
        ).sum(1)
        out.append(grid[int(np.argmax(score))])
    return np.asarray(out)
