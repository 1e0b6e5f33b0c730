"""The base's grown fit from the kind's own start at the grown order (issue 44, session 23).

The base's order growth (``_engine._grow_to``) fits the grown base from the values the base
left at its old order, the new orders at zero. Its nonlinear parameters (a multihead
record's per-run angle zeros ``delta_r`` without ``theta_ref``) then start where the old
base's fit left them, and the old base's start was drawn from orders the missing ones leak
into: on a sparse record (3-4 samples per turn) an order above the base's aliases onto a
low order's phase in one run and not in another, so a run's zero starts (and the fit stays)
in a wrong minimum, and no growth lowers what the views locate (a base 5-6x the noise, the
growth undone by ``growth_left_max``). Before a growth is undone, the grown base is fitted
again from the kind's own start at the grown order (drawn with the grown orders fitted),
and the fit of the lower chi-square is kept: the same model, the better of two starts."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ._fit import FitResult, Fitter


def _power(findings) -> float:
    """What the views located: the sum of ``power - dof`` over the findings."""
    return float(sum(max(f.power - f.dof, 0.0) for f in findings))


def grown_base(
    fitter: Fitter,
    terms: list,
    fresh_terms: Callable[[], list],
    locate_residual: Callable[[np.ndarray], list],
    left_max: float,
) -> tuple[FitResult, list, float, bool]:
    """The grown base fitted from ``terms`` (the old base's values continued), and the views'
    findings on its residual (``locate_residual``) with the power they locate; where that
    power exceeds ``left_max`` (the growth would be undone), the same base fitted from
    ``fresh_terms()`` (the kind's own start at the grown order) too, the fit of the lower
    chi-square kept. Returns ``(fit, findings, power, from_start)``."""
    grown = fitter.fit(terms)
    after = locate_residual(fitter.residual(grown.terms))
    p1 = _power(after)
    if p1 <= left_max:
        return grown, after, p1, False
    fresh = fitter.fit(fresh_terms())
    if not (np.isfinite(fresh.chi2) and fresh.chi2 < grown.chi2):
        return grown, after, p1, False
    after = locate_residual(fitter.residual(fresh.terms))
    return fresh, after, _power(after), True
