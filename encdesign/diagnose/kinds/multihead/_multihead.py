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

Candidates are the multihead catalog effects (terms in :mod:`encdesign.physics._effects`),
plus, for a sensor against a reference, the terms of
:mod:`encdesign.diagnose.kinds.multihead._reference_terms` when that module is present.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import ClassVar, final

import jax.numpy as jnp
import numpy as np

from ...._errors import input_error
from ....io._recording import Recording
from ....physics import _effects as fx
from ...engine import _stepped
from ...engine._candidates import Candidate, Context, Param
from ...engine._kind import AbstractKind
from ...engine._normal import register_factors
from ...engine._prepare import prepare as engine_prepare
from ...engine._protocol import FitDivergence, KindData, KindView, Prepared, steady_tolerance
from ...engine._settings import DEFAULT_SETTINGS, FinderSettings
from ...engine._views import chi2_threshold
from ...engine._views_modulated import view_modulated_orders
from ._confound import own_order_confound, staircase_confound
from ._fourier import base_factors, base_value, fourier_columns, fourier_sum
from ._multihead_probes import (
    BEAM_TILT_AXIAL,
    BEAM_TILT_AXIAL_NO_REF,
    BEARING_WOBBLE,
    ECCENTRICITY_SHIFT,
)
from ._multihead_terms import INTERPOLATION_ERROR, THERMAL_DRIFT, VIBRATION, view_order_step
from ._run_align import low_order_phases, run_offsets_start
from ._symmetry import _symmetric_orders


def make_where(rec: Recording) -> str:
    return str(rec.path) if rec.path is not None else "recording"


@dataclasses.dataclass(kw_only=True)
class MultiheadData(KindData):
    """:class:`~encdesign.diagnose.engine._protocol.KindData` of a multihead record.

    Attributes:
        stepped: a sensor against a reference recorded step by step (no steady motion;
            issue 22 item 5): its ``segments`` are one per run and approach direction
            (:func:`stepped_segments`), its dynamic candidates not testable and its summary
            says so.
    """

    stepped: bool = False


def multihead_data(rec: Recording, settings: FinderSettings = DEFAULT_SETTINGS) -> MultiheadData:
    """Observations of a multihead recording (head readings less the reference angle); a
    sensor against a reference recorded step by step gets its segments here
    (:func:`stepped_segments`)."""
    where = make_where(rec)
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
    kd = MultiheadData(
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
    seg = stepped_segments(kd, settings)
    return kd if seg is None else dataclasses.replace(kd, segments=seg, stepped=True)


def stepped_segments(kd: KindData, settings: FinderSettings) -> np.ndarray | None:
    """Issue 22 item 5: a sensor against a reference recorded step by step (no steady
    motion) gets one segment per run and approach direction instead of being refused: those
    segments, or ``None`` (not a stepped record)."""
    if (
        kd.y.shape[1] == 1
        and kd.theta_ref is not None
        and _stepped.is_stepped(
            kd.shaft, kd.t, kd.run, steady_tolerance(kd, settings), kd.speed_window, settings
        )
    ):
        return _stepped.stepped_segments(kd.shaft, kd.t, kd.run)
    return None


def _is_stepped(kd: KindData) -> bool:
    return isinstance(kd, MultiheadData) and kd.stepped


COVERAGE_ORDER_MAX = 48
"""Orders the coverage test looks at (the engine's default base order and its scan of the
residual stay below this)."""

COVERAGE_ROWS = 200_000
"""Kept rows (drawn at random, fixed seed) the coverage moments are summed over."""


def coverage_limit(
    theta: np.ndarray, run: np.ndarray, n_runs: int, m_max: int, *, coverage_min: float
) -> int:
    """Highest order ``M <= m_max`` such that ``cos m theta, sin m theta`` (m = 1..M) and one
    constant per run are well conditioned over the samples (``FinderSettings.coverage_min``).

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
        if lam < coverage_min:
            break
        best = M
    return best


def max_order_limit(prep: Prepared, fraction: float | None = None) -> int:
    """Highest order the record resolves, and ``2 M + constants <= fraction`` of the values
    (default ``settings.max_param_fraction``): below half the samples per revolution of the
    sparsest-sampled run, or higher where the samples of all runs together cover the circle
    well enough that orders 1..M are well conditioned (:func:`coverage_limit`)."""
    keep = prep.keep
    spr = []
    for r in range(prep.ctx.n_runs):
        m = (prep.run == r) & keep
        revs = prep.ctx.revolutions[r]
        if m.sum() > 0 and revs > 0:
            spr.append(m.sum() / revs)
    nyq = int(math.floor(min(spr) / 2.0)) - 1 if spr else 1
    C, R = prep.n_channels, prep.ctx.n_runs
    frac = prep.settings.max_param_fraction if fraction is None else fraction
    budget = int((frac * prep.n_values - R * C - C - R) // 2)
    want = min(budget, COVERAGE_ORDER_MAX)
    if nyq < want:
        idx = np.flatnonzero(keep)
        if idx.size > COVERAGE_ROWS:
            idx = np.sort(np.random.default_rng(0).choice(idx, COVERAGE_ROWS, replace=False))
        th = prep.rows.take("theta", idx) if hasattr(prep.rows, "take") else prep.rows["theta"][idx]
        nyq = max(
            nyq, coverage_limit(th, prep.run[idx], R, want, coverage_min=prep.settings.coverage_min)
        )
    return int(max(1, min(nyq, budget)))


@functools.lru_cache(maxsize=64)
def _base_candidate(
    C: int, R: int, M: int, held: tuple[int, ...] = (), placed: bool = True
) -> Candidate:
    """The base term for C heads, R runs and orders 1..M (one object per shape, so one
    compiled Jacobian serves every record of that shape). The disk orders in ``held`` are
    held at zero (their Jacobian columns are exactly zero, so the fitter lists them as
    undetermined): without ``theta_ref``, orders seen the same at every head (multiples of
    the symmetry of equally spaced heads) cancel in head differences, and a fit of their
    rounding-level columns would give them any size (issue 44 A). Without ``placed`` the
    heads sit at their nominal azimuths (no placements fitted)."""
    live = np.ones(M)
    for m in held:
        if 1 <= m <= M:
            live[m - 1] = 0.0
    mask = jnp.asarray(live)

    def shifted(p, x):
        """Run one-hot, shaft angles with the run offsets, head azimuths with placements."""
        oh = x["run_onehot"]
        th = x["theta_raw"]
        if R > 1:
            th = th + oh[:, 1:] @ p["run_angle_offset_rad"]
        alpha = x["alpha"]
        if C > 1 and placed:
            alpha = alpha + jnp.concatenate([jnp.zeros(1), p["placement_rad"]])
        return oh, th, alpha

    def fn(p, x):
        oh, th, alpha = shifted(p, x)
        e = fx.base_error_rad(
            th,
            alpha,
            p["fourier_cos_rad"] * mask,
            p["fourier_sin_rad"] * mask,
            jnp.zeros_like(alpha),
        )
        return e + oh @ p["offset_rad"]

    def valjac(p, x):
        # d e_k / d theta = sum_m m (b_m cos - a_m sin): the placement d_k moves head k's
        # argument by -d_k, the run offset delta_r every sample of run r by +delta_r
        oh, th, alpha = shifted(p, x)
        a, b = p["fourier_cos_rad"] * mask, p["fourier_sin_rad"] * mask
        m = jnp.arange(1, M + 1, dtype=th.dtype)
        phi = th[:, None] - alpha[None, :]
        cs, sn = fourier_columns(phi, M)  # issue 43: one sine and cosine per angle
        cs, sn = cs * mask, sn * mask
        v = fourier_sum(phi, a, b) + oh @ p["offset_rad"]
        J = {
            "offset_rad": oh[:, None, :, None] * jnp.eye(C, dtype=th.dtype)[None, :, None, :],
            "fourier_cos_rad": cs,
            "fourier_sin_rad": sn,
        }
        slope = jnp.sum(m * (b * cs - a * sn), axis=-1)  # (n, C)
        if C > 1 and placed:
            J["placement_rad"] = -slope[:, :, None] * jnp.eye(C, dtype=th.dtype)[None, :, 1:]
        if R > 1:
            J["run_angle_offset_rad"] = slope[:, :, None] * oh[:, None, 1:]
        return v, J

    params = [
        Param("offset_rad", "rad", "runs*channels", description="constant per run and head"),
        Param("fourier_cos_rad", "rad", (M,), description="disk error, cos of orders 1..M"),
        Param("fourier_sin_rad", "rad", (M,), description="disk error, sin of orders 1..M"),
    ]
    if C > 1 and placed:
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
    cand = Candidate(
        "base",
        fn,
        tuple(params),
        kinds=("multihead",),
        explanation="base model: disk error function, head placements, zeros",
        valjac=valjac,
        value=base_value(shifted, mask),
    )
    register_factors(cand, base_factors(C, R, M, live, placed))  # issue 43: J = X W
    return cand


def _hold_run_offsets(terms, prep: Prepared) -> str | None:
    """After a base fit: a run's fitted angle zero ``delta_r`` that its low orders reject
    is held at their alignment (issue 41). The disk error's low orders (the start's) are
    common to every run and set the runs' alignment; a strong order that is not the same in
    every run (an error of opposite sign in the two directions, an order switching on) pulls
    the fit to ``delta_r = pi / m``, where it flips, and misaligns the whole disk error of that
    run. The test: the chi-square of run ``r``'s low-order coefficients against run 0's,
    rotated by ``delta``, at the fitted ``delta_r`` less its minimum (scaled by the minimum
    per degree of freedom where that exceeds 1: model error, e.g. higher orders leaking into
    a run that is not whole turns) above ``chi2_threshold(settings.alpha, 1, R - 1)``; then
    every run's zero is held at its low orders' alignment. Returns a note (the terms' values
    and free masks changed: the engine refits), or ``None``."""
    R = prep.ctx.n_runs
    base = next((t for t in terms if t.cand.name == "base"), None)
    name = "run_angle_offset_rad"
    if R < 2 or base is None or name not in base.values:
        return None
    M = int(np.asarray(base.values["fourier_cos_rad"]).size)
    Z, V, mm, resolved = low_order_phases(prep, M, M)
    ok = ~np.isin(mm, _symmetric_orders(prep, int(np.max(mm))))  # alike on every head: no phase
    Z, V, mm = [z[ok] for z in Z], [v[ok] for v in V], mm[ok]
    fitted = np.asarray(base.values[name], float).copy()
    thr = chi2_threshold(prep.settings.alpha, 1, R - 1)
    grid = np.linspace(-np.pi, np.pi, 7200, endpoint=False)
    held, low = [], fitted.copy()
    for r in range(1, R):
        if not (resolved[r] and resolved[0]):  # part of a turn: its own orders cannot judge
            continue
        w = 1.0 / np.maximum(V[r] + V[0], 1e-300)

        def chi(d, r=r, w=w):
            e = Z[r][None, :] * np.exp(-1j * mm[None, :] * np.atleast_1d(d)[:, None]) - Z[0]
            return np.sum(np.abs(e) ** 2 * w[None, :], axis=1)

        g = chi(grid)
        i = int(np.argmin(g))
        fine = grid[i] + np.linspace(-1, 1, 201) * (grid[1] - grid[0])
        cf = chi(fine)
        d_min, c_min = float(fine[int(np.argmin(cf))]), float(cf.min())
        scale = max(1.0, c_min / max(2 * mm.size - 1, 1))
        low[r - 1] = d_min
        if float(chi(fitted[r - 1])[0] - c_min) / scale > thr:
            held.append(r)
    if not held:
        return None
    # every run's zero from its low orders: what pulled one run can pull the others
    base.values[name] = low
    base.free[name][...] = False
    return (
        f"the runs' angle zeros held at the alignment of the disk error's low orders "
        f"(1..{mm.size}): the fit had moved run(s) {held} where they reject it (structure "
        "not the same in every run pulled it)"
    )


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
    and the slope of the mean (both 1), as ``(mean, slope, mean_slope)``."""
    R_off = np.concatenate([[0.0], np.asarray(v.get("run_angle_offset_rad", []))])
    pl = np.concatenate([[0.0], np.asarray(v.get("placement_rad", np.zeros(alpha.size - 1)))])
    a, b = np.asarray(v["fourier_cos_rad"]), np.asarray(v["fourier_sin_rad"])
    m = np.arange(1, a.size + 1)
    x = th + R_off[run]
    mean = np.zeros(th.size)
    top = np.zeros(th.size)
    dmean = np.zeros(th.size)
    for k in range(alpha.size):
        arg = m[None, :] * (x[:, None] - alpha[k] - pl[k])
        c, s_ = np.cos(arg), np.sin(arg)
        mean += c @ a + s_ @ b
        if slope:
            d = c @ (m * b) - s_ @ (m * a)
            top = np.maximum(top, np.abs(d))
            dmean += d
    if slope:
        return mean / alpha.size, top, dmean / alpha.size
    return mean / alpha.size


def _refine_shaft(terms, prep: Prepared) -> str | None:
    """Without ``theta_ref`` the shaft angle is the heads' mean reading, which carries the
    mean of the disk error seen by the heads: the model's error evaluated there differs from
    the error at the true angle by about ``e'(theta) * mean_k e_k`` (second order in the disk
    error; it matters for large errors, e.g. magnetic or capacitive heads, and makes
    harmonics no catalog effect has). The angle becomes ``shaft - mean_k e_k(angle)`` (fixed
    point, ``SHAFT_ITERATIONS`` passes, a lazy column computed per chunk) when that moves
    the fitted readings by more than ``FinderSettings.refine_shaft_min_noise`` of the
    noise; returns a note saying so when it did (the caller refits the base), else None.

    The fixed point contracts only where the head mean's slope is below 1: where it
    reaches ``FinderSettings.refine_shaft_max_slope`` anywhere the refinement would diverge
    (the fitted error is not small, or its head mean holds orders the heads cannot
    separate), and :class:`FitDivergence` says so (the angle is left as it was). Orders
    every head sees alike (equally spaced heads) are held out of the head mean: the base
    holds them at zero, since the common rotation they make is unobservable (issue 44 A).
    Where every run covers less than one turn (``Prepared.part_turn_span``) the heads do not
    determine the head mean: the engine keeps the refinement only where the data prefer it
    (``FinderSettings.refine_part_turn_chi2_drop``; issue 44)."""
    if prep.ctx.has_ref or prep.n_channels < 2:
        return None
    base = next((t for t in terms if t.cand.name == "base"), None)
    if base is None:
        return None
    v = {k: np.array(x, float) for k, x in base.values.items()}
    for m in _symmetric_orders(prep, v["fourier_cos_rad"].size):
        v["fourier_cos_rad"][m - 1] = v["fourier_sin_rad"][m - 1] = 0.0
    alpha = np.asarray(prep.consts["alpha"], float)
    shaft, run, keep = prep.kd.shaft, prep.run, prep.keep

    def corrected(lo: int = 0, hi: int | None = None, with_size: bool = False):
        sh, rn = shaft[lo:hi], run[lo:hi]
        corr = np.zeros(sh.size)
        for _ in range(SHAFT_ITERATIONS - 1):
            corr = _head_mean_error(v, alpha, sh - corr, rn)
        if not with_size:
            return sh - _head_mean_error(v, alpha, sh - corr, rn)
        corr, slope, dmean = _head_mean_error(v, alpha, sh - corr, rn, slope=True)
        return sh - corr, slope * corr, dmean

    ss, nk, steep = 0.0, 0, 0.0
    for lo in range(0, shaft.size, 1 << 16):
        hi = min(shaft.size, lo + (1 << 16))
        _, moved, dmean = corrected(lo, hi, True)
        kb = keep[lo:hi]
        ss += float(np.sum(moved[kb] ** 2))
        nk += int(kb.sum())
        if kb.any():
            steep = max(steep, float(np.max(np.abs(dmean[kb]))))
    size = math.sqrt(ss / max(nk, 1))
    limit = prep.settings.refine_shaft_max_slope
    if not (math.isfinite(size) and math.isfinite(steep)) or steep >= limit:
        raise FitDivergence(
            "shaft-angle refinement: the fitted disk error's head mean has slope "
            f"{steep:.3g} (the fixed point contracts only below {limit:g}, "
            "FinderSettings.refine_shaft_max_slope); the angle is left the heads' mean reading"
        )
    if not math.isfinite(size) or size < prep.settings.refine_shaft_min_noise * float(
        np.min(prep.sigma)
    ):
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
    held = _symmetric_orders(prep, M)
    span = prep.part_turn_span  # issue 44: part of a turn, placements not separable
    cand = _base_candidate(C, R, M, tuple(held), span is None)
    start = {}
    if R > 1:
        start["run_angle_offset_rad"] = run_offsets_start(prep, M)
    terms = [(cand, start)]
    if prep.count_jumps:
        terms.append((_jump_candidate(prep), {}))
    if prep.angle_steps:
        terms.append((_angle_step_candidate(prep), {}))
    info: dict = {"unidentifiable": []}
    if not prep.ctx.has_ref:
        bad = _symmetric_orders(prep, M, prep.settings.head_pattern_min)
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
    if span is not None:
        info["unidentifiable"].append(
            f"the disk error's orders 1..{M} one by one"
            + (" and the head placements (held at the nominal azimuths)" if C > 1 else "")
            + f": every run covers {span / (2 * math.pi):.2f} turn or less, where they are "
            "not separable (only the error's sum over the arcs seen is fitted)"
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


def _angle_step_candidate(prep: Prepared) -> Candidate:
    """The error function's steps of the angle (:func:`._nuisances.angle_steps`): per
    channel, a constant on each arc between consecutive step angles but one (the channel's
    constant takes that one)."""
    arcs = []
    for k in sorted({s["channel_index"] for s in prep.angle_steps}):
        a = sorted(s["angle_rad"] for s in prep.angle_steps if s["channel_index"] == k)
        arcs += [(k, a[j], a[j + 1]) for j in range(len(a) - 1)]
    lo = jnp.asarray([x[1] for x in arcs])
    width = jnp.asarray([x[2] - x[1] for x in arcs])
    sel = np.zeros((len(arcs), prep.n_channels))
    sel[np.arange(len(arcs)), [x[0] for x in arcs]] = 1.0
    selj = jnp.asarray(sel)

    def fn(p, x):
        on = jnp.mod(x["theta"][:, None] - lo[None, :], 2 * jnp.pi) < width[None, :]
        return (on.astype(x["theta"].dtype) * p["arc_rad"][None, :]) @ selj

    return Candidate(
        "angle_steps",
        fn,
        (Param("arc_rad", "rad", (len(arcs),), description="error on each arc between steps"),),
        explanation="steps of the error function at fixed angles, recurring on every pass "
        "(a potentiometer's track, a magnet's segment): a property of the angle (nuisance)",
    )


def _ip_valjac(p, x):
    """``interpolation_error``'s value and Jacobian by hand (its ``jacfwd``, 4 x runs x heads
    tangents, was most of the detection bounds' time, issue 43): column ``(q, r, d)`` is
    harmonic ``q`` of ``psi`` on head ``d``'s rows of run ``r`` (tested against ``jacfwd``)."""
    psi, oh = x["psi"], x["run_onehot"]
    (n, C), L = psi.shape, jnp.maximum(x["signal_periods"], 1.0)
    h = jnp.stack([jnp.cos(psi), jnp.sin(psi), jnp.cos(2.0 * psi), jnp.sin(2.0 * psi)], -1) / L
    J = jnp.einsum("ncq,nr,cd->ncqrd", h, oh, jnp.eye(C, dtype=h.dtype))
    return INTERPOLATION_ERROR.fn(p, x), {"coef": J.reshape(n, C, 4, oh.shape[1] * C)}


@functools.lru_cache(maxsize=16)
def _interpolation_for(C: int, R: int) -> Candidate:
    params = (Param("coef", "1", (4, R * C)),)
    return dataclasses.replace(INTERPOLATION_ERROR, params=params, valjac=_ip_valjac)


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
    # issue 22 item 5: no dynamic candidates on a static stepped record
    return _stepped.static_candidates(tuple(out), _is_stepped(ctx.data))


def multihead_summary(prep: Prepared, base_params: dict) -> dict:
    """For one sensor against a reference: what the record is (span, directions, speeds,
    the sensor's and the reference's value lattices, i.e. quantization) and the dominant
    orders of the sensor's error function (``_reference_terms``)."""
    if not (prep.ctx.has_ref and prep.n_channels == 1):
        return {}
    try:
        from . import _reference_data as rt
    except ImportError:
        return {}
    kd = prep.kd
    out = {
        "sensor": rt.reference_summary(
            kd.t, kd.theta_ref, prep.rows["reading"][:, 0], prep.run, settings=prep.settings
        )
    }
    if _is_stepped(kd):  # issue 22 item 5
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


MULTIHEAD_VIEWS = (
    "spectrum",
    "band",
    "orders",
    "time",
    "drift",
    "line_phase",
    "direction",
    "speed",
    "angle_trend",
    KindView(view_order_step, ("order_step",), rows=True),
    KindView(view_modulated_orders, ("modulated_orders",), rows=True),
)
"""The views run on a multihead record's residual."""


@final
class MultiheadKind(AbstractKind):
    """``multihead``: 2-6 heads on one disk, or one sensor against ``theta_ref``."""

    name: ClassVar[str] = "multihead"
    default_max_order: ClassVar[int] = 12
    noise_replaces: ClassVar[bool] = False
    grows_orders: ClassVar[bool] = True
    reading_lattice: ClassVar[bool] = True

    def data(self, rec, settings=DEFAULT_SETTINGS):
        return multihead_data(rec, settings)

    def views(self, prep):
        return MULTIHEAD_VIEWS

    def plots(self, d, folder):
        return []

    def prepare(self, kd, meta, settings):
        return engine_prepare(kd, meta, settings)

    def base(self, prep, max_order):
        return multihead_base(prep, max_order)

    def candidates(self, ctx):
        return multihead_candidates(ctx)

    def max_order_limit(self, prep):
        return max_order_limit(prep)

    def growth_order_limit(self, prep):
        return max_order_limit(prep, prep.settings.growth_param_fraction)

    def noise(self, prep, base_resid):
        return None

    def refine(self, terms, prep):
        return _refine_shaft(terms, prep)

    def check_base(self, terms, prep):
        return _hold_run_offsets(terms, prep)

    def align(self, terms, prep):
        return _align(terms, prep)

    def summary(self, prep, base_params):
        return multihead_summary(prep, base_params)

    def finish(self, prep, doc, settings):
        return staircase_confound(prep, own_order_confound(prep, doc))

    def report_lines(self, doc):
        return ""


MULTIHEAD = MultiheadKind()
