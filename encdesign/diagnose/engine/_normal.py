"""Issue 43: the accumulated normal equations of a fitter's *static* block.

A block of terms whose free parameters are all linear (the base model with its nonlinear
parameters held, a candidate at held nonlinear values) predicts ``v0 + J p`` with ``v0``
and ``J`` fixed by the held values. Its whitened, projected, scaled residual at scaled
free values ``z`` is ``r(z) = r_ref - S (z - z_ref)`` (``S`` the processed Jacobian,
``r_ref`` the residual at the values ``z_ref`` of the last pass over the rows), so the
per-fold statistics the fitter needs at any ``z`` follow from sums made in that pass,
per fold ``k``: ``G_k = S_k^T S_k`` (the fit's own Gram matrix, summed as the fit sums
it), ``h_k = S_k^T r_ref,k``, ``q_k = |r_ref,k|^2``, and the same unwhitened (each row and
channel divided by ``sqrt(w_c)``, the channel's weight): ``Gu_k``, ``hu_k``, ``qu_k``. With
``dz = z - z_ref``::

    c_k = q_k - 2 dz.h_k + dz^T G_k dz            (whitened chi-square)
    g_k = h_k - G_k dz,  A_k = G_k
    ssr_k = qu_k - 2 dz.hu_k + dz^T Gu_k dz       (unwhitened)

The identities are exact; only their rounding differs from a pass over the rows. The
rounding error of ``c`` is of order ``eps`` times the magnitude of its terms (``q`` and
the two corrections), so :meth:`Accumulated.stats` declines (the fitter then makes the
pass, which sets a new reference) where that magnitude exceeds :data:`CANCEL_MAX` times the
chi-square it would return: ``c`` then carries a relative rounding error of about
``CANCEL_MAX * 2.2e-16`` (``2e-12``) at most, the gradient ``g`` at most that relative to
``|G dz|``. A refit of the same static block on the same observations (the linear step
of a fit, a candidate screened at held values, the backward check, a probe's second
statistics) then costs no pass over the rows.

The Gram matrices of a block do not depend on the observations or the free values: a
block's ``G`` and ``Gu`` are kept (:class:`BlockCache`, keyed by :func:`static_key`) and a
longer block that starts with it (the model and one candidate, one candidate start after
another) sums only its new columns' products (``S^T S_new``); the leading square of any
block's Gram matrix is its leading terms' own, kept too.
"""

from __future__ import annotations

import dataclasses
import functools
import weakref
from collections.abc import Sequence

import jax
import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack

from ._constants import CACHE_BYTES

CANCEL_MAX = 1e4
"""The accumulated statistics are used only while the magnitude of the terms of the
chi-square (``q + 2 |dz.h| + dz^T G dz``) is at most this many times the chi-square itself
(a rounding error of about ``CANCEL_MAX * eps`` relative); beyond it, a pass over the rows."""


def linear_only(term) -> bool:
    """Whether every free parameter of ``term`` is linear (it then joins the static block)."""
    return all(q.linear or not term.free[q.name].any() for q in term.cand.params)


@functools.lru_cache(maxsize=256)
def compiled_valjac(valjac):
    """``jax.jit(valjac)``, one per hand-written ``Candidate.valjac``: the fitter's full
    Jacobian (``_fit.valjac_fn``) and the linear one (:func:`linear_valjac`) call the same
    compiled program (issue 43: a second program keeping only the linear tangents cost each
    process one more XLA compilation per candidate, 0.07-0.1 s each, for the few nonlinear
    columns it saved computing)."""
    return jax.jit(valjac)


@functools.lru_cache(maxsize=256)
def linear_valjac(cand):
    """``f(p, x) -> (v, J)``, compiled: the value of ``cand`` at ``p`` and its Jacobian over
    its *linear* parameters only (a dict by name), the nonlinear ones held at ``p``'s
    values: what a term whose free parameters are all linear needs (:func:`linear_only`),
    without the forward tangents of its nonlinear parameters (the probes' and the static
    block's Jacobians were most of the detection bounds' time, issue 43). A candidate's
    hand-written ``valjac`` is used for its linear tangents only (the compiler drops the
    work of the others). (Only the linear tangents are taken here, in a
    function of their own: jax 0.10.2 mis-evaluated the *nonlinear* half of a split
    Jacobian, ``_fit.valjac_fn``; ``tests/test_fit_fast.py`` checks this one against the
    full ``jacfwd``.)"""
    lin = frozenset(q.name for q in cand.params if q.linear)
    if cand.valjac is not None:
        hand = compiled_valjac(cand.valjac)

        def hv(p, x):  # the linear tangents only, from the one compiled hand-written program
            v, J = hand(p, x)
            return v, {k: J[k] for k in J if k in lin}

        return hv

    def vj(p, x):
        held = {k: v for k, v in p.items() if k not in lin}

        def f(pl):
            return cand.fn({**held, **pl}, x)

        pl = {k: v for k, v in p.items() if k in lin}
        return f(pl), (jax.jacfwd(f)(pl) if pl else {})

    return jax.jit(vj)


_FACTORS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""Candidate -> its factored Jacobian (:func:`register_factors`); an entry goes with its
candidate (a diagnosis builds its own base), so nothing accumulates over diagnoses."""


def register_factors(cand, factors) -> None:
    """Give ``cand`` a factored Jacobian (issue 43): ``factors(p, x, free, rows, full=False)
    -> (v (rows, C), X (rows, F), W (F, C, k), E)`` on a chunk's first ``rows`` rows. The
    Jacobian over the free scalars (gathered by the ``free`` masks, in parameter order) is
    ``J[n, c, j] = sum_f X[n, f] W[f, c, j]`` followed by the columns ``E`` ((rows, C, e) or
    ``None``). Without ``full``: over the linear parameters only (as
    :func:`linear_valjac`), the nonlinear ones held at ``p``'s values, the linear ones at
    zero, ``v`` the value there; with ``full``: at ``p``'s values, every free scalar. Per-row
    features shared by every channel: the fitter caches ``X`` (``F`` numbers a row, not ``C
    k``) and makes the projected, whitened, scaled Jacobian as one matrix product
    (``Fitter._processed``). It must equal the compiled Jacobian to rounding (tested)."""
    _FACTORS[cand] = factors


def factors_of(cand):
    """The function :func:`register_factors` gave ``cand``, or ``None``."""
    return _FACTORS.get(cand)


def static_key(static: Sequence) -> tuple:
    """The identity of a static block's Jacobian: per term its candidate, its nonlinear
    values and its free masks (the linear values do not change the Jacobian)."""
    return tuple(
        (
            id(t.cand),
            tuple(t.values[q.name].tobytes() for q in t.cand.params if not q.linear),
            tuple(t.free[q.name].tobytes() for q in t.cand.params),
        )
        for t in static
    )


def held_key(terms: Sequence) -> tuple:
    """The held (not free) values of ``terms``, as bytes: the static block's prediction
    ``v0`` depends on them (nonlinear ones and linear ones held at a nonzero value)."""
    return tuple(t.values[q.name][~t.free[q.name]].tobytes() for t in terms for q in t.cand.params)


def free_values(terms: Sequence) -> np.ndarray:
    """The free scalars of ``terms`` in parameter order (parameter units)."""
    return np.concatenate(
        [t.values[q.name][t.free[q.name]].ravel() for t in terms for q in t.cand.params]
        or [np.zeros(0)]
    )


def free_scales(terms: Sequence) -> np.ndarray:
    """The scales of the free scalars of ``terms``, in the order of :func:`free_values`
    (scaled value = value / scale, as :meth:`Fitter.stats` scales its columns)."""
    return np.concatenate(
        [t.scale[q.name][t.free[q.name]].ravel() for t in terms for q in t.cand.params]
        or [np.zeros(0)]
    )


@dataclasses.dataclass
class Accumulated:
    """The normal equations of one static block on one set of observations, per fold and
    channel, at reference values (module doc).

    Attributes:
        y: the observations they were summed from (compared by identity: the engine's probes
            give the prepared record new observations).
        held: :func:`held_key` of the block.
        z_ref: the free values at the reference (parameter units).
        sc: the scales of the free values (scaled = value / sc).
        G: ``(K, p, p)`` per-fold Gram matrices of the processed (whitened) Jacobian.
        Gu: ``(K, p, p)`` the same unwhitened.
        h: ``(K, p)`` its products with the reference residual (whitened).
        q: ``(K,)`` the reference residual's whitened sums of squares.
        hu, qu: ``h`` and ``q`` unwhitened.
    """

    y: np.ndarray
    held: tuple
    z_ref: np.ndarray
    sc: np.ndarray
    G: np.ndarray
    Gu: np.ndarray
    h: np.ndarray
    q: np.ndarray
    hu: np.ndarray
    qu: np.ndarray

    def nbytes(self) -> int:
        """Bytes held (the two Gram matrices)."""
        return int(self.G.nbytes + self.Gu.nbytes)

    def stats(self, y, held: tuple, z: np.ndarray, sc: np.ndarray, jac: bool):
        """``(A, g, c, ssr)`` per fold at free values ``z`` (parameter units, scales ``sc``)
        as a pass over the rows would give them, or ``None`` where these sums do not apply
        (other observations, held values or scales) or would round too coarsely
        (:data:`CANCEL_MAX`)."""
        if y is not self.y or held != self.held or not np.array_equal(sc, self.sc):
            return None
        dz = (z - self.z_ref) / np.where(sc != 0, sc, 1.0)
        lin = self.h @ dz
        Gdz = self.G @ dz
        quad = Gdz @ dz
        c = self.q - 2.0 * lin + quad
        size = float(np.sum(self.q) + 2.0 * np.sum(np.abs(lin)) + np.sum(np.abs(quad)))
        if not size <= CANCEL_MAX * max(float(c.sum()), 1e-300):
            return None
        ssr = self.qu - 2.0 * (self.hu @ dz) + (self.Gu @ dz) @ dz
        K, p = self.G.shape[0], self.G.shape[2]
        if not jac:
            return np.zeros((K, p, p)), np.zeros((K, p)), c, ssr
        return self.G.copy(), self.h - Gdz, c, ssr


class BlockCache:
    """A fitter's caches of its static blocks, each within :data:`CACHE_BYTES` (the oldest
    entries dropped first): per chunk the processed Jacobian (``(pred, S, order, edges)`` of
    ``Fitter.processed_block``), per block its Gram matrices ``(G, Gu)`` and its
    :class:`Accumulated` normal equations. Keys are :func:`static_key` s."""

    def __init__(self) -> None:
        self._proc: dict = {}
        self._pbytes = 0
        self._gram: dict = {}
        self._gbytes = 0
        self._acc: dict = {}
        self._abytes = 0

    def clear(self) -> None:
        """Drop everything (after a row column or the weights changed)."""
        self._proc.clear()
        self._gram.clear()
        self._acc.clear()
        self._pbytes = self._gbytes = self._abytes = 0

    def release_processed(self) -> None:
        """Drop the processed Jacobians per chunk (the largest entries), keeping the Gram
        matrices and normal equations: a fitter whose fits are done (issue 43, peak
        memory)."""
        self._proc.clear()
        self._pbytes = 0

    def release_observations(self) -> None:
        """Drop the normal equations (each holds its observations, an (n, C) array),
        keeping their Gram matrices, which do not depend on the observations: for a
        prepared record whose ``y`` is replaced by a new array (no kept normal equations
        match it), so the old one can be freed (issue 43, peak memory)."""
        accs, self._acc, self._abytes = self._acc, {}, 0
        for skey, acc in accs.items():
            self.keep_gram(skey, acc.G, acc.Gu)

    def processed(self, skey: tuple, a: int):
        """The processed Jacobian of block ``skey`` on the chunk from row ``a``, or ``None``."""
        return self._proc.get((skey, a))

    def keep_processed(self, skey: tuple, a: int, hit: tuple) -> None:
        """Keep ``hit`` while the budget allows (never evicts: every pass walks the chunks
        in the same order, so the first chunks stay)."""
        if (skey, a) not in self._proc and self._pbytes + hit[1].nbytes < CACHE_BYTES:
            self._proc[(skey, a)] = hit
            self._pbytes += hit[1].nbytes

    def gram(self, skey: tuple) -> tuple[np.ndarray, np.ndarray] | None:
        """``(G, Gu)`` of block ``skey`` (``(K, p, p)`` each) or ``None``."""
        acc = self._acc.get(skey)
        return (acc.G, acc.Gu) if acc is not None else self._gram.get(skey)

    def keep_gram(self, skey: tuple, G: np.ndarray, Gu: np.ndarray) -> None:
        """Keep the Gram matrices of block ``skey``."""
        if skey in self._acc or skey in self._gram:
            return
        nb = int(G.nbytes + Gu.nbytes)
        while self._gram and self._gbytes + nb > CACHE_BYTES:
            old = self._gram.pop(next(iter(self._gram)))
            self._gbytes -= int(old[0].nbytes + old[1].nbytes)
        self._gram[skey] = (G, Gu)
        self._gbytes += nb

    def accumulated(self, skey: tuple) -> Accumulated | None:
        """The normal equations kept for block ``skey``, or ``None``."""
        return self._acc.get(skey)

    def keep_accumulated(self, skey: tuple, acc: Accumulated) -> None:
        """Keep ``acc`` for block ``skey`` (replacing an older one)."""
        old = self._acc.pop(skey, None)
        self._abytes -= 0 if old is None else old.nbytes()
        while self._acc and self._abytes + acc.nbytes() > CACHE_BYTES:
            self._abytes -= self._acc.pop(next(iter(self._acc))).nbytes()
        self._acc[skey] = acc
        self._abytes += acc.nbytes()

    def longest_prefix(self, static: Sequence) -> int:
        """The most leading terms of ``static`` (fewer than all) whose Gram matrices are
        kept; 0 when none."""
        for k in range(len(static) - 1, 0, -1):
            if self.gram(static_key(static[:k])) is not None:
                return k
        return 0


# ----------------------------------------------------------------------------- solving

PIVOT_TIE = 1e-9
"""Remaining diagonals of the unit-diagonal normal matrix within this of the largest are
tied pivots, broken by column order (:func:`_ordered_pivots`). Equivalent columns (a gauge:
per-run offsets beside a common one, a column repeated) have equal diagonals up to the
rounding of their sums, ~1e-13 at most for another summation order of the same rows: which
of them is kept, and so the gauge-dependent values and the ``unidentifiable`` names, then
follow the columns' order, not the rounding. Far above rounding, far below a difference
between columns that matters to a pivot's size (LAPACK takes the largest)."""


def solve_determined(A: np.ndarray, g: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``(A + lam diag A) dz = g`` on the columns the data determine (pivoted Cholesky,
    relative tolerance 1e-10); the others get 0. Returns (dz, determined indices)."""
    p = A.shape[0]
    if p == 0:
        return np.zeros(0), np.zeros(0, dtype=int)
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d)
    piv, rank = _pivoted_rank(An)
    keep = np.sort(piv[:rank])
    sub = An[np.ix_(keep, keep)] + lam * np.eye(keep.size)
    dz = np.zeros(p)
    try:
        dz[keep] = sla.solve(sub, (g / d)[keep], assume_a="pos") / d[keep]
    except (np.linalg.LinAlgError, ValueError):
        dz[keep] = np.linalg.lstsq(sub, (g / d)[keep], rcond=None)[0] / d[keep]
    return dz, keep


def solve_determined_many(A: np.ndarray, G: np.ndarray) -> np.ndarray:
    """:func:`solve_determined` (``lam = 0``) for the columns of ``G`` at once."""
    p = A.shape[0]
    out = np.zeros((p, G.shape[1]))
    if p == 0:
        return out
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d)
    piv, rank = _pivoted_rank(An)
    keep = np.sort(piv[:rank])
    sub = An[np.ix_(keep, keep)]
    rhs = (G / d[:, None])[keep]
    try:
        out[keep] = sla.solve(sub, rhs, assume_a="pos") / d[keep, None]
    except (np.linalg.LinAlgError, ValueError):
        out[keep] = np.linalg.lstsq(sub, rhs, rcond=None)[0] / d[keep, None]
    return out


def _pivoted_rank(An: np.ndarray, tol: float = 1e-10) -> tuple[np.ndarray, int]:
    """Pivot order and numerical rank of the unit-diagonal normal matrix ``An``: LAPACK's
    pivoted Cholesky (relative tolerance ``tol``); where it leaves columns out (the data do
    not determine them all), the order of :func:`_ordered_pivots` instead, so that which of
    several equivalent columns is kept follows the columns' order, not the rounding of
    their sums (:data:`PIVOT_TIE`)."""
    _, piv, rank, _ = lapack.dpstrf(np.array(An, order="F"), tol=tol, lower=0)
    if int(rank) < An.shape[0] or bool(np.any(np.diag(An) < 1e-200)):
        return _ordered_pivots(An, tol)
    return piv - 1, int(rank)


def _ordered_pivots(An: np.ndarray, tol: float) -> tuple[np.ndarray, int]:
    """Pivoted Cholesky of ``An`` (unit diagonal) whose pivot at each step is the first
    column (in ``An``'s order) of those whose remaining diagonal is within
    :data:`PIVOT_TIE` of the largest; stops where the largest is ``tol`` or less (as
    LAPACK's ``dpstrf``). A column with a zero diagonal is never a pivot. Returns the pivots
    then the other columns (ascending), and the rank."""
    An = np.asarray(An, float)
    p = An.shape[0]
    d = np.diag(An)
    left = np.where(d < 1e-200, -np.inf, d)  # remaining diagonal; -inf: a pivot or zero
    L = np.empty((p, p))
    piv: list[int] = []
    for k in range(p):
        top = float(left.max(initial=-np.inf))
        if not top > tol:  # (a NaN stops too)
            break
        j = int(np.argmax(left >= max(top - PIVOT_TIE, tol)))  # the first of the ties
        col = (An[:, j] - L[:, :k] @ L[j, :k]) * (1.0 / np.sqrt(left[j]))
        L[:, k] = col  # (the rows of earlier pivots: rounding, never read)
        col *= col
        left -= col  # (-inf stays)
        left[j] = -np.inf
        piv.append(j)
    rest = np.setdiff1d(np.arange(p), piv)
    return np.concatenate([np.asarray(piv, int), rest]).astype(int), len(piv)
