"""Fits a selection asks for twice, made once (issue 43).

Stage 4 (:mod:`._select`) asks the fitter for the same fit more than once: the rule that
tests a chosen candidate against a located change (:func:`._spill._kept_fit`) fits the
model so far with the candidate's term, its parameters free, and once the candidate is
named the selection refits exactly those terms (``select``'s ``full``): one more pass over
the rows with the Jacobian of every free parameter, for a fit already made.

Inside :func:`remembering` (one selection), :func:`remembered_steps` answers a fit whose
inputs (the fitter, its observations and weights, every term's candidate, values, free
masks and scales) were fitted before with that fit's result, without a request; a fit of
at most ``max_steps`` Levenberg-Marquardt steps is answered by one of fewer steps only
where that one stopped on its own (``converged``: it left the loop before its limit, so
it takes the same steps under any larger one). A fit is deterministic in its answers, so
the remembered result is the one the fit would make again, up to the rounding of the
fitter's caches (a linear term's value from a kept Jacobian or compiled).
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
from collections.abc import Iterator, Sequence

from ._fit import FitResult, Fitter, Term
from ._stats_pass import FitSteps, drive

_ACTIVE: contextvars.ContextVar[dict | None] = contextvars.ContextVar(
    "encdesign_diagnose_fit_memo", default=None
)


@contextlib.contextmanager
def remembering() -> Iterator[dict]:
    """A fresh memo of fits, active for the block (one selection): key -> ``(max_steps,
    FitResult)``."""
    memo: dict = {}
    token = _ACTIVE.set(memo)
    try:
        yield memo
    finally:
        _ACTIVE.reset(token)


def fit_key(fitter: Fitter, terms: Sequence[Term]) -> tuple:
    """Everything a fit's result depends on besides ``max_steps``: the fitter (its caches),
    its observations (by identity) and channel weights, and per term its candidate and its
    values, free masks and scales (as bytes)."""
    return (
        id(fitter),
        id(fitter.prep.y),
        fitter.w_ch.tobytes(),
        tuple(
            (
                id(t.cand),
                tuple(
                    (v[q.name].tobytes(), f[q.name].tobytes(), s[q.name].tobytes())
                    for q in t.cand.params
                ),
            )
            for t in terms
            for v, f, s in [(t.values, t.free, t.scale)]
        ),
    )


def _copied(fr: FitResult) -> FitResult:
    """``fr`` with its terms copied (a caller may change a term it was handed)."""
    return dataclasses.replace(fr, terms=[t.copy() for t in fr.terms])


def _known(fr: FitResult) -> FitSteps:
    """A fit that asks nothing and returns ``fr``."""
    return _copied(fr)
    yield  # (a generator: drive_many runs it beside the others)


def _kept(memo: dict, key: tuple, max_steps: int, steps: FitSteps) -> FitSteps:
    """``steps``, its result remembered under ``key``."""
    fr = yield from steps
    memo[key] = (max_steps, fr)
    return _copied(fr)


def remembered_steps(fitter: Fitter, terms: Sequence[Term], max_steps: int = 30) -> FitSteps:
    """:meth:`._fit.Fitter.fit_steps` of ``terms``, or (inside :func:`remembering`) the
    result of the same fit made before: with the same ``max_steps``, or with fewer where
    that fit stopped before its limit (module doc)."""
    memo = _ACTIVE.get()
    steps = fitter.fit_steps(list(terms), max_steps=max_steps)
    if memo is None:
        return steps
    key = fit_key(fitter, terms)
    got = memo.get(key)
    if got is not None:
        m, fr = got
        if m == max_steps or (fr.converged and m <= max_steps):
            steps.close()
            return _known(fr)
    return _kept(memo, key, max_steps, steps)


def remembered_fit(fitter: Fitter, terms: Sequence[Term], max_steps: int = 30) -> FitResult:
    """:meth:`._fit.Fitter.fit` through :func:`remembered_steps`."""
    return drive(remembered_steps(fitter, terms, max_steps))


__all__ = ["fit_key", "remembered_fit", "remembered_steps", "remembering"]
