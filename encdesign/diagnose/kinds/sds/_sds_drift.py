"""The SDS ``thermal_drift`` term: a drift of the moving sensors in time with an onset.

Without a temperature column time drives the drift: ``δ_m(t) = k max(t − t_on, 0)`` for
every moving sensor (seed 001's ``κ ΔT(t)`` with a temperature that starts to change at
``t_on`` and then changes at a steady rate; continuous at the onset, as the temperature
is). The onset is a fitted nonlinear parameter, ``onset_from_start_s`` = ``t_on`` less the
record's first moving-sensor window time (s), so that the drift from the start, the
catalog's usual case, is ``onset_from_start_s < 0``: there the term is ``k (t − t̄)``, the
catalog's term before the onset was added, and the onset's column is zero, so it is not
determined (``FitResult.n_determined``): one parameter, the rate, counted as before. The onset is
reported on the recording's own ``t`` (``derived.onset_s``, with its standard error) and
with the first run that drifts.

An onset is tried where the data ask for it: the start at the best onset (scanned at the
first window of every run but the first) is offered only when the drift from that run on
fits the base run means better than the drift from the start by more than one parameter's
worth (BIC: ln of the number of run means), the same measure the drift's plausibility rule
(:func:`onset_power`, ``_sds_common_rules._drift_plausible``) uses against the platform's orders.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from ...engine._candidates import Context, Probe

__all__ = [
    "drift_derived",
    "drift_fn",
    "drift_power_at",
    "drift_probes",
    "drift_start",
    "hinge_run_means",
    "onset_power",
]


def _t_first(tm_c, t_mean):
    return jnp.min(tm_c) + t_mean


def drift_fn(p, x, to_channels, xk):
    """``k (max(t − t_on, 0) − max(t̄ − t_on, 0))`` at every moving sensor's window time
    (pair values), rad; ``t̄`` the record's mean time. The constant makes the drift from the
    start (``t_on`` before every window) ``k (t − t̄)`` whatever ``t_on``: the onset's column
    is then exactly zero (not determined: no parameter counted, no standard error)."""
    _, _, shp = xk(x)
    t_on = _t_first(x["tm_c"], x["t_mean"]) + p["onset_from_start_s"]
    h = jnp.maximum(x["tm_c"] + x["t_mean"] - t_on, 0.0) - jnp.maximum(
        x["t_mean"] - t_on, 0.0
    )  # (n, K, M), s
    tm = jnp.broadcast_to(h[:, :, None, :], shp)
    return to_channels(p["drift_rate_rad_per_s"] * tm, x)


def hinge_run_means(rows, consts, onset_from_start_s: float) -> np.ndarray:
    """``max(t − t_on, 0)`` per run and moving sensor, the mean over the run's revolutions
    (R, M), s: the drift's pattern in the run-mean channels at unit rate."""
    tm = np.asarray(rows["tm_c"], float)
    t_on = float(tm.min()) + float(onset_from_start_s)
    return np.maximum(tm - t_on, 0.0).mean(1) if tm.size else np.zeros((0, 0))


def _power(y: np.ndarray, d: np.ndarray) -> float:
    """Chi-square one column ``d`` (R, M), less a constant per sensor, takes from ``y``."""
    d = d - d.mean(0, keepdims=True)
    dd = float(np.sum(d * d))
    return float(np.sum(d * y)) ** 2 / dd if dd > 0 else 0.0


def drift_power_at(rows, consts, rwm: np.ndarray, onset_from_start_s: float) -> float:
    """Chi-square of the drift from ``onset_from_start_s`` on (its rate, 1 dof) in the
    whitened base run means ``rwm`` (R, M), less a constant per sensor."""
    y = np.asarray(rwm, float)
    return _power(y - y.mean(0, keepdims=True), hinge_run_means(rows, consts, onset_from_start_s))


def _run_starts(rows) -> np.ndarray:
    """Each run's first moving-sensor window time less the record's first, s (R,)."""
    tm = np.asarray(rows["tm_c"], float)
    return tm.reshape(tm.shape[0], -1).min(1) - tm.min()


def onset_power(rows, consts, rwm: np.ndarray) -> dict:
    """The drift from the start and the best drift with an onset at a run's first window
    (runs 1 … R − 1) on the whitened base run means ``rwm`` (R, M), less a constant per
    sensor: ``{"ramp_power", "onset_power", "onset_from_start_s", "n_values"}`` (chi-square
    of the rate at its best onset; the onset's own degree of freedom is the caller's)."""
    y = np.asarray(rwm, float)
    y = y - y.mean(0, keepdims=True)
    ramp = _power(y, hinge_run_means(rows, consts, 0.0))
    best, at = ramp, 0.0
    for s in _run_starts(rows)[1:]:
        pw = _power(y, hinge_run_means(rows, consts, float(s)))
        if pw > best:
            best, at = pw, float(s)
    return {
        "ramp_power": ramp,
        "onset_power": best,
        "onset_from_start_s": at,
        "n_values": int(y.size),
    }


def _before(ctx: Context) -> float:
    """How far before the record's first window the drift from the start puts its onset:
    the record's span and a revolution (s, > 0)."""
    tm = np.asarray(ctx.rows["tm_c"], float)
    return float(np.ptp(tm)) + 2 * math.pi / float(np.asarray(ctx.consts["omega"]))


def drift_start(ctx: Context, resid: np.ndarray, findings) -> list[dict]:
    """The drift from the start (its onset before the record, :func:`_before`: its column
    zero, not determined) and, where the base run means ask for it by more than one
    parameter's worth, the best onset at a run's first window."""
    del findings
    M = int(np.asarray(ctx.consts["psi_m"]).size)
    before = -_before(ctx)
    out = [{"onset_from_start_s": np.asarray(before)}]
    if ctx.noise is None:
        return out
    rwm = resid[:, :M] / np.asarray(ctx.noise, float)[None, :M]
    op = onset_power(ctx.rows, ctx.consts, rwm)
    if op["onset_power"] - op["ramp_power"] > math.log(max(op["n_values"], 2)):
        out.insert(0, {"onset_from_start_s": np.asarray(op["onset_from_start_s"])})
    return out


def drift_derived(ctx: Context, v, se) -> dict:
    """The onset on the recording's own ``t`` (s, with its standard error; the record's
    first window time when the drift runs from the start), whether it does, and the id of
    the first run that drifts."""
    tm = np.asarray(ctx.rows["tm_c"], float)
    t0 = float(np.asarray(ctx.consts["t_mean"]))
    d = float(np.asarray(v["onset_from_start_s"]))
    s = float(np.asarray(se["onset_from_start_s"]))
    from_start = not d > 0
    t_on = float(tm.min()) + t0 + max(d, 0.0)
    ends = tm.reshape(tm.shape[0], -1).max(1) + t0
    first = int(np.argmax(ends > t_on)) if np.any(ends > t_on) else tm.shape[0] - 1
    rid = int(ctx.data.table.run_ids[first]) if ctx.data is not None else first
    return {
        "onset_s": {
            "value": t_on,
            "se": s if (not from_start and math.isfinite(s)) else None,
            "unit": "s",
        },
        "drift_from_start": {"value": bool(from_start), "se": None, "unit": "1"},
        "first_run": {"value": rid, "se": None, "unit": "1"},
    }


def drift_probes(ctx: Context, seen_of) -> list[Probe]:
    """A drift of the moving sensors' pair angles at 1 rad/s over the whole record (its
    onset before the record: not determined there, so not counted in the bound's ``k``)."""
    before = -_before(ctx)
    M = int(ctx.consts["psi_m"].size)
    t = np.asarray(ctx.rows["tmid_c"], float).mean(1)
    pattern = np.repeat(t[:, None], M, 1)
    return [
        Probe(
            {"drift_rate_rad_per_s": np.asarray(1.0), "onset_from_start_s": np.asarray(before)},
            "drift_rate_rad_per_s",
            "rad/s",
            seen=seen_of(ctx, pattern, caught=False),
            held=("onset_from_start_s",),
        )
    ]


def _step_or_outlier(x: np.ndarray) -> tuple[float, int, float, int, float]:
    """``(power, first run index)`` of the best step over the runs and of the best
    single-run outlier in one sensor's whitened run means (each 1 dof, less the mean), and
    the sensor's total power."""
    R = x.size
    x = x - x.mean()
    best_s, k_s = 0.0, 1
    for k in range(1, R):
        s = (np.arange(R) >= k).astype(float)
        s -= s.mean()
        pw = float((s @ x) ** 2 / (s @ s))
        if pw > best_s:
            best_s, k_s = pw, k
    j = int(np.argmax(np.abs(x)))
    return best_s, k_s, float(x[j] ** 2 * R / max(R - 1, 1)), j, float(x @ x)
