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
