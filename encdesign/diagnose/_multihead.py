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
from . import _stepped
from ._candidates import Candidate, Context, Param
from ._engine import MAX_PARAM_FRACTION, Kind, KindData, Prepared
from ._views import Finding, _logp, _thr, run_spans

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
    kd = KindData(
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
    # issue 22 item 5 (call site): a sensor against a reference recorded step by step (no
    # steady motion) gets one segment per run and approach direction instead of being refused
    if (
        H == 1
        and has_ref
        and _stepped.is_stepped(kd.shaft, kd.t, kd.run, kd.steady_tolerance, kd.speed_window)
    ):
        kd.segments = _stepped.stepped_segments(kd.shaft, kd.t, kd.run)
    return kd


COVERAGE_MIN = 0.05
"""Smallest eigenvalue of the correlation matrix of the base model's columns (orders 1..M
and the run constants, over the kept samples) for which orders 1..M count as resolved: 1 when
the samples cover the circle evenly, 0 when an order aliases exactly onto lower ones."""

COVERAGE_ORDER_MAX = 48
"""Orders the coverage test looks at (the engine's default base order and its scan of the
residual stay below this)."""

COVERAGE_ROWS = 200_000
"""Kept rows (drawn at random, fixed seed) the coverage moments are summed over."""


def coverage_limit(theta: np.ndarray, run: np.ndarray, n_runs: int, m_max: int) -> int:
    """Highest order ``M <= m_max`` such that ``cos m theta, sin m theta`` (m = 1..M) and one
    constant per run are well conditioned over the samples (``COVERAGE_MIN``).

    Many revolutions sampled at a rate that is not a whole number of samples per
    revolution fill the circle although each revolution has few samples: orders far above
    the per-revolution Nyquist limit are then resolved (and a disk's error has them).
    ``theta`` (rad) and ``run`` are the kept rows. From the moments
    ``mu_{r,k} = sum_{rows of run r} exp(i k theta)`` for ``k <= 2 m_max``."""
    n = theta.size
    if n < 4 or m_max < 1:
        return 0
    K = 2 * m_max
    k = np.arange(K + 1)
    mu = np.zeros((n_runs, K + 1), complex)
    for a in range(0, n, 1 << 14):
        z = np.exp(1j * theta[a : a + (1 << 14), None] * k[None, :])
        np.add.at(mu, run[a : a + (1 << 14)], z)
    w = mu[:, 0].real
    tot = mu.sum(0) / n
    best = 0
    for M in range(1, m_max + 1):
        m = np.arange(1, M + 1)
        d = m[:, None] - m[None, :]
        s_ = m[:, None] + m[None, :]
        mu_d = tot[np.abs(d)]
        mu_d = np.where(d < 0, np.conj(mu_d), mu_d)
        mu_s = tot[s_]
        cc = 0.5 * (mu_d.real + mu_s.real)
        ss = 0.5 * (mu_d.real - mu_s.real)
        cs = 0.5 * (mu_s.imag - mu_d.imag)
        live = w > 0
        wr = w[live] / n
        c0 = (mu[live][:, m] / n).real  # (runs, M): sum over the run of cos m theta / n
        s0 = (mu[live][:, m] / n).imag
        G = np.block(
            [
                [np.diag(wr), c0, s0],
                [c0.T, cc, cs],
                [s0.T, cs.T, ss],
            ]
        )
        dg = np.sqrt(np.maximum(np.diag(G), 1e-300))
        lam = float(np.linalg.eigvalsh(G / dg[:, None] / dg[None, :])[0])
        if lam < COVERAGE_MIN:
            break
        best = M
    return best


def max_order_limit(prep: Prepared) -> int:
    """Highest order the record resolves, and ``2 M + constants <= MAX_PARAM_FRACTION`` of
    the values: below half the samples per revolution of the sparsest-sampled run, or higher
    where the samples of all runs together cover the circle well enough that orders 1..M
    are well conditioned (:func:`coverage_limit`)."""
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
    want = min(budget, COVERAGE_ORDER_MAX)
    if nyq < want:
        idx = np.flatnonzero(keep)
        if idx.size > COVERAGE_ROWS:
            idx = np.sort(np.random.default_rng(0).choice(idx, COVERAGE_ROWS, replace=False))
        th = prep.rows.take("theta", idx) if hasattr(prep.rows, "take") else prep.rows["theta"][idx]
        nyq = max(nyq, coverage_limit(th, prep.run[idx], R, want))
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
    rows, run = prep.rows, prep.run

    def theta(lo: int = 0, hi: int | None = None) -> np.ndarray:
        return rows.column("theta_raw", lo, hi) + d[run[lo:hi]]

    return theta


SHAFT_ITERATIONS = 3
"""Fixed-point passes of the shaft angle without ``theta_ref`` (each one order of the disk
error's size smaller)."""


def _head_mean_error(
    v: dict, alpha: np.ndarray, th: np.ndarray, run: np.ndarray, slope: bool = False
):
    """The base model's disk error averaged over the heads at shaft angle ``th`` (rad),
    from the base term's values ``v``; with ``slope``, also its largest slope over the heads
    (1), as ``(mean, slope)``."""
    R_off = np.concatenate([[0.0], np.asarray(v.get("run_angle_offset_rad", []))])
    pl = np.concatenate([[0.0], np.asarray(v.get("placement_rad", []))])
    a, b = np.asarray(v["fourier_cos_rad"]), np.asarray(v["fourier_sin_rad"])
    m = np.arange(1, a.size + 1)
    x = th + R_off[run]
    mean = np.zeros(th.size)
    top = np.zeros(th.size)
    for k in range(alpha.size):
        arg = m[None, :] * (x[:, None] - alpha[k] - pl[k])
        c, s_ = np.cos(arg), np.sin(arg)
        mean += c @ a + s_ @ b
        if slope:
            top = np.maximum(top, np.abs(c @ (m * b) - s_ @ (m * a)))
    return (mean / alpha.size, top) if slope else mean / alpha.size


def _refine_shaft(terms, prep: Prepared) -> str | None:
    """Without ``theta_ref`` the shaft angle is the heads' mean reading, which carries the
    mean of the disk error seen by the heads: the model's error evaluated there differs from
    the error at the true angle by about ``e'(theta) * mean_k e_k`` (second order in the disk
    error; it matters for large errors, e.g. magnetic or capacitive heads, and makes
    harmonics no catalog effect has). The angle becomes ``shaft - mean_k e_k(angle)`` (fixed
    point, ``SHAFT_ITERATIONS`` passes, a lazy column computed per chunk) when that moves
    the fitted readings by more than a tenth of the noise; returns a note saying so when it
    did (the caller refits the base), else None."""
    if prep.ctx.has_ref or prep.n_channels < 2:
        return None
    base = next((t for t in terms if t.cand.name == "base"), None)
    if base is None:
        return None
    v = {k: np.array(x, float) for k, x in base.values.items()}
    alpha = np.asarray(prep.consts["alpha"], float)
    shaft, run, keep = prep.kd.shaft, prep.run, prep.keep

    def corrected(lo: int = 0, hi: int | None = None, with_size: bool = False):
        sh, rn = shaft[lo:hi], run[lo:hi]
        corr = np.zeros(sh.size)
        for _ in range(SHAFT_ITERATIONS - 1):
            corr = _head_mean_error(v, alpha, sh - corr, rn)
        if not with_size:
            return sh - _head_mean_error(v, alpha, sh - corr, rn)
        corr, slope = _head_mean_error(v, alpha, sh - corr, rn, slope=True)
        return sh - corr, slope * corr

    ss, nk = 0.0, 0
    for lo in range(0, shaft.size, 1 << 16):
        hi = min(shaft.size, lo + (1 << 16))
        _, moved = corrected(lo, hi, True)
        kb = keep[lo:hi]
        ss += float(np.sum(moved[kb] ** 2))
        nk += int(kb.sum())
    size = math.sqrt(ss / max(nk, 1))
    if not math.isfinite(size) or size < 0.1 * float(np.min(prep.sigma)):
        return None
    prep.rows.set_lazy("theta_raw", corrected)
    return (
        "shaft angle: the heads' mean reading less the fitted disk error's head mean "
        f"(it moved the fitted readings by {size:.3g} rad RMS, second order in the disk error)"
    )


def multihead_base(prep: Prepared, M: int):
    """Base terms (with starts) and the report info for a multihead record."""
    C, R = prep.n_channels, prep.ctx.n_runs
    if "theta_raw" not in prep.rows:  # the angle before alignment (never changed in place)
        prep.rows["theta_raw"] = prep.rows["theta"]
    # issue 22 item 5 (call site): a stepped record (segments given by multihead_data) is
    # static; the flag is read by multihead_candidates and multihead_summary
    prep.consts["stepped"] = prep.kd.segments is not None  # type: ignore[index]
    cand = _base_candidate(C, R, M)
    start = {}
    if R > 1:
        start["run_angle_offset_rad"] = _run_offsets_start(prep, M)
    terms = [(cand, start)]
    if prep.count_jumps:
        terms.append((_jump_candidate(prep), {}))
    info: dict = {"align": _align, "refine": _refine_shaft, "unidentifiable": []}
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


def _bt_basis(alpha, m: float, project: bool):
    """Orthonormal head vectors (complex, (q, C)) of what the base model spans at order ``m``:
    the disk error every head sees phase-shifted by its azimuth, ``u_k = exp(-i m alpha_k)``,
    and without theta_ref also the common mode (the head mean is projected out)."""
    C = alpha.shape[0]
    u = jnp.exp(-1j * m * alpha)
    if not project:
        return (u / jnp.sqrt(C))[None, :]
    q1 = jnp.ones(C, complex) / jnp.sqrt(C)
    v = u - q1 * jnp.vdot(q1, u)
    nv = jnp.sqrt(jnp.sum(jnp.abs(v) ** 2))
    # at a multiple of the head symmetry u is the common mode itself: one vector only
    q2 = jnp.where(nv > 1e-6 * jnp.sqrt(C), v / jnp.maximum(nv, 1e-300), 0.0)
    return jnp.stack([q1, q2])


def _bt_head_specific(alpha, coefs, project: bool):
    """Per runout order: the complex head coefficients ``z_k = c_k - i s_k`` less their part
    in the base model's span (what the disk error, or the head mean, would take)."""
    out = []
    for j, m in enumerate(RUNOUT_ORDERS):
        c, s_ = coefs[j]
        w = c - 1j * s_
        Q = _bt_basis(alpha, m, project)
        out.append(w - Q.T @ (jnp.conj(Q) @ w))
    return out


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
    )


def _bt_start(ctx: Context, resid: np.ndarray, findings) -> list[dict]:
    """The runout orders (1-3) the rotation-locked orders view located (else the spectrum's
    lines within 0.02 of an integer order), with at least a tenth of the strongest one's
    power (a strong order leaks a little into its neighbours over a few turns); all three
    when none is."""

    def located(views, tol):
        pw = np.zeros(3)
        for f in findings:
            if f.view in views and (f.view == "orders" or f.detail.get("integer_order")):
                for o in f.where["orders"]:
                    if np.isfinite(o) and round(o) in (1, 2, 3) and abs(o - round(o)) < tol:
                        j = int(round(o)) - 1
                        pw[j] = max(pw[j], f.power - f.dof)
        return (pw > 0) & (pw >= 0.1 * pw.max())

    on = located(("orders",), 0.5)
    if not on.any():
        on = located(("spectrum",), 0.02)
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
            "value": [int(m) for m, o in zip(RUNOUT_ORDERS, on) if o],
            "se": None,
            "unit": "1",
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
)


ORDER_STEP_BINS = 2048
"""Change points the ``order_step`` view scans (bin edges over the kept rows; the best one
is refined to the row)."""


def _order_step_sums(prep: Prepared, rw: np.ndarray, idx: np.ndarray, P: int):
    """Per kept row ``idx``: the whitened eccentricity columns ``X`` (rows, C, 2) (order 1 of
    the disk error as every head sees it: ``sin, cos (theta - alpha_k)``), and the sums a
    step in them needs: ``X^T r`` (rows, 2), ``X^T X`` (rows, 2, 2), ``X^T B`` (rows, 2, P)
    and ``B^T B``, ``B^T r`` with ``B`` the base columns a step must be told from (one
    constant per run and head, and order 1 over the whole record)."""
    C, R = prep.n_channels, prep.ctx.n_runs
    th = np.asarray(prep.rows.take("theta", idx), float)
    d = th[:, None] - np.asarray(prep.consts["alpha"], float)[None, :]
    X = np.stack([np.sin(d), np.cos(d)], 2)  # (n, C, 2)
    B = np.zeros((idx.size, C, P))
    run = prep.run[idx]
    for k in range(C):
        B[np.arange(idx.size), k, run * C + k] = 1.0
    B[:, :, R * C :] = X
    if prep.kd.project:  # without theta_ref the head mean is projected out (data and terms)
        X = X - X.mean(1, keepdims=True)
        B = B - B.mean(1, keepdims=True)
    w = 1.0 / np.asarray(prep.sigma, float)[None, :, None]
    X, B = X * w, B * w
    r = rw[idx]
    return (
        X,
        np.einsum("nck,nc->nk", X, r),
        np.einsum("nck,ncl->nkl", X, X),
        np.einsum("nck,ncp->nkp", X, B),
        np.einsum("ncp,ncq->pq", B, B),
        np.einsum("ncp,nc->p", B, r),
    )


def _step_gain(Sa, SG, SXB, BBi, Br):
    """Whitened chi-square (2 dof) a step in the eccentricity columns takes out, given the
    suffix sums from the step on (arrays over candidate change points), the base columns
    projected out."""
    g = Sa - SXB @ (BBi @ Br)
    Gp = SG - SXB @ BBi @ np.swapaxes(SXB, -1, -2)
    det = Gp[..., 0, 0] * Gp[..., 1, 1] - Gp[..., 0, 1] * Gp[..., 1, 0]
    tr = Gp[..., 0, 0] + Gp[..., 1, 1]
    ok = det > 1e-9 * np.maximum(tr, 1e-300) ** 2
    det = np.where(ok, det, 1.0)
    q = (
        g[..., 0] ** 2 * Gp[..., 1, 1]
        - 2 * g[..., 0] * g[..., 1] * Gp[..., 0, 1]
        + g[..., 1] ** 2 * Gp[..., 0, 0]
    ) / det
    return np.where(ok, np.maximum(q, 0.0), 0.0)


def view_order_step(prep: Prepared, rw: np.ndarray, scan_order: int) -> list[Finding]:
    """A change at one instant of the disk's order-1 error (the disk moved on its hub): the
    step ``H(tau - t_s)`` times the eccentricity columns every head sees, ``sin, cos(theta -
    alpha_k)`` (so one displacement, phase shifted by the head angle), with the base model's
    constant order 1 and run constants projected out, scanned over the change time on the
    global time axis (runs end to end). Its block means average out over each turn, so the
    ``time`` view does not see it; a line fitted to it is a detuned order 1. Chi-square with
    2 dof at the best change point, Bonferroni over the change points scanned."""
    keep = prep.keep
    kidx = np.flatnonzero(keep)
    C, R = prep.n_channels, prep.ctx.n_runs
    if C == 1 and prep.ctx.has_ref:  # a sensor against a reference: no disk on a hub
        return []
    if kidx.size < 64 or float(np.sum(prep.ctx.revolutions)) < 1.0:
        return []
    P = R * C + 2
    nb = int(min(ORDER_STEP_BINS, kidx.size // 8))
    edges = np.linspace(0, kidx.size, nb + 1).astype(int)
    a = np.zeros((nb, 2))
    G = np.zeros((nb, 2, 2))
    XB = np.zeros((nb, 2, P))
    BB = np.zeros((P, P))
    Br = np.zeros(P)
    pos_bin = np.repeat(np.arange(nb), np.diff(edges))
    step = 1 << 14
    for lo in range(0, kidx.size, step):
        hi = min(kidx.size, lo + step)
        _, ai, Gi, XBi, BBc, Brc = _order_step_sums(prep, rw, kidx[lo:hi], P)
        # the kept rows are in time order, so a chunk's bins are contiguous and ascending
        bi = pos_bin[lo:hi]
        st = np.flatnonzero(np.r_[True, bi[1:] != bi[:-1]])
        a[bi[st]] += np.add.reduceat(ai, st, axis=0)
        G[bi[st]] += np.add.reduceat(Gi, st, axis=0)
        XB[bi[st]] += np.add.reduceat(XBi, st, axis=0)
        BB += BBc
        Br += Brc
    BBi = np.linalg.pinv(BB)

    def suffix(x):
        return np.cumsum(x[::-1], 0)[::-1]

    Sa, SG, SXB = suffix(a), suffix(G), suffix(XB)
    # change points at bin edges 1..nb-1, with at least 1 % of the kept rows either side
    e = np.arange(1, nb)
    margin = max(10, kidx.size // 100)
    e = e[(edges[e] >= margin) & (kidx.size - edges[e] >= margin)]
    if e.size == 0:
        return []
    gain = _step_gain(Sa[e], SG[e], SXB[e], BBi, Br)
    j = int(np.argmax(gain))
    chi = float(gain[j])
    n_tests = int(e.size)
    if chi <= _thr(2, n_tests):
        return []
    # refine to the row: the rows of the bins either side of the best edge
    eb = int(e[j])
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
            _logp(chi, 2),
            detail=detail,
        )
    ]


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
        Param("shift_time_s", "s", "1", linear=False, scale=1e-2),
        Param("shift_x_m", "m", "1"),
        Param("shift_y_m", "m", "1"),
    ),
    signature=("order_step", "time"),
    explanation="A shock or slip moved the disk on its hub during the record: the order-1 "
    "error of the heads changes at one instant (shift_time_s is on the global time axis, runs "
    "end to end).",
    start=_es_start,
    plausible=_es_plausible,
)


@functools.lru_cache(maxsize=16)
def _interpolation_for(C: int, R: int) -> Candidate:
    return dataclasses.replace(INTERPOLATION_ERROR, params=(Param("coef", "1", (4, R * C)),))


def multihead_candidates(ctx: Context) -> tuple[Candidate, ...]:
    """The catalog candidates of a multihead record (and a sensor's reference terms)."""
    C = ctx.n_channels
    ip = _interpolation_for(C, ctx.n_runs)
    out = [THERMAL_DRIFT, ip, VIBRATION]
    if C > 1 or not ctx.has_ref:
        bt = BEAM_TILT_AXIAL if ctx.has_ref else BEAM_TILT_AXIAL_NO_REF
        out += [bt, BEARING_WOBBLE, ECCENTRICITY_SHIFT]
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
    # issue 22 item 5 (call site): no dynamic candidates on a static stepped record
    return _stepped.static_candidates(tuple(out), bool(ctx.consts.get("stepped", False)))


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
    if prep.consts.get("stepped", False):  # issue 22 item 5 (call site)
        out["sensor"]["record_type"] = "static stepped calibration (" + _stepped.STATIC_REASON + ")"
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
        view_order_step,
    ),
    max_order_limit=max_order_limit,
    summary=multihead_summary,
    grows_orders=True,
    reading_lattice=True,
)
