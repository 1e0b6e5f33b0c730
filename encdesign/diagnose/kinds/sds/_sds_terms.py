"""The SDS kind's candidate terms (axis tilt, drift, bearing wobble, beam tilt, coil mismatch,
sensor delay step) and their starts and derived values."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from ...engine._candidates import Candidate, Context, Param, Probe
from ...engine._padded import eval_rows
from ._sds_common_rules import _beam_plausible, _drift_plausible
from ._sds_data import SDSKindData, lattice_floor
from ._sds_drift import drift_derived, drift_fn, drift_probes, drift_start
from ._sds_noise import (
    BEAM_ORDERS,
    EXPLANATIONS,
    _coil_plausible,
    _delay_gauge,
    _delay_plausible,
    _saturating_columns,
    base_orders,
    coil_orders,
    noise_info,
)
from ._sds_transient import _no_transient, transient_cells

# ----------------------------------------------------------------------------- terms


def _to_channels(vp, x):
    """Pair values ``(n, K, F, M)`` -> channels ``(n, K*M)``: mean over the fixed sensors,
    Helmert over the revolutions, projection on the moving-sensor differences without
    ``phi_ref``."""
    v = jnp.mean(vp, axis=2)  # (n, K, M)
    out = jnp.einsum("kr,nrm->nkm", x["helmert"], v)
    m0 = out[:, :1, :]
    m0 = m0 - x["proj"] * jnp.mean(m0, axis=2, keepdims=True)
    out = jnp.concatenate([m0, out[:, 1:, :]], axis=1)
    return out.reshape(out.shape[0], -1)


def _xk(x):
    """``x = φ_r + ψ_m`` broadcast to ``(n, K, F, M)``; ψ_f likewise; shape helpers."""
    n, K, F = x["tf_c"].shape
    M = x["psi_m"].shape[0]
    xm = (x["phi"][:, None] + x["psi_m"][None, :])[:, None, None, :]
    xm = jnp.broadcast_to(xm, (n, K, F, M))
    pf = jnp.broadcast_to(x["psi_f"][None, None, :, None], (n, K, F, M))
    return xm, pf, (n, K, F, M)


def _fourier_terms(orders, a, b, ang):
    o = jnp.asarray(orders, dtype=float)
    arg = ang[..., None] * o
    return jnp.sum(jnp.cos(arg) * a + jnp.sin(arg) * b, axis=-1)


def _tilt(psi, beta, chi):
    a = psi - chi
    d = jnp.arctan2(jnp.sin(a), jnp.cos(a) * jnp.cos(beta)) - a
    return jnp.mod(d + jnp.pi, 2 * jnp.pi) - jnp.pi


@functools.lru_cache(maxsize=32)
def _const_term(M: int) -> Candidate:
    def fn(p, x):
        xm, _, shp = _xk(x)
        vp = jnp.broadcast_to(p["const_rad"][None, None, None, :], shp)
        return _to_channels(vp, x)

    return Candidate(
        "pair_constants",
        fn,
        (Param("const_rad", "rad", (M,), description="pair constant per moving sensor"),),
        kinds=("sds",),
        explanation="base model: pair constants (azimuth errors, mean mark errors)",
    )


@functools.lru_cache(maxsize=32)
def _ripple_term(orders: tuple[int, ...], name: str = "design_ripple", expl: str = "") -> Candidate:
    k = len(orders)

    def fn(p, x):
        xm, _, _ = _xk(x)
        return _to_channels(_fourier_terms(orders, p["cos_rad"], p["sin_rad"], xm), x)

    return Candidate(
        name,
        fn,
        (Param("cos_rad", "rad", (k,)), Param("sin_rad", "rad", (k,))),
        signature=(f"sds_{name}",) if name != "design_ripple" else (),
        kinds=("sds",),
        explanation=expl
        or "base model: the design's speed ripple times disk B's mark errors (orders in x)",
        derived=_ripple_derived(orders),
    )


def _ripple_derived(orders):
    def derived(ctx, v, se):
        amp = np.hypot(v["cos_rad"], v["sin_rad"])
        sa = np.hypot(se["cos_rad"], se["sin_rad"]) / math.sqrt(2)
        out = {
            f"order_{o}_amplitude_rad": {
                "value": float(amp[i]),
                "se": float(sa[i]) if np.isfinite(sa[i]) else None,
                "unit": "rad",
            }
            for i, o in enumerate(orders)
        }
        sp = getattr(ctx.data, "speed", None)
        if sp is not None:
            # the shaft speed ripple itself, from the moving sensors' edge intervals
            for o in orders:
                if o in sp["orders"]:
                    j = int(np.flatnonzero(sp["orders"] == o)[0])
                    out[f"speed_ripple_relative_order_{o}"] = {
                        "value": float(sp["amplitude"][j]),
                        "se": float(sp["stderr"][j]),
                        "unit": "1",
                    }
        return out

    return derived


def _coil_derived(orders, pp):
    """The ripple's derived values plus how many coil orders the budget left out."""
    base = _ripple_derived(orders)

    def derived(ctx, v, se):
        left = pp - 1 - len(orders)
        return base(ctx, v, se) | {
            "coil_orders_left_out": {"value": int(left), "se": None, "unit": "1"}
        }

    return derived


def _axis_tilt_fn(p, x):
    xm, pf, _ = _xk(x)
    beta, chi = p["tilt_rad"], p["azimuth_rad"]
    return _to_channels(_tilt(xm, beta, chi) - _tilt(pf, beta, chi), x)


def _drift_fn(p, x):
    return drift_fn(p, x, _to_channels, _xk)


def _wobble_fn(p, x):
    xm, pf, shp = _xk(x)
    rho, a, b = p["frequency_ratio"], p["sin_rad"], p["cos_rad"]
    att = jnp.sinc(rho)
    t0 = x["t_mean"]
    tm = jnp.broadcast_to(x["tm_c"][:, :, None, :], shp) + t0
    tf = jnp.broadcast_to(x["tf_c"][:, :, :, None], shp) + t0

    def w(t, psi):
        arg = rho * x["omega"] * t - psi
        return att * (a * jnp.sin(arg) + b * jnp.cos(arg))

    # from run first_run on (held, no derivative): a bearing that began to wobble during
    # the record (0: every run)
    on = (x["run_index"] >= p.get("first_run", 0.0) - 0.5).astype(float)
    return _to_channels((w(tm, xm) - w(tf, pf)) * on[:, None, None, None], x)


def _wobble_onsets(R: int) -> list[int]:
    """Onsets tried for the bearing wobble: every run, or from a quarter, half or three
    quarters of the runs on (Bonferroni over them in its matched view)."""
    return sorted({0, *(int(round(R * f)) for f in (0.25, 0.5, 0.75))} - {R})


def _wobble_plausible(ctx: Context, params: dict) -> str | None:
    """A wobble no larger than the quantization floor of a stamp lattice coarser than the
    declared clock (the lattice ``timing_quantization`` is named from) is refused: the
    stamps' rounding on that lattice beats with the mark spacing (a clock not locked to the
    motor), a sawtooth whose part left in each revolution's reading turns by a fraction of a
    cycle from one revolution to the next, as a wobble's does, at up to about the floor
    (seed 001 eq. 23: what the rounding adds to a pair reading); the record cannot tell such
    a wobble from the rounding (training seed 6677, record 18: a 20x clock read as
    ``bearing_wobble`` of 0.7 x the floor). The amplitude compared is the one the readings
    see (``sinc``-attenuated over the window), rad."""
    kd = ctx.data
    if not isinstance(kd, SDSKindData):
        return None
    ratio, floor = lattice_floor(kd)
    if ratio is None or floor is None or not ratio > ctx.settings.sds_lattice_coarser:
        return None
    rho = float(np.asarray(params["frequency_ratio"]))
    seen = abs(float(np.sinc(rho))) * math.hypot(
        float(np.asarray(params["sin_rad"])), float(np.asarray(params["cos_rad"]))
    )
    if seen <= floor:
        return (
            f"its amplitude ({seen:.3g} rad in the readings) is within the quantization "
            f"floor ({floor:.3g} rad) of the stamps' lattice, {ratio:.3g} x the declared "
            "clock: the rounding on that lattice beats with the mark spacing as a wobble "
            "does (confounded with timing_quantization)"
        )
    return None


def _beam_fn(p, x):
    xm, _, shp = _xk(x)
    ph = jnp.broadcast_to(x["phi"][:, None, None, None], shp)
    return _to_channels(_fourier_terms(BEAM_ORDERS, p["cos_rad"], p["sin_rad"], ph), x)


def _delay_fn(p, x):
    xm, _, shp = _xk(x)
    on = (x["run_index"] >= p["first_run"] - 0.5).astype(float)  # held: no derivative
    # without phi_ref the delays are known up to a common value (the per-run offset takes
    # it): they are measured against the held reference sensor, whose column is then exactly
    # zero and left out by rule, not by which of M tied columns rounding puts last in the
    # pivoted Cholesky (that choice moved with the last bit and named the wrong sensor)
    M = x["psi_m"].shape[0]
    ref = (jnp.arange(M) == jnp.round(p["ref_sensor"])).astype(float)
    tau = p["delay_s"] * (1.0 - x["proj"] * ref)
    # a later edge of the moving sensor reads a larger angle: +Omega tau
    d = x["omega"] * tau[None, :] * on[:, None]  # (n, M)
    return _to_channels(jnp.broadcast_to(d[:, None, None, :], shp), x)


@functools.lru_cache(maxsize=32)
def _one_run_offsets(M: int, cells: tuple[tuple[int, int], ...]) -> Candidate:
    """An offset of each ``(sensor, run index)`` of ``cells`` alone (that moving sensor's
    run mean in that run, rad): transients no catalog effect makes (a bracket knocked and
    restored, a glitch of one run), as a term of their own for :func:`_transient_rivals`."""
    sensor = jnp.asarray([c[0] for c in cells])
    run = jnp.asarray([c[1] for c in cells], dtype=float)

    def fn(p, x):
        _, _, shp = _xk(x)
        on = (jnp.abs(x["run_index"][:, None] - run[None, :]) < 0.5).astype(float)  # (n, k)
        at = (jnp.arange(M)[:, None] == sensor[None, :]).astype(float)  # (M, k)
        d = (on * p["offset_rad"][None, :]) @ at.T  # (n, M)
        return _to_channels(jnp.broadcast_to(d[:, None, None, :], shp), x)

    where = ", ".join(f"m{m} in run index {j}" for m, j in cells)
    return Candidate(
        f"the one-run offset{'s' if len(cells) > 1 else ''} of {where}",
        fn,
        (Param("offset_rad", "rad", (len(cells),)),),
        kinds=("sds",),
        explanation="the transients that dominate those sensors' base run means",
    )


def _transient_rivals(ctx: Context) -> list[Candidate]:
    """``Candidate.rivals`` of the smooth SDS candidates: the one-run offsets of the
    transients that dominate sensors' base run means (:func:`transient_cells`), if any. A
    coil ripple's orders in ``phi + psi_m`` (10 parameters at 12 runs) reach a single run
    mean and took 60 % of a 334 chi-square transient, far more than any other candidate:
    the transient's doubt was overruled and the coil named (issue 44, session 21)."""
    cells = tuple((m, j) for m, j, _, _ in transient_cells(ctx))
    return [_one_run_offsets(int(ctx.consts["psi_m"].size), cells)] if cells else []


def _tilt_start(ctx: Context, resid: np.ndarray, findings) -> list[dict]:
    M = ctx.consts["psi_m"].size
    x = ctx.rows["phi"][:, None] + ctx.consts["psi_m"][None, :]
    r = resid[:, :M] / ctx.noise[None, :M]
    X = np.stack([np.cos(2 * x).ravel(), np.sin(2 * x).ravel(), np.ones(x.size)], 1)
    (a, b, _), *_ = np.linalg.lstsq(X, (r * ctx.noise[None, :M]).ravel(), rcond=None)
    amp = max(math.hypot(a, b), 1e-15)
    chi = math.atan2(-a, b) / 2
    beta = 2 * math.sqrt(amp)
    return [
        {"tilt_rad": np.asarray(beta), "azimuth_rad": np.asarray(c)} for c in (chi, chi + np.pi / 2)
    ]


def _wobble_grid(ctx: Context) -> np.ndarray:
    t = ctx.rows["tmid_c"]
    span_rev = max(float(np.ptp(t)) * float(ctx.consts["omega"]) / (2 * np.pi), 1.0)
    step = min(1 / (8 * span_rev), 0.01)
    return np.arange(0.02, 0.98, step)


@jax.jit
def _wobble_cols_jit(rho, x):
    one, zero = jnp.ones(()), jnp.zeros(())
    a = _wobble_fn({"frequency_ratio": rho, "sin_rad": one, "cos_rad": zero}, x)
    b = _wobble_fn({"frequency_ratio": rho, "sin_rad": zero, "cos_rad": one}, x)
    return jnp.stack([a, b], -1)


@jax.jit
def _wobble_cols_grid(rho, x):
    """The two columns at every ratio of ``rho``, rows first: ``(n, G, C, 2)``."""
    return jnp.moveaxis(jax.vmap(_wobble_cols_jit, in_axes=(0, None))(rho, x), 1, 0)


def _wobble_start(ctx: Context, resid: np.ndarray, findings) -> list[dict]:
    rw = resid / ctx.noise[None, :]
    grid = _wobble_grid(ctx)
    consts = {k: v for k, v in ctx.consts.items() if isinstance(v, np.ndarray)}
    # (G, n, C, 2), in bucketed lengths of rows (not one program per record length)
    allc = np.moveaxis(eval_rows(_wobble_cols_grid, grid, ctx.rows, consts), 0, 1)
    run_index = np.asarray(ctx.rows["run_index"], float)
    onsets = _wobble_onsets(int(ctx.n_runs))
    # power of the two columns per (ratio, onset) from per-row normal equations summed over
    # the rows from the onset on (one pass, no QR per pair)
    c = allc / ctx.noise[None, None, :, None]
    a_row = np.einsum("gnci,gncj->gnij", c, c)
    g_row = np.einsum("gnci,nc->gni", c, rw)
    best = []
    for k in onsets:
        on = run_index >= k - 0.5
        A = a_row[:, on].sum(1)
        g = g_row[:, on].sum(1)
        A = A + 1e-12 * np.trace(A, axis1=1, axis2=2)[:, None, None] * np.eye(2)
        pw = np.einsum("gi,gi->g", g, np.linalg.solve(A, g[..., None])[..., 0])
        best += [(float(pw[i]), float(grid[i]), k) for i in range(grid.size)]
    best.sort(reverse=True)
    out, seen = [], []
    for _, rho, k in best:
        if all(abs(rho - s) > 0.03 for s in seen):
            seen.append(rho)
            out.append({"frequency_ratio": np.asarray(rho), "first_run": np.asarray(float(k))})
        if len(out) == 3:
            break
    if all(float(o["first_run"]) > 0 for o in out):
        # the stationary wobble at its best ratio stays among the starts
        _, rho, _ = max(b for b in best if b[2] == 0)
        out.append({"frequency_ratio": np.asarray(rho), "first_run": np.asarray(0.0)})
    return out


def _delay_start(ctx: Context, resid: np.ndarray, findings) -> list[dict]:
    firsts = []
    for f in findings:
        if f.view == "run_step" and f.detail.get("shape") == "step":
            firsts.append(int(f.detail["first_run_index"]))
    if not firsts:
        firsts = [_best_step(ctx, resid)[1]]
    ref = _delay_reference(ctx)
    out = []
    for k in dict.fromkeys(firsts):
        out.append({"first_run": np.asarray(float(k)), "ref_sensor": np.asarray(float(ref))})
    return out[:3]


def _delay_reference(ctx: Context) -> int:
    """The moving sensor the delays are measured against without phi_ref: the one whose
    base run means show the weakest step (``run_change_power``; the first such on a tie).
    A choice made from the data, not from rounding; the reported delays do not depend on
    it (:func:`_delay_gauge` takes the median out)."""
    ch = noise_info(ctx).run_change_power
    if not ch or (float(ctx.consts["proj"]) > 0 and len(ch) == 2):
        # two moving sensors without phi_ref: their projected steps are equal and opposite
        # (a tie only rounding would break): m0 by rule, and the sensor is unidentifiable
        return 0
    return int(np.argmin([float(c[0]) for c in ch]))


def _best_step(ctx: Context, resid: np.ndarray) -> tuple[float, int, int]:
    """(power, first run index, moving sensor) of the strongest step over runs."""
    M = ctx.consts["psi_m"].size
    r = resid[:, :M] / ctx.noise[None, :M]
    R = r.shape[0]
    best = (0.0, R // 2, 0)
    for k in range(1, R):
        s = (np.arange(R) >= k).astype(float)
        s -= s.mean()
        pw = (s @ r) ** 2 / (s @ s)
        m = int(np.argmax(pw))
        if pw[m] > best[0]:
            best = (float(pw[m]), k, m)
    return best


def _no_ref_beam(ctx: Context) -> str | None:
    if ctx.has_ref:
        return None
    return (
        "without phi_ref the per-run offset takes everything common to the moving "
        "sensors; beam_tilt_axial (common to them) is unidentifiable"
    )


def moving_opposed(psi_m) -> bool:
    """Whether every moving sensor sits at one azimuth modulo π (e.g. two opposed ones):
    the tilt's error ``T(ψ)`` is π-periodic, so it is then the same at every moving sensor
    (order 2 in ``φ + ψ_m`` with one phase at all of them)."""
    z = np.exp(2j * np.asarray(psi_m, float))
    return bool(np.max(np.abs(z - z[0])) < 1e-9)


def _no_ref_tilt(ctx: Context) -> str | None:
    if ctx.has_ref or not moving_opposed(ctx.consts["psi_m"]):
        return None
    return (
        "without phi_ref the per-run offset takes everything common to the moving sensors; "
        "with the moving sensors opposed (one azimuth modulo pi) the tilt's error, which "
        "repeats every half turn, is the same at each of them, so axis_tilt is "
        "unidentifiable (a phi_ref column or a moving sensor not opposed to the others "
        "makes it testable)"
    )


def _no_ref_drift(ctx: Context) -> str | None:
    if ctx.has_ref:
        return None
    return (
        "without phi_ref the per-run offset takes everything common to the moving sensors "
        "of a run; a drift in time moves them alike (their window times differ by less "
        "than a revolution: a constant per sensor), so thermal_drift is unidentifiable"
    )


def _tilt_derived(ctx, v, se):
    beta, sb = abs(float(v["tilt_rad"])), se["tilt_rad"]
    sb = float(sb) if np.isfinite(sb) else float("inf")
    out = {"tilt_squared_over_4_rad": {"value": beta**2 / 4, "se": None, "unit": "rad"}}
    if not beta > ctx.settings.resolved_se * sb:
        out["azimuth_identifiable"] = {
            "value": False,
            "se": None,
            "unit": "1",
        }
    return out


def _wobble_derived(ctx, v, se):
    amp = math.hypot(float(v["sin_rad"]), float(v["cos_rad"]))
    s = math.hypot(float(se["sin_rad"]), float(se["cos_rad"])) / math.sqrt(2)
    s = s if math.isfinite(s) else None
    r = float(ctx.consts["radius_m"])
    k = int(round(float(v.get("first_run", 0.0))))
    rid = int(ctx.data.table.run_ids[min(max(k, 0), int(ctx.n_runs) - 1)])
    return {
        "amplitude_rad": {"value": amp, "se": s, "unit": "rad"},
        "runout_m": {"value": amp * r, "se": None if s is None else s * r, "unit": "m"},
        "first_run": {"value": rid, "se": None, "unit": "1"},
    }


def _beam_derived(ctx, v, se):
    out = {}
    for i, n in enumerate(BEAM_ORDERS):
        a = math.hypot(float(v["cos_rad"][i]), float(v["sin_rad"][i]))
        s = math.hypot(float(se["cos_rad"][i]), float(se["sin_rad"][i])) / math.sqrt(2)
        out[f"order_{n}_amplitude_rad"] = {
            "value": a,
            "se": s if math.isfinite(s) else None,
            "unit": "rad",
        }
    return out


def _delay_derived(ctx, v, se):
    # the sensor is the one with the largest step in the median gauge (invariant under the
    # common value); its se is that of its delay against the reference sensor, or (when it
    # is the reference, held) that of another sensor against it: the same difference
    d = _delay_gauge(ctx, v["delay_s"])
    s = np.asarray(se["delay_s"], float)
    m = int(np.argmax(np.abs(d)))
    if not np.isfinite(s[m]):
        ok = np.isfinite(s)
        s = np.where(ok, s, np.min(s[ok]) if ok.any() else np.nan)
    rid = int(ctx.data.table.run_ids[int(v["first_run"])])
    out = {}
    if float(np.asarray(ctx.consts["proj"])) > 0 and d.size == 2:
        # +tau on m1 and -tau on m0 are the same record without phi_ref
        out["sensor_identifiable"] = {"value": False, "se": None, "unit": "1"}
    return out | {
        "sensor": {"value": f"m{m}", "se": None, "unit": "1"},
        "first_run": {"value": rid, "se": None, "unit": "1"},
        "delay_step_s": {
            "value": float(d[m]),
            "se": float(s[m]) if np.isfinite(s[m]) else None,
            "unit": "s",
        },
    }


def middle_half_span(R: int) -> tuple[int, int]:
    """``(lo, hi)``: the first runs of a step in the middle half of ``R`` runs, the span
    the sds delay step's detection bound is stated for (its ends included)."""
    return max(1, round(R / 4)), min(R - 1, round(3 * R / 4))


def _middle_half(R: int) -> list[int]:
    """First runs of a step in the middle half of ``R`` runs: its ends and its middle (the
    step's noncentrality is smallest at the ends: ``k (R - k) / R`` runs' worth)."""
    lo, hi = middle_half_span(R)
    return sorted({lo, R // 2, hi})


def _run_mean_seen(ctx: Context, pattern: np.ndarray, caught: bool):
    """``seen(lam)`` of an effect whose run means are ``pattern`` (R, M) (:class:`Probe`):
    the run-mean noise level is estimated from the ``nu`` values a saturated fit leaves
    (``_level_sigma``) and widened by ``c`` (``run_means_widening`` times
    ``run_means_common_factor``), so ``lam`` at the
    record's level is ``c^2 lam`` at the raw one; the share ``eta`` of the effect that fit
    leaves inflates the level by ``eta c^2 lam / nu`` (the tests then see ``lam / (1 + eta
    c^2 lam / nu)``) unless (``caught``: a step or an outlier) the estimate's own F test at
    ``1e-3 / n_tests`` (``F ~ 1 + eta c^2 lam``) finds and removes it first. ``None`` without
    a run-mean level."""
    lv = noise_info(ctx).levels
    nu = float(lv.get("run_means_dof", 0) or 0)
    if nu <= 0:
        return None
    c2 = (
        float(lv.get("run_means_widening", 1.0) or 1.0)
        * float(lv.get("run_means_common_factor", 1.0) or 1.0)
    ) ** 2
    R, M = pattern.shape
    proj = float(ctx.consts["proj"]) > 0
    e = pattern - pattern.mean(1, keepdims=True) if proj else pattern
    orders = base_orders(ctx.meta, ctx.consts, ctx.max_order)[0]
    X, _ = _saturating_columns(ctx.rows, ctx.consts, orders, ctx.settings.sds_saturate_fraction)
    e0 = e - e.mean(0, keepdims=True)  # what the base's pair constants leave
    ev = e.reshape(-1)
    left = ev - X @ np.linalg.lstsq(X, ev, rcond=None)[0]
    eta = float(left @ left) / max(float(np.sum(e0 * e0)), 1e-300)
    f_crit = float(stats.f.isf(1e-3 / max(M * (2 * R - 1), 1), 1, max(nu - 1, 1)))

    def seen(lam: float) -> float:
        if caught and eta * c2 * lam + 1.0 > f_crit:
            return lam
        return lam / (1.0 + eta * c2 * lam / nu)

    return seen


def _delay_probes(ctx: Context) -> list[Probe]:
    """Per moving sensor, a delay step of 1 s from a run in the middle half of the record
    (the bound: the worst of its ends and middle). Without phi_ref the delays are measured
    against another sensor (the common value is the per-run offset's)."""
    M = int(ctx.consts["psi_m"].size)
    R = int(ctx.n_runs)
    firsts = _middle_half(R)
    ids = ctx.data.table.run_ids if ctx.data is not None else np.arange(R)
    at = (
        f"a step from any run in the middle half of the record (runs {ids[firsts[0]]} to "
        f"{ids[firsts[-1]]}; the worst of them)"
    )
    out = []
    for m in range(M):
        probes = []
        for k in firsts:
            step = np.zeros((R, M))
            step[k:, m] = 1.0
            vals = {
                "delay_s": np.eye(M)[m],
                "first_run": np.asarray(float(k)),
                "ref_sensor": np.asarray(float((m + 1) % M)),
            }
            seen = _run_mean_seen(ctx, step, caught=True)
            probes.append(
                Probe(
                    vals, "delay_step_s", "s", where=f"m{m}", at=at, seen=seen,
                    label=f"from run {k}",
                )
            )  # fmt: skip
        out.append(dataclasses.replace(probes[0], worst_of=tuple(probes[1:])))
    return out


def _drift_probes(ctx: Context) -> list[Probe]:
    """A drift of the moving sensors' pair angles at 1 rad/s over the whole record
    (:func:`._sds_drift.drift_probes`)."""
    return drift_probes(ctx, _run_mean_seen)


def sds_candidates(ctx: Context) -> tuple[Candidate, ...]:
    """The SDS catalog candidates for this record."""
    M = ctx.consts["psi_m"].size
    pp = int(ctx.meta.get("encoder", {}).get("pole_pairs", 0) or 0)
    orders = base_orders(ctx.meta, ctx.consts, ctx.max_order)[0]
    opposed = moving_opposed(ctx.consts["psi_m"])
    coil = coil_orders(ctx.meta, ctx.consts)  # less those that vanish without phi_ref
    n = coil_order_count(ctx, pp, orders, len(coil))
    return _catalog(M, pp, coil[:n], opposed)


def coil_order_count(
    ctx: Context, pp: int, orders_base: Sequence[int], n_orders: int | None = None
) -> int:
    """How many of the coil orders ``1 … pp − 1`` ``coil_mismatch`` fits, the lowest first:
    as many as the parameter budget leaves (``max_param_fraction`` of the fitted values
    ``R × K × M``, less the base model's pair constants and design-ripple pairs), all of
    them when it leaves none (the rule then refuses it by name).

    The values count ``K``, the complete revolutions of the shortest run, so one run short
    by a revolution takes 20 % of the budget from every run (at 12 runs, 3 moving sensors:
    180 -> 144 values, 18 -> 14.4 parameters, with 7 in the base and 10 in five coil
    orders); a refusal of the whole effect then hid a coil ripple 15-50x the noise. A
    torque ripple of order ``n`` moves the speed by about ripple / (``n`` x inertia), so
    the low orders carry the most of it; the orders left out are reported
    (``coil_orders_left_out``) and stay in the order views. ``n_orders``: the coil orders
    there are to fit (``pp − 1`` when not given; fewer where some vanish on the record)."""
    n = max(pp - 1, 0) if n_orders is None else int(n_orders)
    R, C = int(ctx.n_runs), int(ctx.n_channels)
    M = int(ctx.consts["psi_m"].size)
    base = M + 2 * len(orders_base)
    budget = int((ctx.settings.max_param_fraction * R * C - base) // 2)
    return n if budget < 1 else min(n, budget)


@functools.lru_cache(maxsize=16)
def _catalog(
    M: int, pp: int, coil_orders: tuple[int, ...] = (), opposed: bool = False
) -> tuple[Candidate, ...]:
    """One set of candidate objects per layout (one compiled Jacobian each). Every
    candidate but the delay step is refused when one run's deviation on one sensor
    dominates the base residual (:func:`_transient`): a smooth pattern in the platform
    angle or in time would only take a part of that transient.

    With the moving sensors ``opposed`` (:func:`moving_opposed`) the tilt's order 2 in
    ``φ + ψ_m`` has one phase at every moving sensor: it shows in the view of what is
    common to them (``common_orders``), where beam tilt × axial runout shows too, so the
    tilt's signature holds that view and the two are tried (and reported as confounded
    where the record cannot tell them apart) rather than the tilt never being tried."""
    tilt_sig = ("sds_axis_tilt", "orders", *(("common_orders",) if opposed else ()))
    out = [
        Candidate(
            "axis_tilt",
            _axis_tilt_fn,
            (
                Param("tilt_rad", "rad", linear=False, scale=1e-3),
                Param("azimuth_rad", "rad", linear=False, scale=0.3),
            ),
            signature=tilt_sig,
            kinds=("sds",),
            explanation=EXPLANATIONS["axis_tilt"],
            applies=_no_ref_tilt,
            start=_tilt_start,
            plausible=_no_transient(),
            rivals=_transient_rivals,
            derived=_tilt_derived,
        ),
        Candidate(
            "thermal_drift",
            _drift_fn,
            (
                Param("drift_rate_rad_per_s", "rad/s"),
                Param(
                    "onset_from_start_s",
                    "s",
                    linear=False,
                    scale=0.1,
                    description="the drift's onset after the record's first window time "
                    "(<= 0, held at 0: from the start); on t: derived onset_s",
                ),
            ),  # fmt: skip
            signature=("sds_thermal_drift", "run_step"),
            kinds=("sds",),
            explanation=EXPLANATIONS["thermal_drift"],
            applies=_no_ref_drift,
            start=drift_start,
            derived=drift_derived,
            plausible=_no_transient(_drift_plausible),
            rivals=_transient_rivals,
            probes=_drift_probes,
        ),
        Candidate(
            "bearing_wobble",
            _wobble_fn,
            (
                Param("frequency_ratio", "1", linear=False, scale=0.01),
                Param("sin_rad", "rad"),
                Param("cos_rad", "rad"),
                Param("first_run", "1", linear=False, fit=False, first_run=True),
            ),
            signature=("sds_bearing_wobble",),
            kinds=("sds",),
            explanation=EXPLANATIONS["bearing_wobble"],
            start=_wobble_start,
            plausible=_no_transient(_wobble_plausible),
            rivals=_transient_rivals,
            derived=_wobble_derived,
        ),
        Candidate(
            "beam_tilt_axial",
            _beam_fn,
            (
                Param("cos_rad", "rad", (len(BEAM_ORDERS),)),
                Param("sin_rad", "rad", (len(BEAM_ORDERS),)),
            ),
            signature=("sds_beam_tilt_axial", "common_orders"),
            kinds=("sds",),
            explanation=EXPLANATIONS["beam_tilt_axial"],
            applies=_no_ref_beam,
            plausible=_no_transient(_beam_plausible),
            rivals=_transient_rivals,
            derived=_beam_derived,
        ),
        Candidate(
            "sensor_delay_step",
            _delay_fn,
            (
                Param("delay_s", "s", (M,), scale=1e-10),
                Param("first_run", "1", linear=False, fit=False, first_run=True),
                Param("ref_sensor", "1", linear=False, fit=False),
            ),
            signature=("run_step",),
            kinds=("sds",),
            explanation=EXPLANATIONS["sensor_delay_step"],
            start=_delay_start,
            plausible=_delay_plausible,
            # a step shared by the moving sensors, or confined to one run, is not one
            # sensor's persisting delay: a test of the fitted pattern, never overruled by
            # dominance (a ramp common to the sensors was named a delay step, session 21)
            doubt_overruled=False,
            derived=_delay_derived,
            probes=_delay_probes,
        ),
    ]
    if pp > 1 and coil_orders:
        orders = tuple(coil_orders)
        coil = _ripple_term(orders, "coil_mismatch", EXPLANATIONS["coil_mismatch"])
        out.append(
            dataclasses.replace(
                coil,
                plausible=_no_transient(_coil_plausible),
                rivals=_transient_rivals,
                signature=("sds_coil_mismatch", "run_step"),
                derived=_coil_derived(orders, pp),
            )
        )
    return tuple(out)
