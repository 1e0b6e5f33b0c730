"""Multihead kind for the engine: base model, views and candidate terms (``docs/effects.md``).

Base model per head ``k`` at azimuth ``alpha_k`` and run ``r``::

    y_k = reading_k - theta_ref = c_{r,k} + sum_{m=1..M} a_m cos m(th - alpha_k - d_k)
                                             + b_m sin m(th - alpha_k - d_k)
    th = theta + delta_r

one constant per head and run (each acquisition has its own zeros, of the heads and of
``theta_ref``), one disk error function seen through every head (eccentricity at order 1,
tilt at order 2, grating errors at any order), head placements ``d_k`` (head 0 the reference),
and one angle offset ``delta_r`` per run after the first (the zero of the angle the disk error
is evaluated at also moves between runs). Without ``theta_ref`` the shaft angle is the head
mean and only head differences are fitted (the per-sample head mean is projected out).
With one head and ``theta_ref`` this is a sensor against a reference: the error function of
the sensor, one constant per run.

Candidates are the multihead catalog effects (terms in :mod:`encdesign.diagnose._effects`),
plus, for a sensor against a reference, the terms of
:mod:`encdesign.diagnose._reference_terms` when that module is present.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax.numpy as jnp
import numpy as np

from .._errors import input_error
from ..io._recording import Recording
from . import _effects as fx
from ._candidates import Candidate, Context, Param
from ._engine import MAX_PARAM_FRACTION, Kind, KindData, Prepared
from ._views import run_spans

RUNOUT_ORDERS = (1.0, 2.0, 3.0)


def _where(rec: Recording) -> str:
    return str(rec.path) if rec.path is not None else "recording"


def multihead_data(rec: Recording) -> KindData:
    """Observations of a multihead recording (head readings less the reference angle)."""
    where = _where(rec)
    if rec.kind != "multihead":
        raise input_error(f"{where}: kind", f"got {rec.kind!r}", "'multihead'")
    enc = rec.encoder
    H = len(rec.head_columns)
    has_ref = "theta_ref" in rec.columns
    if H < 2 and not has_ref:
        raise input_error(
            f"{where}: [encoder].head_angles_deg",
            f"{H} head and no theta_ref column",
            "at least 2 heads, or one head with a theta_ref column",
        )
    # y (n, C) is the only array per row this kind makes: the readings are the recording's
    # own columns (read per chunk), the shaft is theta_ref itself or the heads' mean
    ref = np.asarray(rec.columns["theta_ref"], float) if has_ref else None
    if has_ref:
        shaft = ref
        y = np.empty((rec.n_rows, H))
        for k, h in enumerate(rec.head_columns):
            np.subtract(np.asarray(rec.columns[h], float), shaft, out=y[:, k])
    else:
        y = rec.heads()
        shaft = y.mean(1)
        y -= shaft[:, None]
    radius = enc.get("optical_radius_m")
    L = int(enc.get("signal_periods_per_rev", enc.get("grating_lines", 0)) or 0)
    return KindData(
        y=y,
        shaft=shaft,
        t=np.asarray(rec.columns["t"], float),
        run=np.asarray(rec.runs),
        reading=None,
        reading_cols=tuple(np.asarray(rec.columns[h], float) for h in rec.head_columns),
        theta_ref=ref,
        temp=np.asarray(rec.columns["temp_c"], float) if "temp_c" in rec.columns else None,
        alpha=np.deg2rad(np.asarray(enc["head_angles_deg"], float)),
        radius_m=float(radius) if radius is not None else None,
        signal_periods=L,
        project=not has_ref,
        unit="rad",
        channel_names=list(rec.head_columns),
        sensor=str(enc.get("sensor", "optical")),
        where=where,
    )


def max_order_limit(prep: Prepared) -> int:
    """Highest order the record resolves: below half the samples per revolution of the
    sparsest-sampled run, and ``2 M + constants <= MAX_PARAM_FRACTION`` of the values."""
    keep = prep.keep
    spr = []
    for r in range(prep.ctx.n_runs):
        m = (prep.run == r) & keep
        revs = prep.ctx.revolutions[r]
        if m.sum() > 0 and revs > 0:
            spr.append(m.sum() / revs)
    nyq = int(math.floor(min(spr) / 2.0)) - 1 if spr else 1
    C, R = prep.n_channels, prep.ctx.n_runs
    budget = int((MAX_PARAM_FRACTION * prep.n_values - R * C - C - R) // 2)
    return int(max(1, min(nyq, budget)))


@functools.lru_cache(maxsize=64)
def _base_candidate(C: int, R: int, M: int) -> Candidate:
    """The base term for C heads, R runs and orders 1..M (one object per shape, so one
    compiled Jacobian serves every record of that shape)."""

    def fn(p, x):
        oh = x["run_onehot"]
        th = x["theta_raw"]
        if R > 1:
            th = th + oh[:, 1:] @ p["run_angle_offset_rad"]
        alpha = x["alpha"]
        if C > 1:
            alpha = alpha + jnp.concatenate([jnp.zeros(1), p["placement_rad"]])
        e = fx.base_error_rad(
            th, alpha, p["fourier_cos_rad"], p["fourier_sin_rad"], jnp.zeros_like(alpha)
        )
        return e + oh @ p["offset_rad"]

    params = [
        Param("offset_rad", "rad", "runs*channels", description="constant per run and head"),
        Param("fourier_cos_rad", "rad", (M,), description="disk error, cos of orders 1..M"),
        Param("fourier_sin_rad", "rad", (M,), description="disk error, sin of orders 1..M"),
    ]
    if C > 1:
        params.append(
            Param(
                "placement_rad",
                "rad",
                (C - 1,),
                linear=False,
                scale=1e-4,
                description="head azimuth errors (head 0 the reference)",
            )
        )
    if R > 1:
        params.append(
            Param(
                "run_angle_offset_rad",
                "rad",
                (R - 1,),
                linear=False,
                scale=1e-2,
                description="angle zero of each run after the first",
            )
        )
    return Candidate(
        "base",
        fn,
        tuple(params),
        kinds=("multihead",),
        explanation="base model: disk error function, head placements, zeros",
    )


def _run_offsets_start(prep: Prepared, M: int) -> np.ndarray:
    """Start for ``delta_r``: each run's low orders fitted alone, phase-aligned to run 0
    on a 0.05 deg grid (the orders' phases advance by ``m delta``)."""
    R = prep.ctx.n_runs
    if R < 2:
        return np.zeros(0)
    C = prep.n_channels
    alpha = prep.consts["alpha"]
    Mz = int(min(M, 6))
    Z = []
    P = 2 * Mz + C
    spans = dict(run_spans(prep.run))
    for r in range(R):
        # least squares on the normal equations, accumulated in blocks of rows (the design
        # (rows, C, 2 Mz + C) is never built whole)
        G = np.zeros((P, P))
        h = np.zeros(P)
        a0, b0 = spans.get(r, (0, 0))
        for a in range(a0, b0, 1 << 16):
            b = min(b0, a + (1 << 16))
            kb = prep.keep[a:b]
            th = prep.rows.column("theta_raw", a, b)[kb]
            y = prep.y[a:b][kb]
            cols = []
            for k in range(C):
                ck = []
                for mm in range(1, Mz + 1):
                    ck += [np.cos(mm * (th - alpha[k])), np.sin(mm * (th - alpha[k]))]
                cols.append(np.stack(ck, 1))
            X = np.stack(cols, 1)  # (n, C, 2Mz)
            const = np.broadcast_to(np.eye(C)[None], (th.size, C, C))
            X = np.concatenate([X, const], 2)
            if prep.kd.project:
                X = X - X.mean(1, keepdims=True)
                y = y - y.mean(1, keepdims=True)
            Xf = X.reshape(-1, P)
            G += Xf.T @ Xf
            h += Xf.T @ y.ravel()
        coef = np.linalg.lstsq(G, h, rcond=None)[0]
        a, b = coef[0 : 2 * Mz : 2], coef[1 : 2 * Mz : 2]
        Z.append(a - 1j * b)
    grid = np.linspace(-np.pi, np.pi, 7200, endpoint=False)
    mm = np.arange(1, Mz + 1)
    out = []
    for r in range(1, R):
        score = np.real(
            (Z[r] * np.conj(Z[0]))[None, :] * np.exp(-1j * mm[None, :] * grid[:, None])
        ).sum(1)
        out.append(grid[int(np.argmax(score))])
    return np.asarray(out)


def _align(terms, prep: Prepared):
    """Shaft angle with the fitted run offsets applied (for rotation-locked candidates): a
    lazy row column ``fn(lo, hi)`` (rad), computed per chunk from ``theta_raw``."""
    d = np.zeros(prep.ctx.n_runs)
    for t in terms:
        if t.cand.name == "base" and "run_angle_offset_rad" in t.values:
            d = d + np.concatenate([[0.0], t.values["run_angle_offset_rad"]])
    raw, run = prep.rows["theta_raw"], prep.run

    def theta(lo: int = 0, hi: int | None = None) -> np.ndarray:
        return raw[lo:hi] + d[run[lo:hi]]

    return theta


def multihead_base(prep: Prepared, M: int):
    """Base terms (with starts) and the report info for a multihead record."""
    C, R = prep.n_channels, prep.ctx.n_runs
    if "theta_raw" not in prep.rows:  # the angle before alignment (never changed in place)
        prep.rows["theta_raw"] = prep.rows["theta"]
    cand = _base_candidate(C, R, M)
    start = {}
    if R > 1:
        start["run_angle_offset_rad"] = _run_offsets_start(prep, M)
    terms = [(cand, start)]
    if prep.count_jumps:
        terms.append((_jump_candidate(prep), {}))
    info: dict = {"align": _align, "unidentifiable": []}
    if not prep.ctx.has_ref:
        alpha = prep.consts["alpha"]
        bad = []
        for m in range(1, M + 1):
            v = np.exp(-1j * m * alpha)
            if np.sum(np.abs(v - v.mean()) ** 2) / C <= 0.05:
                bad.append(m)
        info["unidentifiable"] += [
            "every error common to all heads at one sample (no theta_ref: the shaft angle is "
            "the head mean)",
            "the common part of each run's head constants",
        ]
        if bad:
            info["unidentifiable"].append(
                f"disk error orders {bad}: the same at every head (multiples of the head "
                "symmetry), they cancel in head differences"
            )
    info["unidentifiable"].append(
        "the common rotation of all heads (head 0's placement is the reference)"
    )
    return terms, info


def _jump_candidate(prep: Prepared) -> Candidate:
    idx = [j["index"] for j in prep.count_jumps]
    ch = [max(j["channel_index"], 0) for j in prep.count_jumps]
    taus = jnp.asarray([prep.rows["tau"][i] for i in idx])
    C = prep.n_channels
    sel = np.zeros((len(idx), C))
    sel[np.arange(len(idx)), ch] = 1.0
    selj = jnp.asarray(sel)

    def fn(p, x):
        step = (x["tau"][:, None] >= taus[None, :] - 1e-12).astype(x["tau"].dtype)
        return (step * p["jump_rad"][None, :]) @ selj

    return Candidate(
        "count_jumps",
        fn,
        (Param("jump_rad", "rad", (len(idx),), description="size of each located count jump"),),
        explanation="located count jumps (nuisance)",
    )


# ----------------------------------------------------------------------------- candidates


def _R(x):
    return x["radius_m"]


def _bt_fn(p, x):
    return fx.beam_tilt_axial_rad(
        x["theta"],
        _R(x),
        p["beam_tilt_rad"],
        p["runout_cos_m"],
        p["runout_sin_m"],
        jnp.asarray(RUNOUT_ORDERS),
    )


def _bt_start(ctx: Context, resid: np.ndarray, findings) -> list[dict]:
    th = ctx.rows["theta"]
    C = ctx.n_channels
    R = float(ctx.consts["radius_m"])
    rows = []
    for m in RUNOUT_ORDERS:
        X = np.stack([np.cos(m * th), np.sin(m * th)], 1)
        coef = np.linalg.lstsq(X, resid, rcond=None)[0]  # (2, C)
        rows.append(coef)
    Mx = np.concatenate(rows, 0)  # (6, C): rows zc1, zs1, zc2, ...
    U, S, Vt = np.linalg.svd(Mx, full_matrices=False)
    beta = Vt[0] * 5e-3 / max(np.max(np.abs(Vt[0])), 1e-12)
    z = U[:, 0] * S[0] * R / (5e-3 / max(np.max(np.abs(Vt[0])), 1e-12))
    del C
    return [{"beam_tilt_rad": beta, "runout_cos_m": z[0::2], "runout_sin_m": z[1::2]}]


def _bt_derived(ctx: Context, v: dict, se: dict) -> dict:
    R = float(ctx.consts["radius_m"])
    prod = np.outer(v["beam_tilt_rad"], np.hypot(v["runout_cos_m"], v["runout_sin_m"]))
    return {
        "error_amplitude_rad": {
            "value": (prod / R).tolist(),
            "se": None,
            "unit": "rad",
            "note": "per head (rows) and runout order 1..3 (columns)",
        },
        "tilt_runout_product_m_rad": {
            "value": prod.tolist(),
            "se": None,
            "unit": "m rad",
            "note": "only the products beta_k z_m are observable",
        },
    }


BEAM_TILT_AXIAL = Candidate(
    "beam_tilt_axial",
    _bt_fn,
    (
        Param("beam_tilt_rad", "rad", "channels", linear=False, scale=5e-3),
        Param("runout_cos_m", "m", (3,), linear=False, scale=None),
        Param("runout_sin_m", "m", (3,), linear=False, scale=None),
    ),
    signature=("orders", "spectrum"),
    explanation="Axial runout of the disk seen through tangentially tilted beams (seed 001, "
    "axial shifts): a head-specific error at low integer orders that is not a phase-shifted "
    "copy of the other heads' errors, which the encoder theorem assumes.",
    start=_bt_start,
    derived=_bt_derived,
)


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
    if abs(nu - round(nu)) < 0.01:
        return f"frequency ratio {nu:.4f} is an integer: synchronous, not a wobble"
    revs = float(np.max(ctx.revolutions))
    if nu * revs < 3.0:
        return (
            f"{nu * revs:.1f} wobble cycles in the longest run: a slow drift or a step "
            "fits as well (needs 3)"
        )
    return None


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
        if float(np.sum(ctx.revolutions)) >= 2
        else "needs at least two revolutions to resolve a fractional order"
    ),
    start=_wb_start,
    plausible=_wb_plausible,
    derived=_wb_derived,
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


def _one_speed(ctx) -> float | None:
    """The steady speed (rad/s) when every kept row turns at one |speed|, else ``None``."""
    w = np.abs(np.asarray(ctx.rows["omega"], float))
    w = w[w > 0]
    if w.size and np.ptp(w) <= 0.05 * np.max(w):
        return float(np.median(w))
    return None


def _gain(rw: np.ndarray, X: np.ndarray) -> float:
    """Whitened chi-square that regressors ``X`` (n, q) take out of ``rw`` (n, C)."""
    if X.shape[0] <= X.shape[1]:
        return 0.0
    Q, _ = np.linalg.qr(X)
    return float(np.sum((Q.T @ rw) ** 2))


def _vb_locked_margin(ctx, resid: np.ndarray, f_hz: float) -> tuple[float, float]:
    """``(frequency, margin)``: the line's frequency refined on a grid of +-2 Rayleigh bins
    (the spectrum's peak of a record with excluded stretches, set to zero, can split in two
    and sit a bin off: a frequency fit started there does not find the line), and at one
    speed by how much (whitened chi-square less ``k ln N`` for its parameters) a line fixed
    in time at it beats a rotation-locked error at the nearest integer order (the same phase
    in every run: ``cos m theta, sin m theta`` per channel). A line at a non-integer order
    that the record resolves beats it clearly; a rotation-locked error (any number of turns)
    or a line that the span cannot tell from one (``|order - m| * turns`` small) does not.
    When the base model has order ``m`` the locked error is already fitted, so what the line
    takes out of this residual is all its own (the locked alternative gains nothing).
    ``1e9`` when not at one speed."""
    t = np.asarray(ctx.rows["t"], float)
    th = np.asarray(ctx.rows["theta"], float)
    oh = np.asarray(ctx.rows["run_onehot"], float)
    rw = np.asarray(resid, float).reshape(t.size, -1) / np.asarray(ctx.noise)[None, :]
    rw = rw - oh @ np.linalg.lstsq(oh, rw, rcond=None)[0]  # the run constants are the base's
    T = float(np.max(_run_durations(ctx)))
    if T <= 0:
        return f_hz, 1e9
    N = rw.size
    w = _one_speed(ctx)
    m = round(f_hz / (w / (2 * np.pi))) if w is not None else 0
    in_base = 1 <= m <= int(ctx.consts.get("max_order", 0))
    locked = np.stack([np.cos(m * th), np.sin(m * th)], 1)
    # at one speed near a base order the base's order m is refitted with the line (as the
    # engine's trial fit does): the line's gain is over it (the base residual alone shows
    # the line less the base's share of it, split around a reversal)
    g0 = _gain(rw, locked) if in_base else 0.0
    best = (-math.inf, f_hz)
    for f in f_hz + np.linspace(-2.0, 2.0, 41) / T:
        c, s_ = np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)
        X = np.concatenate([c[:, None] * oh, s_[:, None] * oh], 1)
        g = _gain(rw, np.concatenate([X, locked], 1)) - g0 if in_base else _gain(rw, X)
        best = max(best, (g, float(f)))
    g_vib, f_best = best
    if w is None or m < 1:
        return f_best, 1e9
    k_vib = 2 * oh.shape[1] * rw.shape[1]
    k_lock = 2 * rw.shape[1]
    if in_base:
        g_lock = 0.0  # in the base model: what the line takes beyond it is its own
    else:
        g_lock = _gain(rw, locked)
    margin = (g_vib - k_vib * math.log(N)) - (g_lock - k_lock * math.log(N))
    return f_best, float(margin)


def _vb_start(ctx, resid, findings):
    out = []
    for f in findings:
        if f.view == "spectrum" and f.detail.get("fixed_in") != "order":
            fr = [v for v in f.where["frequencies_hz"] if v > 0]
            if fr:
                f0, margin = _vb_locked_margin(ctx, resid, float(np.median(fr)))
                out.append({"frequency_hz": f0, "locked_margin": margin})
    return out[:3]


def _run_durations(ctx: Context) -> np.ndarray:
    oh = ctx.rows["run_onehot"] > 0
    t = ctx.rows["t"]
    return np.array([np.ptp(t[oh[:, r]]) if oh[:, r].any() else 0.0 for r in range(oh.shape[1])])


LOCKED_MARGIN = 10.0
"""Chi-square (less k ln N) by which a line at one speed near an integer order must beat a
rotation-locked error there to be a vibration (the information criterion's BIC_MIN)."""


def _vb_plausible(ctx, v):
    f = float(v["frequency_hz"])
    if f <= 0:
        return "frequency is not positive"
    w = _one_speed(ctx)
    if w is not None:
        order = f / (w / (2 * np.pi))
        res = max(0.02, 1.0 / max(float(np.sum(ctx.revolutions)), 1e-9))
        margin = float(np.asarray(v.get("locked_margin", 0.0)))
        # within the span's resolution of an integer order, the data must show that it is
        # not rotation locked (the line beats the locked order by LOCKED_MARGIN)
        if abs(order - round(order)) < res and round(order) >= 1 and margin < LOCKED_MARGIN:
            return (
                f"at one speed a line at {f:.4g} Hz is shaft order {order:.3f}: a "
                f"rotation-locked error at order {round(order)} fits as well (chi-square "
                f"margin {margin:.1f}, needs {LOCKED_MARGIN:.0f}; two speeds separate them)"
            )
    T = float(np.max(_run_durations(ctx)))
    if f * T < 3.0:
        return (
            f"{f * T:.1f} cycles of {f:.3g} Hz in the longest run: a slow drift or a step "
            "fits as well (needs 3)"
        )
    return None


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
            "in time beats a rotation-locked error at the nearest integer order (held)",
        ),
    ),
    signature=("spectrum",),
    explanation="Relative oscillation of head and scale at a structural frequency "
    "(seed 002): fixed in Hz across runs at different speeds, so its shaft order moves with "
    "speed (reported at its apparent frequency when aliased by the sampling).",
    start=_vb_start,
    plausible=_vb_plausible,
)


def _th_fn(p, x):
    return x["driver"][:, None] * p["rate"][None, :]


def _th_unit(ctx):
    return "rad/K" if ctx.consts.get("driver_name") == "temp_c" else "rad/s"


THERMAL_DRIFT = Candidate(
    "thermal_drift",
    _th_fn,
    (Param("rate", "rad/K (temp_c) or rad/s (no temp_c)", "channels"),),
    signature=("drift", "time"),
    explanation="Expansion of mounts and disk with temperature (seed 001: about 0.7 arcsec/K): "
    "a slow error correlated with temp_c (or time), different between heads.",
)


def _ip_fn(p, x):
    L = jnp.maximum(x["signal_periods"], 1.0)
    return fx.interpolation_harmonics_rad(x["psi"], L, p["coef"])


def _ip_derived(ctx, v, se):
    c = np.asarray(v["coef"])
    L = max(ctx.signal_periods, 1)
    return {
        "offset_a": {"value": c[0].tolist(), "se": None, "unit": "1"},
        "offset_b": {"value": (-c[1]).tolist(), "se": None, "unit": "1"},
        "amplitude_error": {"value": (-2 * c[3]).tolist(), "se": None, "unit": "1"},
        "phase_error_rad": {"value": (-2 * c[2]).tolist(), "se": None, "unit": "rad"},
        "amplitude_1x_rad": {
            "value": (np.hypot(c[0], c[1]) / L).tolist(),
            "se": None,
            "unit": "rad",
        },
        "amplitude_2x_rad": {
            "value": (np.hypot(c[2], c[3]) / L).tolist(),
            "se": None,
            "unit": "rad",
        },
    }


INTERPOLATION_ERROR = Candidate(
    "interpolation_error",
    _ip_fn,
    (Param("coef", "1", (4, 0)),),  # shape fixed per record below
    signature=("line_phase",),
    explanation="Imperfect quadrature signals interpolated by arctangent (seed 002 eq. 4): "
    "offsets, amplitude ratio and phase error give orders L and 2L of the shaft angle "
    "(L signal periods per revolution).",
    applies=lambda ctx: (
        None if ctx.signal_periods > 0 else "needs grating_lines or signal_periods_per_rev"
    ),
    derived=_ip_derived,
)


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
    out = []
    for f in findings:
        if f.view == "time" and "global_step_time_s" in f.detail:
            out.append({"shift_time_s": f.detail["global_step_time_s"]})
    return out[:2]


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
        Param("shift_time_s", "s", "1", linear=False, scale=1e-2),
        Param("shift_x_m", "m", "1"),
        Param("shift_y_m", "m", "1"),
    ),
    signature=("time",),
    explanation="A shock or slip moved the disk on its hub during the record: the order-1 "
    "error of the heads changes at one instant (shift_time_s is on the global time axis, runs "
    "end to end).",
    start=_es_start,
    plausible=_es_plausible,
)


@functools.lru_cache(maxsize=16)
def _interpolation_for(C: int) -> Candidate:
    return dataclasses.replace(INTERPOLATION_ERROR, params=(Param("coef", "1", (4, C)),))


def multihead_candidates(ctx: Context) -> tuple[Candidate, ...]:
    """The catalog candidates of a multihead record (and a sensor's reference terms)."""
    C = ctx.n_channels
    ip = _interpolation_for(C)
    out = [THERMAL_DRIFT, ip, VIBRATION]
    if C > 1 or not ctx.has_ref:
        out += [BEAM_TILT_AXIAL, BEARING_WOBBLE, ECCENTRICITY_SHIFT]
    else:
        out += [BEARING_WOBBLE]
    if ctx.has_ref and C == 1:
        try:
            from . import _reference_terms  # 16b's sensor-against-reference terms
        except ImportError:
            pass
        else:
            out += list(getattr(_reference_terms, "CANDIDATES", ()))
            if ctx.n_runs > 1:  # one set of signal harmonics per run (per-run zeros)
                out.append(_reference_terms.interpolation_candidate(ctx.n_runs))
    return tuple(out)


def multihead_summary(prep: Prepared, base_params: dict) -> dict:
    """For one sensor against a reference: what the record is (span, directions, speeds,
    the sensor's and the reference's value lattices, i.e. quantization) and the dominant
    orders of the sensor's error function (``_reference_terms``)."""
    if not (prep.ctx.has_ref and prep.n_channels == 1):
        return {}
    try:
        from . import _reference_terms as rt
    except ImportError:
        return {}
    kd = prep.kd
    out = {"sensor": rt.reference_summary(kd.t, kd.theta_ref, prep.rows["reading"][:, 0], prep.run)}
    b = base_params.get("base", {})
    if "fourier_cos_rad" in b:
        c, s_ = b["fourier_cos_rad"], b["fourier_sin_rad"]
        out["sensor"]["dominant_orders"] = rt.dominant_orders(
            np.asarray(c["value"], float),
            np.asarray(s_["value"], float),
            np.asarray([np.nan if v is None else v for v in c["se"]], float),
            np.asarray([np.nan if v is None else v for v in s_["se"]], float),
        )
    return out


MULTIHEAD = Kind(
    name="multihead",
    data=multihead_data,
    base=multihead_base,
    candidates=multihead_candidates,
    views=(
        "spectrum",
        "band",
        "orders",
        "time",
        "drift",
        "line_phase",
        "direction",
        "speed",
        "angle_trend",
    ),
    max_order_limit=max_order_limit,
    summary=multihead_summary,
    reading_lattice=True,
)
