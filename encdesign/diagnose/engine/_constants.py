"""The finder's fixed numerical constants (not decisions, so not ``FinderSettings`` fields):
chunk sizes, cache budgets, the variances of noise estimators."""

from __future__ import annotations

import math

CHUNK_ROWS = 8192
CACHE_BYTES = 6.0e7
"""Budget of each of the fitter's two caches (Jacobians of linear terms, processed static
blocks): what does not fit is recomputed, so memory stays bounded on long records."""
D2_VAR = 2.0 * (70.0 / 36.0 - 1.0)
"""Variance of log(residual variance / second-difference variance) times N (white noise)."""
MEDIAN_VAR = 2.0 / math.log(2.0) ** 2
"""Variance of log(median periodogram level) times the number of periodogram bins."""

FIT_STOP_CHI2 = 1e-2
"""A Levenberg-Marquardt fit stops once a step lowers chi-square by less than this (absolute,
chi-square units) or by less than :data:`FIT_STOP_REL` of it: two fits whose chi-square
differ by less than :func:`fit_stop_tolerance` are equal as far as the fits can tell."""

FIT_STOP_REL = 1e-7
"""The relative decrease of chi-square below which a fit stops (see :data:`FIT_STOP_CHI2`)."""


def fit_stop_tolerance(chi2: float) -> float:
    """Chi-square below which two fits' difference is the fits' stopping tolerance, not the
    data: ``max(FIT_STOP_CHI2, FIT_STOP_REL * chi2)`` (chi-square units)."""
    return max(FIT_STOP_CHI2, FIT_STOP_REL * chi2)
