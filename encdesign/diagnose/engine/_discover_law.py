"""Discovery's linear algebra and speed law (issue 41): the pseudo-inverse on the scaled
Gram (directions the catalog model spans dropped), a term's chi-square gain, and the speed
exponent's fit and standard error, and the library's term and per-fold sums (split from
:mod:`._discover` for the module size)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from scipy import optimize

from ._discover_lines import Line


@dataclasses.dataclass
class Term:
    """One library term: ``line``, ``frame``, ``modulation``; ``H`` maps its parameters to
    the line's full block; ``beta`` the speed exponent (``speed`` modulation); ``step`` its
    change time (``step`` modulation, :func:`locate_steps`); ``level``: a ``growth`` term that
    holds its own level (its first half of ``H``, :mod:`._discover_growth`); ``decay``: the
    decay time a ``ringdown`` term shares over the runs and its standard error
    (:func:`._discover_ring.locate_ringdowns`)."""

    line: int
    frame: str
    modulation: str
    H: np.ndarray
    beta: float | None = None
    beta_se: float | None = None
    H0: np.ndarray | None = None
    step: dict | None = None
    level: bool = False
    decay: dict | None = None

    @property
    def name(self) -> str:
        return f"{self.frame} / {self.modulation} @ line {self.line}"

    @property
    def n_params(self) -> int:
        """Parameters the term fits: its linear ones, a speed exponent, a decay time."""
        return self.H.shape[1] + (self.beta is not None) + (self.decay is not None)


@dataclasses.dataclass
class Sums:
    """Per-fold sums of the full blocks, made orthogonal to the catalog model's Jacobian.

    ``A`` (K, Q, Q), ``b`` (K, Q): Gram and products with the whitened residual; ``raw``
    (K, Q, Q): the Gram before the projection (a direction the catalog model spans keeps
    nothing of its raw norm, and is dropped); ``rr``
    (K,): the residual's chi-square per fold; ``slices``: each line's columns in ``Q``;
    ``layout``: per line ``(n_blocks, S, C, n_basis)``; ``scales``: the centres and half
    spans of the growth (``tau``) and temperature (``driver``) modulations."""

    A: np.ndarray
    b: np.ndarray
    rr: np.ndarray
    raw: np.ndarray
    slices: list[slice]
    layout: list[tuple[int, int, int, int]]
    blocks: list[str]
    scales: dict


BETA_RANGE = (-4.0, 4.0)
"""Range searched for a speed exponent."""


KEEP_SHARE = 1e-6
"""A direction of a term keeps at least this share of its raw norm after the projection on
the catalog model, else the catalog model spans it and it is dropped."""


def _psolve(
    A: np.ndarray, B: np.ndarray, rtol: float = 1e-10, raw: np.ndarray | None = None
) -> np.ndarray:
    """``A^+ B`` for a symmetric positive semi-definite ``A``, on the unit-diagonal scaled
    matrix (columns of very different sizes): eigenvalues under ``rtol`` times the largest
    dropped; with ``raw`` (the Gram before a projection), scaled by its diagonal instead and
    eigenvalues under :data:`KEEP_SHARE` dropped (directions the projection took)."""
    if A.size == 0:
        return np.zeros((0,) + B.shape[1:])
    d = np.sqrt(np.maximum(np.diag(A if raw is None else raw), 0.0))
    d = np.where(d > 0, d, 1.0)
    An = A / d[:, None] / d[None, :]
    ev, V = np.linalg.eigh(An)
    tol = rtol * max(float(ev.max()), 1e-300) if raw is None else KEEP_SHARE
    keep = ev > tol
    inv = np.where(keep, 1.0 / np.where(keep, ev, 1.0), 0.0)
    Bn = B / d.reshape((-1,) + (1,) * (B.ndim - 1))
    VB = V.T @ Bn
    X = V @ (inv.reshape((-1,) + (1,) * (VB.ndim - 1)) * VB)
    return X / d.reshape((-1,) + (1,) * (X.ndim - 1))


def _speed_H(term: Term, lay, beta: float, speed: np.ndarray) -> np.ndarray:
    """The speed term's restriction: the frame scaled per cell by ``(speed / geometric
    mean)^beta`` (``term.H0``: the static restriction). Where the catalog model already
    spans the static frame, the projection leaves only the law's shape; near ``beta = 0``
    that shape has no norm left and is dropped (:data:`KEEP_SHARE`)."""
    if term.H0 is None:
        raise ValueError(f"discovery: speed term of line {term.line} has no static restriction H0")
    f = (speed / math.exp(np.mean(np.log(np.maximum(speed, 1e-12))))) ** beta
    nb, S, C, nj = lay
    scale = np.broadcast_to(f[None, :, None, None], (nb, S, C, nj)).reshape(-1)
    return term.H0 * scale[:, None]


def _gain(A: np.ndarray, b: np.ndarray, raw: np.ndarray | None = None) -> float:
    """In-sample chi-square drop ``b' A^+ b`` (``raw``: see :func:`_psolve`)."""
    return float(b @ _psolve(A, b, raw=raw)) if b.size else 0.0


def _gain_in(H: np.ndarray, A: np.ndarray, b: np.ndarray, raw: np.ndarray) -> float:
    """In-sample chi-square drop of the restriction ``H`` (columns in the coordinates of the
    summed sums ``A``, ``b``, ``raw``): :func:`_gain` of its projected Gram."""
    return _gain(H.T @ A @ H, H.T @ b, H.T @ raw @ H)


def _fit_beta(term: Term, lay, sl: slice, sums: Sums, speed: np.ndarray, infl: float) -> None:
    """The speed exponent minimising chi-square, and its standard error (profile curvature,
    inflated by ``infl``, the residual's chi-square per value when above 1)."""
    At, bt, Rt = sums.A.sum(0)[sl, sl], sums.b.sum(0)[sl], sums.raw.sum(0)[sl, sl]

    def g(beta: float) -> float:
        return -_gain_in(_speed_H(term, lay, beta, speed), At, bt, Rt)

    grid = np.linspace(*BETA_RANGE, 33)
    vals = [g(v) for v in grid]
    i = int(np.argmin(vals))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    res = optimize.minimize_scalar(g, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    bh = float(res.x)
    h = 1e-3
    curv = (g(bh + h) - 2 * g(bh) + g(bh - h)) / h**2
    term.beta = bh
    term.beta_se = float(math.sqrt(2.0 / curv) * math.sqrt(max(infl, 1.0))) if curv > 0 else None
    term.H = _speed_H(term, lay, bh, speed)


def _sibling(tm: Term, lib: Sequence[Term], modulation: str) -> Term | None:
    """The term of ``lib`` at ``tm``'s line and frame with ``modulation``."""
    return next(
        (
            u
            for u in lib
            if u.line == tm.line and u.frame == tm.frame and u.modulation == modulation
        ),
        None,
    )


def _scatter_se(tm: Term, lib: Sequence[Term], sums: Sums) -> None:
    """The speed exponent's standard error with the run-to-run scatter about the law: scaled
    by the square root of the chi-square per degree of freedom by which each run's own
    amplitude and phase (the ``per_cell`` term of the same frame) beats the law, when above
    1 (a Birge ratio: the law's own misfit across the runs, not only the noise)."""
    pc = _sibling(tm, lib, "per_cell")
    if pc is None or tm.beta_se is None:
        return
    sl = sums.slices[tm.line]
    At, bt, Rt = sums.A.sum(0)[sl, sl], sums.b.sum(0)[sl], sums.raw.sum(0)[sl, sl]

    def g(H: np.ndarray) -> float:
        return _gain_in(H, At, bt, Rt)

    dof = pc.H.shape[1] - tm.H.shape[1] - 1
    if dof > 0:
        tm.beta_se *= math.sqrt(max((g(pc.H) - g(tm.H)) / dof, 1.0))


def _embed(sums: Sums, terms: Sequence[Term]) -> np.ndarray:
    """The joint restriction ``(Q, sum q)`` of ``terms``."""
    Q = sums.A.shape[1]
    Hs = []
    for tm in terms:
        H = np.zeros((Q, tm.H.shape[1]))
        H[sums.slices[tm.line]] = tm.H
        Hs.append(H)
    return np.concatenate(Hs, 1) if Hs else np.zeros((Q, 0))


def _heldout(
    A: np.ndarray, b: np.ndarray, H: np.ndarray, folds: Sequence[int], raw: np.ndarray
) -> float:
    """K-fold held-out chi-square drop of the model ``H`` over ``folds``: fitted without each
    fold, scored on it (``raw``: the Gram before the projection, per fold)."""
    rows = np.flatnonzero(np.any(H != 0, 1))  # the columns of the lines it touches
    H = H[rows]
    Af = H.T @ (A[:, rows][:, :, rows] @ H)
    Rf = H.T @ (raw[:, rows][:, :, rows] @ H)
    bf = b[:, rows] @ H
    At, bt, Rt = Af[list(folds)].sum(0), bf[list(folds)].sum(0), Rf[list(folds)].sum(0)
    out = 0.0
    for k in folds:
        beta = _psolve(At - Af[k], bt - bf[k], raw=Rt - Rf[k])
        out += float(2 * beta @ bf[k] - beta @ Af[k] @ beta)
    return out


def _same_span(sums: Sums, a: Term, b: Term) -> bool:
    """Whether two terms at one line span the same columns once the catalog model is
    projected out (e.g. one sensor's ``forward``, ``reverse``, ``direction`` and the one
    reverse run's ``cell`` where the base holds the static order): the record cannot tell
    them apart, so a repeat of the selection that takes either includes both (ties broken
    by rounding would otherwise split the inclusion probability)."""
    q = a.H.shape[1]
    if a is b or a.line != b.line or b.H.shape[1] != q or a.beta is not None or b.beta is not None:
        return a is b
    sl = sums.slices[a.line]
    At, Rt = sums.A.sum(0)[sl, sl], sums.raw.sum(0)[sl, sl]

    def rank(H: np.ndarray) -> int:
        # on the unit-diagonal form of the raw Gram (as _pinv: a direction that keeps less
        # than 1e-6 of its raw norm after the catalog's projection is not there)
        d = np.sqrt(np.maximum(np.diag(H.T @ Rt @ H), 1e-300))
        ev = np.linalg.eigvalsh((H.T @ At @ H) / d[:, None] / d[None, :])
        return int(np.sum(ev > 1e-6))

    return rank(a.H) == q == rank(b.H) and rank(np.concatenate([a.H, b.H], 1)) == q


def one_structure(sums: Sums, lib: Sequence[Term], thresh: np.ndarray, i: int, j: int) -> bool:
    """Whether terms ``i`` and ``j`` of one frame at two lines are one structure the record
    cannot place at either line: each, fitted beside the other (all folds, after the
    catalog's projection), gains no more than its own multiple-testing threshold ``thresh``
    (the mutual tie of :func:`taken_by`, which then says so in a line's words). On an SDS
    record's few platform positions two orders can be near-aliases, and the noise of the
    folds left out decides which one a repeat of the selection takes: a repeat that takes
    either has confirmed the structure in that frame, so it includes both
    (:func:`._discover.select_terms`; the line reported is the one chosen on all folds).
    Session 40: one sensor's order 5 switching on at run 11 of 24 (5x, training seed
    20261536), chosen at order 5 on all folds; the repeats took the same sensor's step at
    orders 8 and 29 and its growth at 8 (each beside the order 5 step 5.1, 5.2, 6.6 against
    thresholds 16-17; the step beside them 8.7, 14.0, 13.4 against 18.8), its inclusion was
    0.4, and nothing was kept. Terms of two frames, or at one line (:func:`_same_span`,
    ``same_place``), are not this rule's."""
    a, b = lib[i], lib[j]
    if a.frame != b.frame or a.line == b.line:
        return False
    sa, sb = sums.slices[a.line], sums.slices[b.line]
    rows = np.r_[np.arange(sa.start, sa.stop), np.arange(sb.start, sb.stop)]
    At = sums.A[:, rows][:, :, rows].sum(0)  # the two lines' columns only
    Rt = sums.raw[:, rows][:, :, rows].sum(0)
    bt = sums.b[:, rows].sum(0)
    na, qa = sa.stop - sa.start, a.H.shape[1]
    H = np.zeros((rows.size, qa + b.H.shape[1]))
    H[:na, :qa], H[na:, qa:] = a.H, b.H
    both = _gain_in(H, At, bt, Rt)
    alone_a, alone_b = _gain_in(H[:, :qa], At, bt, Rt), _gain_in(H[:, qa:], At, bt, Rt)
    return both - alone_b <= thresh[i] and both - alone_a <= thresh[j]


def _kept_share(sums: Sums, tm: Term) -> float:
    """The share of a term's raw norm (its columns' whitened Gram, summed over the folds)
    that the projection on the catalog model's Jacobian leaves it: 1 where the catalog spans
    none of it, near 0 where a catalog effect holds the same structure (a disk order the base
    holds: what is left is the part its fitted placements moved)."""
    sl = sums.slices[tm.line]
    raw = float(np.trace(tm.H.T @ sums.raw.sum(0)[sl, sl] @ tm.H))
    return float(np.trace(tm.H.T @ sums.A.sum(0)[sl, sl] @ tm.H)) / raw if raw > 0 else 0.0


def _tie_pick(sums: Sums, lib: Sequence[Term], i: int, own_min: float) -> int:
    """Of the terms of the library with the same span as term ``i`` (:func:`_same_span`: the
    record cannot tell them apart), the first of the library that keeps at least
    ``own_min`` (``settings.discover_own_share_min``) of its raw norm after the catalog's
    projection (:func:`_kept_share`), else the first. A term the catalog mostly spans is
    the catalog's structure, and its remnant can coincide with another term's columns to
    ``KEEP_SHARE`` of its raw norm: a disk order the base holds, moved by one head's
    placement, left 5e-4 of its norm on that head, and as the first of the library it
    replaced that head's own term (training seed 20261507, ``head_defect`` 5x: frame
    ``disk`` for ``head 2``)."""
    same = [j for j in range(len(lib)) if _same_span(sums, lib[i], lib[j])]
    return next((j for j in same if _kept_share(sums, lib[j]) >= own_min), same[0])


def taken_by(
    sums: Sums,
    lib: Sequence[Term],
    lines: Sequence[Line],
    thresh: np.ndarray,
    kept: list[int],
    li: int,
) -> str:
    """Words for a located line ``li`` at which no term is kept although its best term
    (largest in-sample gain past its threshold ``thresh``) passes its multiple-testing
    threshold alone: where beside the terms kept (``kept``, at other lines) it gains no more
    than its threshold, those terms take its structure, and the record cannot tell the two
    apart; empty otherwise. On an SDS record's few platform positions two orders can be
    near-aliases, and the noise picks one (session 38: training seed 20261520's
    ``platform_step`` 2x at order 5 and order 26, gains 41.9 and 42.3 alone, 3.2 and 3.6
    beside each other, thresholds 18.0; a rule reading the lower order read training seed
    7572's order 7 as order 1, so the record's words say which lines tie, and no pick is
    claimed)."""
    own = [i for i, tm in enumerate(lib) if tm.line == li]
    if not kept or not own:
        return ""
    At, bt, Rt = sums.A.sum(0), sums.b.sum(0), sums.raw.sum(0)

    def gain(terms: list[Term]) -> float:
        return _gain_in(_embed(sums, terms), At, bt, Rt)

    alone = {i: gain([lib[i]]) for i in own}
    i = max(own, key=lambda j: alone[j] - thresh[j])
    if alone[i] <= thresh[i]:
        return ""
    ks = [lib[j] for j in kept]
    beside = gain([*ks, lib[i]]) - gain(ks)
    if beside > thresh[i]:
        return ""
    where = ", ".join(sorted({lines[t.line].label() for t in ks}))
    return (
        f"; its best term ({lib[i].frame} / {lib[i].modulation}) passes its threshold alone "
        f"(chi-square {alone[i]:.1f} against {float(thresh[i]):.1f}) but gains "
        f"{max(beside, 0.0):.1f} beside the terms kept at {where}: they take its structure, "
        "and the record cannot tell the lines apart"
    )
