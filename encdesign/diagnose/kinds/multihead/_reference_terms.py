"""The finder's candidates for one sensor read against a reference (``docs/effects.md``).

The physics of each term (direction hysteresis, reading delay, scale error, quantization,
interpolation error; derivations and closed forms) is in
:mod:`encdesign.physics._sensor_effects`, the data helpers (reference velocity, the value
lattice :func:`detect_lsb`, a record's summary) in
:mod:`encdesign.diagnose.kinds.multihead._reference_data`;
this module registers each term as a :class:`~encdesign.diagnose.Candidate` of the multihead
kind, tried on a sensor against a reference.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ....physics._sensor_effects import (
    REFERENCE_PARAM_UNITS,
    interpolation_params_from_harmonics,
    quantization_rad,
    reading_delay_rad,
    scale_error_rad,
)
from ...engine._candidates import Candidate, Context, Param, Probe
from ...engine._lattice import Lattice, detect_lsb
from ...engine._padded import eval_rows

__all__ = ["CANDIDATES", "interpolation_candidate"]

# ----------------------------------------------------------------------------- candidates
# The engine's registration API (``encdesign.diagnose.engine._candidates``): each term above as a
# :class:`Candidate` of the multihead kind, tried on a sensor against a reference.

# The plausibility bounds of these candidates are FinderSettings fields
# (direction_offset_max_rad, delay_angle_max_rad, scale_error_max, signal_error_max_rad,
# interp_spread_min, quant_amplitude_tol, signal_first_order_max_rad), read through
# ``ctx.settings``.


def _by_run(ctx: Context, name: str) -> list[np.ndarray]:
    rows = ctx.rows
    onehot = np.asarray(rows["run_onehot"])
    col = np.asarray(rows[name])
    return [col[onehot[:, r] > 0.5] for r in range(onehot.shape[1])]


def _both_directions(ctx: Context) -> bool:
    return any(d.size and d.min() < 0 < d.max() for d in _by_run(ctx, "direction"))


def _need_ref(ctx: Context) -> str | None:
    if not ctx.has_ref or ctx.n_channels != 1:
        return "only for one sensor against a reference (one head and theta_ref)"
    return None


def _hyst_fn(p: dict, x: dict) -> Array:
    return (0.5 * p["hysteresis_rad"] * x["direction"])[:, None]


def _hyst_applies(ctx: Context) -> str | None:
    why = _need_ref(ctx)
    if why:
        return why
    if not _both_directions(ctx):
        return "no run turns in both directions: a direction offset is a run constant"
    return None


def _sensor_name(ctx: Context) -> str:
    names = ctx.data.channel_names if ctx.data is not None else []
    return names[0] if names else "all"


def _hyst_probes(ctx: Context) -> list[Probe]:
    """An offset of 1 rad between the directions (the bound: the smallest offset)."""
    return [Probe({"hysteresis_rad": np.asarray(1.0)}, "hysteresis_rad", "rad", _sensor_name(ctx))]


def _delay_probes(ctx: Context) -> list[Probe]:
    """A reading delay of 1 s (the bound: the smallest delay)."""
    return [Probe({"delay_s": np.asarray(1.0)}, "delay_s", "s", _sensor_name(ctx))]


def _hyst_plausible(ctx: Context, p: dict) -> str | None:
    h = abs(float(np.asarray(p["hysteresis_rad"])))
    if h > ctx.settings.direction_offset_max_rad:
        return f"an offset of {h:.3g} rad between directions is not backlash or hysteresis"
    return None


def _hyst_derived(ctx: Context, p: dict, se: dict) -> dict:
    w = np.abs(np.asarray(ctx.rows["omega"], dtype=np.float64))
    if w.size == 0 or np.max(w) <= 0 or np.ptp(w) > ctx.settings.speed_spread_min * np.max(w):
        return {}
    h = float(np.asarray(p["hysteresis_rad"]))
    s_h = float(np.asarray(se.get("hysteresis_rad", np.nan)))
    wm = float(np.median(w))
    return {"equivalent_delay_s": {"value": -h / (2 * wm), "se": s_h / (2 * wm), "unit": "s"}}


def _delay_fn(p: dict, x: dict) -> Array:
    return reading_delay_rad(x["omega"], p["delay_s"])[:, None]


def _delay_applies(ctx: Context) -> str | None:
    why = _need_ref(ctx)
    if why:
        return why
    runs = [np.abs(w) for w in _by_run(ctx, "omega") if w.size]
    spread = ctx.settings.speed_spread_min
    within = any(np.ptp(w) > spread * np.max(w) for w in runs if np.max(w) > 0)
    if within:
        return None
    allw = np.concatenate(runs) if runs else np.zeros(0)
    vary = allw.size > 0 and np.ptp(allw) > spread * np.max(allw)
    if _both_directions(ctx):
        # at one speed in both directions a delay -omega*tau is the same column as a
        # direction offset h = -2|omega|tau: it is tried, and the engine reports the two as
        # confounded (two speeds separate them)
        del vary
        return None
    return "the speed is the same throughout every run: -omega*tau is a run constant"


def _delay_plausible(ctx: Context, p: dict) -> str | None:
    tau = abs(float(np.asarray(p["delay_s"])))
    w = float(np.max(np.abs(np.asarray(ctx.rows["omega"])))) if ctx.rows["omega"].size else 0.0
    if tau * w > ctx.settings.delay_angle_max_rad:
        return f"a lag of {tau:.3g} s is {tau * w:.3g} rad at {w:.3g} rad/s: not a reading delay"
    return None


def _scale_fn(p: dict, x: dict) -> Array:
    # about each run's mid angle (the run constants take the rest): the term's own size is
    # then the ramp's, not s times the angle's distance from zero
    th = x["theta"] - x["run_onehot"] @ p["center_rad"]
    return scale_error_rad(th, p["scale"])[:, None]


def _scale_start(ctx: Context, residual: np.ndarray, findings: list) -> list[dict]:
    th = np.asarray(ctx.rows["theta"], dtype=np.float64)
    onehot = np.asarray(ctx.rows["run_onehot"], dtype=np.float64)
    n = np.maximum(onehot.sum(0), 1.0)
    return [{"center_rad": (onehot.T @ th) / n, "scale": np.asarray(0.0)}]


def _scale_probes(ctx: Context) -> list[Probe]:
    """A scale error of 1 (sensor turns per reference turn - 1) about each run's mid angle
    (the bound: the smallest ``|s|``)."""
    (start,) = _scale_start(ctx, np.zeros(0), [])
    return [Probe({**start, "scale": np.asarray(1.0)}, "scale", "1", _sensor_name(ctx))]


def _scale_plausible(ctx: Context, p: dict) -> str | None:
    s = abs(float(np.asarray(p["scale"])))
    if s > ctx.settings.scale_error_max:
        return f"a scale error of {s:.3g} means the declared ratio is wrong, not a sensor error"
    return None


def _interp_fn(p: dict, x: dict) -> Array:
    # the sensor interpolates its own signals: their phase is P times the angle the sensor
    # sees, theta_ref plus its own error function (held: a smooth fit of the reading, so
    # neither its noise nor its quantization enters the phase), not P times the reference
    # angle: at P = 2048 an error of 1 mrad is 2 rad of phase
    P = x["signal_periods"]
    psi = P * _sensor_angle(p, x)
    c = p["coef"]
    if c.ndim == 2:  # (4, R): one set per run (a re-zeroed reading moves the signal phase)
        c = (x["run_onehot"] @ c.T).T
    e = (
        c[0] * jnp.cos(psi)
        + c[1] * jnp.sin(psi)
        + c[2] * jnp.cos(2.0 * psi)
        + c[3] * jnp.sin(2.0 * psi)
    ) / jnp.maximum(P, 1.0)
    return e[:, None]


INTERP_SMOOTH_ORDERS = 12
"""Fourier orders of the sensor's own error function in its angle (held, for the phase)."""


def _sensor_angle(p: dict, x: dict, xp=jnp) -> Array:
    """The angle the sensor sees, ``theta + e(theta)`` (the held smooth fit; its zero per
    run is the reference's: a re-zeroed reading's offset is not a signal phase). ``xp``:
    ``jnp`` in the term, ``np`` on concrete rows (no XLA program per record length)."""
    th = x["theta"]
    return th + _smooth_basis(th, INTERP_SMOOTH_ORDERS, xp) @ p["smooth_rad"]


def _sensor_angle_fit(ctx: Context) -> dict:
    """Least squares of ``reading - theta`` on a constant per run and orders
    ``1..INTERP_SMOOTH_ORDERS`` of ``theta`` over the kept rows: ``smooth_rad``."""
    rows = ctx.rows
    th = np.asarray(rows["theta"], dtype=np.float64)
    oh = np.asarray(rows["run_onehot"], dtype=np.float64)
    d = np.asarray(rows["reading"], dtype=np.float64)[:, 0] - th
    F = _smooth_basis(th, INTERP_SMOOTH_ORDERS, np)
    coef, *_ = np.linalg.lstsq(np.concatenate([oh, F], 1), d, rcond=None)
    R = oh.shape[1]
    return {"smooth_rad": coef[R:]}


def _interp_applies(ctx: Context) -> str | None:
    why = _need_ref(ctx)
    if why:
        return why
    P = int(ctx.signal_periods)
    if P < 1:
        return "signal_periods_per_rev (or grating_lines) unknown"
    th = np.asarray(ctx.rows["theta"])
    turns = float(np.sum(ctx.revolutions))
    if turns <= 0 or th.size < 8:
        return "the record does not turn"
    # each sample's signal phase is known (P times the angle the sensor sees), so orders P
    # and 2P beyond the sampling's Nyquist order are no obstacle (they alias in time, not in
    # phase); what is needed is that the sampled phases cover the signal period
    x = {"theta": np.asarray(th, dtype=np.float64)}
    psi = P * _sensor_angle(_sensor_angle_fit(ctx), x, np)
    X = np.stack([np.cos(psi), np.sin(psi), np.cos(2 * psi), np.sin(2 * psi)], 1)
    lam = float(np.linalg.eigvalsh(X.T @ X / psi.size)[0])
    spread = ctx.settings.interp_spread_min
    if lam < spread:
        return (
            f"the sampled signal phases sit on a few points of the period (smallest "
            f"eigenvalue {lam:.3f} of the harmonics' mean square, needs {spread})"
        )
    return None


def _interp_probes(ctx: Context) -> list[Probe]:
    """A signal offset ``offset_a`` of 1 (an error ``cos(psi) / P`` rad at order P), the
    same in every run, at the angle the sensor sees (held, as the fit holds it)."""
    c = np.zeros((4, ctx.n_runs)) if ctx.n_runs > 1 else np.zeros(4)
    c[0] = 1.0
    vals = {**_sensor_angle_fit(ctx), "coef": c}
    at = f"order {int(ctx.signal_periods)} (P)"
    return [Probe(vals, "offset_a", "1", _sensor_name(ctx), at=at)]


def _interp_start(ctx: Context, residual: np.ndarray, findings: list) -> list[dict]:
    """The angle the sensor sees, held (:func:`_sensor_angle_fit`): the signal phase is then
    ``P`` times the reference angle plus the sensor's own error function."""
    return [_sensor_angle_fit(ctx)]


def _interp_plausible(ctx: Context, p: dict) -> str | None:
    c = np.abs(np.asarray(p["coef"], dtype=np.float64))
    if np.max(c) > ctx.settings.signal_error_max_rad:
        return (
            f"a harmonic of {np.max(c):.3g} rad of signal phase is beyond what an arctangent "
            "interpolation of readable signals gives"
        )
    return None


def _interp_derived(ctx: Context, p: dict, se: dict) -> dict:
    c = np.asarray(p["coef"], dtype=np.float64)
    s = np.asarray(se.get("coef", np.full(c.shape, np.nan)), dtype=np.float64)
    if c.ndim == 2:  # one set per run: the signal errors at run 0's zero of the reference
        c, s = c[:, 0], s.reshape(c.shape)[:, 0]
    v = interpolation_params_from_harmonics(c)
    err = {"offset_a": s[0], "offset_b": s[1], "amplitude_ratio": 2 * s[3]}
    err["phase_error_rad"] = 2 * s[2]
    units = REFERENCE_PARAM_UNITS["interpolation_error"]
    out = {k: {"value": v[k], "se": float(err[k]), "unit": units[k]} for k in v}
    P = int(ctx.signal_periods)
    out["orders"] = {"value": [P, 2 * P], "se": None, "unit": "1"}
    big = float(np.max(np.abs(c)))
    if big > ctx.settings.signal_first_order_max_rad:
        out["first_order_note"] = {
            "value": big,
            "se": None,
            "unit": "rad",
            "note": f"a harmonic of {big:.3g} rad of signal phase: beyond first order, the "
            "offsets, amplitude ratio and phase error are approximate (the fitted harmonics "
            "at orders P and 2P are not)",
        }
    return out


QUANT_SMOOTH_ORDERS = 48
"""Fourier orders of the smooth (unquantized) reading the quantization term rebuilds."""
QUANT_POLY_DEGREE = 8
"""Degree of the per-run Legendre polynomials in the angle (part of a turn, drifts)."""


def _smooth_basis(theta: Array, n_orders: int, xp=jnp) -> Array:
    """``cos(m theta)`` then ``sin(m theta)``, ``m = 1 … n_orders`` (``theta`` in rad), shape
    ``(n, 2 n_orders)``; ``xp``: ``jnp`` in a term, ``np`` on concrete rows."""
    m = xp.arange(1, n_orders + 1, dtype=xp.float64)
    arg = theta[:, None] * m[None, :]
    return xp.concatenate([xp.cos(arg), xp.sin(arg)], axis=1)


def _legendre(u: Array, degree: int, xp=jnp) -> Array:
    """``P_0 … P_degree`` at ``u`` (Bonnet's recursion), shape ``(n, degree + 1)``."""
    out = [xp.ones_like(u), u]
    for k in range(1, degree):
        out.append(((2 * k + 1) * u * out[k] - k * out[k - 1]) / (k + 1))
    return xp.stack(out[: degree + 1], axis=1)


def _poly_basis(theta: Array, onehot: Array, mid: Array, half: Array, xp=jnp) -> Array:
    """Per-run Legendre polynomials of the angle (rad) scaled to ``[-1, 1]`` over the run,
    shape ``(n, R * (degree + 1))`` (run-major); ``xp`` as :func:`_smooth_basis`."""
    u = (theta - onehot @ mid) / (onehot @ half)
    L = _legendre(u, QUANT_POLY_DEGREE, xp)
    return (onehot[:, :, None] * L[:, None, :]).reshape(theta.shape[0], -1)


_POLY = tuple(f"poly{k}_rad" for k in range(QUANT_POLY_DEGREE + 1))


def _quant_smooth(p: dict, x: dict) -> Array:
    th = x["theta"]
    oh = x["run_onehot"]
    poly = jnp.stack([p[k] for k in _POLY], axis=1)  # (R, degree + 1)
    return (
        th
        + _smooth_basis(th, QUANT_SMOOTH_ORDERS) @ p["smooth_rad"]
        + _poly_basis(th, oh, p["run_mid_rad"], p["run_half_rad"]) @ poly.ravel()
        + p["lag_s"] * x["omega"]
        + p["way_rad"] * x["direction"]
    )


def _quant_fn(p: dict, x: dict) -> Array:
    off = x["run_onehot"] @ p["lattice_offset_rad"]
    e = quantization_rad(_quant_smooth(p, x), p["lsb_rad"], off, p["blur_rad"])
    return (p["amplitude"] * e)[:, None]


_quant_fn_jit = jax.jit(_quant_fn)
""":func:`_quant_fn` as one XLA program (the start evaluates it on whole records through
:func:`~encdesign.diagnose.engine._padded.eval_rows`: a compile per bucketed length, not one
per operation and record length)."""


def _quant_lattice(ctx: Context) -> Lattice:
    rows = ctx.rows
    run = np.argmax(np.asarray(rows["run_onehot"]), axis=1)
    return detect_lsb(np.asarray(rows["reading"])[:, 0], run, settings=ctx.settings)


def _quant_applies(ctx: Context) -> str | None:
    why = _need_ref(ctx)
    if why:
        return why
    lat = _quant_lattice(ctx)
    if lat.lsb_rad is None:
        return f"the readings lie on no value lattice ({lat.note})"
    return None


def smooth_reading(ctx: Context) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The unquantized reading (rad) rebuilt as a smooth least-squares fit of the reading
    itself: ``QUANT_SMOOTH_ORDERS`` Fourier orders of the angle, per-run Legendre
    polynomials of degree ``QUANT_POLY_DEGREE`` (part of a turn), and the reference velocity
    ``omega`` (rad/s) and direction sign (the reading lags by ``-omega tau`` and moves by
    ``h / 2`` with the direction: neither is a function of the angle where a run turns both
    ways or at two speeds, and without them the rebuilt reading, hence the staircase's
    phase, is off by ``omega tau`` in each direction: a fitted staircase amplitude of 1.42
    or 2 10^4 on training records 7558 and 7553 of ``test_vibration_doubt``); the
    staircase, about white, averages out. Returns
    ``(coefficients, run_mid_rad, run_half_rad, smooth_rad)``: the coefficients of the
    Fourier orders, the polynomials (run-major) and ``omega`` and the direction, last; the
    rebuilt reading per kept row."""
    rows = ctx.rows
    th = np.asarray(rows["theta"], dtype=np.float64)
    onehot = np.asarray(rows["run_onehot"], dtype=np.float64)
    reading = np.asarray(rows["reading"], dtype=np.float64)[:, 0]
    motion = np.stack(
        [np.asarray(rows[k], dtype=np.float64) for k in ("omega", "direction")], axis=1
    )
    n_runs = onehot.shape[1]
    lo, hi = np.zeros(n_runs), np.ones(n_runs)
    for r in range(n_runs):
        m = onehot[:, r] > 0.5
        if m.sum() > 1:
            lo[r], hi[r] = th[m].min(), th[m].max()
    mid, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), 1e-9)
    K = rebuild_orders(ctx)
    F = _smooth_basis(th, K, np)
    Pb = _poly_basis(th, onehot, mid, half, np)
    A = np.concatenate([F, Pb, motion], 1)
    c, *_ = np.linalg.lstsq(A, reading - th, rcond=None)
    # in the layout of QUANT_SMOOTH_ORDERS orders (cosines, then sines), the orders above K
    # zero
    pad = np.zeros(QUANT_SMOOTH_ORDERS - K)
    coef = np.concatenate([c[:K], pad, c[K : 2 * K], pad, c[2 * K :]])
    return coef, mid, half, th + A @ c


def rebuild_orders(ctx: Context) -> int:
    """The Fourier orders of the rebuilt reading (:func:`smooth_reading`): the base model's
    (``ctx.max_order``, chosen by the engine on held-out error), at most
    ``QUANT_SMOOTH_ORDERS`` (all of them before the base is built). A sampled staircase is
    not white: at a steady speed its harmonics fold to lines at fixed orders of each run,
    and orders beyond what the sensor's error function needs take them, moving the
    rebuilt reading (0.15 LSB RMS, against 0.03 with the base's 12 orders, on training
    record 7558 of ``test_vibration_doubt``, whose second staircase harmonic folds to order
    33 in its second run) and with it the staircase's phase."""
    K = int(ctx.max_order)
    return min(K, QUANT_SMOOTH_ORDERS) if K > 0 else QUANT_SMOOTH_ORDERS


def _rebuilt_reading(ctx: Context, lat: Lattice, q: float) -> dict[str, np.ndarray]:
    """The quantization term's parameters that hold the lattice and the rebuilt reading
    (:func:`smooth_reading`): ``lsb_rad`` (``q``, rad), the lattice's offset per run, the
    smooth orders' coefficients, each run's middle and half span, its polynomial
    coefficients; shared by the term's start and the staircase rival of
    ``interpolation_error``."""
    n_runs = int(np.asarray(ctx.rows["run_onehot"]).shape[1])
    coef, mid, half, _ = smooth_reading(ctx)
    nf = 2 * QUANT_SMOOTH_ORDERS
    poly = coef[nf:-2].reshape(n_runs, QUANT_POLY_DEGREE + 1)
    return {
        "lsb_rad": np.asarray(q),
        "lattice_offset_rad": np.array([lat.offset_rad.get(r, 0.0) for r in range(n_runs)]),
        "smooth_rad": coef[:nf],
        "run_mid_rad": mid,
        "run_half_rad": half,
        **{k: poly[:, i] for i, k in enumerate(_POLY)},
        "lag_s": np.asarray(coef[-2]),
        "way_rad": np.asarray(coef[-1]),
    }


def _quant_start(ctx: Context, residual: np.ndarray, findings: list) -> list[dict]:
    """Rebuild the unquantized reading as a smooth least-squares fit of the reading itself
    (``QUANT_SMOOTH_ORDERS`` Fourier orders of the angle and per-run Legendre polynomials of
    degree ``QUANT_POLY_DEGREE``, for part of a turn; the staircase, about white, averages
    out), take the lattice of the readings, and pick the blur (noise ahead of the quantizer)
    on a grid ``0 … q`` (:data:`BLUR_GRID`) by least squares of the engine's residual less
    the staircase at amplitude 1: a free amplitude lets a staircase at a wrong phase or blur
    shrink to a column of nothing scaled up (an amplitude of 2 10^4 on training record
    7553)."""
    rows = ctx.rows
    lat = _quant_lattice(ctx)
    q = float(lat.lsb_rad)
    reading = np.asarray(rows["reading"], dtype=np.float64)[:, 0]
    p0 = {
        **_rebuilt_reading(ctx, lat, q),
        "blur_rad": np.asarray(0.0),
        "amplitude": np.asarray(1.0),
    }
    x = {k: np.asarray(rows[k]) for k in ("theta", "run_onehot", "omega", "direction")}
    r = np.asarray(residual, dtype=np.float64).reshape(reading.size, -1)[:, 0]
    best = (np.inf, 0.0)
    step = BLUR_GRID[1] - BLUR_GRID[0]
    for grid in (BLUR_GRID, None):
        if grid is None:  # the finer grid about the coarse grid's best
            grid = np.clip(best[1] / q + step * (BLUR_GRID - 0.5), 0.0, None)
        for b in grid * q:
            col = eval_rows(_quant_fn_jit, {**p0, "blur_rad": np.asarray(b)}, x)[:, 0]
            sse = float(np.sum((r - col) ** 2))
            if sse < best[0]:
                best = (sse, float(b))
    p0["blur_rad"] = np.asarray(best[1])
    return [p0]


BLUR_GRID = np.linspace(0.0, 1.0, 21)
"""Blurs (in LSB) :func:`_quant_start` tries, the staircase at its own size (amplitude 1),
then the same number of blurs one grid step wide about the best. The fundamental's size
goes as ``exp(-2 pi^2 b^2)``: a blur 0.05 LSB off at 0.1-0.15 LSB is 10 % of it, and the
fitted amplitude made up the rest (1.13 with the coarse grid alone on training record
7558, 1.17 on 7553)."""


def _quant_plausible(ctx: Context, p: dict) -> str | None:
    a = float(np.asarray(p["amplitude"]))
    tol = ctx.settings.quant_amplitude_tol
    if not 1.0 - tol <= a <= 1.0 + tol:
        return (
            f"the staircase of the detected step explains the residual with an amplitude of "
            f"{a:.2f}, not 1: the residual is not the quantization"
        )
    return None


def _quant_derived(ctx: Context, p: dict, se: dict) -> dict:
    q = float(np.asarray(p["lsb_rad"]))
    cpt = 2 * np.pi / q
    return {
        "lsb_rad": {"value": q, "se": 0.0, "unit": "rad"},
        "counts_per_turn": {"value": cpt, "se": 0.0, "unit": "1"},
        "bits_per_turn": {"value": float(np.log2(cpt)), "se": 0.0, "unit": "bit"},
        "floor_rms_rad": {"value": q / np.sqrt(12.0), "se": 0.0, "unit": "rad"},
    }


STAIRCASE_BLURS = (0.0, 0.25, 0.5)
"""Blurs (in LSB) of the staircase columns :func:`_staircase_rivals` fits, each with an
amplitude of its own: the staircase's harmonics at their own phases, in the proportions of
noise ahead of the quantizer from none to half an LSB."""


def _staircase_rivals(ctx: Context) -> list[Candidate]:
    """``Candidate.rivals`` of ``interpolation_error``: where the readings lie on a value
    lattice of step ``q``, the quantization staircase of that lattice (the reading rebuilt as
    :func:`smooth_reading`, the lattice's offset per run), as a term with a free amplitude per
    blur of :data:`STAIRCASE_BLURS`; none without a lattice.

    The staircase is a sawtooth of period ``q`` in the reading: lines at shaft orders
    ``k 2 pi / q``. A sensor with ``2 pi / q`` counts per turn equal to ``L`` or ``2 L`` (a
    resolver of ``L`` = 2048 signal periods read at 4096 counts per turn) puts its staircase's
    fundamental at ``interpolation_error``'s own order, and the harmonic pair fits it with a
    free phase and size, before ``quantization``, whose amplitude is held near 1, can: the
    pair was named and quantization refused (issue 44, seed 7558). A signal error of its own
    has its own phase and keeps its gain beside the staircase."""
    lat = None if _need_ref(ctx) else _quant_lattice(ctx)
    if lat is None or lat.lsb_rad is None:
        return []
    q = float(lat.lsb_rad)
    held = {k: jnp.asarray(v) for k, v in _rebuilt_reading(ctx, lat, q).items()}
    blurs = jnp.asarray(STAIRCASE_BLURS, dtype=jnp.float64) * q

    def fn(p: dict, x: dict) -> Array:
        smooth = _quant_smooth(held, x)
        off = x["run_onehot"] @ held["lattice_offset_rad"]
        cols = jnp.stack([quantization_rad(smooth, q, off, b) for b in blurs], axis=1)
        return (cols @ p["amplitude"])[:, None]

    return [
        Candidate(
            STAIRCASE_RIVAL,
            fn,
            (Param("amplitude", "1", (len(STAIRCASE_BLURS),), scale=1.0),),
            explanation=(
                f"the staircase of the readings' value lattice, {2 * np.pi / q:.6g} counts "
                "per turn, at its own phases"
            ),
            plausible=_staircase_plausible,
        )
    ]


STAIRCASE_RIVAL = "the quantization staircase"
"""The name of :func:`_staircase_rivals`'s term (in the refusals it makes)."""


def staircase_fundamental(amplitude: np.ndarray) -> float:
    """The fundamental of the staircase :func:`_staircase_rivals` fits with ``amplitude``
    (one per blur of :data:`STAIRCASE_BLURS`), in units of a sharp staircase's ``q / pi``:
    ``sum_j a_j g_1(b_j)`` with ``g_1(b) = exp(-2 pi^2 (b^2 + b_min^2))``
    (:func:`~encdesign.physics._sensor_effects.blurred_sawtooth`, ``b_min = 1 / 64``)."""
    b2 = np.square(np.asarray(STAIRCASE_BLURS)) + (1.0 / 64) ** 2
    return float(np.sum(np.asarray(amplitude, float) * np.exp(-2 * np.pi**2 * b2)))


def _staircase_plausible(ctx: Context, p: dict) -> str | None:
    """The staircase rival's fundamental is at most a sharp staircase's ``q / pi``, within
    ``quant_amplitude_tol`` (noise ahead of the quantizer only lowers it): where it takes more
    at that order (beside the model so far, which may hold the quantization term itself: a
    bound that errs on the rival's side), what it shares with ``interpolation_error`` is
    beyond what the LSB makes, and it is no rival (:func:`._spill.rival_rule`)."""
    f = staircase_fundamental(np.asarray(p["amplitude"]))
    top = 1.0 + ctx.settings.quant_amplitude_tol
    if abs(f) > top:
        return f"a staircase fundamental of {f:.2f} q / pi, beyond the LSB's (at most {top})"
    return None


def _candidates() -> tuple:
    hyst = Candidate(
        name="direction_hysteresis",
        fn=_hyst_fn,
        params=(
            Param(
                "hysteresis_rad",
                "rad",
                scale=1e-3,
                description="reading offset forward minus backward",
            ),
        ),
        signature=("direction",),
        explanation=(
            "the error profile moves by a constant when the direction of rotation reverses "
            "(backlash in the coupling or drive, magnetic hysteresis of the sensor); at one "
            "speed it is also what a reading delay tau = -h / (2|omega|) gives "
            "(equivalent_delay_s)"
        ),
        applies=_hyst_applies,
        plausible=_hyst_plausible,
        derived=_hyst_derived,
        probes=_hyst_probes,
    )
    delay = Candidate(
        name="reading_delay",
        fn=_delay_fn,
        params=(
            Param("delay_s", "s", scale=1e-4, description="lag of the sensor behind the reference"),
        ),
        signature=("speed", "direction"),
        explanation=(
            "a time lag between sensor and reference (filtering, latency): an error "
            "-omega*tau that grows with speed and flips with direction; at one speed in both "
            "directions it equals a direction offset h = -2|omega|tau"
        ),
        applies=_delay_applies,
        plausible=_delay_plausible,
        probes=_delay_probes,
    )
    scale = Candidate(
        name="scale_error",
        fn=_scale_fn,
        params=(
            Param("scale", "1", scale=1e-4, description="sensor turns per reference turn - 1"),
            Param(
                "center_rad",
                "rad",
                shape="runs",
                linear=False,
                fit=False,
                description="mid angle of each run (held)",
            ),
        ),
        signature=("angle_trend",),
        explanation=(
            "the sensor advances (1 + s) turns per reference turn (gear ratio, counts per "
            "turn, a stepper's steps): an error growing linearly with the reference angle"
        ),
        applies=_need_ref,
        start=_scale_start,
        plausible=_scale_plausible,
        probes=_scale_probes,
    )
    interp = Candidate(
        name="interpolation_error",
        fn=_interp_fn,
        params=(
            Param(
                "coef",
                "rad",
                shape=(4,),
                scale=1e-3,
                description="(c1, s1, c2, s2) of the signal phase at orders P and 2P",
            ),
            Param(
                "smooth_rad",
                "rad",
                shape=(2 * INTERP_SMOOTH_ORDERS,),
                linear=False,
                fit=False,
                description="the sensor's own error function, for its signal phase (held)",
            ),
        ),
        signature=("orders", "spectrum", "line_phase"),
        explanation=(
            "offsets, amplitude mismatch and phase error of the sensor's own sin/cos signals "
            "(signal_periods_per_rev periods per turn) give orders P and 2P of the shaft"
        ),
        applies=_interp_applies,
        start=_interp_start,
        plausible=_interp_plausible,
        probes=_interp_probes,
        derived=_interp_derived,
        rivals=_staircase_rivals,
    )
    quant = Candidate(
        name="quantization",
        fn=_quant_fn,
        params=(
            # held at their start values (found from the data); they enter nonlinearly
            Param(
                "lsb_rad",
                "rad",
                linear=False,
                fit=False,
                description="step of the value lattice (LSB)",
            ),
            Param("lattice_offset_rad", "rad", shape="runs", linear=False, fit=False),
            Param("smooth_rad", "rad", shape=(2 * QUANT_SMOOTH_ORDERS,), linear=False, fit=False),
            *(
                Param(k, "rad", shape="runs", linear=False, fit=False, description="smooth")
                for k in _POLY
            ),
            Param("run_mid_rad", "rad", shape="runs", linear=False, fit=False),
            Param("run_half_rad", "rad", shape="runs", linear=False, fit=False),
            Param("lag_s", "s", linear=False, fit=False, description="smooth: omega's"),
            Param("way_rad", "rad", linear=False, fit=False, description="smooth: direction's"),
            Param(
                "blur_rad",
                "rad",
                linear=False,
                fit=False,
                description="noise ahead of the quantizer",
            ),
            Param("amplitude", "1", scale=1.0, description="1 when the staircase explains it"),
        ),
        signature=("floor", "spectrum", "time", "orders"),
        explanation=(
            "a reading of finite resolution: a staircase of one LSB on the value lattice of "
            "the readings, a uniform error of +-LSB/2 (RMS LSB/sqrt(12)), blurred by the "
            "noise ahead of the quantizer"
        ),
        applies=_quant_applies,
        start=_quant_start,
        plausible=_quant_plausible,
        derived=_quant_derived,
    )
    return (hyst, delay, scale, interp, quant)


CANDIDATES = _candidates()
"""The sensor-against-reference candidates, for the engine (multihead kind, one head)."""


@functools.lru_cache(maxsize=8)
def interpolation_candidate(n_runs: int) -> Candidate:
    """``interpolation_error`` with one coefficient set per run (``coef`` of shape
    ``(4, R)``): a reading re-zeroed by any amount between runs moves its signal phase by
    ``P`` times that amount, so the harmonics keep their sizes but not their phases; one run:
    the catalog's candidate."""
    base = next(c for c in CANDIDATES if c.name == "interpolation_error")
    if n_runs <= 1:
        return base
    q, *rest = base.params
    per_run = dataclasses.replace(q, shape=(4, int(n_runs)))
    return dataclasses.replace(base, params=(per_run, *rest))
