"""The rules of the SDS catalog effects common to the moving sensors (``thermal_drift``,
``beam_tilt_axial``) and the clock's rounding constant within a run read by the tests of a
common part (issue 41, session 42: moved out of :mod:`._sds_noise`, with
:func:`rounding_scale` and :func:`_within_rounding` added)."""

from __future__ import annotations

import math

import numpy as np

from ...engine._candidates import Context
from ._sds_drift import drift_power_at
from ._sds_level_out import common_share
from ._sds_noise import BEAM_ORDERS, noise_info


def _drift_plausible(ctx: Context, params: dict) -> str | None:
    """A drift in time is refused when an order of the platform angle (common to the
    moving sensors) fits the base residual's common structure better by BIC (ln of the
    number of run means per parameter; the order has 2, the drift 1, or 2 with an onset in
    the record, its power then at the fitted onset): with the platform stepped by a fixed
    angle such an order is nearly a trend over the runs, and the better fit is the order
    (out of catalog: reported, not named)."""
    info = noise_info(ctx)
    dv = info.drift_vs_orders
    if not dv:
        return None
    pd, k = dv["drift_power"], 1
    d = float(np.asarray(params.get("onset_from_start_s", 0.0)))
    if d > 0 and info.base_resid is not None and ctx.noise is not None:
        M = int(np.asarray(ctx.consts["psi_m"]).size)
        rwm = info.base_resid[:, :M] / np.asarray(ctx.noise, float)[None, :M]
        pd, k = drift_power_at(ctx.rows, ctx.consts, rwm, d), 2
    if dv["order_power"] - pd > (2 - k) * math.log(max(dv["n_values"], 2)):
        return (
            f"order {dv['order']} of the platform angle fits the common structure better "
            f"(chi-square {dv['order_power']:.0f}, 2 dof, vs {pd:.0f}, {k} dof) "
            f"and is nearly a trend over these runs (correlation {dv['correlation']:.2f} with "
            "a drift): not a drift in time"
        )
    return _within_rounding(ctx, pd, k)


def _beam_plausible(ctx: Context, params: dict) -> str | None:
    """Beam tilt x axial runout lives at orders 1..3 of φ: refused when the base residual's
    strongest common order is another one (an out-of-catalog order that orders 1..3 take in
    part through the sparse platform positions)."""
    pw = np.asarray(noise_info(ctx).common_order_power, float)
    if pw.size == 0:
        return None
    top = int(np.argmax(pw)) + 1
    if top not in BEAM_ORDERS and pw[top - 1] > ctx.settings.sds_common_order_ratio * max(
        pw[n - 1] for n in BEAM_ORDERS if n <= pw.size
    ):
        return (
            f"the common structure peaks at order {top} of the platform angle (chi-square "
            f"{pw[top - 1]:.0f}), not at the beam-tilt orders {list(BEAM_ORDERS)}"
        )
    own = [n for n in BEAM_ORDERS if n <= pw.size]
    return _within_rounding(ctx, float(sum(pw[n - 1] for n in own)), 2 * len(own))


def _tests_rounding_scale(ctx: Context) -> float:
    """``SDSNoiseInfo.common_scale`` where ``FinderSettings.sds_clock_lock_level`` is 3 (the
    tests of a common part read the clock's rounding), else 1."""
    return noise_info(ctx).common_scale if ctx.settings.sds_clock_lock_level == 3 else 1.0


def rounding_scale(ctx: Context, cols: np.ndarray, M: int) -> float:
    """The factor (at most 1) on the chi-square of columns ``cols`` (R, C, q; whitened, the
    first ``M`` channels the moving sensors' run means) with the part of them in the run
    means' component common to the moving sensors read, as the common views read it,
    against that component's level with the clock's rounding constant within a run
    (``SDSNoiseInfo.common_scale`` ``S``): ``1 / (1 + kappa (1 / S - 1))``, ``kappa`` the
    columns' share of their squared norm in that component (``common_share`` of the run-mean
    part times its share of the norm: 1 for a pattern common to the moving sensors and
    constant within a run, a third for one of three sensors' run means). 1 where ``S`` is 1
    (no rounding constant within a run: the clock locked to the motor, or far from it) and
    unless ``FinderSettings.sds_clock_lock_level`` is 3 (off by default: docs/diagnose.md)."""
    scale = _tests_rounding_scale(ctx)
    if not scale < 1.0:  # the default: nothing to compute per start of the matched views
        return 1.0
    X = np.asarray(cols, float)
    total = float(np.sum(X**2))
    if not total > 0 or X.ndim != 3 or X.shape[1] < M:
        return 1.0
    rm = X[:, :M, :]
    kappa = common_share(rm) * float(np.sum(rm**2)) / total
    return float(1.0 / (1.0 + kappa * (1.0 / scale - 1.0)))


def _within_rounding(ctx: Context, power: float, k: int) -> str | None:
    """A catalog effect common to the moving sensors (``beam_tilt_axial``, ``thermal_drift``)
    read, as the common views read it (``SDSNoiseInfo.common_scale``), against the common
    component's level with the clock's rounding constant within a run
    (:func:`._sds_clock_lock.rounding_common_excess`): refused where its whitened common
    power ``power`` in the base residual (``k`` parameters) then no longer lowers the
    information criterion by ``bic_min`` (``-power * common_scale + k ln N``, ``N`` the run
    means and contrasts fitted). The candidate's own criterion reads its chi-square at the
    level every channel is whitened with, which leaves out that rounding (it lives only in
    the common component, session 40); a pattern common to the moving sensors is tested
    against the same noise whether a view or a candidate tests it. Nothing changes where the
    rounding's share is 0 (the clock locked to the motor, or far from it: ``common_scale`` 1),
    nor unless ``FinderSettings.sds_clock_lock_level`` is 3 (off by default: near lock it lost
    five of six training near-noise drifts, the model being the rounding's upper value).
    Training: unlocked-clock 6824 record 22 (session 42), clean, lock share 0.88, the
    rounding's common excess 17.9 nrad RMS (the record's own common noise 13.5 nrad against
    2.4 in the differences, by its noise-free twin) while the whitening level was 5.0 nrad:
    named ``beam_tilt_axial`` at dBIC -16.7."""
    scale = _tests_rounding_scale(ctx)
    if not scale < 1.0 or not power > 0:
        return None
    n = int(np.asarray(ctx.rows["phi"]).size) * int(ctx.n_channels)
    dbic = -power * scale + k * math.log(max(n, 2))
    if dbic > -ctx.settings.bic_min:
        return (
            f"its common pattern (chi-square {power:.0f}, {k} dof, at the whitening level) is "
            f"{power * scale:.1f} against the common component's level with the clock's "
            f"rounding constant within a run (the clock nearly locked to the motor): dBIC "
            f"{dbic:.1f}, not below -{ctx.settings.bic_min:.0f}: the rounding, not an effect"
        )
    return None
