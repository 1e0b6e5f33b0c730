"""Discovery's ``growth`` term with its own level (issue 41, session 22; split from
:mod:`._discover` for the module size).

A structure that grows across the record (wear, a loosening part, a slow thermal change of
one sensor) has an amplitude ``a + b tau``: a level and a rate, in one phase pair each. The
``growth`` term until session 21 was the rate alone, the amplitude linear in the centred
time ``(tau - tau_mid) / tau_half``: where the catalog model holds the frame's static order
(one sensor's own error function, the base orders) the projection takes the level and that
is all that is left; elsewhere it is an amplitude that passes through zero at mid-record and
changes sign, which no growing structure does, and a growth from zero was only modelled as
two terms (the static order, then the rate) that the forward selection must take one by
one. On an SDS record (24 runs, one moving sensor's order growing from zero at 5x the
run-mean noise) a step at a golden-angle near-alias of the order takes more in-sample
chi-square than either of them alone, and its inclusion splits over the aliases: nothing
was kept at a line the truth's level and rate together take 62 held-out chi-square at
(``benchmarks/discovery.py --seed 20261371 --kinds sds``, ``slow_growth`` 5x).

The term holds the level where the catalog model leaves any direction of it (a direction
keeps more than :data:`~._discover_law.KEEP_SHARE` of its raw norm after the projection,
the rule :func:`~._discover_law._psolve` drops directions by); its parameters are the
level's (first) and the rate's, and its multiple-testing count is their number.
"""

from __future__ import annotations

import numpy as np

from ._discover_law import KEEP_SHARE, Sums, Term, _embed, _gain_in, _heldout
from ._discover_lines import hmap


def level_is_free(sums: Sums, line: int, H0: np.ndarray) -> bool:
    """Whether the catalog model leaves any direction of the static restriction ``H0`` of
    line ``line`` (its projected Gram, scaled by the raw Gram's diagonal, has an eigenvalue
    over :data:`KEEP_SHARE`)."""
    sl = sums.slices[line]
    A = H0.T @ sums.A.sum(0)[sl, sl] @ H0
    R = H0.T @ sums.raw.sum(0)[sl, sl] @ H0
    d = np.sqrt(np.maximum(np.diag(R), 0.0))
    if not np.any(d > 0):
        return False
    d = np.where(d > 0, d, 1.0)
    ev = np.linalg.eigvalsh(A / d[:, None] / d[None, :])
    return bool(ev.max() > KEEP_SHARE)


def growth_term(sums: Sums, line: int, frame: str, M: np.ndarray, level: bool = True) -> Term:
    """The ``growth`` term of ``frame`` (map ``M``) at line ``line``: the level (where
    ``level`` allows it and the catalog model leaves it: :func:`level_is_free`) and the rate
    over the centred time, one parameter set for the record (``growth_level`` on the term says
    which). :func:`._discover.library` allows the level on SDS records only, where it was
    built and measured (session 22); on the measured ODrive records (one run, one speed) it
    read static lines as growths at a lower held-out gain and left 3 of 10 modelled lines
    unmodelled, so other kinds keep the rate alone beside their ``static`` term."""
    lay = sums.layout[line]
    one = np.ones(lay[1])
    H0, H1 = hmap(lay, 0, M, one), hmap(lay, 1, M, one)
    if level and level_is_free(sums, line, H0):
        return Term(line, frame, "growth", np.concatenate([H0, H1], 1), level=True)
    return Term(line, frame, "growth", H1)


def same_place(a: Term, b: Term) -> bool:
    """Whether two terms sit at one line in one frame (their modulations may differ): a
    repeat of the selection that takes either includes the other
    (:func:`._discover.select_terms`). A growth with its level and a step late in the record
    are nearly the same columns (training seed 7572, one sensor's order 7 switching on at run
    15 of 24, 6x: the step on all folds, the growth in 3 of the 5 repeats, and nothing kept)."""
    return a.line == b.line and a.frame == b.frame


def _rank(sums: Sums, line: int, H: np.ndarray) -> int:
    """Directions of ``H`` the catalog model leaves (the rule of :func:`level_is_free`)."""
    sl = sums.slices[line]
    A = H.T @ sums.A.sum(0)[sl, sl] @ H
    d = np.sqrt(np.maximum(np.diag(H.T @ sums.raw.sum(0)[sl, sl] @ H), 0.0))
    d = np.where(d > 0, d, 1.0)
    return int(np.sum(np.linalg.eigvalsh(A / d[:, None] / d[None, :]) > KEEP_SHARE))


def nested(sums: Sums, a: Term, b: Term) -> bool:
    """Whether one of two terms at one line spans the other (``static`` in a ``growth``
    with its level, a ``speed`` law in ``per_cell``): the forward selection's in-sample
    margin, its threshold and its per-parameter penalty already prefer the smaller of such
    two; :func:`best_at_place` swaps only terms that are not nested."""
    H = np.concatenate([a.H, b.H], 1)
    return _rank(sums, a.line, H) <= max(_rank(sums, a.line, a.H), _rank(sums, a.line, b.H))


def best_at_place(
    sums: Sums, lib: list[Term], chosen: list[int], thresh: np.ndarray, me: float
) -> list[int]:
    """``chosen`` with each term replaced by the term of its line and frame (any modulation
    whose in-sample gain passes its own threshold, not nested with it: :func:`nested`) of
    the largest margin of the forward
    selection with the K-fold held-out gain beside the others chosen in place of the
    in-sample gain (``gain (1 - me q) - threshold``, ``me``:
    ``settings.discover_model_error``; the smaller of two nested terms keeps its
    preference): ranked in-sample, the larger of two terms the record barely tells apart
    wins (a growth with its level, 4 parameters, over a step, 2, where an order switches on
    late: training seed 7572 at 5x, in-sample 52.8 against 50.1, held out 45.7 against
    49.1). Called on records of one cell only (an SDS record): where runs differ in speed or
    direction the per-run terms (``cell``, ``per_cell``) win held out by the finder's own
    small model error (a run's angle offset fitted with the structure present), which the
    in-sample margin's per-parameter penalty is there for (a multihead torque ripple's
    speed law was read as one run's ``cell`` and a growth)."""
    folds = list(range(sums.A.shape[0]))
    At, bt, Rt = sums.A.sum(0), sums.b.sum(0), sums.raw.sum(0)
    out = list(chosen)
    for n, i in enumerate(chosen):
        others = [lib[j] for j in out if j != i]
        best, best_g = i, -np.inf
        for j, tm in enumerate(lib):
            if not same_place(lib[i], tm) or (j != i and (j in out or nested(sums, lib[i], tm))):
                continue
            sl = sums.slices[tm.line]
            if j != i and _gain_in(tm.H, At[sl, sl], bt[sl], Rt[sl, sl]) <= thresh[j]:
                continue
            g = _heldout(sums.A, sums.b, _embed(sums, [*others, tm]), folds, sums.raw)
            g = g * (1.0 - me * tm.n_params) - thresh[j]
            if g > best_g:
                best, best_g = j, g
        out[n] = best
    return out
