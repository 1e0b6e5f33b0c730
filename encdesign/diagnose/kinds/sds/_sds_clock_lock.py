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


def _saw_covariance(x: np.ndarray) -> np.ndarray:
    """``E[s(u) s(u + x)]`` (tick²) of the rounding error ``s(u) = round(u) - u`` at a uniform
    sub-tick phase ``u``: ``1/12 - v (1 - v) / 2``, ``v = x mod 1`` (the Bernoulli polynomial
    of the sawtooth's Fourier series; ``1/12`` at ``v = 0``, ``-1/24`` at half a tick)."""
    v = np.mod(np.asarray(x, float), 1.0)
    return 1.0 / 12.0 - 0.5 * v * (1.0 - v)


def mean_rounding_covariance(psi: np.ndarray, ticks: float) -> float:
    """The mean over every pair (a sensor with itself included) of sensors at azimuths
    ``psi`` (rad) of their roundings' covariance (tick², :func:`_saw_covariance`) on a
    revolution of ``ticks`` clock ticks: sensor ``s`` sees the marks ``ticks psi_s / 2 pi``
    ticks later."""
    d = float(ticks) * np.asarray(psi, float) / (2 * np.pi)
    return float(np.mean(_saw_covariance(d[:, None] - d[None, :])))


def rounding_common_excess(
    run_clock: np.ndarray | None,
    clock_s: float | None,
    psi_f: np.ndarray,
    psi_m: np.ndarray,
    n_marks: int,
    lock: float,
) -> float:
    """What the clock's rounding constant within a run adds to the run means' component
    common to the moving sensors over their differences (rad², at least 0): an excess
    ``e`` (:func:`._sds_noise._common_factor`) that the revolution contrasts and the fixed
    sensors' differences do not see where the clock is nearly locked to the motor, predicted
    from the clock alone (so no effect in the record can raise it). The tests of patterns
    common to the moving sensors read it (``SDSNoiseInfo.common_scale``); the level every
    channel is whitened with does not.

    Model: an edge's rounding is ``tau s(u)`` at its sub-tick phase ``u``. The marks' phases
    are spread over the tick by the disk's graduation errors (larger than a tick), so a
    sensor's run mean of one revolution keeps ``1 / n_marks`` of the rounding's variance;
    where the clock is nearly locked every revolution of a run repeats those phases (the
    share ``lock``, :func:`clock_lock_share`), so that part is constant within the run.
    Sensor ``s`` at azimuth ``psi_s`` sees the marks ``T psi_s / 2 pi`` ticks later (``T``
    the revolution in ticks), so two sensors' roundings have the covariance
    ``_saw_covariance(T (psi_s - psi_s') / 2 pi) / n_marks``. A pair's reading holds the
    moving sensor's rounding less the fixed sensors' mean (times ``omega = 2 pi / period``;
    the cross terms average out over the platform's angles), so the common component
    (``M`` times the moving sensors' mean) has the variance ``M (V_m + V_f)`` and a
    difference ``(M C_0 - M V_m) / (M - 1)``, ``V`` the mean of the sensors' covariances and
    ``C_0 = 1/12``. With two fixed sensors half a revolution apart (a whole number of ticks
    near lock) their rounding does not cancel in their mean and never shows in their
    difference; three moving sensors a third apart nearly cancel theirs.

    Checked by simulation (``write_concealed_sds``, clean, the clock on and off at one key,
    training keys 6785523 and 6785524, lock 0.98): the rounding's common component was 1.69
    and 1.45e-8 rad RMS, this model 1.47 and 1.99e-8 (the second a revolution of a multiple
    of 3 ticks: the moving sensors at one phase). An RMS over 11 degrees of freedom is known
    to about 20 %; the model is the expectation over disks (one disk's marks give its own
    spread of phases, mostly through the first harmonic of the rounding). Jitter before the
    stamping would smooth the rounding's dependence on the phase (less constant within a
    run): the model is the unsmoothed upper value, and the direct cap of
    :func:`._sds_noise._direct_common_factor` still holds it to what the common component
    supports. ``0`` without a declared clock."""
    if run_clock is None or not clock_s or not len(run_clock) or not lock > 0:
        return 0.0
    period = float(np.mean(np.asarray(run_clock, float)[:, 1]))
    if not period > 0:
        return 0.0
    ticks = period / float(clock_s)
    M, F = int(np.size(psi_m)), int(np.size(psi_f))
    if M - 1 <= 0 or F <= 0:  # no differences of the moving sensors, or no fixed sensor
        return 0.0

    v_m, v_f = mean_rounding_covariance(psi_m, ticks), mean_rounding_covariance(psi_f, ticks)
    c0 = 1.0 / 12.0
    excess = M * (v_m + v_f) - M * (c0 - v_m) / (M - 1)
    omega_tau = 2 * np.pi / period * float(clock_s)  # a tick in rad of the shaft
    e = lock * omega_tau * omega_tau * excess / n_marks
    return float(e) if e > 0 else 0.0
