"""The ``order_step`` change located with the runs' angle zeros re-chosen (issue 44 C).

Without a reference head the shaft angle of each run is known up to an angle zero
``delta_r`` (``run_angle_offset_rad`` of the base, run 0 the reference). Where every run
covers part of a turn, the base is fitted before any change is searched for, and a change
of the disk's order 1 (an eccentricity shift) in a later run pulls that run's zero: a
rotated disk error changes its order 1 as a shift does, and on part of a turn the higher
orders that tell the two apart are ill-determined. The pulled zero (radians off, session
23: ``benchmarks/run_zero_pull.py``) leaves a residual whose best change point lies away
from the truth, and the view's profile at that zero (its tangent projected out,
``_order_step_bins.order_step_width``) cannot move it back (a tangent is a first-order
move). Here the change time is profiled with the later runs' zeros chosen jointly with it
(session 23, outside the finder: ``benchmarks/zero_profile_scan.py``).

The model at trial zero moves ``z_r`` (rad, from the base's fitted zeros; ``z_0 = 0``): a
constant per run and head, the disk orders ``1..M`` of the base at the head arguments
``phi = theta - alpha_k + z_r`` with their coefficients refitted (shared by every run),
and the step ``sin, cos (phi)`` (order 1) from the change on; the data are the residual
``rw`` plus the base's fitted disk error (in the span at ``z = 0``), projected over the
heads and whitened as the view's. Everything is linear but the zeros, and a move of a
zero is a rotation of a run's Fourier columns (order ``m`` by ``m z_r``): per run the
rows enter through the R factor of a QR of its columns (``[const_k, sin m phi, cos m
phi | y]``, accumulated block by block) and the step through the within-run sums from the
change on, so each trial ``(change, zeros)`` costs a few small matrix products, not a pass
over the rows.

The search: at ``FinderSettings.zero_profile_points`` change points (the view's bin edges,
every later run's first row) the chi-square is minimised over a grid of
``zero_profile_grid`` moves per later run (their product, or coordinate sweeps where it
exceeds ``zero_profile_configs_max``), then the zeros are refined by a shrinking
coordinate search (``zero_profile_rounds``): at the ``zero_profile_refine`` best change
points on the grid, then at every one the refinement may still bring within the interval.
The best change point's neighbourhood is scanned row by row
(:func:`.._located.scan_indices`), each row's zeros refined from the best's. The
interval: every change point within ``change_chi2(change_time_level)`` of the least
(:func:`.._located.interval_of`, widened over the gaps of the scan).

Numbers: the base's residual is computed as a vector (not a difference of squares: the
data hold the disk error, 3-300x the noise or more); the step's coordinates use the
directions of the base's columns the fitter itself determines (its pivot tolerance). Where
the chi-square at the fitted zeros differs from that of the residual alone (the same
model on small data) by more than the interval's bound, the profile is not used (the
view's own location stands): a base of many orders on a short arc (training
``change_coverage`` 7820/8, 24 orders on 0.33 turn).
"""

from __future__ import annotations

import inspect
import itertools

import numpy as np

from ...engine._located import change_chi2, interval_of, located_time, scan_indices
from ...engine._normal import _pivoted_rank
from ...engine._protocol import Prepared
from ._symmetry import _symmetric_orders

BLOCK_ROWS = 1 << 13
"""Kept rows per block of the pass over the rows (bounded temporaries)."""

BATCH = 64
"""Trial zero settings per batch of the evaluation (bounded temporaries)."""

PIVOT_TOL = inspect.signature(_pivoted_rank).parameters["tol"].default
"""The fitter's relative pivot tolerance on its scaled Gram (one source: its default)."""


def _base(prep: Prepared, terms=None):
    """The fitted base term of ``terms`` (default: the base fit's) where the profile applies
    (part of a turn, no reference head, several runs, the runs' angle zeros and disk orders
    in the base), else ``None``."""
    terms = prep.base_terms if terms is None else terms
    base = next((t for t in terms or () if t.cand.name == "base"), None)
    if (
        base is None
        or prep.part_turn_span is None
        or prep.ctx.has_ref
        or prep.ctx.n_runs < 2
        or prep.n_channels < 2
        or "run_angle_offset_rad" not in base.values
        or "fourier_cos_rad" not in base.values
    ):
        return None
    return base


def applies(prep: Prepared) -> bool:
    """Whether the view's change is located here (see :func:`_base`)."""
    return _base(prep) is not None


class _Sums:
    """Per run the R factor of its whitened columns with the data, and per change point the
    within-run sums of the step's columns from it on."""

    def __init__(self, prep: Prepared, rw: np.ndarray, kidx: np.ndarray, base, disk=True):
        C, R = prep.n_channels, prep.ctx.n_runs
        a = np.ravel(np.asarray(base.values["fourier_cos_rad"], float))
        b = np.ravel(np.asarray(base.values["fourier_sin_rad"], float))
        # the base's orders less those every head sees alike (held by the base: no column
        # after the projection over the heads), order 1 always (the step's)
        held = set(_symmetric_orders(prep, a.size)) - {1}
        self.m = np.array([m for m in range(1, a.size + 1) if m not in held])
        # a constant per head but the first (projected, the heads' constants sum to zero)
        self.nc = C - 1 if prep.kd.project else C
        self.C, self.R, self.M = C, R, self.m.size
        self.L = self.nc + 2 * self.M
        self.coef = np.stack([b[self.m - 1], a[self.m - 1]], 1).ravel()  # (sin, cos) of m
        self.coef = self.coef * bool(disk)  # without it: the data the residual alone
        self.prep, self.rw, self.kidx, self.base = prep, rw, kidx, base
        self.run = np.asarray(prep.run[kidx], int)
        self.alpha = np.asarray(prep.consts["alpha"], float)
        zeros = np.ravel(np.asarray(base.values["run_angle_offset_rad"], float))
        self.zeros = np.concatenate([[0.0], zeros])  # the fitted ones: moves are from them
        self.w = 1.0 / np.asarray(prep.sigma, float)
        L = self.L
        Raug = [np.zeros((0, L + 1)) for _ in range(R)]
        for lo in range(0, kidx.size, BLOCK_ROWS):
            V, y = self._rows(lo, min(kidx.size, lo + BLOCK_ROWS))
            run = self.run[lo : lo + V.shape[0]]
            for r in np.unique(run):
                on = run == r
                A = np.concatenate([V[on], y[on][:, :, None]], 2).reshape(-1, L + 1)
                Raug[r] = np.linalg.qr(np.concatenate([Raug[r], A]), mode="r")
        self.Rr = np.zeros((R, L, L))
        self.q = np.zeros((R, L))
        self.perp = 0.0
        for r in range(R):
            Ra = np.zeros((L + 1, L + 1))
            Ra[: Raug[r].shape[0]] = Raug[r][: L + 1]
            self.Rr[r], self.q[r] = Ra[:L, :L], Ra[:L, L]
            self.perp += float(Ra[L, L] ** 2)
        self.T = np.einsum("rki,rkj->rij", self.Rr, self.Rr)  # V_r^T V_r
        self.t = np.einsum("rki,rk->ri", self.Rr, self.q)  # V_r^T y_r
        self.qq = float(np.sum(self.q**2))
        starts = np.flatnonzero(np.r_[True, self.run[1:] != self.run[:-1]])
        self.first = {int(self.run[s]): int(s) for s in starts}

    def _rows(self, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
        """Kept-row positions ``lo..hi``: the columns ``V`` (rows, C, L) (a constant per
        head, ``sin, cos (m phi)``), projected over the heads and whitened, and the data
        ``y`` (rows, C): the residual plus the base's fitted disk error."""
        idx = self.kidx[lo:hi]
        C, M, nc = self.C, self.M, self.nc
        th = np.asarray(self.prep.rows.take("theta_raw", idx), float)
        th = th + self.zeros[np.asarray(self.prep.run[idx], int)]
        md = (th[:, None] - self.alpha[None, :])[:, :, None] * self.m
        u = np.stack([np.sin(md), np.cos(md)], 3).reshape(idx.size, C, 2 * M)
        one = np.broadcast_to(np.eye(C)[:, C - nc :], (idx.size, C, nc))
        V = np.concatenate([one, u], 2)
        if self.prep.kd.project:
            V = V - V.mean(1, keepdims=True)
        V = V * self.w[None, :, None]
        y = np.asarray(self.rw[idx], float) + V[:, :, nc:] @ self.coef
        return V, y

    def suffix(self, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """At kept-row positions ``pos``: the sums over the rows of the same run from ``pos``
        on of ``u1^T V`` (N, 2, L) and ``u1^T y`` (N, 2) (``u1``: the order-1 columns)."""
        pos = np.asarray(pos, int)
        C = self.nc
        S1, Sy = np.zeros((pos.size, 2, self.L)), np.zeros((pos.size, 2))
        ends = np.array([self.first.get(int(r) + 1, self.kidx.size) for r in self.run[pos]])
        for lo in range(0, self.kidx.size, BLOCK_ROWS):
            hi = min(self.kidx.size, lo + BLOCK_ROWS)
            sel = np.flatnonzero((pos < hi) & (ends > lo))
            if sel.size == 0:
                continue
            V, y = self._rows(lo, hi)
            u1 = V[:, :, C : C + 2]
            a = np.cumsum(np.einsum("nci,ncj->nij", u1, V)[::-1], 0)[::-1]
            ay = np.cumsum(np.einsum("nci,nc->ni", u1, y)[::-1], 0)[::-1]
            a = np.concatenate([a, np.zeros((1, 2, self.L))])
            ay = np.concatenate([ay, np.zeros((1, 2))])
            s = np.clip(pos[sel], lo, hi) - lo  # rows from s on within the block ...
            e = np.clip(ends[sel], lo, hi) - lo  # ... up to the run's end
            S1[sel] += a[s] - a[e]
            Sy[sel] += ay[s] - ay[e]
        return S1, Sy

    def _rot(self, z: np.ndarray) -> np.ndarray:
        """``E_r`` per trial zero move ``z`` (K,): (K, L, P), the run's columns in the
        shared ones (its Fourier columns rotated by ``m z``; its constants' slot filled by
        the caller)."""
        C, M = self.nc, self.M
        K = z.size
        E = np.zeros((K, self.L, self.R * C + 2 * M))
        mz = z[:, None] * self.m
        c, s = np.cos(mz), np.sin(mz)
        i = C + 2 * np.arange(M)
        j = self.R * C + 2 * np.arange(M)
        E[:, i, j], E[:, i, j + 1] = c, -s
        E[:, i + 1, j], E[:, i + 1, j + 1] = s, c
        return E

    def chi2(self, Z: np.ndarray, pos: np.ndarray, S1: np.ndarray, Sy: np.ndarray):
        """Chi-square (K, N) of the model with trial zero moves ``Z`` (K, R) and the step
        from each kept-row position ``pos`` (N,) on (``S1``, ``Sy``: :meth:`suffix`)."""
        out = np.zeros((Z.shape[0], pos.size))
        for k0 in range(0, Z.shape[0], BATCH):
            out[k0 : k0 + BATCH] = self._chi2(Z[k0 : k0 + BATCH], pos, S1, Sy, False)
        return out

    def pairs(self, Z: np.ndarray, pos: np.ndarray, S1: np.ndarray, Sy: np.ndarray):
        """Chi-square (N,) of the model with the zero moves ``Z[n]`` and the step from
        ``pos[n]`` on."""
        out = np.zeros(pos.size)
        for k0 in range(0, pos.size, BATCH):
            k1 = k0 + BATCH
            out[k0:k1] = self._chi2(Z[k0:k1], pos[k0:k1], S1[k0:k1], Sy[k0:k1], True)
        return out

    def _chi2(self, Z, pos, S1, Sy, paired: bool):
        C, R, L = self.nc, self.R, self.L
        K = Z.shape[0]
        E = []
        for r in range(R):
            Er = self._rot(Z[:, r])
            Er[:, np.arange(C), r * C + np.arange(C)] = 1.0
            E.append(Er)
        E = np.stack(E, 1)  # (K, R, L, P)
        A = (self.Rr[None] @ E).reshape(K, R * L, -1)
        norm = np.sqrt(np.sum(A**2, 1))  # (K, P): columns scaled to unit norm
        norm = np.where(norm > 0, norm, 1.0)
        Qa, Ra = np.linalg.qr(A / norm[:, None, :])  # B = blockdiag(Q_r) A: basis Q_r Qa
        cy = np.einsum("kip,i->kp", Qa, self.q.ravel())
        res = self.q.ravel()[None, :] - np.einsum("kip,kp->ki", Qa, cy)
        base = self.perp + np.sum(res**2, 1)  # (K,) (the residual itself: no cancellation)
        # the step's coordinates in that basis, X^T B (scaled) Ra^-1, from the directions
        # the fitter determines (Ra's singular values above the root of its pivot
        # tolerance: ``_normal._pivoted_rank`` on the scaled Gram): on part of a turn the
        # base's orders are nearly dependent, and the rest would amplify rounding
        Ur, sr, Wr = np.linalg.svd(Ra)
        live = sr > sr[:, :1] * np.sqrt(PIVOT_TOL)
        Bp = np.swapaxes(Wr, 1, 2) * np.where(live, 1.0 / np.where(live, sr, 1.0), 0.0)[:, None]
        Bp = Bp / norm[:, :, None]
        cy = np.einsum("kpq,kp->kq", Ur, cy) * live  # the data in the same directions
        # the step's columns on run r: u1 rotated by z_r (order 1)
        c1, s1 = np.cos(Z), np.sin(Z)
        Q1 = np.stack([np.stack([c1, -s1], -1), np.stack([s1, c1], -1)], -2)  # (K, R, 2, 2)
        o1 = slice(C, C + 2)
        # whole later runs: X^T B, X^T X, X^T y
        Q1t = np.swapaxes(Q1, -1, -2)
        XBr = Q1t @ (self.T[None, :, o1, :] @ E)
        XXr = Q1t @ self.T[None, :, o1, o1] @ Q1
        Xyr = np.einsum("krai,ra->kri", Q1, self.t[:, o1])

        def after(x):  # sums over the runs after r (index r)
            cs = np.cumsum(x[:, ::-1], 1)[:, ::-1]
            return np.concatenate([cs[:, 1:], np.zeros_like(cs[:, :1])], 1)

        XBt, XXt, Xyt = after(XBr), after(XXr), after(Xyr)
        rp = self.run[pos]
        if paired:  # one zero setting per change point: index n of both
            n = np.arange(pos.size)
            Qp, Ep = Q1[n, rp], E[n, rp]
            QS = np.swapaxes(Qp, -1, -2) @ S1
            XB = QS @ Ep + XBt[n, rp]
            XX = QS[..., o1] @ Qp + XXt[n, rp]
            Xy = np.einsum("nai,na->ni", Qp, Sy) + Xyt[n, rp]
            h = XB @ Bp
            g = Xy - np.einsum("niq,nq->ni", h, cy)
            return base - _gain(XX - np.einsum("niq,njq->nij", h, h), g)
        XB, XX = XBt[:, rp].copy(), XXt[:, rp].copy()  # (K, N, ...)
        Xy = Xyt[:, rp].copy()
        for r in np.unique(rp):  # the change's own run: its rows from the change on
            on = rp == r
            Qr = Q1[:, r]
            QS = np.swapaxes(Qr, -1, -2)[:, None] @ S1[on][None]
            XB[:, on] += QS @ E[:, r][:, None]
            XX[:, on] += QS[..., o1] @ Qr[:, None]
            Xy[:, on] += np.einsum("kai,na->kni", Qr, Sy[on])
        h = XB @ Bp[:, None]
        g = Xy - np.einsum("kniq,kq->kni", h, cy)
        return base[:, None] - _gain(XX - np.einsum("kniq,knjq->knij", h, h), g)


def _gain(
    Gp: np.ndarray,
    g: np.ndarray,
    rtol: float = float(np.finfo(float).eps),
    floor: float = float(np.finfo(float).tiny),
) -> np.ndarray:
    """``g^T Gp^-1 g`` (2 dof) per change point, 0 where ``Gp`` is singular (the step's
    columns, the base's projected out, have no norm left there): ``det(Gp) <= rtol *
    max(tr(Gp), floor)^2``. Also the ``order_step`` view's step gain
    (:func:`._multihead_terms._step_gain`, with its own ``rtol``)."""
    det = Gp[..., 0, 0] * Gp[..., 1, 1] - Gp[..., 0, 1] * Gp[..., 1, 0]
    tr = Gp[..., 0, 0] + Gp[..., 1, 1]
    ok = det > rtol * np.maximum(tr, floor) ** 2
    det = np.where(ok, det, 1.0)
    q = (
        g[..., 0] ** 2 * Gp[..., 1, 1]
        - 2 * g[..., 0] * g[..., 1] * Gp[..., 0, 1]
        + g[..., 1] ** 2 * Gp[..., 0, 0]
    ) / det
    return np.where(ok, np.maximum(q, 0.0), 0.0)


def _refine(sm: _Sums, pos, S1, Sy, Z0: np.ndarray, step: float, rounds: int):
    """Per position (N,) its zero moves refined from ``Z0`` (N, R) by a coordinate search
    whose step halves each round; returns ``(chi2 (N,), Z (N, R))``."""
    Z = Z0.copy()
    best = sm.pairs(Z, pos, S1, Sy)
    N = pos.size
    for _ in range(rounds):
        for r in range(1, sm.R):
            T = np.concatenate([Z, Z])
            T[:N, r] += step
            T[N:, r] -= step
            c = sm.pairs(
                T, np.concatenate([pos, pos]), np.concatenate([S1, S1]), np.concatenate([Sy, Sy])
            ).reshape(2, N)
            k = np.argmin(c, 0)
            better = c[k, np.arange(N)] < best
            Z[better] = T[k * N + np.arange(N)][better]
            best[better] = c[k, np.arange(N)][better]
        step *= 0.5
    return best, Z


def _grid_configs(sm: _Sums, pos, S1, Sy, grid: np.ndarray, cap: int, rounds: int):
    """Per position the least chi-square over trial zero moves on ``grid`` (every later
    run): their product where it has at most ``cap`` settings, else coordinate sweeps of
    one run's grid at a time from the best setting so far (``rounds`` sweeps). Returns
    ``(chi2 (N,), Z (N, R))``."""
    R = sm.R
    if grid.size ** (R - 1) <= cap:
        Z = np.array([(0.0, *z) for z in itertools.product(grid, repeat=R - 1)])
        tab = sm.chi2(Z, pos, S1, Sy)
        k = np.argmin(tab, 0)
        return tab[k, np.arange(pos.size)], Z[k]
    cur = np.zeros(R)
    best = np.full(pos.size, np.inf)
    Zb = np.zeros((pos.size, R))
    for _ in range(rounds):
        for r in range(1, R):
            Z = np.repeat(cur[None, :], grid.size, 0)
            Z[:, r] = grid
            tab = sm.chi2(Z, pos, S1, Sy)
            k = np.argmin(tab, 0)
            c = tab[k, np.arange(pos.size)]
            better = c < best
            best[better], Zb[better] = c[better], Z[k[better]]
            cur = Zb[int(np.argmin(best))].copy()
    return best, Zb


def _located(prep: Prepared, sm: _Sums, pos: np.ndarray, margin: int):
    """``(best, lo, hi)`` kept-row positions of the change profiled with the zeros chosen
    jointly with it, from the change points ``pos`` (see module)."""
    s = prep.settings
    n = sm.kidx.size
    pos = np.unique(np.concatenate([pos, [sm.first[r] for r in range(1, sm.R)]]))
    pos = pos[(pos >= margin) & (pos <= n - margin)]
    if pos.size == 0:
        return None
    nz = int(s.zero_profile_grid)
    grid = np.unique(np.append(-np.pi + 2 * np.pi * np.arange(nz) / nz, 0.0))
    # the data hold the base's disk error (to the noise, 3-300x it or more): where its
    # size and the columns' conditioning leave the chi-square at the fitted zeros off by
    # more than the interval's bound from that of the residual alone (the same model, the
    # data small), the profile cannot locate the change (the view's own stands)
    c = change_chi2(s.change_time_level)
    small = _Sums(sm.prep, sm.rw, sm.kidx, sm.base, disk=False)
    z0 = np.zeros((1, sm.R))
    none = np.zeros((1, 2, sm.L)), np.zeros((1, 2))
    at0 = sm.chi2(z0, pos[:1], *none)[0, 0] - small.chi2(z0, pos[:1], *none)[0, 0]
    if not abs(at0) <= c:
        return None
    S1, Sy = sm.suffix(pos)
    chi, Z = _grid_configs(sm, pos, S1, Sy, grid, s.zero_profile_configs_max, s.zero_profile_rounds)
    step = 2 * np.pi / nz
    # refined where it can matter: the best on the grid first, then every change point
    # whose grid value lies within c of the best refined plus the largest drop a
    # refinement gave so far (the grid's error), until none is left
    done = np.zeros(pos.size, bool)
    todo = np.argsort(chi)[: s.zero_profile_refine]
    drop = 0.0
    while todo.size:
        grid_chi = chi[todo]
        chi[todo], Z[todo] = _refine(
            sm, pos[todo], S1[todo], Sy[todo], Z[todo], step, s.zero_profile_rounds
        )
        done[todo] = True
        drop = max(drop, float(np.max(grid_chi - chi[todo])))
        todo = np.flatnonzero(~done & (chi <= float(np.min(chi[done])) + c + drop))
    kb = int(np.argmin(chi))
    # the best change point's neighbourhood row by row, each row's zeros from the best's
    fine = np.setdiff1d(scan_indices(int(pos[kb]), margin, n - margin), pos)
    if fine.size:
        F1, Fy = sm.suffix(fine)
        Zf = np.repeat(Z[kb][None], fine.size, 0)
        half = s.zero_profile_rounds // 2  # the last half of the schedule: they lie near
        cf, _ = _refine(sm, fine, F1, Fy, Zf, step * 0.5**half, s.zero_profile_rounds - half)
        pos, chi = np.concatenate([pos, fine]), np.concatenate([chi, cf])
    return interval_of(pos, chi, c)


def zero_profile(
    prep: Prepared, rw: np.ndarray, kidx: np.ndarray, cand: np.ndarray, margin: int
) -> tuple[int, dict] | None:
    """``(position, located_time)`` of the ``order_step`` view's change (the kept-row
    position ``kidx[position]`` the first row after it) with the runs' angle zeros chosen
    jointly with it, or ``None`` where this does not apply (:func:`applies`). ``rw``: the
    whitened residual (rows, C), ``cand``: the view's change points (kept-row positions),
    ``margin``: rows kept either side."""
    base = _base(prep)
    if base is None:
        return None
    sm = _Sums(prep, rw, kidx, base)
    cand = np.asarray(cand, int)
    pick = np.linspace(0, cand.size - 1, prep.settings.zero_profile_points).astype(int)
    got = _located(prep, sm, cand[np.unique(pick)], margin)
    return None if got is None else (got[0], located_time(prep, kidx, *got))


def shift_time_profile(fitter, prep: Prepared, terms: list, idx: int, name: str) -> dict | None:
    """The ``located_time`` of ``eccentricity_shift``'s ``shift_time_s`` (``terms[idx]``,
    a step of order 1 as the ``order_step`` view's) with the runs' angle zeros chosen
    jointly with it: the profile of the module on the residual of the other terms, or
    ``None`` where it does not apply (then :func:`...engine._steps.time_param_interval`)."""
    base = _base(prep, terms)
    if base is None:
        return None
    others = [t for i, t in enumerate(terms) if i != idx]
    rw = fitter.residual(others) / np.asarray(prep.sigma, float)[None, :]
    kidx = np.flatnonzero(prep.keep)
    s = prep.settings
    margin = max(s.order_step_margin_rows, int(kidx.size * s.order_step_margin_share))
    tau = np.asarray(prep.rows.take("tau", kidx), float)
    fitted = int(np.searchsorted(tau, float(np.ravel(terms[idx].values[name])[0])))
    pos = np.linspace(0, kidx.size - 1, s.zero_profile_points).astype(int)
    got = _located(prep, _Sums(prep, rw, kidx, base), np.append(pos, fitted), margin)
    return None if got is None else located_time(prep, kidx, *got)
