"""The finder's decision thresholds and fixed constants."""

from __future__ import annotations

import math

VERDICTS = ("consistent", "missing_physics", "unexplained")
MAX_PARAM_FRACTION = 0.1
"""The model never has more parameters than this fraction of the fitted values."""
N_FOLDS = 5
BIC_MIN = 10.0
HELDOUT_MIN = 10.0
PLAUSIBLE_RATIO = 4.0
LOCATED_SHARE_MIN = 0.2
SIGNATURE_LEFT_MAX = 0.5
COLLINEAR_REFUSE = 0.995
COLLINEAR_NOTE = 0.95
# two candidates the data cannot tell apart: chi-square within TIE_CHI2 of each other and
# fitted errors correlated above TIE_CORR (over the kept rows, noise-whitened)
TIE_CHI2 = 10.0
TIE_CORR = 0.9
LATTICE_NOISE_SHARE = 0.25
"""``quantization`` is named from the readings' value lattice (a floor, not a fitted term)
when its floor ``LSB^2 / 12`` is at least this share of the channel's measured noise
variance: the LSB is then coarser than about twice the noise ahead of the quantizer, and the
reading's resolution, not the sensor's noise, sets the floor."""
CHUNK_ROWS = 8192
CACHE_BYTES = 6.0e7
"""Budget of each of the fitter's two caches (Jacobians of linear terms, processed static
blocks): what does not fit is recomputed, so memory stays bounded on long records."""
D2_VAR = 2.0 * (70.0 / 36.0 - 1.0)
"""Variance of log(residual variance / second-difference variance) times N (white noise)."""
MEDIAN_VAR = 2.0 / math.log(2.0) ** 2
"""Variance of log(median periodogram level) times the number of periodogram bins."""
