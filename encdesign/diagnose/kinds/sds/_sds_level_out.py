"""The SDS run-mean level without the structure a test is testing (issue 41, session 23).

The run-mean level (:func:`._sds_noise._level_sigma`) is ``sqrt(SSR / nu)`` of the
saturated fit's residual, widened for its ``nu`` degrees of freedom. A structure that no
saturating column spans and that is too weak for the level's own search (an order of one
moving sensor at 2x the noise: about a third of its power is left by the saturating
columns) stays in ``SSR`` and is counted as noise: the test of that very structure then
divides by a level it inflated itself (1.26-1.51x for a static one-sensor order at 2x on the
discovery benchmark's records, session 22's audit), and its chi-square falls by that ratio
squared.

A test of columns ``X`` (a located order of one sensor, a discovered term) is therefore
read against the level **without** ``X``: the saturated fit's residual ``e`` less its
projection on ``X`` (made orthogonal to the saturating and taken columns ``Q``; rank ``r``),
``s'^2 = (SSR - g_X) / (nu - r)``, widened for ``nu - r`` degrees of freedom
(:func:`._sds_noise.dof_widening`), the common factor recomputed at ``s'``. This is the
F-test's denominator: under noise alone ``g_X`` and ``SSR - g_X`` are independent
chi-squares of ``r`` and ``nu - r`` degrees of freedom (``X`` reaches the test's residual
only through directions orthogonal to ``Q``, the base's columns are inside ``Q``), so the
test stays at its level (the widening turns the F-test's threshold into the engine's
chi-square one, as for the level itself), while a structure in ``X`` no longer dilutes its
own test. The factor a test's chi-square is multiplied by is ``(sigma / sigma')^2``
(:func:`level_factor`), where ``sigma`` is the run-mean level the record is whitened with.
The ``modulated_orders`` view's growths and switches are read the same way
(:func:`modulated_scale`: the order's cos / sin times the shape), so a growing or switching
order no longer dilutes its own test either (session 23, s23-mod41).

The common factor ``g`` (:func:`._sds_noise._common_factor`, capped by
:func:`._sds_noise._direct_common_factor`) models the run means' noise as ``s^2`` on every
component plus an excess ``e = s^2 (g^2 - 1)`` on the moving sensors' common component only
(the fixed sensors' timing noise, the same in every pair of a run): covariance
``s^2 I + e P_c``, ``P_c`` the projector on the per-run means over the moving sensors. A test
of columns ``X`` then sees ``s^2 + e kappa`` with ``kappa = tr(P_X P_c) / rank(X)``
(:func:`common_share`): 1 for a pattern common to the moving sensors, ``1 / M`` for an order
of one sensor, 0 for their differences. Its level without its columns is therefore
``s' c(nu - r) sqrt(1 + kappa (g(s')^2 - 1))`` (session 27, with
``FinderSettings.sds_level_common_share`` on, the default since s27-sds27b; the ``run_step``
view's steps and outliers are read so too, :func:`run_step_scale`, so every one-sensor test
is read at its share and the views' findings rank like with like): the same as before for
common patterns, a factor ``g`` no longer charged in full to a one-sensor test (``g`` =
1.0-1.35 on the discovery benchmark's SDS records, while the true common level there was
0.5-1.5 times the differences'; ``tests/test_sds_level_out.py``: a one-sensor test keeps its
false-alarm rate at its share of a common excess 3 ``s^2``, and was 20 times below it with
the full factor). The level the record is whitened with keeps the full factor (``kappa =
1``). Since session 38 (``FinderSettings.sds_level_per_component``, on since session
41) a test's common part is read at the common component's own level where that is below
session 27's (:mod:`._sds_level_component`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ._sds_clock_lock import lock_mixed_factor
from ._sds_level_common import CommonPart
from ._sds_level_component import ComponentLevel


class RunMeanLevel:
    """``sigma_of(s, nu)`` on arrays: the run-mean level (rad) of raw levels ``s`` (rad) with
    ``nu`` degrees of freedom, ``s c(nu) g(s)``, as :func:`._sds_noise._level_sigma` makes
    it: ``c = widen(nu)`` (:func:`._sds_noise.dof_widening`, once per distinct ``nu``) and
    the common factor ``g(s) = sqrt(1 + excess / s^2)`` (:func:`._sds_noise._common_factor`,
    ``excess`` (rad^2) its ``e``, 0 where the run means are projected on the differences),
    capped by ``sqrt(max(1, ucl / s^2))`` (:func:`._sds_noise._direct_common_factor`, ``ucl``
    (rad^2) its upper confidence limit; ``None``: no cap), or mixed with it at the share
    ``lock`` (:func:`._sds_clock_lock.lock_mixed_factor`). Neither ``excess`` nor ``ucl``
    depends on ``s``: :class:`LevelOut` reads hundreds of levels without a Python call
    each, equal to those functions' (``tests/test_sds_level_out.py``)."""

    def __init__(
        self,
        widen: Callable[[float], float],
        excess: float,
        ucl: float | None,
        lock: float = 0.0,
        rounding: float = 0.0,
    ):
        self.widen, self.excess, self.ucl, self.lock = widen, float(excess), ucl, float(lock)
        self.rounding = float(rounding)

    def widening(self, nu, p: float | None = None) -> np.ndarray:
        """``c = widen(nu)`` on an array of degrees of freedom (once per distinct value);
        ``p``: the test's false-alarm probability, passed on as ``widen(nu, p)`` (``None``:
        ``widen``'s own, the level's ``sds_sigma_test_p``)."""
        nu = np.asarray(nu)
        vals, inv = np.unique(nu, return_inverse=True)
        w = (lambda v: self.widen(v)) if p is None else (lambda v: self.widen(v, p))
        return np.array([w(float(v)) for v in vals.ravel()])[inv].reshape(nu.shape)

    def __call__(self, s, nu, share=None, p: float | None = None) -> np.ndarray:
        """The level (rad) at raw levels ``s`` with ``nu`` degrees of freedom; ``share``
        (same shape, 0..1; ``None``: 1): the tested columns' share ``kappa`` in the moving
        sensors' common component (:func:`common_share`), whose factor is then
        ``sqrt(1 + kappa (g^2 - 1))`` (module doc: the common part's excess reaches a
        test only through its common component)."""
        s, nu = np.asarray(s, float), np.asarray(nu)
        c = self.widening(nu, p)
        g = self.common_factor(s, test=share is not None)
        if share is not None:
            g = np.sqrt(1.0 + np.clip(np.asarray(share, float), 0.0, 1.0) * (g**2 - 1.0))
        return s * c * g

    def common_factor(self, s, test: bool = False) -> np.ndarray:
        """The common factor ``g(s)`` (no unit, at least 1 where ``ucl`` is given) at raw
        levels ``s`` (rad): the moving sensors' common component at ``s g(s)`` (class
        doc). ``test``: a test's level (read at its columns' share), whose excess is at
        least ``rounding`` (rad^2, :func:`._sds_clock_lock.rounding_common_excess`: the
        clock's rounding constant within a run, which only the common component holds;
        session 42; ``FinderSettings.sds_clock_lock_level`` 3, else 0), as the common views
        read it (``SDSNoiseInfo.common_scale``); the whitening level (``test`` false) does not."""
        s = np.asarray(s, float)
        excess = max(self.excess, self.rounding) if test else self.excess
        g = np.sqrt(1.0 + excess / s**2)
        if self.ucl is not None:
            g = lock_mixed_factor(g, np.sqrt(np.maximum(1.0, self.ucl / s**2)), self.lock)
        return g


class LevelOut:
    """``factor(cols) -> (sigma / sigma')^2`` (module doc) for columns ``cols`` (R, M, q)
    on the run means (rows in the level's order: the kept runs), projected on the
    moving-sensor differences where the run means are (``proj``); :meth:`pairs` for many
    pairs of columns at once.

    ``e`` (R*M,): the saturated fit's residual; ``Q`` (R*M, k): the orthonormal basis it is
    the residual of (saturating columns and the change points, outliers and one-sensor orders
    the level took); ``n_ind``: the independent values; ``sigma_of(s_raw, nu)``: the run-mean
    level from raw levels and their degrees of freedom, element by element on arrays
    (widening and common factor, as :func:`._sds_noise._level_sigma` makes it:
    :class:`RunMeanLevel`). A direction of the columns that ``Q`` holds
    (its part off ``Q`` below ``1e-6`` of the columns' norm) is no degree of freedom of the
    level (it is not in ``e``); fewer than 3 degrees of freedom left: factor 1. ``share``:
    the common factor charged at the tested columns' share (:func:`common_share`;
    ``FinderSettings.sds_level_common_share``, given where the level is built,
    :func:`._sds_noise.run_mean_levels`), fixed at construction (:attr:`share`). ``common``
    (with the share, a :class:`RunMeanLevel` and the run means not projected): the base
    residual's run means (R, M) and the base's common columns (R, k), whose common component
    (:class:`._sds_level_common.CommonPart`) at its own unbiased
    level then replaces the common factor in a test's level where it has degrees of freedom
    left (``FinderSettings.sds_level_common_direct``, session 28). ``component`` (with
    ``common``): that level taken only where it is below session 27's
    (:class:`._sds_level_component.ComponentLevel`,
    ``FinderSettings.sds_level_per_component``, session 38)."""

    def __init__(
        self,
        e,
        Q,
        n_ind: int,
        sigma_of: Callable[..., float | np.ndarray],
        proj,
        M,
        share: bool = False,
        common: tuple[np.ndarray, np.ndarray] | None = None,
        component: bool = False,
    ):
        self.e, self.Q, self.sigma_of, self.proj, self.M = e, Q, sigma_of, bool(proj), int(M)
        self._share = bool(share)
        direct = self._share and not self.proj and isinstance(sigma_of, RunMeanLevel)
        part = ComponentLevel if component else CommonPart
        self.common = part(*common) if direct and common is not None else None
        self.ssr = float(e @ e)
        self.nu = int(n_ind - Q.shape[1])
        ok = self.nu > 0 and self.ssr > 0
        self.memo: dict = {}  # orders_scale per (angles, orders, channels): views re-run often
        self.sigma = float(sigma_of(math.sqrt(self.ssr / self.nu), self.nu)) if ok else 0.0

    @property
    def share(self) -> bool:
        """Whether a test's common factor is charged at its columns' share (module doc);
        set when the level is built, never after (the views and discovery share one
        level)."""
        return self._share

    def _off(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``X`` (R, M, ...) projected as the run means are, flattened to (R*M, -1), and
        less its part in ``Q``; and the columns' squared norms before."""
        if self.proj:
            X = X - X.mean(1, keepdims=True)
        X = X.reshape(X.shape[0] * X.shape[1], -1)
        return X - self.Q @ (self.Q.T @ X), np.sum(X**2, 0)

    def _factor(
        self, g: np.ndarray, r: np.ndarray, share=None, gc=None, p: float | None = None
    ) -> np.ndarray:
        """``(sigma / sigma')^2`` per power ``g`` taken by columns of rank ``r`` (arrays of
        one shape): one call of ``sigma_of`` on all of them (session 24: a call per entry
        was a fifth of an SDS record's discovery time). ``share`` (same shape): the
        columns' share in the common component (:func:`common_share`), passed on to
        ``sigma_of`` where it takes one (:class:`RunMeanLevel`); ``None``: the full
        common factor. ``gc`` (two arrays of that shape, with ``common``): the power the
        columns' common parts take from the common component and their rank
        (:class:`._sds_level_common.CommonPart`): the level with the common component at
        its own level where it is defined."""
        g, r = np.asarray(g, float), np.asarray(r, int)
        out = np.ones(g.shape)
        # r = 0 (the columns inside Q: the level took them already): s' = s, only the share
        idx = np.flatnonzero(((r > 0) | (share is not None)) & (self.nu - r >= 3))
        n = self.nu - r.ravel()[idx]
        s2 = np.maximum(self.ssr - g.ravel()[idx], 0.0) / n
        keep = s2 > 0
        idx, n, s2 = idx[keep], n[keep], s2[keep]
        if idx.size:
            if share is not None and isinstance(self.sigma_of, RunMeanLevel):
                k = np.asarray(share, float).ravel()[idx]
                sig = np.asarray(self.sigma_of(np.sqrt(s2), n, k, p), float)
                level = self.sigma_of

                def widen(nu):  # the widening at the test's own p (None: the level's)
                    return level.widening(nu, p)

                if self.common is not None and gc is not None:  # (set only on a RunMeanLevel)
                    pc, rc = (np.asarray(a).ravel()[idx] for a in gc)
                    if isinstance(self.common, ComponentLevel):
                        g2 = self.sigma_of.common_factor(np.sqrt(s2), test=True) ** 2
                        sig = self.common.capped(widen, s2, n, k, pc, rc, sig, s2 * g2)
                    else:
                        own = self.common.levels(widen, s2, n, k, pc, rc)
                        sig = np.where(np.isfinite(own), own, sig)
            else:
                sig = np.asarray(self.sigma_of(np.sqrt(s2), n), float)
            out.flat[idx] = (self.sigma / sig) ** 2
        return out

    def __call__(self, cols: np.ndarray) -> float:
        X = np.asarray(cols, float)
        if X.ndim != 3 or X.shape[1] != self.M or not self.sigma > 0:
            return 1.0
        Xp, n2 = self._off(X)
        if not np.any(n2 > 0):  # no column at all
            return 1.0
        U, s, _ = np.linalg.svd(Xp, full_matrices=False)
        U = U[:, s > 1e-6 * math.sqrt(float(n2.max()))]
        g = float(np.sum((U.T @ self.e) ** 2))
        k = common_share(X if not self.proj else X - X.mean(1, keepdims=True))
        k = np.array([k]) if self.share else None
        gc = None
        if self.common is not None:
            pc, rc = self.common.power(X)
            gc = (np.array([pc]), np.array([rc]))
        return float(self._factor(np.array([g]), np.array([U.shape[1]]), k, gc)[0])

    def pairs(self, A: np.ndarray, p: float | None = None) -> np.ndarray:
        """``(G,)``: the factor of each pair of columns of ``A`` (R, M, G, 2); ``p``: the
        tests' false-alarm probability the level is widened at (``None``: the level's own,
        ``sds_sigma_test_p``; only with the share, on a :class:`RunMeanLevel`)."""
        if not self.sigma > 0:
            return np.ones(A.shape[2])
        Xp, n2 = self._off(A)
        G = A.shape[2]
        P = Xp.reshape(-1, G, 2)
        gram = np.einsum("ngi,ngj->gij", P, P)
        ev, V = np.linalg.eigh(gram)  # (G, 2), (G, 2, 2)
        big = ev > 1e-12 * n2.reshape(G, 2).max(1)[:, None]
        b = np.einsum("n,ngi->gi", self.e, P)
        proj = np.einsum("gi,gij->gj", b, V)  # b along the eigenvectors
        g = np.sum(np.where(big, proj**2 / np.where(big, ev, 1.0), 0.0), 1)
        k = pair_shares(A if self.share and not self.proj else None)
        gc = self.common.pair_powers(A) if self.common is not None else None
        return self._factor(g, big.sum(1), k, gc, p)


def common_share(X: np.ndarray) -> float:
    """``kappa = tr(P_X P_c) / rank(X)``: the share of columns ``X`` (R, M, q) on the run
    means in the moving sensors' common component (``P_c``: per run, the mean over the
    moving sensors; ``P_X``: the projector on the columns' span). 1 for a pattern common to
    the moving sensors, ``1 / M`` for a pattern of one sensor, 0 for the sensors'
    differences; 1 for columns of rank 0 (nothing to weigh)."""
    X = np.asarray(X, float)
    R, M = X.shape[0], X.shape[1]
    F = X.reshape(R * M, -1)
    U, s, _ = np.linalg.svd(F, full_matrices=False)
    U = U[:, s > 1e-9 * max(float(s.max(initial=0.0)), 1e-300)]
    if U.shape[1] == 0:
        return 1.0
    c = U.reshape(R, M, -1).sum(1) / math.sqrt(M)  # (R, rank): the common Helmert parts
    return float(np.sum(c**2) / U.shape[1])


def pair_shares(A: np.ndarray | None) -> np.ndarray | None:
    """``(G,)``: :func:`common_share` of each pair of columns of ``A`` (R, M, G, 2), from
    the pair's 2x2 Gram matrices (all of ``A`` and its common part), ``tr(G^+ G_c) /
    rank``; ``None`` for ``None`` (run means projected on the differences: no common
    factor to weigh)."""
    if A is None:
        return None
    A = np.asarray(A, float)
    M = A.shape[1]
    c = A.sum(1) / math.sqrt(M)  # (R, G, 2)
    gram = np.einsum("rmgi,rmgj->gij", A, A)
    gc = np.einsum("rgi,rgj->gij", c, c)
    ev, V = np.linalg.eigh(gram)
    big = ev > 1e-12 * np.maximum(ev.max(1, keepdims=True), 1e-300)
    inv = np.where(big, 1.0 / np.where(big, ev, 1.0), 0.0)
    pinv = np.einsum("gik,gk,gjk->gij", V, inv, V)
    r = big.sum(1)
    tr = np.einsum("gij,gji->g", pinv, gc)
    return np.where(r > 0, tr / np.maximum(r, 1), 1.0)


def order_columns(phi: np.ndarray, M: int, order: int, sensor: int) -> np.ndarray:
    """``(R, M, 2)``: cos / sin of ``order`` times the platform angles ``phi`` (one per run)
    on moving sensor ``sensor``'s run means only (the ``orders`` view's test on that
    channel)."""
    phi = np.asarray(phi, float)
    X = np.zeros((phi.size, M, 2))
    X[:, sensor, 0] = np.cos(order * phi)
    X[:, sensor, 1] = np.sin(order * phi)
    return X


def orders_scale(factor: LevelOut, phi: np.ndarray, M: int, max_order: int, C: int) -> np.ndarray:
    """``(max_order, C)``: per order ``1..max_order`` and channel the factor on the
    ``orders`` view's chi-square (:class:`LevelOut` of that order on that moving sensor's
    run means; 1 on the other channels)."""
    phi = np.asarray(phi, float)
    key = (phi.tobytes(), int(M), int(max_order), int(C), factor.share)
    if key in factor.memo:
        return factor.memo[key]
    m = np.arange(1, max_order + 1)
    cs = np.stack([np.cos(np.outer(phi, m)), np.sin(np.outer(phi, m))], -1)  # (R, L, 2)
    A = np.zeros((phi.size, M, M, max_order, 2))
    for k in range(M):
        A[:, k, k] = cs
    out = np.ones((max_order, C))
    out[:, :M] = factor.pairs(A.reshape(phi.size, M, M * max_order, 2)).reshape(M, max_order).T
    out.setflags(write=False)
    factor.memo[key] = out
    return out


def modulated_scale(
    factor: LevelOut, phi: np.ndarray, shapes: np.ndarray, M: int, max_order: int, C: int
) -> np.ndarray:
    """``(S, max_order, C)``: per amplitude shape (``shapes`` (S, R): the ``modulated_orders``
    view's growth, decay and switches on the run means, rows in the level's order), order
    ``1..max_order`` and channel the factor on that view's chi-square: :class:`LevelOut` of
    the order's cos / sin times the shape on that moving sensor's run means (a growth or a
    step is read against the level without itself, as a static order is in
    :func:`orders_scale`); 1 on the other channels."""
    phi = np.asarray(phi, float)
    W = np.asarray(shapes, float)
    key = ("modulated", phi.tobytes(), W.tobytes(), W.shape, int(M), int(max_order), int(C))
    key = (*key, factor.share)
    if key in factor.memo:
        return factor.memo[key]
    S, R = W.shape
    m = np.arange(1, max_order + 1)
    cs = np.stack([np.cos(np.outer(phi, m)), np.sin(np.outer(phi, m))], -1)  # (R, L, 2)
    A = np.zeros((R, M, S, M, max_order, 2))
    for k in range(M):
        A[:, k, :, k] = W.T[:, :, None, None] * cs[:, None]
    out = np.ones((S, max_order, C))
    f = factor.pairs(A.reshape(R, M, S * M * max_order, 2)).reshape(S, M, max_order)
    out[:, :, :M] = np.moveaxis(f, 1, 2)
    out.setflags(write=False)
    factor.memo[key] = out
    return out


def run_step_scale(factor: LevelOut, keep: np.ndarray, M: int) -> tuple[np.ndarray, np.ndarray]:
    """``(M, R)`` twice: per moving sensor the factor on the ``run_step`` view's chi-square
    of a step from run ``k`` on (column 0 unused: no step) and of an outlier at run ``k``
    (:class:`LevelOut` of the centred step / indicator on that sensor's run means, rows
    ``keep`` of the ``R`` runs in the level's order), so a one-sensor step or outlier is read
    at its share of the common factor as the ``orders`` and ``modulated_orders`` views'
    one-sensor tests are (session 27: the ranking of the views' findings compares like with
    like; used where ``FinderSettings.sds_level_common_share`` is on)."""
    keep = np.asarray(keep, bool)
    R = keep.size
    key = ("run_step", keep.tobytes(), int(M), factor.share)
    if key in factor.memo:
        return factor.memo[key]
    j = np.arange(R)
    steps = (j[None, :] >= j[:, None]).astype(float)  # (k, R): on from run k
    steps -= steps.mean(1, keepdims=True)
    outl = np.eye(R) - 1.0 / R
    shapes = np.concatenate([steps, outl])[:, keep]  # (2R, kept)
    S, n = shapes.shape
    A = np.zeros((n, M, M, S, 2))
    for m in range(M):
        A[:, m, m, :, 0] = shapes.T
    f = factor.pairs(A.reshape(n, M, M * S, 2)).reshape(M, S)
    out = (f[:, :R], f[:, R:])
    for a in out:
        a.setflags(write=False)
    factor.memo[key] = out
    return out


def common_shapes_scale(
    factor: LevelOut, phi: np.ndarray, shapes: np.ndarray, orders: np.ndarray, p: float
) -> np.ndarray:
    """``(S, L)``: per amplitude shape (``shapes`` (S, R): 1 for a static order, the
    ``common_modulated`` view's growths and switches) and order of ``orders`` (L,) the factor
    on the chi-square of a pattern common to the moving sensors, ``cos / sin (n phi)`` times the
    shape on every moving sensor's run means (``phi`` (R,) the platform angle, rad; rows in
    the level's order): :class:`LevelOut` of those columns, so a common pattern is read
    against the run-mean level without itself and with the common component at its own level
    where that is below session 27's (:mod:`._sds_level_component`; issue 41, session 42: the
    ``common_orders`` and ``common_modulated`` views read at the whitening level had tested a
    2x platform step at 2.1-2.3x its true noise). ``p``: the false-alarm probability of each
    test (the view's threshold's): the level is widened at it, so a common component of few
    degrees of freedom does not raise the rate at the view's Bonferroni-small ``p``
    (``FinderSettings.sds_sigma_test_p`` is 1e-4; at 2e-6 and 17 degrees of freedom its
    widening lets six times the rate through)."""
    phi = np.asarray(phi, float)
    W = np.asarray(shapes, float)
    o = np.asarray(orders, float)
    key = ("common", phi.tobytes(), W.tobytes(), W.shape, o.tobytes(), factor.share, p)
    if key in factor.memo:
        return factor.memo[key]
    S, R = W.shape
    ang = np.outer(phi, o)  # (R, L)
    cs = np.stack([np.cos(ang), np.sin(ang)], -1)  # (R, L, 2)
    A = W.T[:, :, None, None] * cs[:, None]  # (R, S, L, 2)
    A = np.repeat(A.reshape(R, 1, S * o.size, 2), factor.M, axis=1)
    out = factor.pairs(A, p).reshape(S, o.size)
    out.setflags(write=False)
    factor.memo[key] = out
    return out
