"""The SDS kind's noise levels (saturated run-mean fit, contrasts, widened for their degrees of
freedom), the common-order view and the candidates' plausibility rules."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from functools import partial
from typing import Any

import numpy as np
from scipy import stats

from ...engine._candidates import Context
from ...engine._protocol import NoiseEstimate, Prepared
from ...engine._settings import FinderSettings
from ._sds_clock_lock import lock_mixed_factor
from ._sds_drift import _step_or_outlier, onset_power
from ._sds_level_out import LevelOut, RunMeanLevel
from ._sds_pairs import _best_pair, _order_groups, _projected_pairs

REFERENCE_RADIUS_M = 0.0254
BEAM_ORDERS = (1, 2, 3)

EXPLANATIONS = {
    "axis_tilt": (
        "The disk axis is tilted against the platform axis; the sensors then read the disk at "
        "projected azimuths (seed 001 eq. 26), an error of nearly pure order 2 in the "
        "platform angle, about tilt²/4. The simulation assumed both axes aligned."
    ),
    "thermal_drift": (
        "The moving sensors drift against their disk with temperature (seed 001: about "
        "0.7 arcsec/K); with no temperature column the drift shows as a trend in time. The "
        "simulation held the temperature constant."
    ),
    "bearing_wobble": (
        "The shaft bearings move the disk centre at a frequency that is not a multiple of the "
        "shaft speed (cage, balls); the error changes from one revolution to the next and "
        "cancels only in opposed sensor pairs. The simulation assumed perfect bearings."
    ),
    "beam_tilt_axial": (
        "The moving sensors' beams are tilted tangentially and the platform moves axially as "
        "it turns (axial runout), so the read point slides along the track: an error in the "
        "platform angle common to all moving sensors. Only the product tilt × runout is seen."
    ),
    "coil_mismatch": (
        "Unequal stator coils make the shaft speed ripple at orders below the pole-pair count; "
        "with the disk's mark errors at the same orders it biases the shifted delta sum "
        "(seed 001 eqs. 46-53). The design's motor had no such ripple."
    ),
    "sensor_delay_step": (
        "One moving sensor's edges arrive later (or earlier) from one run on: a delay in its "
        "electronics or cable changed (a re-plugged connector, a thermal step in a "
        "comparator). Its pairs read +Omega*tau from then on. The design has fixed delays."
    ),
    "timing_quantization": (
        "The edges are stamped on a coarser clock than the declared one, which adds a noise "
        "floor to every reading (it cannot be fitted away, only made smaller with a faster "
        "clock)."
    ),
}


def design_orders(p: int, q: int | None, c: int | None, cap: int) -> list[int]:
    """The motor's ripple orders up to ``cap``: multiples of the pole pairs ``p``, of
    ``p`` times the commutation states ``c`` and of the cogging order (``q`` coils)."""
    orders = set(range(p, cap + 1, p))
    if c:
        orders |= set(range(p * c, cap + 1, p * c))
    if q:
        cog = 2 * p * q // math.gcd(2 * p, q)
        orders |= set(range(cog, cap + 1, cog))
    return sorted(o for o in orders if o <= cap)


def common_x_orders(consts: Mapping[str, Any], orders) -> list[int]:
    """Orders ``n`` in ``x = φ + ψ_m`` whose columns vanish on the moving-sensor differences
    (``n ψ_m`` equal mod 2π for every sensor) when the record is projected (no phi_ref)."""
    if float(consts["proj"]) <= 0:
        return []
    psi = np.asarray(consts["psi_m"], float)
    out = []
    for n in orders:
        z = np.exp(1j * n * psi)
        if np.max(np.abs(z - z.mean())) < 1e-9:
            out.append(int(n))
    return out


def coil_orders(meta: Mapping[str, Any], consts: Mapping[str, Any]) -> tuple[int, ...]:
    """The coil orders ``1 … pole_pairs − 1`` ``coil_mismatch`` may fit, less those with one phase
    at every moving sensor without phi_ref (:func:`common_x_orders`): on the projected values their
    columns are rounding, which a fit takes at any amplitude (2.6e6 rad at order 4 of four equally
    spaced sensors, training key 7258500), as the base leaves such design orders out."""
    pp = int(meta.get("encoder", {}).get("pole_pairs", 0) or 0)
    gone = set(common_x_orders(consts, range(1, pp)))
    return tuple(o for o in range(1, pp) if o not in gone)


def base_orders(
    meta: Mapping[str, Any], consts: Mapping[str, Any], max_order: int
) -> tuple[list[int], list[int]]:
    """``(orders, left_out)``: the design's ripple orders in the base model at
    ``max_order`` (:func:`design_orders` of the ``[encoder]`` table), less those with one
    phase at every moving sensor without phi_ref (:func:`common_x_orders`: taken by the
    per-run offset), and those left out."""
    enc = meta.get("encoder", {})
    p = int(enc.get("pole_pairs", 0) or 0)
    orders = (
        design_orders(p, enc.get("stator_coils"), enc.get("commutation_states"), max_order)
        if p > 0
        else []
    )
    common_x = common_x_orders(consts, orders)
    return [o for o in orders if o not in common_x], common_x


@dataclasses.dataclass(frozen=True)
class SDSNoiseInfo:
    """What the sds noise hook (:func:`sds_noise`) found on the base residual, for the
    candidates' rules and the summary (``Context.noise_info``).

    Attributes:
        levels: the two noise levels and how they were found (``noise_estimate``).
        common_order_power: the base residual's power per order common to the moving
            sensors (:func:`common_order_power`).
        drift_vs_orders: a drift in time against the best common order, or ``None``.
        run_change_power: per moving sensor, the best step and single-run outlier of its
            whitened base run means (:func:`_step_or_outlier`).
        base_resid: the base residual over the kept rows the levels were estimated from,
            for the probes' re-estimates (:func:`levels_of`); ``None`` before the stage ran.
        level_factor: ``factor(cols (R, M, q)) -> (sigma / sigma')^2``, the run-mean level
            without a test's columns (:mod:`._sds_level_out`); ``None`` before the stage ran.
        common_scale: the factor (at most 1) on the chi-square of a pattern common to the
            moving sensors in the whitened run means (the views ``common_orders`` and
            ``common_modulated``): ``(g / g_c)^2``, ``g`` the run means' common factor the
            record is whitened with, ``g_c`` the same with the clock's rounding constant
            within a run (:func:`._sds_clock_lock.rounding_common_excess`,
            ``FinderSettings.sds_clock_lock_level``), which only that component holds.
    """

    levels: dict = dataclasses.field(default_factory=dict)
    common_order_power: tuple[float, ...] = ()
    drift_vs_orders: dict | None = None
    run_change_power: tuple[tuple, ...] = ()
    base_resid: np.ndarray | None = dataclasses.field(default=None, compare=False, repr=False)
    level_factor: LevelOut | None = dataclasses.field(default=None, compare=False, repr=False)
    common_scale: float = 1.0


def noise_info(ctx: Context) -> SDSNoiseInfo:
    """The sds noise stage's findings (empty before it ran)."""
    info = ctx.noise_info
    return info if isinstance(info, SDSNoiseInfo) else SDSNoiseInfo()


def span_basis(X: np.ndarray) -> np.ndarray:
    """Orthonormal basis ``(n, rank)`` of the column span of ``X`` (n, q), from its SVD
    (singular values above ``1e-10`` of the largest). Not a QR with small diagonals dropped:
    where a column depends on earlier ones (the per-sensor constants projected on the
    moving-sensor differences without ``phi_ref`` have rank ``M - 1``) Householder QR puts
    an arbitrary direction there (mostly the first run's rows), and every later column's
    part along it is lost with it: the saturated fit then left part of every pattern it
    spans in the first run's values, and the run-mean level grew with a catalog effect (an
    order-1 ``coil_mismatch`` at about 1.5x its bound raised it by 45-75 % on 12-run benches
    without ``phi_ref``, so it was not named)."""
    if X.shape[1] == 0:
        return np.zeros((X.shape[0], 0))
    U, s, _ = np.linalg.svd(X, full_matrices=False)
    return U[:, s > 1e-10 * max(float(s.max(initial=0.0)), 1e-300)]


def _ls_power_flat(rw: np.ndarray, cols: np.ndarray) -> float:
    """Power (chi-square) the columns ``(n, C, q)`` take out of ``rw`` (n, C)."""
    X = cols.reshape(-1, cols.shape[-1])
    keep = np.any(np.abs(X) > 0, axis=0)
    X = X[:, keep]
    if X.shape[1] == 0:
        return 0.0
    Q = span_basis(X)
    return float(np.sum((Q.T @ rw.ravel()) ** 2))


def _saturating_columns(
    rows: Mapping[str, Any],
    consts: Mapping[str, Any],
    orders_base: list[int],
    fraction: float,
) -> tuple:
    """Columns ``(R*M, q)`` over the run-mean channels that span every smooth structure a
    platform bench can put there: a constant per moving sensor, rotating orders ``1..L``
    and the design orders in ``x = φ + ψ_m``, common orders ``1..L`` in ``φ``, a drift in
    time; ``L`` as large as ``fraction`` (``FinderSettings.sds_saturate_fraction``) of the values
    allows. Projected on the moving-sensor differences without ``phi_ref``."""
    phi = np.asarray(rows["phi"], float)
    psi_m = np.asarray(consts["psi_m"], float)
    R, M = phi.size, psi_m.size
    x = phi[:, None] + psi_m[None, :]
    ph = np.broadcast_to(phi[:, None], (R, M))
    t = np.broadcast_to(np.asarray(rows["tmid_c"]).mean(1)[:, None], (R, M))
    cols = [np.eye(M)[None, :, :].repeat(R, 0).reshape(R * M, M)]
    n0 = M + 1 + 2 * len(orders_base)
    L = int(max(0, (fraction * R * M - n0) // 4))
    L = min(L, max(1, (R - 1) // 2))
    rot = sorted(set(range(1, L + 1)) | set(orders_base))
    for n in rot:
        cols += [np.cos(n * x).reshape(-1, 1), np.sin(n * x).reshape(-1, 1)]
    for n in range(1, L + 1):
        cols += [np.cos(n * ph).reshape(-1, 1), np.sin(n * ph).reshape(-1, 1)]
    cols.append((t / max(np.ptp(t), 1e-12)).reshape(-1, 1))
    X = np.concatenate(cols, 1)
    if float(consts["proj"]) > 0:
        X3 = X.reshape(R, M, -1)
        X = (X3 - X3.mean(1, keepdims=True)).reshape(R * M, -1)
    return X, L


def dof_widening(nu: float, q: int = 2, *, p: float) -> float:
    """Factor ``c`` on a noise level estimated with ``nu`` degrees of freedom so that the
    engine's tests, which treat the level as known (chi-square thresholds), keep their
    false-alarm rate: ``c² = q F⁻¹(1 − p; q, nu) / χ²⁻¹(1 − p; q)``, the ratio of the
    F-test's threshold to the chi-square test's for a ``q``-parameter term at tail
    probability ``p`` (about the engine's Bonferroni-corrected levels; for ``nu`` = 18, c is
    1.3 for q = 1…6 within 0.05). 1 for ``nu`` → ∞."""
    if not np.isfinite(nu) or nu > 1e4:
        return 1.0
    nu = max(float(nu), 1.0)
    return float(math.sqrt(q * stats.f.isf(p, q, nu) / stats.chi2.isf(p, q)))


def _sensor_helmert(M: int) -> np.ndarray:
    """Orthonormal ``(M, M)`` basis over the moving sensors: column 0 common (1/√M each),
    columns 1… the differences."""
    H = np.zeros((M, M))
    H[:, 0] = 1.0 / math.sqrt(M)
    for k in range(1, M):
        H[:k, k] = 1.0
        H[k, k] = -k
        H[:, k] /= math.sqrt(k * (k + 1))
    return H


def _common_factor(
    contrast_levels: list[float],
    proj: bool,
    fixed: np.ndarray | None,
    s_raw: float,
    M: int,
    K: int,
) -> float:
    """Factor on the run-mean level for the part of the noise common to the moving sensors
    (at least 1; 1 without ``phi_ref``, where the run means are projected on the
    differences).

    The fixed sensors' timing noise (jitter, and the clock's rounding of their edges where
    the clock is not locked to the motor) enters every pair of a run alike: it adds a part
    common to the moving sensors, so the run means' common component (one per run) varies
    more than their differences. The saturated fit takes every common pattern up to order
    ``(R - 1) // 2`` in φ and leaves that component (nearly) no degrees of freedom: the
    run-mean level is in effect the differences' level, and a pattern common to the moving
    sensors (beam tilt x axial runout, a drift, coil orders at multiples of ``M``) was
    tested against too small a level (clean benches with the clock unlocked, dev seeds
    5330-5359: the common variance 3.8 times the differences' on average; false alarms,
    and bounds below where detection starts). The factor is ``sqrt(1 + e / s_raw²)`` with
    ``e`` the larger of two estimates of what the common part adds to the common
    component's variance (``M`` times its per-value variance) at the run-mean level:

    * from the revolution contrasts, ``(s_common² − s_differences²) / K``: the noise from
      one revolution to the next (many degrees of freedom), averaged over the ``K``
      revolutions of a run mean;
    * from the fixed sensors' own run means (``fixed`` (R, F), :func:`sds_data`'s
      ``fixed_c``), ``M s_f² / F``: their differences between fixed sensors (Helmert over
      ``F``, ``(R − 1)(F − 1)`` degrees of freedom; the moving sensors' noise cancels
      there) give the variance ``s_f²`` of one fixed sensor's run mean. This one sees
      noise constant within a run and changing between runs, which the contrasts do not:
      with the clock nearly locked to the motor (speed offsets of 1-2e-5) the fixed
      sensors' rounding drifts slowly within a run, the contrasts' ratio² was 0.8 and 3.5
      and the run means' common variance 61 and 45 times the differences' (dev keys
      5354000, 5323002).

    Absolute excesses, not ratios: with the clock locked to the motor the moving sensors'
    rounding, fixed within a run, dominates the run means' differences and the fixed
    sensors' is one constant over the runs, so the contrasts' ratio (2.8 on average) does
    not carry over to the run means (their common variance 0.75 times the differences').

    The larger per-value level is used, as for the contrasts themselves (the engine weighs
    channels as independent: conservative for common and differential patterns alike)."""
    ok = not proj and s_raw > 0
    return math.sqrt(1.0 + _common_excess(contrast_levels, fixed, M, K) / s_raw**2) if ok else 1.0


def _common_excess(lv: list[float], fixed: np.ndarray | None, M: int, K: int) -> float:
    """:func:`_common_factor`'s ``e`` (rad², at least 0; independent of ``s_raw``)."""
    excess = 0.0
    if len(lv) > 1:
        excess = (lv[0] ** 2 - lv[1] ** 2) / K
    if fixed is not None and fixed.ndim == 2 and fixed.shape[1] > 1:
        R, F = fixed.shape
        d = (fixed - fixed.mean(0)) @ _sensor_helmert(F)[:, 1:]
        s_f2 = float(np.sum(d**2)) / max((R - 1) * (F - 1), 1)
        excess = max(excess, M * s_f2 / F)
    return max(excess, 0.0)


def common_base_columns(phi: np.ndarray, psi_m: np.ndarray, orders_base: list[int]) -> np.ndarray:
    """Columns ``(R, k)`` the base model puts in the run means' part common to the moving sensors
    (with ``phi_ref``): the constant and, per design order ``n`` of the base, the mean over the
    moving sensors of its columns ``cos / sin n (φ + ψ_m)`` where that mean is not zero
    (``n ψ_m`` not spread evenly: e.g. ``n`` a multiple of ``M`` for equally spaced sensors)."""
    phi = np.asarray(phi, float)
    psi = np.asarray(psi_m, float)
    cols = [np.ones(phi.size)]
    for n in orders_base:
        z = np.mean(np.exp(1j * n * (phi[:, None] + psi[None, :])), 1)
        if float(np.max(np.abs(z))) > 1e-9:
            cols += [z.real, z.imag]
    return np.stack(cols, 1)


def _direct_common_factor(
    resid_means: np.ndarray, common_base: np.ndarray, s_raw: float, quantile: float
) -> float | None:
    """What the base residual's own common component supports as the common factor (at
    least 1; ``None`` without degrees of freedom): its variance over the ``R − k``
    degrees of freedom the base's common columns (``common_base``, :func:`common_base_columns`)
    leave, at its upper confidence limit ``SS / χ²⁻¹(quantile; R − k)``, over ``s_raw²``.

    :func:`_common_factor` estimates the common excess indirectly (revolution contrasts,
    fixed sensors) and assumes the run-constant noise is as large in the common component
    as in the differences. With the clock locked to the motor it is not: the moving
    sensors' rounding nearly cancels in their mean, the common component's variance was
    0.4-1.1 times the differences' on clean benches while the indirect factor² was 1.4-2.2
    (session 17 dev seeds 5330-5349, session 18 training seeds 6120-6127), and every
    run-mean test paid for it. A catalog effect common to the moving sensors raises this
    estimate (the probes re-run it on the residual with the effect,
    :func:`levels_of`), so it caps the indirect factor, never raises it."""
    ucl = _direct_ucl(resid_means, common_base, quantile)
    return None if ucl is None or not s_raw > 0 else math.sqrt(max(1.0, ucl / s_raw**2))


def _direct_ucl(means: np.ndarray, base: np.ndarray | None, q: float | None) -> float | None:
    """:func:`_direct_common_factor`'s upper confidence limit (rad²; independent of ``s_raw``)."""
    R, M = means.shape
    z0 = means.mean(1) * math.sqrt(M)  # the common Helmert component
    A = span_basis(base) if base is not None else np.zeros((R, R))
    dof = R - A.shape[1]
    if dof <= 0 or q is None:
        return None
    z = z0 - A @ (A.T @ z0)
    return float(z @ z) / float(stats.chi2.ppf(q, dof))


def _common_scale(info: dict, rounding: float, lock: float) -> float:
    """The factor (at most 1) on the chi-square of a pattern common to the moving sensors
    (``SDSNoiseInfo.common_scale``: the views ``common_orders`` and ``common_modulated``):
    ``(g / g_c)^2``, ``g`` the run means' common factor the record is whitened with (``info``:
    :func:`_level_sigma`'s), ``g_c`` the indirect one with its excess at least ``rounding``
    (rad², the clock's rounding constant within a run,
    :func:`._sds_clock_lock.rounding_common_excess`), capped (or mixed at the share ``lock``)
    by the direct one as ``g`` is. Only the common component holds that rounding, so the
    level every channel is whitened with keeps ``g``."""
    g, g_i = info.get("run_means_common_factor"), info.get("run_means_common_factor_indirect")
    s = float(info.get("run_means_rad") or 0.0)
    if not rounding > 0 or not s > 0 or g is None or g_i is None:
        return 1.0
    g_c = math.sqrt(max(g_i * g_i, 1.0 + rounding / (s * s)))
    g_c = float(lock_mixed_factor(g_c, info.get("run_means_common_factor_direct"), lock))
    return min(1.0, (g / g_c) ** 2)


def _widen(test_p: float, nu: float, p: float | None = None) -> float:
    """:func:`dof_widening` at ``nu`` degrees of freedom and the test's ``p`` (``None``: the
    level's ``test_p``): the run-mean level's widening, which a test may ask at its own ``p``
    (:meth:`._sds_level_out.RunMeanLevel.widening`, session 42)."""
    return dof_widening(nu, p=test_p if p is None else p)


def _level_sigma(
    resid: np.ndarray,
    K: int,
    X: np.ndarray,
    proj: bool = False,
    info: dict | None = None,
    *,
    test_p: float,
    level_alpha: float,
    fixed: np.ndarray | None = None,
    common_base: np.ndarray | None = None,
    common_quantile: float | None = None,
    phi: np.ndarray | None = None,
    pairs: tuple[np.ndarray, np.ndarray] | None = None,
    state: dict | None = None,
    share: bool = False,
    direct: bool = False,
    component: bool = False,
    lock: float = 0.0,
    rounding: float = 0.0,
) -> np.ndarray:
    """Noise per channel: one level for the run means, one for the revolution contrasts
    (each pooled over the moving sensors, which see the same clock and marks).

    Run means: the residual of a saturated least-squares fit (:func:`_saturating_columns`:
    every smooth pattern in the platform angle up to order ``L``, so no catalog effect and
    no low order can inflate it), plus the significant change points (a step on one sensor
    from one run on) and single-value outliers (one sensor in one run), each searched for
    and tested as F(1, dof) against what is left (Bonferroni), so neither can inflate it
    either; with the platform angles ``phi`` (one per run, rows in time order) also an order
    of ``phi`` on one sensor that is there throughout, grows or switches on (a pair of
    columns, :func:`_order_groups`, F(2, dof); each step takes the column or pair of least
    Bonferroni-adjusted p-value; issue 41, session 18). The level is ``sqrt(SSR / nu)`` with
    ``nu`` = independent values − rank (without ``phi_ref`` the values of a run are projected
    on the moving-sensor differences: ``R·(M − 1)`` independent values, not ``R·M``), then
    widened by :func:`dof_widening` (``nu``) for its estimation error: with ~12 platform
    positions it is known to ~±17 %, which the engine's known-level tests would otherwise
    turn into false alarms. With ``phi_ref`` it is then raised by :func:`_common_factor` (from
    the contrasts and the fixed sensors' run means ``fixed``): the saturated fit leaves the run
    means' common component no degrees of freedom. With ``common_base`` (the base's common
    columns, :func:`common_base_columns`) and ``common_quantile`` that factor is capped at what
    the common component of ``resid`` supports (:func:`_direct_common_factor`), or mixed with it
    at the clock's rounding share ``lock`` (:func:`lock_mixed_factor`).

    Contrasts: the robust scale (1.4826 MAD) of the contrasts (nothing constant within a run
    reaches them), separately for the part common to the moving sensors (the fixed sensors'
    timing noise enters every pair alike) and for the differences; the larger per-value level is
    used (the engine weighs channels as independent: conservative). ``state`` (a dict) receives
    ``factor``: the level without a test's columns (:mod:`._sds_level_out`, with ``rounding``)."""
    R, C = resid.shape
    M = C // K
    out = np.empty(C)
    ym = resid[:, :M].ravel()
    n_ind = R * (M - 1) if proj else R * M

    # candidate columns: a change point per sensor and run, a single value per sensor and run
    cols = []
    for m in range(M):
        for k in range(1, R):
            a = np.zeros((R, M))
            a[k:, m] = 1.0
            cols.append(a)
        for r in range(R):
            a = np.zeros((R, M))
            a[r, m] = 1.0
            cols.append(a)
    A = np.stack(cols, -1)  # (R, M, n_cols)
    if proj:
        A = A - A.mean(1, keepdims=True)
    A = A.reshape(R * M, -1)
    n_tests = max(1, A.shape[1])
    Q = span_basis(X)
    if pairs is None and phi is not None:
        pairs = _projected_pairs(_order_groups(phi, R, M, proj), Q)
    Qa = np.zeros((Q.shape[0], 0))  # the columns taken, orthogonal to the saturating ones
    added = orders = 0
    for _ in range(3 * M):
        e = ym - Q @ (Q.T @ ym)
        ssr0 = float(e @ e)
        dof = n_ind - Q.shape[1] - 1
        if dof < 3 or ssr0 <= 0:
            break
        Ap = A - Q @ (Q.T @ A)
        nn = np.sum(Ap**2, 0)
        ok = nn > 1e-10 * np.sum(A**2, 0)
        gain = np.where(ok, (e @ Ap) ** 2 / np.where(ok, nn, 1.0), 0.0)
        j = int(np.argmax(gain))
        f = gain[j] / ((ssr0 - gain[j]) / dof) if ssr0 > gain[j] else np.inf
        # Bonferroni-adjusted log p-values: the single column, and the best pair of orders
        lp = stats.f.logsf(f, 1, dof) + math.log(n_tests) if ok[j] else 0.0
        pair = _best_pair(e, dof - 1, Qa, pairs) if pairs is not None else None
        if pair is not None and pair[0] < lp:
            if pair[0] >= math.log(level_alpha):
                break
            new = pair[1]
            orders += 1
        elif lp >= math.log(level_alpha):
            break
        else:
            new = Ap[:, j : j + 1]
            added += 1
        Q = span_basis(np.concatenate([Q, new], 1))
        Qa = np.concatenate([Qa, span_basis(new)], 1)
    e = ym - Q @ (Q.T @ ym)
    ssr0, rk0 = float(e @ e), Q.shape[1]
    nu = max(n_ind - rk0, 1)
    s_raw = math.sqrt(ssr0 / nu) if ssr0 > 0 else 0.0
    c = dof_widening(nu, p=test_p)
    lv: list[float] = []
    if C > M:
        H = _sensor_helmert(M)
        z = resid[:, M:].reshape(R, K - 1, M) @ H
        parts = [z[..., :1].ravel()] + ([z[..., 1:].ravel()] if M > 1 else [])
        for x in parts:
            s = 1.4826 * float(np.median(np.abs(x)))
            lv.append(s if s > 0 else float(np.sqrt(np.mean(x**2))))
        out[M:] = max(lv)

    def factors(s: float) -> tuple[float, float, float | None]:
        g_i = _common_factor(lv, proj, fixed, s, M, K)
        g_d = None
        if not proj and common_base is not None and common_quantile is not None:
            g_d = _direct_common_factor(resid[:, :M], common_base, s, common_quantile)
        return float(lock_mixed_factor(g_i, g_d, lock)), g_i, g_d

    g, g_ind, g_dir = factors(s_raw)
    out[:M] = s_raw * c * g
    if state is not None:  # s * widening(nu) * factors(s)[0] on arrays of s and nu
        ucl = None if proj else _direct_ucl(resid[:, :M], common_base, common_quantile)
        excess = 0.0 if proj else _common_excess(lv, fixed, M, K)
        sigma_of = RunMeanLevel(partial(_widen, test_p), excess, ucl, lock, rounding)
        both = (direct or component) and common_base is not None
        common = (resid[:, :M], common_base) if both else None
        state["factor"] = LevelOut(e, Q, n_ind, sigma_of, proj, M, share, common, component)
    if info is not None:
        info.update(
            run_means_rad=s_raw,
            run_means_dof=int(nu),
            run_means_widening=c,
            run_means_common_factor=g,
            run_means_common_factor_indirect=g_ind,
            run_means_common_factor_direct=g_dir,
            run_means_steps_or_outliers=added,
            run_means_sensor_orders=orders,
            contrasts_common_rad=lv[0] if lv else None,
            contrasts_differences_rad=lv[1] if len(lv) > 1 else None,
        )
    if not np.all(np.isfinite(out)) or np.any(out <= 0):
        out = np.full(C, float(np.std(resid)) or 1e-12)
    return out


def run_mean_levels(
    K: int,
    rows: Mapping[str, Any],
    consts: Mapping[str, Any],
    orders: list[int],
    settings: FinderSettings,
) -> Callable[..., np.ndarray]:
    """``levels(resid, info=None) -> sigma (C,)``: :func:`_level_sigma` on a residual (R, C:
    one row per run, ``K`` revolution columns per moving sensor) with the kind's settings
    spelled once: the saturating columns of the design ``orders``
    (:func:`_saturating_columns`), the one-sensor order pairs in the platform angles
    ``rows["theta"]`` (:func:`_order_groups`, projected off those columns once: the probes
    re-run the level many times), the fixed sensors' run means (``rows["fixed_c"]``), the
    base's common columns (:func:`common_base_columns`) and the thresholds of ``settings``.
    Used by the prepare stage, the noise hook and the probes' re-estimates
    (:func:`levels_of`), so that they cannot drift apart."""
    X, _ = _saturating_columns(rows, consts, orders, settings.sds_saturate_fraction)
    proj = float(consts["proj"]) > 0
    phi = np.asarray(rows["theta"], float)
    pairs = _projected_pairs(
        _order_groups(phi, phi.size, int(np.asarray(consts["psi_m"]).size), proj), span_basis(X)
    )
    fixed = np.asarray(rows["fixed_c"], float)
    common = common_base_columns(rows["phi"], consts["psi_m"], orders)
    switch = settings.sds_clock_lock_level  # 1: the views' rounding, 2: mixing, 3: tests
    lock = float(np.asarray(consts.get("clock_lock", 0.0))) * (switch == 2)
    rounding = float(np.asarray(consts.get("clock_round_excess", 0.0))) * (switch > 0 and not proj)

    def levels(resid: np.ndarray, info: dict | None = None, state=None) -> np.ndarray:
        info = {} if info is None and state is not None else info
        sig = _level_sigma(
            resid,
            K,
            X,
            proj,
            info=info,
            test_p=settings.sds_sigma_test_p,
            level_alpha=settings.sds_level_alpha,
            fixed=fixed,
            common_base=common,
            common_quantile=settings.sds_common_level_quantile,
            pairs=pairs,
            state=state,
            share=settings.sds_level_common_share > 0,
            direct=settings.sds_level_common_direct > 0,
            component=settings.sds_level_per_component > 0,
            lock=lock,
            rounding=rounding * (switch == 3),
        )
        if state is not None:  # (``info`` is a dict there: the line above)
            state["common_scale"] = _common_scale(info, rounding, lock)
        return sig

    return levels


def levels_of(ctx: Context):
    """``levels(resid) -> sigma (C,)``: the noise stage's own estimate (:func:`run_mean_levels`,
    same orders and settings) on another residual of the kept rows (``None`` before the stage
    ran): what a probe's effect added to the base residual makes of it."""
    base = noise_info(ctx).base_resid
    if base is None:
        return None
    orders = base_orders(ctx.meta, ctx.consts, ctx.max_order)[0]
    K = base.shape[1] // int(np.asarray(ctx.consts["psi_m"]).size)
    return run_mean_levels(K, ctx.rows, ctx.consts, orders, ctx.settings)


def sds_noise(prep: Prepared, resid: np.ndarray) -> NoiseEstimate:
    """Noise hook: the two levels of :func:`_level_sigma` on the base residual, with what
    the candidates' rules need (:class:`SDSNoiseInfo`: the base residual's common-order
    powers (:func:`common_order_power`) for the plausibility of ``beam_tilt_axial``, ...)."""
    # one row per run, every run kept (sds_prepare): the rows are the residual's rows
    orders = base_orders(prep.ctx.meta, prep.consts, prep.ctx.max_order)[0]
    info: dict = {}
    state: dict = {}
    levels = run_mean_levels(prep.kd.n_revs, prep.rows, prep.consts, orders, prep.settings)
    sig = levels(resid[prep.keep], info, state)
    M = prep.consts["psi_m"].size
    rwm = resid[:, :M] / sig[None, :M]
    pw = common_order_power(prep, rwm)
    found = SDSNoiseInfo(
        levels=info,
        common_order_power=tuple(float(v) for v in pw),
        drift_vs_orders=_drift_vs_orders(prep, rwm, pw),
        run_change_power=tuple(_step_or_outlier(rwm[:, m]) for m in range(M)),
        base_resid=np.asarray(resid[prep.keep], float),
        level_factor=state.get("factor"),
        common_scale=float(state.get("common_scale", 1.0)),
    )
    return NoiseEstimate(sig, found)


def _drift_vs_orders(prep: Prepared, rwm: np.ndarray, pw: np.ndarray) -> dict | None:
    """A drift in time against the orders of the platform angle, both common to the moving
    sensors, on the whitened base run means: the drift's power (1 dof), the best order's
    (2 dof) and the correlation of the drift column with that order's two columns. With the
    platform stepped by a fixed angle (e.g. golden-angle steps), order ``n`` advances by a
    nearly fixed phase per run: over a few runs it is nearly a trend in time (order 5 with
    golden steps), so the two can be confounded."""
    if float(prep.consts["proj"]) > 0 or pw.size == 0:
        return None
    R, M = rwm.shape
    phi = np.asarray(prep.rows["phi"], float)
    t = np.asarray(prep.rows["tmid_c"], float).mean(1)
    y = (rwm - rwm.mean(0, keepdims=True)).ravel()
    d = np.repeat(t - t.mean(), M)
    pd = float((d @ y) ** 2 / max(d @ d, 1e-300))
    n = int(np.argmax(pw)) + 1
    X = np.stack(
        [np.cos(n * phi) - np.cos(n * phi).mean(), np.sin(n * phi) - np.sin(n * phi).mean()], 1
    )
    X = np.repeat(X, M, axis=0)
    Q, _ = np.linalg.qr(X)
    dn = d / max(np.linalg.norm(d), 1e-300)
    rho = float(np.linalg.norm(Q.T @ dn))
    op = onset_power(prep.rows, prep.consts, rwm)
    return {
        "drift_power": pd,
        "onset_power": op["onset_power"],
        "order": n,
        "order_power": float(pw[n - 1]),
        "correlation": rho,
        "n_values": int(R * M),
    }


def _common_max_order(R: int) -> int:
    return int(max(1, (R - 1) // 2))


def common_order_power(prep: Prepared, rwm: np.ndarray) -> np.ndarray:
    """Chi-square (2 dof) of orders ``1..(R-1)//2`` in the platform angle φ, one coefficient
    pair for all moving sensors (a pattern common to them), in the whitened run means
    ``rwm`` (R, M), less a constant per sensor."""
    phi = np.asarray(prep.rows["phi"], float)
    R, M = rwm.shape
    y = (rwm - rwm.mean(0, keepdims=True)).ravel()
    out = []
    for n in range(1, _common_max_order(R) + 1):
        c = np.repeat(np.cos(n * phi), M).reshape(R, M)
        sn = np.repeat(np.sin(n * phi), M).reshape(R, M)
        X = np.stack([(c - c.mean(0)).ravel(), (sn - sn.mean(0)).ravel()], 1)
        if float(prep.consts["proj"]) > 0:
            X = np.zeros_like(X)  # common to the moving sensors: taken by the run offsets
        out.append(_ls_power_flat(y[:, None], X[:, None, :]))
    return np.asarray(out)


def _coil_plausible(ctx: Context, params: dict) -> str | None:
    """Coil orders that are multiples of the moving-sensor count are a pattern common to
    the moving sensors: refused when that is the fitted effect's main part and the base
    residual's common structure peaks at another order (aliased through the platform
    positions)."""
    M = int(ctx.consts["psi_m"].size)
    amp = np.hypot(np.asarray(params["cos_rad"]), np.asarray(params["sin_rad"]))
    n = coil_orders(ctx.meta, ctx.consts)[int(np.argmax(amp))]  # its fitted orders, lowest first
    pw = np.asarray(noise_info(ctx).common_order_power, float)
    if M < 2 or n % M or pw.size == 0:
        return None
    top = int(np.argmax(pw)) + 1
    own = pw[min(n, pw.size) - 1]
    if top != n and pw[top - 1] > ctx.settings.sds_common_order_ratio * own:
        return (
            f"its main order {n} is common to the moving sensors, but the common structure "
            f"peaks at order {top} of the platform angle (chi-square {pw[top - 1]:.0f})"
        )
    return None


def _delay_gauge(ctx: Context, delay) -> np.ndarray:
    """The fitted delays per moving sensor; without phi_ref a delay common to every moving
    sensor is taken by the per-run offset, so the delays are known up to a common value:
    the median is taken out (one sensor's step then shows on that sensor alone)."""
    d = np.asarray(delay, float)
    if float(np.asarray(ctx.consts["proj"])) > 0 and d.size > 2:
        d = d - np.median(d)
    return d


def _delay_plausible(ctx: Context, params: dict) -> str | None:
    """A delay step is one sensor's (its electronics, its cable): refused when another
    moving sensor carries more than half of the largest step (a pattern common to the
    moving sensors, e.g. a drift or a platform-angle order, is not a sensor's delay)."""
    dd = np.abs(_delay_gauge(ctx, params["delay_s"]))
    d = np.sort(dd)[::-1]
    if d.size > 1 and d[1] > ctx.settings.sds_delay_shared_max * d[0]:
        return (
            f"the step is shared by several moving sensors ({d[1] / d[0]:.0%} of the largest "
            "on the next one): not one sensor's delay"
        )
    # a delay change persists: a change confined to one run (a single-run outlier fits the
    # sensor's base run means better than any step, both 1 dof) is a transient, not a step
    ch = noise_info(ctx).run_change_power
    if ch:
        m = int(np.argmax(dd))
        ps, ks, po, jo, _ = ch[m]
        if po > ps * (1 + 1e-9):
            return (
                f"the change on m{m} is confined to one run (run index {jo}: a single-run "
                f"outlier fits with chi-square {po:.0f}, the best step from one run on with "
                f"{ps:.0f}): a transient in one run, not a persisting delay step"
            )
    return None
