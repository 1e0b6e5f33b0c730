"""The multihead kind's candidate terms (beam tilt, bearing wobble, vibration, thermal drift,
interpolation error, eccentricity shift) and its order-step view (``docs/effects.md``)."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from ....physics import _effects as fx
from ...engine._candidates import Candidate, Context, Param, Probe
from ...engine._located import change_chi2, interval_of, located_time
from ...engine._protocol import Prepared
from ...engine._views import Finding, chi2_threshold, log10_tail_p
from ...engine._views_time import order_change_fits_better
from ._aliases import catalog_orders_at
from ._beam_tilt import _bt_head_specific, bt_valjac
from ._order_step_bins import order_step_bins, order_step_width
from ._order_step_head import base_rows, head_step_gain
from ._order_step_zeros import _gain, shift_time_profile, zero_profile
from ._runout import RUNOUT_ORDERS, _bt_orders_significant, _bt_orders_supported
from ._vibration_doubt import (
    NO_DOUBT,
    arc_orders,
    covered_turns,
    left_out_orders,
    locked_margin,
    one_speed,
    order_res,
    run_durations,
    staircase_columns,
    staircase_margin,
)
from ._vibration_jac import bearing_wobble_valjac, eccentricity_shift_valjac, vibration_valjac

# ----------------------------------------------------------------------------- candidates


def _R(x):
    return x["radius_m"]


def _bt_make(project: bool) -> Candidate:
    """Axial beam tilt as a linear term: per head and runout order ``m`` (1-3) a cosine and
    a sine of ``m theta`` with the same phase origin at every head (``beta_k z(theta) / R``
    has no head-angle phase), less the base model's span at that order. The product form
    ``beta_k z_m`` is not used: with two heads and theta_ref (three without) its tangent
    space at an order holds the base model's own pattern, so it was always ill-conditioned
    against the base; projected, the fitted part is the identifiable, head-specific one."""

    def fn(p, x):
        alpha = x["alpha"]
        th = x["theta"]
        on = p["orders_on"]
        coefs = [(p[f"cos{j + 1}_rad"], p[f"sin{j + 1}_rad"]) for j in range(3)]
        zs = _bt_head_specific(alpha, coefs, project)
        e = 0.0
        for j, m in enumerate(RUNOUT_ORDERS):
            z = zs[j] * on[j]
            e = e + jnp.real(z)[None, :] * jnp.cos(m * th)[:, None]
            e = e - jnp.imag(z)[None, :] * jnp.sin(m * th)[:, None]
        return e

    params = []
    for j in range(3):
        params += [
            Param(f"cos{j + 1}_rad", "rad", "channels", description=f"cos of order {j + 1}"),
            Param(f"sin{j + 1}_rad", "rad", "channels", description=f"sin of order {j + 1}"),
        ]
    params.append(
        Param(
            "orders_on",
            "1",
            (3,),
            linear=False,
            fit=False,
            description="runout orders 1-3 fitted (those the views located; held)",
        )
    )
    return Candidate(
        "beam_tilt_axial",
        fn,
        tuple(params),
        signature=("orders", "spectrum"),
        explanation="Axial runout of the disk seen through tangentially tilted beams (seed "
        "001, axial shifts): a head-specific error at low integer orders that is not a "
        "phase-shifted copy of the other heads' errors, which the encoder theorem assumes "
        "(fitted: its part the base model's disk error cannot take).",
        start=_bt_start,
        derived=_bt_derived,
        valjac=bt_valjac(project),
    )


def _bt_start(ctx: Context, resid: np.ndarray, findings) -> list[dict]:
    """The runout orders (:data:`RUNOUT_ORDERS`) the record supports
    (:func:`_bt_orders_supported`, all of them tested together); when it supports none, those
    the rotation-locked orders view located (else the spectrum's lines within
    ``FinderSettings.integer_order_tol`` of an integer order, else all of them)."""

    def located(views, tol):
        on = np.zeros(len(RUNOUT_ORDERS), bool)
        for f in findings:
            if f.view in views and (f.view == "orders" or f.detail.get("integer_order")):
                for o in f.where["orders"]:
                    if np.isfinite(o) and abs(o - round(o)) < tol and round(o) in RUNOUT_ORDERS:
                        on[RUNOUT_ORDERS.index(round(o))] = True
        return on

    sup = _bt_orders_supported(ctx, resid, np.ones(len(RUNOUT_ORDERS), bool))
    if sup.any():
        return [{"orders_on": sup.astype(float)}]
    on = located(("orders",), 0.5)  # the orders view: nearest integer
    if not on.any():
        on = located(("spectrum",), ctx.settings.integer_order_tol)
    if not on.any():
        on[:] = True
    return [{"orders_on": on.astype(float)}]


def _bt_derived(ctx: Context, v: dict, se: dict) -> dict:
    alpha = jnp.asarray(ctx.consts["alpha"], float)
    coefs = [
        (jnp.asarray(v[f"cos{j + 1}_rad"]), jnp.asarray(v[f"sin{j + 1}_rad"])) for j in range(3)
    ]
    zs = _bt_head_specific(alpha, coefs, not ctx.has_ref)
    on = np.asarray(v["orders_on"], float)
    amp = np.stack([np.abs(np.asarray(z)) * on[j] for j, z in enumerate(zs)], 1)  # (C, 3)
    out = {
        "error_amplitude_rad": {
            "value": amp.tolist(),
            "se": None,
            "unit": "rad",
            "note": "per head (rows) and runout order 1..3 (columns): the head-specific part "
            "(what the base model's disk error cannot take)",
        },
        "orders_fitted": {
            "value": _bt_orders_significant(ctx, amp, on),
            "se": None,
            "unit": "1",
            "note": "the runout orders fitted whose head-specific part is significant against "
            "the noise (chi-square over the heads at FinderSettings.alpha, Bonferroni over the "
            "orders fitted); an order the residual showed only through the base model's "
            "reaction to the others is fitted at about zero and not listed",
        },
    }
    if ctx.radius_m:
        out["tilt_runout_product_m_rad"] = {
            "value": (amp * float(ctx.radius_m)).tolist(),
            "se": None,
            "unit": "m rad",
            "note": "beta_k z_m (head-specific part): only the products are observable",
        }
    return out


BEAM_TILT_AXIAL = _bt_make(False)
BEAM_TILT_AXIAL_NO_REF = _bt_make(True)


def _wb_fn(p, x):
    oh = x["run_onehot"]
    return fx.bearing_wobble_rad(
        x["theta"],
        x["alpha"],
        _R(x),
        p["frequency_ratio"],
        oh @ p["runout_a_m"],
        oh @ p["runout_b_m"],
    )


def _spectrum_orders(findings, integer: bool | None) -> list[float]:
    out = []
    for f in findings:
        if f.view != "spectrum":
            continue
        if integer is not None and f.detail.get("integer_order") != integer:
            continue
        o = [v for v in f.where["orders"] if np.isfinite(v)]
        if o:
            out.append(float(np.median(o)))
    return out


def _wb_start(ctx, resid, findings):
    return [{"frequency_ratio": o} for o in _spectrum_orders(findings, False)[:3]]


def _wb_plausible(ctx, v):
    nu = float(v["frequency_ratio"])
    if nu <= 0:
        return f"frequency ratio {nu:.3g} is not positive"
    if abs(nu - round(nu)) < ctx.settings.wobble_integer_tol:
        return f"frequency ratio {nu:.4f} is an integer: synchronous, not a wobble"
    st = ctx.settings
    revs = float(np.max(ctx.revolutions))
    if nu * revs >= st.wobble_cycles_min:
        return None
    # fewer cycles than the rule asks in every run: a slow drift or a step could pose as
    # it, unless the record tells them apart: runs at clearly different speeds that share
    # one order (not one frequency) over enough cycles in all
    w = np.abs(np.asarray(ctx.rows["omega"], float))
    w = w[w > 0]
    total = nu * float(np.sum(ctx.revolutions))
    if w.size and np.max(w) >= st.speed_ratio_min * np.min(w) and total >= st.wobble_cycles_min:
        return None
    return (
        f"{nu * revs:.1f} wobble cycles in the longest run: a slow drift or a step fits as "
        f"well (needs {st.wobble_cycles_min:g}, or runs at speeds {st.speed_ratio_min:g}x "
        f"apart showing the same order over {st.wobble_cycles_min:g} cycles in all)"
    )


def _wb_derived(ctx, v, se):
    rho = np.hypot(v["runout_a_m"], v["runout_b_m"])
    return {
        "runout_m": {
            "value": rho.tolist(),
            "se": None,
            "unit": "m",
            "note": "radial runout amplitude per run",
        }
    }


BEARING_WOBBLE = Candidate(
    "bearing_wobble",
    _wb_fn,
    (
        Param("frequency_ratio", "1", "1", linear=False, scale=1e-3),
        Param("runout_a_m", "m", "runs"),
        Param("runout_b_m", "m", "runs"),
    ),
    signature=("spectrum",),
    explanation="Shaft runout not synchronous with rotation (balls, cage, races): a "
    "fractional order, not repeatable revolution to revolution, cancelling in opposed-head "
    "sums like eccentricity.",
    applies=lambda ctx: (
        None
        if float(np.sum(ctx.revolutions)) >= ctx.settings.wobble_revolutions_min
        else f"needs at least {ctx.settings.wobble_revolutions_min:g} revolutions to resolve "
        "a fractional order"
    ),
    start=_wb_start,
    plausible=_wb_plausible,
    derived=_wb_derived,
    valjac=bearing_wobble_valjac,
)


def _vb_fn(p, x):
    oh = x["run_onehot"]
    C = x["reading"].shape[1]
    R = oh.shape[1]
    return fx.vibration_rad(
        x["t"],
        p["frequency_hz"],
        oh @ p["cos_rad"].reshape(R, C),
        oh @ p["sin_rad"].reshape(R, C),
    )


def _vb_start(ctx, resid, findings):
    out = []
    stair = None
    for f in findings:
        if f.view == "spectrum" and f.detail.get("fixed_in") != "order":
            fr = [v for v in f.where["frequencies_hz"] if v > 0]
            if fr:
                f0, margin = locked_margin(ctx, resid, float(np.median(fr)))
                if stair is None:
                    stair = staircase_columns(ctx)
                out.append(
                    {
                        "frequency_hz": f0,
                        "locked_margin": margin,
                        "staircase_margin": staircase_margin(ctx, resid, f0, stair),
                    }
                )
    return out[:3]


def _vb_plausible(ctx, v):
    f = float(v["frequency_hz"])
    if f <= 0:
        return "frequency is not positive"
    w = one_speed(ctx)
    if w is not None:
        order = f / (w / (2 * np.pi))
        res = order_res(ctx)
        margin = float(np.asarray(v.get("locked_margin", 0.0)))
        # within the span's resolution of an integer order, the data must show that it is
        # not rotation locked (the line beats the locked order by FinderSettings.locked_margin);
        # so too at a catalog order the sampling folds onto it, and on part of a turn at the
        # orders within the arc's resolution (issue 44)
        folded = catalog_orders_at(ctx, f, w, res * w / (2 * np.pi))
        near = abs(order - round(order)) < res and round(order) >= 1
        left = left_out_orders(ctx, order)  # seen once: the orders the base left out
        arc = sorted(set(arc_orders(ctx, order)) | set(left))
        wide = any(m != round(order) for m in arc)  # part of a turn: more than the nearest
        if (near or folded or wide) and margin < ctx.settings.locked_margin:
            m = folded[0] if folded else round(order)
            at = f" folded by the sampling (apparent order {order:.3f})" if folded else ""
            alt = f"order {m}"
            if wide and not folded:
                why = "; located in the base residual, left out of the base" if left else ""
                alt = f"orders {arc[0]}-{arc[-1]} (part of a turn, {covered_turns(ctx):.2f}{why})"
            return (
                f"at one speed a line at {f:.4g} Hz is shaft order {m if folded else order:.6g}"
                f"{at}: a rotation-locked error at {alt} fits as well (chi-square margin "
                f"{margin:.1f}, needs {ctx.settings.locked_margin:.0f}; two speeds separate them)"
            )
    stair = float(np.asarray(v.get("staircase_margin", NO_DOUBT)))
    if stair < ctx.settings.locked_margin:
        return (
            f"a line at {f:.4g} Hz takes {stair:.1f} in chi-square (less k ln N) beyond the "
            f"quantization staircase's first {ctx.settings.vibration_staircase_harmonics} "
            "harmonics at the sensor's reading angle (their own phase in each run and "
            f"direction; needs {ctx.settings.locked_margin:.0f}): the staircase, sampled, "
            "folds to lines; this one is what the quantization leaves"
        )
    T = float(np.max(run_durations(ctx)))
    need = ctx.settings.vibration_cycles_min
    if f * T < need:
        return (
            f"{f * T:.1f} cycles of {f:.3g} Hz in the longest run: a slow drift or a step "
            f"fits as well (needs {need:g})"
        )
    return None


VIBRATION_PROBE_NYQUIST = 0.6
"""The vibration's bound is stated for a line at this fraction of the Nyquist frequency of
the slowest-sampled run, moved to the nearest half-integer shaft order (off the orders the
base model fits; a line's bound hardly depends on where it is off them)."""


def _vb_probe_hz(ctx: Context) -> float | None:
    """The frequency (Hz) the vibration's bound is stated at (:data:`VIBRATION_PROBE_NYQUIST`)."""
    t = np.asarray(ctx.rows["t"], float)
    oh = np.asarray(ctx.rows["run_onehot"], float) > 0
    dts = [np.median(np.diff(t[oh[:, r]])) for r in range(oh.shape[1]) if oh[:, r].sum() > 2]
    dts = [d for d in dts if d > 0]
    if not dts:
        return None
    f = VIBRATION_PROBE_NYQUIST * 0.5 / float(max(dts))
    w = np.abs(np.asarray(ctx.rows["omega"], float))
    w = w[w > 0]
    if w.size:
        f_rot = float(np.median(w)) / (2 * np.pi)
        f = (math.floor(f / f_rot) + 0.5) * f_rot
    return f if f > 0 else None


def _vb_probes(ctx: Context) -> list[Probe]:
    """Per head, a line of 1 rad on that head alone in every run (its own phase per run)."""
    f = _vb_probe_hz(ctx)
    if f is None:
        return []
    C, R = ctx.n_channels, ctx.n_runs
    names = ctx.data.channel_names if ctx.data is not None else [f"h{k}" for k in range(C)]
    out = []
    for k in range(C):
        cos = np.zeros((R, C))
        cos[:, k] = 1.0
        vals = {
            "frequency_hz": np.asarray(f),
            "cos_rad": cos,
            "sin_rad": np.zeros((R, C)),
            "locked_margin": np.asarray(NO_DOUBT),
            "staircase_margin": np.asarray(NO_DOUBT),
        }
        out.append(Probe(vals, "amplitude_rad", "rad", where=names[k], at=f"a line at {f:.6g} Hz"))
    return out


VIBRATION = Candidate(
    "vibration",
    _vb_fn,
    (
        Param("frequency_hz", "Hz", "1", linear=False, scale=1e-3),
        Param("cos_rad", "rad", "runs*channels"),
        Param("sin_rad", "rad", "runs*channels"),
        Param(
            "locked_margin",
            "1",
            linear=False,
            fit=False,
            description="at one speed: whitened chi-square (less k ln N) by which a line fixed "
            "in time beats a rotation-locked error at the nearest integer order (on part of a "
            "turn the orders within the arc's resolution) (held)",
        ),
        Param(
            "staircase_margin",
            "1",
            linear=False,
            fit=False,
            description="a quantized sensor: whitened chi-square (less k ln N) the line takes "
            "beyond the quantization staircase's harmonics at the sensor's reading angle (held)",
        ),
    ),
    signature=("spectrum",),
    explanation="Relative oscillation of head and scale at a structural frequency "
    "(seed 002): fixed in Hz across runs at different speeds, so its shaft order moves with "
    "speed (reported at its apparent frequency when aliased by the sampling).",
    start=_vb_start,
    plausible=_vb_plausible,
    doubt_overruled=False,  # the locked-order margin is a test on the data
    probes=_vb_probes,
    valjac=vibration_valjac,
)


def _th_fn(p, x):
    return x["driver"][:, None] * p["rate"][None, :]


def _th_unit(ctx):
    return "rad/K" if ctx.driver_name == "temp_c" else "rad/s"


def _th_probes(ctx: Context) -> list[Probe]:
    """Per head, a drift of 1 rad/K (or rad/s) on that head alone."""
    C = ctx.n_channels
    names = ctx.data.channel_names if ctx.data is not None else [f"h{k}" for k in range(C)]
    unit = _th_unit(ctx)
    return [Probe({"rate": np.eye(C)[k]}, "rate", unit, where=names[k]) for k in range(C)]


THERMAL_DRIFT = Candidate(
    "thermal_drift",
    _th_fn,
    (Param("rate", "rad/K (temp_c) or rad/s (no temp_c)", "channels"),),
    signature=("drift", "time"),
    explanation="Expansion of mounts and disk with temperature (seed 001: about 0.7 arcsec/K): "
    "a slow error correlated with temp_c, different between heads.",
    # issue 44 E: without a temperature that varies, a slow error in time is not attributable
    # to temperature (it may be a step the motion hides, a reference's drift, ...): the
    # drift is reported located, never named thermal_drift
    applies=lambda ctx: (
        None
        if ctx.driver_name == "temp_c"
        else "needs a temp_c column that varies (a drift in time alone is reported located, "
        "not attributed to temperature)"
    ),
    probes=_th_probes,
)


def _ip_fn(p, x):
    L = jnp.maximum(x["signal_periods"], 1.0)
    oh = x["run_onehot"]
    R, C = oh.shape[1], x["psi"].shape[1]
    # one set per run and head: a head's zero set anew for a run by any amount (not a whole
    # number of signal periods) moves the signal phase psi = L * reading by a constant, which
    # rotates harmonic 1 by L*dz and harmonic 2 by 2 L*dz (the same physics, other phases)
    c = p["coef"].reshape(4, R, C)
    coef = jnp.einsum("nr,qrc->qnc", oh, c)
    return fx.interpolation_harmonics_rad(x["psi"], L, coef)


def _ip_derived(ctx, v, se):
    C, R = ctx.n_channels, ctx.n_runs
    c = np.asarray(v["coef"]).reshape(4, R, C)
    if R == 1:
        c = c[:, 0]
    L = max(ctx.signal_periods, 1)
    note = {"note": "per run (rows) and head (columns)"} if R > 1 else {}
    return {
        "offset_a": {"value": c[0].tolist(), "se": None, "unit": "1", **note},
        "offset_b": {"value": (-c[1]).tolist(), "se": None, "unit": "1", **note},
        "amplitude_error": {"value": (-2 * c[3]).tolist(), "se": None, "unit": "1", **note},
        "phase_error_rad": {"value": (-2 * c[2]).tolist(), "se": None, "unit": "rad", **note},
        "amplitude_1x_rad": {
            "value": (np.hypot(c[0], c[1]) / L).tolist(),
            "se": None,
            "unit": "rad",
            **note,
        },
        "amplitude_2x_rad": {
            "value": (np.hypot(c[2], c[3]) / L).tolist(),
            "se": None,
            "unit": "rad",
            **note,
        },
    }


def _ip_probes(ctx: Context) -> list[Probe]:
    """Per head, a signal offset ``offset_a`` of 1 (an error ``cos(psi) / L`` rad at order
    L) on that head alone, the same in every run."""
    C, R = ctx.n_channels, ctx.n_runs
    if ctx.signal_periods <= 0:
        return []
    names = ctx.data.channel_names if ctx.data is not None else [f"h{k}" for k in range(C)]
    out = []
    for k in range(C):
        c = np.zeros((4, R, C))
        c[0, :, k] = 1.0
        vals = {"coef": c.reshape(4, R * C)}
        out.append(
            Probe(vals, "offset_a", "1", where=names[k], at=f"order {ctx.signal_periods} (L)")
        )
    return out


INTERPOLATION_ERROR = Candidate(
    "interpolation_error",
    _ip_fn,
    (Param("coef", "1", (4, 0)),),  # shape (4, runs * heads) fixed per record below
    signature=("line_phase",),
    explanation="Imperfect quadrature signals interpolated by arctangent (seed 002 eq. 4): "
    "offsets, amplitude ratio and phase error give orders L and 2L of the shaft angle "
    "(L signal periods per revolution).",
    applies=lambda ctx: (
        None if ctx.signal_periods > 0 else "needs grating_lines or signal_periods_per_rev"
    ),
    derived=_ip_derived,
    probes=_ip_probes,
)


ORDER_STEP_BINS = 2048
"""Change points the ``order_step`` view scans (bin edges over the kept rows; the best one
is refined to the row)."""


def _order_step_sums(prep: Prepared, rw: np.ndarray, idx: np.ndarray, P: int):
    """Per kept row ``idx``: the whitened eccentricity columns ``X`` (rows, C, 2) (order 1 of
    the disk error as every head sees it: ``sin, cos (theta - alpha_k)``), and the sums a
    step in them needs: ``X^T r`` (rows, 2), ``X^T X`` (rows, 2, 2), ``X^T B`` (rows, 2, P)
    and ``B^T B``, ``B^T r`` with ``B`` the base columns a step must be told from (one
    constant per run and head, then order 1 over the whole record; on part of a turn the
    base's own columns, :func:`._order_step_bins.order_step_width`)."""
    X, B = base_rows(prep, idx, P)
    r = rw[idx]
    Xt, Bf = X.transpose(0, 2, 1), B.reshape(-1, P)  # (matmul: einsum's loops were 5x slower)
    return X, np.einsum("nck,nc->nk", X, r), Xt @ X, Xt @ B, Bf.T @ Bf, Bf.T @ r.ravel()


def _step_kept(SG, SXB, BBi):
    """The least share of a step's (2-column) whitened norm squared that the base columns
    leave, over its directions: ``1 - rho^2`` with ``rho`` the step's largest canonical
    correlation with the base (the smaller root of ``det(Gp - l SG) = 0``, ``Gp`` its Gram
    after the base columns are projected out; 0 where ``SG`` is singular)."""
    Gp = SG - SXB @ BBi @ np.swapaxes(SXB, -1, -2)
    dB = SG[..., 0, 0] * SG[..., 1, 1] - SG[..., 0, 1] * SG[..., 1, 0]
    lam = np.linalg.eigvals(np.linalg.pinv(SG) @ Gp).real.min(-1)
    return np.where(dB > 0, np.clip(lam, 0.0, 1.0), 0.0)


def _step_gain(Sa, SG, SXB, BBi, Br):
    """Whitened chi-square (2 dof) a step in the eccentricity columns takes out, given the
    suffix sums from the step on (arrays over candidate change points), the base columns
    projected out (the step's likelihood ratio with the base refitted jointly); 0 where
    the projected step is singular (relative determinant <= 1e-9)."""
    g = Sa - SXB @ (BBi @ Br)
    Gp = SG - SXB @ BBi @ np.swapaxes(SXB, -1, -2)
    return _gain(Gp, g, rtol=1e-9, floor=1e-300)


def _step_deflation(SG, SXB, BBi, kept_min: float):
    """The factor on a step's chi-square as evidence of a change: ``min(1, kept /
    kept_min)``, ``kept`` the least share of its norm squared the base leaves
    (:func:`_step_kept`). Where the base nearly spans the step (``kept < kept_min``, rule
    ``collinear_refuse``) what it leaves of it is small, and a misfit of the base along it
    is amplified by ``1 / kept``; deflated, that amplification is bounded at the refusal
    level, and the gain of a step the base does not nearly span is untouched (continuous
    at ``kept_min``; issue 44 C, session 23: left out, such change points lost a shift that
    lay among them)."""
    return np.minimum(_step_kept(SG, SXB, BBi) / kept_min, 1.0)


def view_order_step(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
    """A change at one instant of the disk's order-1 error (the disk moved on its hub): the
    step ``H(tau - t_s)`` times the eccentricity columns every head sees, ``sin, cos(theta -
    alpha_k)`` (so one displacement, phase shifted by the head angle), with the base model's
    constant order 1 and run constants projected out (on part of a turn all the base's own
    columns: the step's gain with the base refitted jointly, ``order_step_width``), scanned
    over the change time on the
    global time axis (runs end to end). Its block means average out over each turn, so the
    ``time`` view does not see it; a line fitted to it is a detuned order 1. Chi-square with
    2 dof at the best change point, Bonferroni over the change points scanned."""
    keep = prep.keep
    kidx = np.flatnonzero(keep)
    C, R = prep.n_channels, prep.ctx.n_runs
    if C == 1 and prep.ctx.has_ref:  # a sensor against a reference: no disk on a hub
        return []
    s = prep.settings
    if kidx.size < s.order_step_min_rows or float(np.sum(prep.ctx.revolutions)) < (
        s.order_step_revolutions_min
    ):
        return []
    P = R * C + order_step_width(prep)
    nb = int(min(ORDER_STEP_BINS, kidx.size // 8))
    # per bin of kept rows (time order); the geometry kept across scans (issue 43)
    a, G, XB, BB, Br, edges = order_step_bins(prep, rw, kidx, P, nb, _order_step_sums)
    BBi = np.linalg.pinv(BB)

    def suffix(x):
        return np.cumsum(x[::-1], 0)[::-1]

    Sa, SG, SXB = suffix(a), suffix(G), suffix(XB)
    # change points at bin edges 1..nb-1, with at least order_step_margin_rows and
    # order_step_margin_share of the kept rows either side
    e = np.arange(1, nb)
    margin = max(s.order_step_margin_rows, int(kidx.size * s.order_step_margin_share))
    e = e[(edges[e] >= margin) & (kidx.size - edges[e] >= margin)]
    if e.size == 0:
        return []
    # the evidence: the gain deflated where the base nearly spans the step (rule
    # collinear_refuse; issue 44 C, session 22: short_arcs clean 6334/0, a false change
    # where the base's run zero and disk orders nearly spanned the step; session 23:
    # deflated, not left out); the location and its interval: the likelihood's profile
    # (the undeflated gain, which the interval's calibration assumes), every change point
    kept_min = 1.0 - s.collinear_refuse**2
    like = _step_gain(Sa[e], SG[e], SXB[e], BBi, Br)
    chi = float(np.max(like * _step_deflation(SG[e], SXB[e], BBi, kept_min)))
    n_tests = int(e.size)
    if chi <= chi2_threshold(prep.settings.alpha, 2, n_tests):
        return []
    # refine to the row: the rows of the bins either side of the likelihood's best edge
    eb = int(e[int(np.argmax(like))])
    lo, hi = edges[max(eb - 1, 0)], edges[min(eb + 1, nb)]
    _, ai, Gi, XBi, _, _ = _order_step_sums(prep, rw, kidx[lo:hi], P)
    tail = min(eb + 1, nb)
    base_a = Sa[tail] if tail < nb else np.zeros(2)
    base_G = SG[tail] if tail < nb else np.zeros((2, 2))
    base_XB = SXB[tail] if tail < nb else np.zeros((2, P))
    ra = base_a + np.cumsum(ai[::-1], 0)[::-1]
    rG = base_G + np.cumsum(Gi[::-1], 0)[::-1]
    rXB = base_XB + np.cumsum(XBi[::-1], 0)[::-1]
    gi = _step_gain(ra, rG, rXB, BBi, Br)
    ok = (np.arange(lo, hi) >= margin) & (kidx.size - np.arange(lo, hi) >= margin)
    gi = np.where(ok, gi, -1.0)
    i_after = int(kidx[lo + int(np.argmax(gi))])  # first kept row after the change
    located = _order_step_interval(prep, kidx, lo, gi, ok, edges[e], like)
    # issue 44 C, part turns: located with the runs' zeros re-chosen (the fit's start, the
    # row below, stays the view's: the trial fits hold the base's zeros)
    zp = zero_profile(prep, rw, kidx, edges[e], margin)
    located = located if zp is None else zp[1]
    # issue 44 C, session 25: the time is the order change's only where that model fits
    # better than a step of one head's constant (a count jump): else the time view's
    hs, hk, hj = head_step_gain(prep, rw, kidx, P, edges, e, BBi, Br)
    if not order_change_fits_better(float(np.max(like)), hs, s.order_step_head_ratio):
        located = None
    i_before = int(kidx[max(np.searchsorted(kidx, i_after) - 1, 0)])
    tau_a = float(prep.rows.take("tau", np.array([i_after]))[0])
    tau_b = float(prep.rows.take("tau", np.array([i_before]))[0])
    t_a = float(prep.rows.take("t", np.array([i_after]))[0])
    t_b = float(prep.rows.take("t", np.array([i_before]))[0])
    r_after = int(prep.run[i_after])
    detail = {
        "shape": "order_change",
        "order": 1,
        # the change lies between the last row before it and the first row after it (a
        # change between two runs is put at the start of the later one)
        "global_step_time_s": 0.5 * (tau_a + tau_b) if prep.run[i_before] == r_after else tau_a,
        "step_time_s": t_a,
        "step_times_s": [t_b if prep.run[i_before] == r_after else t_a, t_a],
        "n_values": int(kidx.size * C),
        "n_change_points": n_tests,
        "order_change_chi2": float(np.max(like)),
        "head_step_chi2": hs,
        "head_step_head": hk,
        "head_step_time_s": float(prep.rows.take("t", kidx[edges[e[hj]] : edges[e[hj]] + 1])[0]),
    }
    return [
        Finding(
            "order_step",
            {
                "orders": [1.0],
                "frequencies_hz": [],
                "heads": list(range(C)),
                "runs": [int(prep.run_ids[r_after])],
                "times_s": detail["step_times_s"],
            },
            chi,
            2,
            log10_tail_p(chi, 2),
            detail=detail,
            located_time=located,
        )
    ]


def _order_step_interval(prep, kidx, lo, gi, ok, edge_pos, edge_gain) -> dict:
    """The ``located_time`` of the order-1 change: the profile of its chi-square gain over
    the rows ``gi`` (kept-row positions ``lo ..``, ``ok`` the candidates), widened where the
    interval reaches the rows scanned to the nearest bin edge ``edge_pos`` whose gain
    ``edge_gain`` lies outside it (a conservative bound, :mod:`engine._located`)."""
    c = change_chi2(prep.settings.change_time_level)
    pos = np.arange(lo, lo + gi.size)[ok]
    g = gi[ok]
    best = int(pos[int(np.argmax(g))])
    _, a, b = interval_of(pos, -g, c, best=best)
    out = edge_pos[edge_gain < float(g.max()) - c]
    if a == pos[0]:  # reaches the rows scanned: the nearest bin edge outside below it
        below = out[out < a]
        a = int(below.max()) + 1 if below.size else 1
    if b == pos[-1]:
        above = out[out > b]
        b = int(above.min()) - 1 if above.size else kidx.size - 1
    return located_time(prep, kidx, best, a, b)


def _es_fn(p, x):
    return fx.eccentricity_shift_rad(
        x["theta"],
        x["tau"],
        x["alpha"],
        _R(x),
        p["shift_time_s"],
        p["shift_x_m"],
        p["shift_y_m"],
        x["step_width_s"],
    )


def _es_start(ctx, resid, findings):
    # the order-1 change point first: the time view's block means average an order-1
    # change out over each turn, so its change points are those of other structure
    out = [
        {"shift_time_s": f.detail["global_step_time_s"]}
        for f in findings
        if f.view == "order_step" and "global_step_time_s" in f.detail
    ]
    out += [
        {"shift_time_s": f.detail["global_step_time_s"]}
        for f in findings
        if f.view == "time" and "global_step_time_s" in f.detail
    ]
    return out[:3]


def _es_plausible(ctx, v):
    tau = ctx.rows["tau"]
    ts = float(v["shift_time_s"])
    if not (tau.min() < ts < tau.max()):
        return f"shift time {ts:.4g} s lies outside the record"
    return None


ECCENTRICITY_SHIFT = Candidate(
    "eccentricity_shift",
    _es_fn,
    (
        Param("shift_time_s", "s", "1", linear=False, scale=1e-2, global_time=True),
        Param("shift_x_m", "m", "1"),
        Param("shift_y_m", "m", "1"),
    ),
    signature=("order_step", "time"),
    explanation="A shock or slip moved the disk on its hub during the record: the order-1 "
    "error of the heads changes at one instant (shift_time_s is fitted on the global time "
    "axis, runs end to end, and reported on the recording's own t with its run).",
    start=_es_start,
    plausible=_es_plausible,
    valjac=eccentricity_shift_valjac,
    time_profile=shift_time_profile,
)
