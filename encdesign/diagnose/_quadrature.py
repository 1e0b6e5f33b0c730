"""Discrepancy finder for ``quadrature`` recordings (the two raw signals of one head or
interferometer), e.g. a Lissajous capture sorted by phase.

Geometry. Each sample is a point ``(sa, sb)``; its measured phase is
``psi = atan2(sb, sa)`` and its radius ``r = hypot(sa, sb)``. A model of the signals is a
closed curve ``C(phi) = (sa(phi), sb(phi))`` over one signal period ``phi ∈ [0, 2π)``.
Without a position reference only the *shape* of that curve is observable (any
re-parametrisation of ``phi`` draws the same figure), so the residual of a sample is its
radial distance to the curve along its own ray, ``(r − R(psi)) / A`` with ``R(psi)`` the
curve's radius at phase ``psi`` (found by Newton iterations on ``phi``) and ``A`` the mean
radius: a dimensionless number, equal to the phase error scale in rad for small errors.

Base model (``docs/effects.md``, "Quadrature signals"; seed 002 eq. 1 and Heydemann's
correction): an ellipse, ``sa = p + a cos phi``, ``sb = q + b sin(phi + alpha)`` (offsets
``p, q``, amplitudes ``a, b`` in signal units, phase error ``alpha`` rad), plus noise.

Candidate ``signal_shape``: signals that are not pure sinusoids, with the same shape
function for both channels (seed 002 eq. 1 with ``F1 = F2 = F``, the second read a quarter
period later): ``F(x) = cos x + Σ_{h=2..H} [c_h cos(h x) + s_h sin(h x)]``,
``sa = p + a F(phi)``, ``sb = q + b F(phi + alpha − π/2)``. A harmonic ``h`` of relative
amplitude ``c`` moves the radius at orders ``h ± 1`` of the phase and makes an
interpolation error of about ``c`` rad at order ``h ± 1``.

Candidate ``vibration`` needs time order (``t``); a capture sorted by phase has lost it,
so it is reported as not testable there.

Held-out data: interleaved phase sectors (every 4th of 32) are left out of every fit.
An effect is named only when it lowers the BIC on the fitted part and the held-out RMS by
at least 20 %. Fits use optimistix Gauss–Newton.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._errors import input_error
from ..io._recording import Recording
from ..physics._ellipse import correct_signals, fit_ellipse
from ._orderscan import bic, order_scan, rms, sector_split

N_NEWTON = 6


def _curve(params: jnp.ndarray, phi: jnp.ndarray, n_harm: int):
    p, q, a, b, alpha = params[0], params[1], params[2], params[3], params[4]

    def shape(x):
        f = jnp.cos(x)
        for i in range(n_harm):
            h = i + 2
            f = f + params[5 + 2 * i] * jnp.cos(h * x) + params[6 + 2 * i] * jnp.sin(h * x)
        return f

    return p + a * shape(phi), q + b * shape(phi + alpha - jnp.pi / 2)


def _radius_on_ray(params: jnp.ndarray, psi: jnp.ndarray, n_harm: int):
    """Radius of the model curve along the ray at phase ``psi`` (and the curve phase)."""

    def step(phi, _):
        (sa, sb), (dsa, dsb) = jax.jvp(
            lambda ph: _curve(params, ph, n_harm), (phi,), (jnp.ones_like(phi),)
        )
        ang = jnp.arctan2(sb, sa)
        dang = (sa * dsb - sb * dsa) / (sa**2 + sb**2)
        err = jnp.arctan2(jnp.sin(ang - psi), jnp.cos(ang - psi))
        return phi - err / dang, None

    phi0 = psi - params[4] / 2.0
    phi, _ = jax.lax.scan(step, phi0, None, length=N_NEWTON)
    sa, sb = _curve(params, phi, n_harm)
    return jnp.hypot(sa, sb), phi


@functools.partial(jax.jit, static_argnames=("n_harm",))
def _fit(x0, psi, r, w, scale, n_harm: int):
    def resid(x, args):
        rr, _ = _radius_on_ray(x, psi, n_harm)
        return w * (r - rr) / scale

    # Gauss–Newton: the problem is mildly ill-conditioned (offsets vs even harmonics), where
    # Levenberg–Marquardt's damping cost ~4x the steps for the same optimum.
    solver = optx.GaussNewton(rtol=1e-7, atol=1e-10)
    sol = optx.least_squares(resid, solver, x0, max_steps=60, throw=False)
    rr, phi = _radius_on_ray(sol.value, psi, n_harm)
    return sol.value, (r - rr) / scale, phi, sol.result == optx.RESULTS.successful


def ellipse_start(sa: np.ndarray, sb: np.ndarray) -> np.ndarray:
    """Linear least-squares conic fit, converted to ``[p, q, a, b, alpha]`` (signal units,
    rad): the starting point of the fits and the plain Heydemann estimate."""
    # sa² , sb², sa·sb, sa, sb, 1 — solve A sa² + B sb² + C sa sb + D sa + E sb = 1
    X = np.column_stack([sa**2, sb**2, sa * sb, sa, sb])
    A, B, C, D, E = np.linalg.lstsq(X, np.ones_like(sa), rcond=None)[0]
    den = 4 * A * B - C**2
    p = (C * E - 2 * B * D) / den
    q = (C * D - 2 * A * E) / den
    k = 1 + A * p**2 + B * q**2 + C * p * q
    # sa = p + a cos φ, sb = q + b sin(φ + α) satisfies u²/a² + v²/b² - 2uv sinα/(ab) = cos²α
    a = math.sqrt(k / A / (1 - C**2 / (4 * A * B)))
    b = math.sqrt(k / B / (1 - C**2 / (4 * A * B)))
    alpha = math.asin(np.clip(-C / (2 * math.sqrt(A * B)), -1.0, 1.0))
    return np.array([p, q, a, b, alpha])


EXPLANATIONS = {
    "signal_shape": (
        "The signals are not pure sinusoids (grating duty cycle, detector geometry): their "
        "harmonics bend the Lissajous figure in a way no ellipse can follow, leaving an "
        "interpolation error at multiples of the signal frequency beyond the 1st and 2nd."
    ),
}


def diagnose_quadrature(
    rec: Recording,
    *,
    n_harmonics: int = 4,
    min_heldout_gain: float = 0.2,
    plots: str | Path | None = None,
) -> dict[str, Any]:
    """Diagnose a ``quadrature`` recording; returns the diagnose JSON contract as a dict.

    Args:
        rec: the recording (columns ``sa``, ``sb``).
        n_harmonics: harmonics 2 … ``n_harmonics + 1`` in the ``signal_shape`` candidate.
        min_heldout_gain: relative held-out RMS cut an effect must give to be named.
        plots: folder for PNG figures (``None``: no plots).

    Returns:
        ``verdict``, ``rms_before``, ``heldout_rms_before`` (dimensionless radial residual
        ≈ rad of signal phase), ``effects``, ``unexplained``, ``base``, ``heydemann``,
        ``rejected``, ``not_testable``, ``report``.
    """
    sa, sb = rec.columns["sa"], rec.columns["sb"]
    psi = np.arctan2(sb, sa)
    r = np.hypot(sa, sb)
    if np.ptp(psi) < np.pi or r.mean() <= 0 or np.std(r) > 0.5 * r.mean():
        raise input_error(
            str(rec.path), "the signals do not go round a Lissajous figure", "a full period"
        )
    scale = float(r.mean())
    train, held = sector_split(psi + np.pi, n_sectors=32, every=4, offset=1)
    clipping = detect_clipping(sa, sb, ellipse_start(sa, sb))
    keep = ~clipping["mask"]
    train, held = train & keep, held & keep
    w_train = train.astype(float)
    start = ellipse_start(sa[train], sb[train])

    def fit(n_harm: int, x0: np.ndarray) -> dict:
        x, res, phi, ok = _fit(
            jnp.asarray(x0), jnp.asarray(psi), jnp.asarray(r), jnp.asarray(w_train), scale, n_harm
        )
        res = np.asarray(res)
        return {
            "x": np.asarray(x),
            "resid": res,
            "phi": np.asarray(phi),
            "rms": rms(res[train]),
            "heldout_rms": rms(res[held]),
            "bic": bic(res[train], 5 + 2 * n_harm),
            "converged": bool(ok),
        }

    base = fit(0, start)
    cand = fit(n_harmonics, np.concatenate([base["x"], np.zeros(2 * n_harmonics)]))
    gain = 1.0 - cand["heldout_rms"] / base["heldout_rms"]
    effects, rejected = [], []
    final = base
    if cand["bic"] < base["bic"] and gain >= min_heldout_gain and cand["converged"]:
        final = cand
        harm = {
            str(i + 2): {
                "relative_amplitude": float(math.hypot(cand["x"][5 + 2 * i], cand["x"][6 + 2 * i])),
                "phase_rad": float(math.atan2(cand["x"][6 + 2 * i], cand["x"][5 + 2 * i])),
            }
            for i in range(n_harmonics)
        }
        top = max(harm, key=lambda h: harm[h]["relative_amplitude"])
        effects.append(
            {
                "name": "signal_shape",
                "params": {"harmonics": harm, **_ellipse_params(cand["x"])},
                "rms_after": cand["rms"],
                "heldout_rms_after": cand["heldout_rms"],
                "heldout_improvement": gain,
                "explanation": EXPLANATIONS["signal_shape"]
                + f" Largest: harmonic {top}, {100 * harm[top]['relative_amplitude']:.2f} % "
                "of the fundamental.",
            }
        )
    else:
        why = []
        if cand["bic"] >= base["bic"]:
            why.append("no BIC improvement")
        if gain < min_heldout_gain:
            why.append(f"held-out RMS changes by {-100 * gain + 0.0:+.1f} % (needs -20 %)")
        if not cand["converged"]:
            why.append("fit did not converge")
        rejected.append(
            {"name": "signal_shape", "heldout_rms": cand["heldout_rms"], "reason": "; ".join(why)}
        )
    orders = list(range(1, 41))
    # clipped samples are zero-filled (a gapped Fourier fit would be ill-conditioned)
    scan_before = order_scan(psi, np.where(keep, base["resid"], 0.0), orders)
    scan_after = order_scan(psi, np.where(keep, final["resid"], 0.0), orders)
    covered = set()
    if effects:
        covered = {o for h in range(2, n_harmonics + 2) for o in (h - 1, h + 1)}
    covered |= {1, 2}  # the ellipse's own orders
    left = [int(o) for o in scan_after.significant if o not in covered]
    unexplained = []
    if left:
        amp = dict(zip(scan_after.orders.tolist(), scan_after.amplitude.tolist()))
        unexplained.append(
            {
                "where": {
                    "orders": left,
                    "frequencies_hz": [],
                    "heads": [],
                    "runs": [],
                    "times_s": [],
                },
                "rms": float(math.sqrt(sum(amp[o] ** 2 / 2 for o in left))),
                "note": "radial harmonics (cycles per signal period) left after the fit",
            }
        )
    # plain Heydemann (encdesign.physics._ellipse): ellipse fitted on the same samples, radial
    # residual of the corrected unit circle
    hey = fit_ellipse(sa[train], sb[train], method="heydemann", throw=True)
    hs, hc = correct_signals(sa, sb, hey.params)
    hres = np.hypot(np.asarray(hs), np.asarray(hc)) - 1.0
    if clipping["channels"]:
        cres = final["resid"][~keep]
        unexplained.insert(
            0,
            {
                "where": {
                    "orders": [],
                    "frequencies_hz": [],
                    "heads": [],
                    "runs": [],
                    "times_s": [],
                    "phase_deg": clipping["phase_deg"],
                },
                "rms": rms(cres),
                "fraction_of_samples": float(np.mean(~keep)),
                "note": "signal clipping: "
                + "; ".join(
                    f"{c['channel']} flat at {c['level']:.1f} ({c['samples']} samples, the "
                    f"ellipse would reach {c['model_extreme']:.1f})"
                    for c in clipping["channels"]
                )
                + ". The signals exceed the range of the acquisition (amplifier or ADC "
                "saturation); no catalog effect models this, so the clipped samples were left "
                "out of every fit.",
            },
        )
    verdict = "missing_physics" if effects else ("unexplained" if unexplained else "consistent")
    period = rec.encoder.get("signal_period_m")
    out = {
        "recording": str(rec.path) if rec.path else None,
        "kind": "quadrature",
        "verdict": verdict,
        "residual_unit": "relative radius (≈ rad of signal phase)",
        "rms_before": base["rms"],
        "heldout_rms_before": base["heldout_rms"],
        "effects": effects,
        "unexplained": unexplained,
        "base": {**_ellipse_params(base["x"]), "converged": base["converged"]},
        "heydemann": {
            **{k: float(v) for k, v in hey.params.as_dict().items()},
            "rms": rms(hres[train]),
            "heldout_rms": rms(hres[held]),
            "note": "plain Heydemann correction (algebraic ellipse fit), radial residual of the "
            "corrected unit circle",
        },
        "rejected": rejected,
        "not_testable": [
            {
                "name": "vibration",
                "reason": "needs time order (column t); rows sorted by phase have lost it"
                if "t" not in rec.columns
                else "not modelled for quadrature recordings yet",
            }
        ],
        "spectrum": {
            "orders": orders,
            "before": scan_before.amplitude.tolist(),
            "after": scan_after.amplitude.tolist(),
        },
        "heldout": "every 4th of 32 phase sectors",
    }
    if period:
        out["signal_period_m"] = period
    out["report"] = quadrature_report(out)
    if plots is not None:
        out["plots"] = [str(p) for p in plot_quadrature(out, sa, sb, psi, base, final, plots)]
    return out


def detect_clipping(
    sa: np.ndarray, sb: np.ndarray, ellipse: np.ndarray, *, band: float = 0.002
) -> dict:
    """Find signals stuck at a level the fitted ellipse would exceed (saturation).

    A channel extreme is called clipped when more than three times the samples a sinusoid
    would put within ``band`` (relative to the amplitude) of its peak sit at the observed
    extreme, and the ellipse fitted to all samples reaches more than 1 % of the amplitude
    beyond it. Returns ``mask`` (samples at a clipped level), ``channels`` (one dict per
    clipped channel extreme) and ``phase_deg`` (the phases where clipping happens).
    """
    p, q, a, b, _ = ellipse
    mask = np.zeros(sa.size, dtype=bool)
    channels = []
    expected = sa.size * math.sqrt(2 * band) / math.pi
    for name, s, centre, amp in (("sa", sa, p, a), ("sb", sb, q, b)):
        for sign in (1.0, -1.0):
            level = s.max() if sign > 0 else s.min()
            at = np.abs(s - level) < band * amp
            model_extreme = centre + sign * amp
            beyond = sign * (model_extreme - level)
            if at.sum() > 3 * expected and beyond > 0.01 * amp:
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


def _ellipse_params(x: np.ndarray) -> dict:
    return {
        "offset_a": float(x[0]),
        "offset_b": float(x[1]),
        "amplitude_a": float(x[2]),
        "amplitude_b": float(x[3]),
        "amplitude_ratio": float(x[3] / x[2]),
        "phase_error_rad": float(x[4]),
    }


def quadrature_report(d: dict) -> str:
    """One-page plain-text report of a quadrature diagnosis."""
    b = d["base"]
    lines = [
        f"Diagnosis of {d['recording']} (quadrature)",
        f"verdict: {d['verdict']}",
        f"base ellipse: offsets ({b['offset_a']:.3f}, {b['offset_b']:.3f}), amplitudes "
        f"({b['amplitude_a']:.3f}, {b['amplitude_b']:.3f}), phase error "
        f"{b['phase_error_rad'] * 1e3:.2f} mrad",
        f"residual RMS before: {d['rms_before']:.3e} fitted, {d['heldout_rms_before']:.3e} "
        "held out (relative radius)",
        f"plain Heydemann: {d['heydemann']['rms']:.3e} fitted, "
        f"{d['heydemann']['heldout_rms']:.3e} held out",
    ]
    for e in d["effects"]:
        lines.append(
            f"  + {e['name']}: {e['rms_after']:.3e} fitted, {e['heldout_rms_after']:.3e} held "
            f"out ({100 * e['heldout_improvement']:.0f} % better). {e['explanation']}"
        )
    for r in d["rejected"]:
        lines.append(f"  - {r['name']} rejected: {r['reason']}")
    for u in d["unexplained"]:
        what = u["note"] if "phase_deg" in u["where"] else f"orders {u['where']['orders']}"
        lines.append(f"  ? unexplained: {what} ({u['rms']:.2e} RMS)")
    for n in d["not_testable"]:
        lines.append(f"  . {n['name']}: not testable ({n['reason']})")
    return "\n".join(lines)


def plot_quadrature(d, sa, sb, psi, base, final, folder) -> list:
    """Lissajous figure with the fitted curves, residual vs phase, spectra, RMS bars."""
    from ..io._study import new_figure, save_figure
    from ._plots import rms_bars, rms_steps

    folder = Path(folder)
    stem = Path(d["recording"] or "quadrature").stem
    fig, ax = new_figure(2, 2, figsize=(11, 9))
    ax[0, 0].plot(sa, sb, ",", color="0.5", label="samples")
    phi = jnp.linspace(0, 2 * jnp.pi, 721)
    for fitd, lab in ((base, "ellipse (base)"), (final, "final model")):
        n_harm = (len(fitd["x"]) - 5) // 2
        ca, cb = _curve(jnp.asarray(fitd["x"]), phi, n_harm)
        ax[0, 0].plot(np.asarray(ca), np.asarray(cb), lw=1, label=lab)
    ax[0, 0].set(aspect="equal", xlabel="sa", ylabel="sb", title=f"{stem}: Lissajous figure")
    ax[0, 0].legend(fontsize=8)
    order = np.argsort(psi)
    ax[0, 1].plot(np.degrees(psi[order]), base["resid"][order], lw=0.5, label="base")
    ax[0, 1].plot(np.degrees(psi[order]), final["resid"][order], lw=0.5, label="final")
    ax[0, 1].set(xlabel="phase (deg)", ylabel="relative radial residual")
    ax[0, 1].legend(fontsize=8)
    o = np.asarray(d["spectrum"]["orders"])
    ax[1, 0].semilogy(o, d["spectrum"]["before"], "o-", ms=3, label="base")
    ax[1, 0].semilogy(o, d["spectrum"]["after"], "o-", ms=3, label="final")
    ax[1, 0].set(xlabel="order (cycles per signal period)", ylabel="residual amplitude")
    ax[1, 0].legend(fontsize=8)
    names, fitted, held = rms_steps(d)
    rms_bars(
        ax[1, 1],
        ["Heydemann", *names],
        [d["heydemann"]["rms"], *fitted],
        [d["heydemann"]["heldout_rms"], *held],
    )
    ax[1, 1].set(ylabel="RMS (relative radius)")
    ax[1, 1].legend(fontsize=8)
    return [save_figure(fig, folder, f"{stem}-diagnosis.png")]
