"""Quadrature kind for the engine: the two raw signals of one head or interferometer.

Geometry. Each sample is a point ``(sa, sb)``; its measured phase is
``psi = atan2(sb, sa)`` and its radius ``r = hypot(sa, sb)``. Without a position reference
only the *shape* of the Lissajous figure is observable (any re-parametrisation of the
signal phase draws the same figure), so the observation is the radius along each sample's
own ray, as a function of ``psi``, relative to the mean radius ``A0`` (dimensionless; for
small errors it equals the phase error scale in rad).

Base model (``docs/effects.md``, "Quadrature signals"; seed 002 eq. 1 and Heydemann's
correction): an ellipse ``sa = p + a cos phi``, ``sb = q + b sin(phi + alpha)`` (offsets
``p, q``, amplitudes ``a, b``, phase error ``alpha``), whose radius along the ray at ``psi``
has a closed form (:func:`ray_radius`). Its five parameters are fitted by the engine
(Levenberg-Marquardt) from the algebraic conic fit (:func:`ellipse_start`, plain Heydemann).
To first order the ellipse is the radial orders 0, 1 and 2 of the phase (``A``; offsets:
order 1; amplitude mismatch and phase error: order 2).

Candidate ``signal_shape`` (seed 002 eq. 1 with signals that are not pure sinusoids): the
radial Fourier orders ``3 .. max_order`` of ``psi``. A signal harmonic ``h`` of relative
amplitude ``c`` moves the radius at orders ``h - 1`` and ``h + 1``; when both channels have
the same shape a quarter period apart, the odd harmonics ``4k - 1`` and ``4k + 1`` both land
on radial order ``4k`` only (``|z| = |1 + c e^{-i 4k phi}|``) and even harmonics ``h`` on the
odd orders ``h +- 1``; orders ``4k + 2`` need shapes that differ between the channels. Which
of the two harmonics made an order, and so the interpolation (phase) error, is not
observable from the figure alone: the report says so and gives the error for one dominant
harmonic (equal to the radial amplitude).

Candidate ``vibration`` is not testable here: the radius of the figure does not depend on
the motion, so a vibration shows only in the interpolated position, which needs a reference.

Nuisances (engine): rows with ``t`` are prepared as a motion of the unwrapped phase (gaps,
reversals, dwells excluded and reported); a capture without ``t`` is put in phase order
(``t`` = row index in that order, one segment). Signal clipping (:func:`detect_clipping`)
is left out of every fit through the engine's ``masked`` rows and reported as unexplained.
Held-out proof: the engine's K randomised blocked folds (phase sectors for a phase-sorted
capture, time blocks otherwise).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any, ClassVar, final

import jax.numpy as jnp
import numpy as np

from ...._errors import input_error
from ....io._recording import Recording
from ...engine._candidates import Candidate, Context, Param, Probe
from ...engine._kind import AbstractKind
from ...engine._prepare import prepare as engine_prepare
from ...engine._protocol import KindData, NoiseEstimate, Prepared, drive_channel
from ...engine._settings import DEFAULT_SETTINGS, FinderSettings

ELLIPSE_NAMES = ("offset_a", "offset_b", "amplitude_a", "amplitude_b", "phase_error_rad")

EXPLANATIONS = {
    "signal_shape": (
        "The signals are not pure sinusoids (grating duty cycle, detector geometry, "
        "non-linear detectors): their harmonics bend the Lissajous figure in a way no ellipse "
        "can follow, leaving radial structure, and an interpolation error, at orders of the "
        "signal period beyond the 1st and 2nd."
    ),
    "vibration": (
        "A vibration moves the scale against the head: it shows in the interpolated position "
        "(sidebands around the excitation), not in the shape of the Lissajous figure."
    ),
}


def ellipse_start(sa: np.ndarray, sb: np.ndarray) -> np.ndarray:
    """Linear least-squares conic fit (plain Heydemann), as ``[p, q, a, b, alpha]``
    (signal units, rad): the starting point of the fit.

    Raises:
        ValueError: the points do not lie near an ellipse (a degenerate conic).
    """
    # centred and scaled first (raw detector signals may sit far from the origin)
    ma, mb = float(np.mean(sa)), float(np.mean(sb))
    sc = float(np.sqrt(np.var(sa) + np.var(sb)))
    if not sc > 0:
        raise ValueError("the signals do not vary")
    x, y = (sa - ma) / sc, (sb - mb) / sc
    X = np.column_stack([x**2, y**2, x * y, x, y])
    A, B, C, D, E = np.linalg.lstsq(X, np.ones_like(x), rcond=None)[0]
    den = 4 * A * B - C**2
    if not (den > 0 and A > 0 and B > 0):
        raise ValueError("the signals do not draw an ellipse")
    p = (C * E - 2 * B * D) / den
    q = (C * D - 2 * A * E) / den
    k = 1 + A * p**2 + B * q**2 + C * p * q
    # sa = p + a cos phi, sb = q + b sin(phi + alpha): u^2/a^2 + v^2/b^2 - 2uv sin(alpha)/(ab)
    # = cos^2(alpha)
    a = math.sqrt(k / A / (1 - C**2 / (4 * A * B)))
    b = math.sqrt(k / B / (1 - C**2 / (4 * A * B)))
    alpha = math.asin(float(np.clip(-C / (2 * math.sqrt(A * B)), -1.0, 1.0)))
    return np.array([ma + sc * p, mb + sc * q, sc * a, sc * b, alpha])


def ray_radius(p, q, a, b, alpha, psi):
    """Radius of the ellipse ``sa = p + a cos phi, sb = q + b sin(phi + alpha)`` along the
    ray from the origin at angle ``psi`` (closed form; the origin must lie inside).

    With the ray point ``s (cos psi, sin psi)``: ``u = (sa - p)/a = cos phi`` and
    ``w = ((sb - q)/b - u sin alpha)/cos alpha = sin phi`` are linear in ``s``, and
    ``u^2 + w^2 = 1`` is a quadratic whose positive root is the radius. Works on numpy
    and JAX arrays (differentiable)."""
    xp = jnp if isinstance(psi, jnp.ndarray) or hasattr(psi, "aval") else np
    c, s = xp.cos(psi), xp.sin(psi)
    sn, cs = xp.sin(alpha), xp.cos(alpha)
    u1, u0 = c / a, -p / a
    w1 = (s / b - u1 * sn) / cs
    w0 = (-q / b - u0 * sn) / cs
    qa = u1**2 + w1**2
    qb = u1 * u0 + w1 * w0
    qc = u0**2 + w0**2 - 1.0
    return (-qb + xp.sqrt(xp.maximum(qb**2 - qa * qc, 0.0))) / qa


def detect_clipping(
    sa: np.ndarray,
    sb: np.ndarray,
    ellipse: np.ndarray,
    *,
    settings: FinderSettings = DEFAULT_SETTINGS,
) -> dict:
    """Find signals stuck at a level the fitted ellipse would exceed (saturation).

    A channel extreme is called clipped when more than ``settings.clip_excess_ratio`` times
    the samples a sinusoid would put within ``settings.clip_band`` (relative to the
    amplitude) of its peak sit at the observed extreme, and the ellipse fitted to all samples
    reaches more than ``settings.clip_beyond_share`` of the amplitude beyond it. The level
    tried is the extreme, then (where that fails) the value with fewer samples beyond it
    than a clipped level must hold: a glitch beyond a clipped level does not hide it. A
    clipped level hides the arc about the peak, even about it, so each side of the peak (the
    other signal above or below its centre) must hold half the samples a clipped level
    needs: samples of one phase bunch at a level wherever the phase dwells (a reversal; a
    sampling rate locked to the signal period puts a sample at the same phase every period;
    session 39, training ``sensor,quadrature`` seed 6753 record 18: 110 samples at one phase,
    102-103 deg, 13 deg from the peak, read as clipping). Returns
    ``mask`` (samples at a clipped level), ``channels`` (one dict per clipped channel
    extreme) and ``phase_deg`` (the phases where clipping happens).
    """
    p, q, a, b, _ = ellipse
    mask = np.zeros(sa.size, dtype=bool)
    channels = []
    band = settings.clip_band
    expected = sa.size * math.sqrt(2 * band) / math.pi
    need = settings.clip_excess_ratio * expected
    # fewer samples than a clipped level must hold may lie beyond it (glitches added after
    # the clipping, training seed 6678: one sample 0.1 below a floor of 483 clipped samples
    # hid it, whose flat segment was then fitted as signal_shape)
    k = int(min(max(math.floor(need), 0), sa.size - 1))
    for name, s, centre, amp, other, mid in (("sa", sa, p, a, sb, q), ("sb", sb, q, b, sa, p)):
        srt = np.sort(s)
        for sign in (1.0, -1.0):
            model_extreme = centre + sign * amp
            for level in dict.fromkeys((srt[-1], srt[-1 - k]) if sign > 0 else (srt[0], srt[k])):
                at = np.abs(s - level) < band * amp
                beyond = sign * (model_extreme - level)
                # and the level hides the arc about the peak, which is even about it: each
                # side (the other signal above or below its centre) holds half of it
                side = min(np.sum(other[at] > mid), np.sum(other[at] < mid))
                if side > need / 2 and beyond > settings.clip_beyond_share * amp:
                    break
            else:
                continue
            mask |= at
            channels.append(
                {
                    "channel": name,
                    "level": float(level),
                    "samples": int(at.sum()),
                    "model_extreme": float(model_extreme),
                }
            )
    phases = np.degrees(np.arctan2(sb[mask], sa[mask]))
    centres = sorted({float(45 * round(float(x) / 45)) for x in phases}) if mask.any() else []
    return {"mask": mask, "channels": channels, "phase_deg": centres}


# ----------------------------------------------------------------------------- kind data


def _signals(rec: Recording) -> tuple[np.ndarray, np.ndarray, str]:
    where = str(rec.path) if rec.path is not None else "recording"
    sa = np.asarray(rec.columns["sa"], float)
    sb = np.asarray(rec.columns["sb"], float)
    return sa, sb, where


def quadrature_start(rec: Recording, settings: FinderSettings = DEFAULT_SETTINGS) -> dict[str, Any]:
    """Checks, the conic start, clipping and the centred radius of a quadrature recording.

    The rays start at the centre ``(p0, q0)`` of the conic fitted to the unclipped samples
    (raw detector signals may sit on large DC levels), so ``psi`` and ``r`` are measured
    about it and the base model's offsets are corrections to it.

    Raises:
        EncdesignInputError: the signals do not draw an ellipse that covers a signal period.
    """
    sa, sb, where = _signals(rec)
    bad = "the signals do not draw a Lissajous ellipse"
    if sa.size < 32 or np.ptp(sa) <= 0 or np.ptp(sb) <= 0:
        raise input_error(f"{where}: columns sa, sb", bad, "sa, sb covering a signal period")
    try:
        e_all = ellipse_start(sa, sb)
        clip = detect_clipping(sa, sb, e_all, settings=settings)
        keep = ~clip["mask"]
        e1 = ellipse_start(sa[keep], sb[keep]) if keep.sum() >= 32 else e_all
    except ValueError as ex:
        raise input_error(f"{where}: columns sa, sb", f"{bad} ({ex})", "an ellipse") from ex
    centre = (float(e1[0]), float(e1[1]))
    xa, xb = sa - centre[0], sb - centre[1]
    psi = np.arctan2(xb, xa)
    r = np.hypot(xa, xb)
    cover = np.unique(np.floor((psi + np.pi) / (2 * np.pi) * 16))
    s = settings
    if (
        abs(e1[4]) >= s.quad_phase_error_max_rad
        or cover.size < s.quad_sectors_min
        or np.std(r[keep]) > s.quad_radius_spread_max * np.mean(r[keep])
    ):
        raise input_error(
            f"{where}: columns sa, sb",
            f"{bad} (phase error {e1[4]:.3g} rad, {cover.size} of 16 phase sectors covered, "
            f"radius spread {np.std(r[keep]) / max(np.mean(r[keep]), 1e-300):.2f})",
            "two signals in quadrature over at least 3/4 of a signal period",
        )
    e0 = np.array([0.0, 0.0, e1[2], e1[3], e1[4]])
    a0 = float(0.5 * (e1[2] + e1[3]))
    r0 = ray_radius(*e0, psi)
    m = clip["mask"]
    clip_rms = float(np.sqrt(np.mean(((r[m] - r0[m]) / a0) ** 2))) if m.any() else 0.0
    return dict(
        sa=sa,
        sb=sb,
        psi=psi,
        r=r,
        centre=centre,
        e0=e0,
        a0=a0,
        r0=r0,
        clip=clip,
        clip_rms=clip_rms,
        where=where,
    )


@dataclasses.dataclass(kw_only=True)
class QuadratureData(KindData):
    """:class:`~encdesign.diagnose.engine._protocol.KindData` plus the record's conic start.

    Attributes:
        start: :func:`quadrature_start` of the recording, with ``has_t`` (whether it has a
            ``t`` column).
    """

    start: dict[str, Any]


def quadrature_data(rec: Recording, st: dict[str, Any] | None = None) -> QuadratureData:
    """Observations: the relative radius less the conic-fit ellipse's, ``(r - R0(psi))/A0``.

    With ``t``: rows in time order, the unwrapped phase is the 'shaft' (segments where the
    signal phase does not advance steadily are excluded). Without ``t``: rows in phase
    order, ``t`` = row index in that order, one segment. ``st``: :func:`quadrature_start`
    of ``rec`` (computed when not given)."""
    if st is None:
        st = quadrature_start(rec)
        st["has_t"] = "t" in rec.columns
    psi = st["psi"]
    y = ((st["r"] - st["r0"]) / st["a0"])[:, None]
    run = np.asarray(rec.runs)
    if "t" in rec.columns:
        t = np.asarray(rec.columns["t"], float)
        shaft = np.empty_like(psi)
        for rid in np.unique(run):
            m = np.flatnonzero(run == rid)
            shaft[m] = np.unwrap(psi[m])
        segments = None
    else:
        order = np.argsort(psi, kind="stable")
        t = np.empty(psi.size)
        t[order] = np.arange(psi.size, dtype=float)
        shaft = psi.copy()
        segments = np.zeros(psi.size, dtype=int)
    masked: tuple = ()
    clip = st["clip"]
    e0, a0 = st["e0"], st["a0"]
    rel = np.array([e0[0] / a0, e0[1] / a0, e0[2] / a0, e0[3] / a0, e0[4]])
    if clip["channels"]:
        masked = (
            (
                clip["mask"],
                "signal clipping: "
                + "; ".join(
                    f"{c['channel']} flat at {c['level']:.6g} ({c['samples']} samples, the "
                    f"ellipse would reach {c['model_extreme']:.6g})"
                    for c in clip["channels"]
                ),
            ),
        )
    return QuadratureData(
        **drive_channel(
            y,
            shaft,
            t,
            run,
            unit="1",
            channel_name="radius",
            sensor="quadrature",
            where=st["where"],
            signal_periods=1,
        ),
        start=st,
        segments=segments,
        masked=masked,
        constants={"ellipse_start": rel},  # the base term's start, relative to A0
    )


# ----------------------------------------------------------------------------- terms


def _base_fn(p, x):
    psi = x["psi"][:, 0]
    r = ray_radius(
        p["offset_a"], p["offset_b"], p["amplitude_a"], p["amplitude_b"], p["phase_error_rad"], psi
    )
    e0 = x["ellipse_start"]
    return (r - ray_radius(e0[0], e0[1], e0[2], e0[3], e0[4], psi))[:, None]


BASE = Candidate(
    "ellipse",
    _base_fn,
    (
        Param("offset_a", "1", linear=False, scale=1e-3, description="offset of sa / A0"),
        Param("offset_b", "1", linear=False, scale=1e-3, description="offset of sb / A0"),
        Param("amplitude_a", "1", linear=False, scale=1e-3, description="amplitude of sa / A0"),
        Param("amplitude_b", "1", linear=False, scale=1e-3, description="amplitude of sb / A0"),
        Param("phase_error_rad", "rad", linear=False, scale=1e-3, description="alpha"),
    ),
    kinds=("quadrature",),
    explanation="base model: the ellipse of the Lissajous figure (offsets, amplitudes, "
    "phase error; Heydemann)",
)


def _harmonics_of(m: int) -> str:
    if m % 4 == 0:
        return f"signal harmonics {m - 1} and/or {m + 1} (same shape in both channels)"
    if m % 2:
        return f"even signal harmonics {m - 1} and/or {m + 1}"
    return f"harmonics {m - 1}/{m + 1} of shapes that differ between the channels"


def _signal_shape(orders: tuple[int, ...]) -> Candidate:
    m = jnp.asarray(orders, dtype=float)

    def fn(p, x):
        arg = x["psi"][:, :1] * m[None, :]
        return (jnp.cos(arg) @ p["cos"] + jnp.sin(arg) @ p["sin"])[:, None]

    def derived(ctx: Context, v: dict, se: dict) -> dict:
        amp = np.hypot(v["cos"], v["sin"])
        s_amp = np.sqrt((v["cos"] * se["cos"]) ** 2 + (v["sin"] * se["sin"]) ** 2) / np.where(
            amp > 0, amp, np.inf
        )
        top = [int(i) for i in np.argsort(-amp)[:6]]
        period = ctx.meta.get("encoder", {}).get("signal_period_m")
        out = {
            "radial_amplitude": {
                "value": {str(orders[i]): float(amp[i]) for i in top},
                "se": {str(orders[i]): float(np.nan_to_num(s_amp[i])) for i in top},
                "unit": "1",
            },
            "radial_phase_rad": {
                "value": {
                    str(orders[i]): float(np.arctan2(-v["sin"][i], v["cos"][i])) for i in top
                },
                "se": None,
                "unit": "rad",
            },
            "from_signal_harmonics": {
                "value": {str(orders[i]): _harmonics_of(orders[i]) for i in top},
                "se": None,
                "unit": "",
            },
            "interpolation_error_one_harmonic_rad": {
                "value": {str(orders[i]): float(amp[i]) for i in top},
                "se": {str(orders[i]): float(np.nan_to_num(s_amp[i])) for i in top},
                "unit": "rad",
                "note": "phase (interpolation) error amplitude at that order if one signal "
                "harmonic makes it; two harmonics on one order can add or cancel in the phase "
                "while the radius shows their sum: not observable without a reference",
            },
        }
        if period:
            out["interpolation_error_one_harmonic_m"] = {
                "value": {str(orders[i]): float(amp[i] * period / (2 * np.pi)) for i in top},
                "se": None,
                "unit": "m",
            }
        return out

    def plausible(ctx: Context, v: dict) -> str | None:
        amp = float(np.max(np.hypot(v["cos"], v["sin"])))
        if amp > ctx.settings.signal_shape_max:
            return f"a radial harmonic of {amp:.2f} of the radius is not a signal shape"
        return None

    def probes(ctx: Context) -> list[Probe]:
        # radial orders 3 (even signal harmonics 2, 4) and 4 (odd ones 3, 5 of one shape):
        # one column pair each, the bound of a higher order alone is about the same
        out = []
        for i, m in enumerate(orders[:2]):
            vals = {"cos": np.eye(len(orders))[i], "sin": np.zeros(len(orders))}
            out.append(Probe(vals, "radial_amplitude", "1", "radius", f"radial order {m}"))
        return out

    return Candidate(
        "signal_shape",
        fn,
        (
            Param("cos", "1", (len(orders),), description=f"radial orders {list(orders)}"),
            Param("sin", "1", (len(orders),)),
        ),
        signature=("orders",),
        kinds=("quadrature",),
        explanation=EXPLANATIONS["signal_shape"],
        derived=derived,
        plausible=plausible,
        probes=probes,
        orders=tuple(orders),
    )


_SHAPES: dict[tuple[int, ...], Candidate] = {}


def signal_shape_candidate(max_order: int) -> Candidate:
    """``signal_shape`` at radial orders ``3 .. max_order`` (one object per order set)."""
    orders = tuple(range(3, max(int(max_order), 3) + 1))
    if orders not in _SHAPES:
        _SHAPES[orders] = _signal_shape(orders)
    return _SHAPES[orders]


def _vibration(has_t: bool) -> Candidate:
    why = (
        "the radius of the Lissajous figure does not depend on the motion: a vibration shows "
        "only in the interpolated position, which needs a reference (record the head against "
        "one as a multihead sensor-against-reference recording)"
    )
    if not has_t:
        why += "; and rows without t have no time order"
    return Candidate(
        "vibration",
        lambda p, x: jnp.zeros_like(x["reading"]),
        (),
        signature=("spectrum",),
        kinds=("quadrature",),
        explanation=EXPLANATIONS["vibration"],
        applies=lambda ctx: why,
    )


VIBRATION = {True: _vibration(True), False: _vibration(False)}


def quadrature_limit(prep: Prepared) -> int:
    """Highest radial order the record resolves: an eighth of the kept samples (the phase
    is sampled irregularly), within the parameter budget, from ``settings.quad_order_min`` to
    ``quad_order_max``."""
    s = prep.settings
    n = int(prep.keep.sum())
    budget = int((s.max_param_fraction * prep.n_values - 5) // 2)
    return int(max(s.quad_order_min, min(n // 8, budget, s.quad_order_max)))


def quadrature_base(prep: Prepared, M: int, st: dict[str, Any]):
    """The ellipse, started at the conic fit (plain Heydemann) of the unclipped rows."""
    a0 = st["a0"]
    start = dict(zip(ELLIPSE_NAMES, prep.consts["ellipse_start"]))
    info = {
        "signal_scale_A0": a0,
        "unidentifiable": [
            "the interpolated phase itself (no reference): only the figure's shape is fitted"
        ],
    }
    return [(BASE, start)], info


def _signals_rows(prep: Prepared, st: dict[str, Any]):
    """``sa, sb`` (about the rays' centre), ``psi, r`` in the engine's row order (from y and
    the phase)."""
    psi = prep.rows["psi"][:, 0]
    rel = prep.consts["ellipse_start"]
    r = st["a0"] * (prep.y[:, 0] + ray_radius(*rel, psi))
    return r * np.cos(psi), r * np.sin(psi), psi, r


def _ellipse_summary(base_params: dict, a0: float, centre: tuple[float, float]) -> dict:
    """The ellipse in signal units (offsets include the rays' centre), with se."""
    bp = base_params["ellipse"]
    out: dict[str, Any] = {}
    for n, k in enumerate(ELLIPSE_NAMES):
        v, se = bp[k]["value"], bp[k]["se"]
        f = 1.0 if k == "phase_error_rad" else a0
        out[k] = {
            "value": v * f + (centre[n] if n < 2 else 0.0),
            "se": None if se is None else se * f,
            "unit": "rad" if k == "phase_error_rad" else "signal unit",
        }
    ra, rb = bp["amplitude_a"], bp["amplitude_b"]
    ratio = rb["value"] / ra["value"]
    se_r = None
    if ra["se"] is not None and rb["se"] is not None:
        se_r = abs(ratio) * math.hypot(ra["se"] / ra["value"], rb["se"] / rb["value"])
    out["amplitude_ratio"] = {"value": ratio, "se": se_r, "unit": "1"}
    out["signal_scale_A0"] = a0
    return out


def _heydemann(prep: Prepared, st: dict[str, Any]) -> dict:
    """Plain Heydemann (conic fit) on the kept rows: fitted and K-fold held-out RMS of the
    relative radius along the ray, in the engine's folds."""
    sa, sb, psi, r = _signals_rows(prep, st)  # about the centre
    a0 = st["a0"]
    keep = prep.keep
    e = ellipse_start(sa[keep], sb[keep])
    res = (r - ray_radius(*e, psi)) / a0
    held = np.zeros_like(res)
    for f in range(int(prep.fold_design["k"])):
        tr = keep & (prep.fold != f)
        ho = prep.fold == f
        ef = ellipse_start(sa[tr], sb[tr])
        held[ho] = (r[ho] - ray_radius(*ef, psi[ho])) / a0
    params = dict(zip(ELLIPSE_NAMES, (float(x) for x in e)))
    params["offset_a"] += st["centre"][0]
    params["offset_b"] += st["centre"][1]
    params["amplitude_ratio"] = float(e[3] / e[2])
    return {
        **params,
        "rms": float(np.sqrt(np.mean(res[keep] ** 2))),
        "heldout_rms": float(np.sqrt(np.mean(held[keep] ** 2))),
        "note": "plain Heydemann correction (algebraic conic fit) on the kept rows; radius "
        "along the ray relative to A0, in the engine's folds (signal units for its ellipse)",
    }


def quadrature_summary(prep: Prepared, base_params: dict, st: dict[str, Any]) -> dict:
    """Kind-specific keys: ``ellipse`` (signal units, with se), ``heydemann``, ``clipping``."""
    out = {
        "ellipse": _ellipse_summary(base_params, st["a0"], st["centre"]),
        "heydemann": _heydemann(prep, st),
        "clipping": {
            "channels": st["clip"]["channels"],
            "phase_deg": st["clip"]["phase_deg"],
            "fraction_of_samples": float(np.mean(st["clip"]["mask"])),
        },
        "residual": "radius along each sample's ray relative to the mean radius A0 "
        "(~ rad of signal phase); orders are cycles per signal period"
        + ("" if st["has_t"] else "; rows without t are in phase order, t = row index"),
    }
    enc = prep.ctx.meta.get("encoder", {})
    if "signal_period_m" in enc:
        out["signal_period_m"] = enc["signal_period_m"]
    return out


def quadrature_noise(prep: Prepared, resid: np.ndarray) -> np.ndarray:
    """Noise std from second differences of the residual between neighbours in signal
    phase (kept rows: glitches are already out): structure that is a function of the phase cancels
    (it is smooth over the phase step between neighbours), whatever the motion was."""
    keep = prep.keep
    psi = np.mod(prep.rows["psi"][keep, 0], 2 * np.pi)
    r = resid[keep, 0][np.argsort(psi, kind="stable")]
    if r.size < 16:
        return np.full(1, np.nan)
    d2 = r[2:] - 2 * r[1:-1] + r[:-2]
    return np.array([math.sqrt(float(np.mean(d2**2)) / 6.0)])


def _start(prep: Prepared) -> dict[str, Any]:
    """The conic start of the prepared record (its :class:`QuadratureData`)."""
    kd = prep.kd
    assert isinstance(kd, QuadratureData)
    return kd.start


@final
class QuadratureKind(AbstractKind):
    """``quadrature``: one pair of sin/cos signals (the record's conic start travels in its
    :class:`QuadratureData`): views orders (of the phase), and with ``t`` also time and
    spectrum (Hz)."""

    name: ClassVar[str] = "quadrature"
    default_max_order: ClassVar[int] = 12
    noise_replaces: ClassVar[bool] = False
    grows_orders: ClassVar[bool] = False
    reading_lattice: ClassVar[bool] = False

    def data(self, rec, settings=DEFAULT_SETTINGS):
        st = quadrature_start(rec, settings)
        st["has_t"] = "t" in rec.columns
        return quadrature_data(rec, st)

    def views(self, prep):
        return ("orders", "time", "spectrum") if _start(prep)["has_t"] else ("orders",)

    def plots(self, d, folder):
        return quadrature_plots(d, folder)

    def prepare(self, kd, meta, settings):
        return engine_prepare(kd, meta, settings)

    def base(self, prep, max_order):
        return quadrature_base(prep, max_order, _start(prep))

    def candidates(self, ctx):
        kd = ctx.data
        assert isinstance(kd, QuadratureData)
        return (
            signal_shape_candidate(int(ctx.max_order)),
            VIBRATION[bool(kd.start["has_t"])],
        )

    def max_order_limit(self, prep):
        return quadrature_limit(prep)

    def noise(self, prep, base_resid):
        return NoiseEstimate(quadrature_noise(prep, base_resid))

    def refine(self, terms, prep):
        return None

    def align(self, terms, prep):
        return None

    def summary(self, prep, base_params):
        return quadrature_summary(prep, base_params, _start(prep))

    def finish(self, prep, doc, settings):
        return finish(doc, _start(prep), settings)

    def report_lines(self, doc):
        return quadrature_report_lines(doc)


QUADRATURE = QuadratureKind()


def finish(
    doc: dict[str, Any], st: dict, settings: FinderSettings = DEFAULT_SETTINGS
) -> dict[str, Any]:
    """The kind's additions before the engine's verdict: clipping as unexplained structure
    (the verdict is then never ``consistent``), the ellipse with the named effects."""
    doc["noise"]["method"] = (
        "the smaller of the median of the base residual's periodogram (rows in time or phase "
        "order) and the second differences of the base residual between neighbours in signal "
        "phase (structure that is a function of the phase cancels there)"
    )
    doc["ellipse_with_effects"] = _ellipse_summary(
        doc["base"]["terms_with_effects"], st["a0"], st["centre"]
    )
    for e in doc["effects"]:
        if e["name"] != "signal_shape":
            continue
        amp = e["derived"]["radial_amplitude"]
        odd = [
            float(v)
            for k, v in amp["value"].items()
            if int(k) % 2 and v > settings.resolved_se * (amp["se"].get(k) or 0.0)
        ]
        if odd:  # an even signal harmonic moves the radius at order 1 too: the offsets take it
            bound = max(odd) * st["a0"]
            msg = (
                "odd radial orders (even signal harmonics) are present: an even harmonic also "
                "moves the radius at order 1, which no fit can tell from the offsets; the "
                f"offsets are uncertain by about +-{bound:.4g} signal units (the largest odd "
                "radial amplitude times A0), beyond their standard errors"
            )
            e["notes"] = list(e["notes"]) + [msg]
            doc["ellipse_with_effects"]["offsets_confounded_with_even_harmonics"] = bound
            doc["ellipse"]["offsets_confounded_with_even_harmonics"] = bound
    clip = st["clip"]
    if clip["channels"]:
        doc["unexplained"].insert(
            0,
            {
                "view": "clipping",
                "where": {
                    "orders": [],
                    "frequencies_hz": [],
                    "heads": [],
                    "runs": [],
                    "times_s": [],
                    "phase_deg": clip["phase_deg"],
                },
                "rms": st["clip_rms"],
                "channels": sorted({c["channel"] for c in clip["channels"]}),
                "fraction_of_samples": float(np.mean(clip["mask"])),
                "note": "signal clipping: the signals exceed the range of the acquisition "
                "(amplifier or ADC saturation); no catalog effect models this, so the "
                "clipped samples were left out of every fit",
            },
        )
    return doc


def quadrature_report_lines(doc: dict) -> str:
    """Extra report lines: the ellipse in signal units and plain Heydemann."""
    e = doc["ellipse"]

    def f(k, scale=1.0, unit=""):
        v = e[k]
        se = "" if v["se"] is None else f" +- {v['se'] * scale:.3g}"
        return f"{v['value'] * scale:.6g}{se}{unit}"

    h = doc["heydemann"]
    lines = [
        f"ellipse (base fit): offsets {f('offset_a')}, {f('offset_b')}; amplitudes "
        f"{f('amplitude_a')}, {f('amplitude_b')} (signal units); ratio {f('amplitude_ratio')}; "
        "phase error "
        f"{f('phase_error_rad', 1e3, ' mrad')}",
        f"plain Heydemann: {h['rms']:.4g} fitted, {h['heldout_rms']:.4g} held out",
    ]
    if doc["effects"]:
        e = doc["ellipse_with_effects"]
        lines.insert(
            1,
            f"ellipse (with the named effects): offsets {f('offset_a')}, {f('offset_b')}; "
            f"ratio {f('amplitude_ratio')}; phase error {f('phase_error_rad', 1e3, ' mrad')}",
        )
    for u in doc["unexplained"]:
        if u.get("view") == "clipping":
            lines.append(
                f"clipping: {100 * u['fraction_of_samples']:.1f} % of the samples at phases "
                f"{u['where']['phase_deg']} deg, left out of every fit"
            )
    return "\n".join(lines) + "\n"


def quadrature_plots(d: Any, folder: str | os.PathLike) -> list[Path]:
    """Lissajous figure (kept and excluded samples, base ellipse) and the radial residual
    against the signal phase (base and final model), plus the order spectrum."""
    from ....io._study import new_figure, save_figure

    pd = d.plot_data
    prep, r0, r1 = pd["prep"], pd["base_resid"], pd["final_resid"]
    doc = d.doc
    e = doc["ellipse"]
    a0 = e["signal_scale_A0"]
    c0 = (doc["ellipse"]["offset_a"]["value"], doc["ellipse"]["offset_b"]["value"])
    psi = prep.rows["psi"][:, 0]
    keep = prep.keep
    rel = prep.consts["ellipse_start"]
    r = a0 * (prep.y[:, 0] + ray_radius(*rel, psi))
    # the rays start at the conic centre: the base fit's offsets are small corrections to it
    centre = (
        c0[0] - a0 * doc["base"]["terms"]["ellipse"]["offset_a"]["value"],
        c0[1] - a0 * doc["base"]["terms"]["ellipse"]["offset_b"]["value"],
    )
    sa, sb = centre[0] + r * np.cos(psi), centre[1] + r * np.sin(psi)
    fig, ax = new_figure(1, 3, figsize=(15, 4.6))
    if (~keep).any():
        ax[0].plot(sa[~keep], sb[~keep], ",", color="tab:red", label="excluded")
    ax[0].plot(sa[keep], sb[keep], ",", color="0.3", label="kept")
    ph = np.linspace(0, 2 * np.pi, 721)
    ax[0].plot(
        e["offset_a"]["value"] + e["amplitude_a"]["value"] * np.cos(ph),
        e["offset_b"]["value"]
        + e["amplitude_b"]["value"] * np.sin(ph + e["phase_error_rad"]["value"]),
        lw=1,
        color="tab:blue",
        label="ellipse (base)",
    )
    ax[0].set(aspect="equal", xlabel="sa", ylabel="sb", title="Lissajous figure")
    ax[0].legend(loc="best", fontsize=7)
    o = np.argsort(psi[keep])
    ph_deg = np.degrees(psi[keep][o])
    ax[1].plot(ph_deg, r0[keep, 0][o], ",", color="tab:red", label="base")
    ax[1].plot(ph_deg, r1[keep, 0][o], ",", color="tab:blue", label="final")
    ax[1].set(xlabel="signal phase (deg)", ylabel="radial residual (relative to A0)")
    ax[1].set_title(f"verdict: {doc['verdict']}")
    ax[1].legend(loc="best", fontsize=7)
    sp = doc["spectrum"]
    ax[2].semilogy(sp["orders"], np.asarray(sp["before"]) + 1e-30, "o-", ms=3, label="base")
    ax[2].semilogy(sp["orders"], np.asarray(sp["after"]) + 1e-30, "o-", ms=3, label="final")
    ax[2].set(xlabel="order (cycles per signal period)", ylabel="radial amplitude (1)")
    ax[2].legend(loc="best", fontsize=7)
    return [save_figure(fig, Path(folder), "lissajous.png")]
