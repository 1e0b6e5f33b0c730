"""The spectrum view's test with an estimated noise (issue 44): an F test, not a chi-square.

The views whiten the residual by ``sigma``, the noise std per channel estimated from the
base residual's periodogram (``_noise.noise_spectral_dof``). Where that estimate rests on a
few hundred bins (a sparse record: a few hundred rows), it is itself a random variable,
``sigma_hat^2 = sigma^2 chi2(d) / d`` with ``d`` its effective degrees of freedom, and a
bin's whitened power is ``chi2(q) / (chi2(d) / d)``, ``q`` times an ``F(q, d)`` variable: its
tail is heavier than ``chi2(q)``'s, and a chi-square threshold raises the family false alarm
(session 22: 0.0014 against 0.0009 at ``alpha`` = 0.001, 4 heads, 2 runs of 200 rows).

The spectrum view sums the whitened power of ``C`` channels, each whitened by its own
estimate of ``d_k`` degrees of freedom. To first order in the estimates' errors
``delta_k = sigma_k^2 / sigma_hat_k^2 - 1`` (variance ``2 / d_k``), the sum is a chi-square
scaled by the mean of the ``delta_k``, whose variance ``sum(2 / d_k) / C^2`` is that of one
shared estimate of ``d = C^2 / sum(1 / d_k)`` degrees of freedom: the sum is tested as
``q F(q, d)``. A channel alone is tested with the fewest ``d_k`` (the most conservative).
Where the noise is not estimated from bins (``prep.noise_dof`` None, or a channel's
estimate from the kind's own method) ``d`` is unlimited and the tests are the chi-square's.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np
from scipy import stats


def pooled_noise_dof(prep, per_channel: bool = False) -> float:
    """Effective degrees of freedom of the noise estimate the spectrum view's sum over the
    channels sees (``per_channel``: of one channel alone, the fewest); ``inf`` where the
    noise is taken as known."""
    d = getattr(prep, "noise_dof", None)
    if d is None:
        return math.inf
    d = np.asarray(d, float)
    if d.size == 0 or not np.all(d > 0):
        return math.inf
    if per_channel:
        return float(np.min(d))
    inv = float(np.sum(1.0 / d))
    return float(d.size**2 / inv) if inv > 0 else math.inf


def estimated_threshold(alpha: float, q: int, n_tests: int, d: float) -> float:
    """The whitened power (chi-square units, ``q`` dof) over which one of ``n_tests`` tests
    is significant at family level ``alpha``, the noise estimated with ``d`` degrees of
    freedom (``d`` inf: the chi-square's threshold)."""
    return _threshold(float(alpha / max(n_tests, 1)), float(q), float(d))


@functools.lru_cache(maxsize=4096)
def _threshold(p: float, q: float, d: float) -> float:
    if not math.isfinite(d):
        return float(stats.chi2.isf(p, q))
    return float(q * stats.f.isf(p, q, d))


def estimated_log10_p(power: float, q: int, d: float, chi2_log10_p: Callable) -> float:
    """log10 of the tail probability of a whitened power ``power`` on ``q`` dof, the noise
    estimated with ``d`` degrees of freedom; ``chi2_log10_p(power, q)``: the chi-square's
    (the noise known, ``_views.log10_tail_p``), returned where ``d`` is inf or the F tail
    underflows, and the floor of the F's (whose tail is the heavier: never more significant
    than the chi-square)."""
    c = chi2_log10_p(float(power), q)
    if not math.isfinite(d):
        return c
    v = float(stats.f.logsf(float(power) / max(q, 1), q, d) / math.log(10))
    return max(v, c) if math.isfinite(v) else c
