"""The share of the clock's rounding that the SDS run means keep constant within a run where the
clock is nearly locked to the motor, and the run-mean common factor at that share (issue 41,
session 39; used by :mod:`._sds_noise` and :mod:`._sds_level_out`)."""

from __future__ import annotations

import numpy as np


def clock_lock_share(
    run_clock: np.ndarray | None, clock_s: float | None, K: int, n_marks: int
) -> float:
    """The share (0 … 1) of the clock's rounding of the run means that the revolution
    contrasts and the fixed sensors' differences do not see: ``|D_K(f)|^2 (1 - |D_N(b)|^2)``,
    with ``f`` the revolution time in clock ticks less the nearest whole number (the clock
    phase an edge moves by from one revolution to the next; ``run_clock`` (R, 2): each run's
    first edge time and revolution time, :func:`._sds_data._run_clock`), ``b`` the same for
    the mark spacing (revolution time over ``n_marks``), ``D_K(f) = mean_k exp(2 pi i k f)``
    over the ``K`` revolutions of a run mean and ``D_N`` over the ``N`` marks.

    The rounding of an edge is a function of its clock phase. Where the clock is nearly
    locked to the motor (``f`` near 0: speed offsets near a multiple of 1e-7) every
    revolution of a run has its edges at nearly the same phases, so the rounding does not
    average over the run's revolutions (the contrasts do not see it), and the moving
    sensors, at the platform's angle, take new phases in every run. Unlike the
    independent-revolution noise :func:`._sds_noise._common_factor` models, this part is
    common to the moving sensors at a level the differences do not show. With the mark
    spacing a whole number of ticks too (``b`` = 0: the clock exactly locked, 10^7 ticks a
    revolution) every edge of a sensor has one phase, its rounding one value per run: the
    case the common factor's cap was measured on (:func:`._sds_noise._direct_common_factor`),
    left as it is.

    Measured on 48 clean 12-run records with the clock unlocked (training keys
    8210000-8210023, speed offsets 1-3e-5, and 8211000-8211023, within 0.08 ticks a
    revolution of lock; ``K`` = 4): the base residual's common component was 1.65 times
    (median; 0.66-3.20) the modelled level on the 13 records with ``|D_4(f)|^2`` over 0.94,
    0.75 times (median; one at 1.88) on the other 35. ``0`` without a declared clock."""
    if run_clock is None or not clock_s or not len(run_clock):
        return 0.0
    period = np.asarray(run_clock, float)[:, 1]
    if not np.all(period > 0):
        return 0.0
    ticks = float(np.mean(period)) / float(clock_s)
    f = ticks - round(ticks)
    b = ticks / n_marks - round(ticks / n_marks)
    within = abs(np.mean(np.exp(2j * np.pi * f * np.arange(K)))) ** 2
    spread = 1.0 - abs(np.mean(np.exp(2j * np.pi * b * np.arange(n_marks)))) ** 2
    return float(np.clip(within * spread, 0.0, 1.0))


def lock_mixed_factor(g_i, g_d, lock: float):
    """The common factor from the indirect one ``g_i`` (:func:`._sds_noise._common_factor`)
    and the direct one ``g_d`` (:func:`._sds_noise._direct_common_factor`; ``None``:
    ``g_i``), scalars or arrays:
    ``sqrt((1 - w) min(g_i, g_d)^2 + w g_d^2)`` with ``w`` = ``lock``
    (:func:`clock_lock_share`). The indirect factor misses the clock's rounding that is
    constant within a run (the docstring of :func:`clock_lock_share`), so at the share ``w`` of
    that rounding the factor is what the common component itself supports, not capped by
    the indirect one; at ``w`` = 0 it is ``min(g_i, g_d)``, as without the share."""
    if g_d is None:
        return g_i
    g_min = np.minimum(g_i, g_d)
    if not lock > 0:
        return g_min
    return np.sqrt((1.0 - lock) * g_min**2 + lock * np.asarray(g_d) ** 2)
