"""Discrepancy finder for ``motion`` recordings (shaft angle against time).

Base model (``docs/effects.md``, "Shaft motion"): per run, a start angle, a constant speed
and a slow drift of the speed loop (cubic in time), plus the motor's design ripple: with
``commutation_states`` given, position harmonics at multiples of
``commutation_states · pole_pairs`` per revolution; a drive with sinusoidal (field-oriented)
commutation states none, and then the design ripple is empty. Noise is what is left.

The shaft angle is ``theta = theta0 + omega t + drift(t) + sum_m [c_m cos(m theta) +
s_m sin(m theta)]``: a speed ripple of relative amplitude ``r`` at order ``m`` moves the
angle by ``r / m`` rad, so each effect is a set of Fourier orders of the angle (linear in
its coefficients, fitted by least squares; reported both as angle amplitude in rad and as
relative speed ripple ``m·amplitude``). Catalog candidates and their orders (``p`` pole
pairs, ``s`` stator slots, up to ``max_order``):

* ``cogging``: multiples of ``lcm(2p, s)``;
* ``magnet_asymmetry``: multiples of ``p``;
* ``coil_mismatch``: ``1 … p`` and multiples of ``s``;
* ``speed_control_loop``: ripple fixed in Hz rather than in order; it can only be told
  apart from the others with runs at different speeds, and is reported as not testable on a
  single-speed recording.

Held-out data: interleaved angular sectors (every 5th of 40 sectors of the turn) are left
out of every fit; an effect is named only when it lowers the BIC on the fitted part *and*
the held-out RMS by at least 20 %. Orders shared between candidates go to the one accepted
first, and the overlap is reported as confounding.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..io._recording import Recording
from ._orderscan import (
    bic,
    forward_select,
    fourier_columns,
    order_scan,
    rms,
    sector_split,
)

EXPLANATIONS = {
    "cogging": (
        "Magnet-to-slot attraction (cogging torque) was left out: it makes the speed ripple "
        "at multiples of lcm(2·pole_pairs, slots) per revolution, strongest at low speed."
    ),
    "magnet_asymmetry": (
        "Unequal magnets or pole spacing were left out: the torque, and so the speed, "
        "ripples at multiples of the pole-pair count per revolution."
    ),
    "coil_mismatch": (
        "Unequal stator coils were left out: they add low-order speed harmonics (orders 1 … "
        "pole_pairs) and harmonics at multiples of the slot count."
    ),
}


def motion_angle(rec: Recording) -> np.ndarray:
    """Shaft angle in rad from a motion recording (``theta``, or ``counts`` with
    ``counts_per_rev``)."""
    if "theta" in rec.columns:
        return rec.columns["theta"]
    return rec.columns["counts"] / rec.encoder["counts_per_rev"] * 2.0 * np.pi


def candidate_orders(pole_pairs: int, slots: int | None, max_order: int) -> dict[str, list[int]]:
    """Orders per revolution of each catalog candidate for a motor (see module doc)."""
    p = pole_pairs
    out: dict[str, list[int]] = {}
    if slots:
        lcm = 2 * p * slots // math.gcd(2 * p, slots)
        out["cogging"] = list(range(lcm, max_order + 1, lcm))
    out["magnet_asymmetry"] = list(range(p, max_order + 1, p))
    coil = set(range(1, p + 1))
    if slots:
        coil |= set(range(slots, max_order + 1, slots))
    out["coil_mismatch"] = sorted(coil)
    return {k: v for k, v in out.items() if v}


def diagnose_motion(
    rec: Recording,
    *,
    max_order: int = 200,
    min_heldout_gain: float = 0.2,
    plots: str | Path | None = None,
) -> dict[str, Any]:
    """Diagnose a ``motion`` recording; returns the diagnose JSON contract as a dict.

    Args:
        rec: the recording (needs ``[motor] pole_pairs``; ``stator_slots`` recommended).
        max_order: highest order per revolution modelled (default 200).
        min_heldout_gain: relative held-out RMS cut an effect must give to be named.
        plots: folder for PNG figures (``None``: no plots).

    Returns:
        ``verdict``, ``rms_before``, ``heldout_rms_before`` (rad), ``effects``,
        ``unexplained``, plus ``base``, ``rejected``, ``confounding``, ``not_testable``,
        ``report`` (text).
    """
    from .._errors import input_error

    motor = rec.meta.get("motor", {})
    if "pole_pairs" not in motor:
        raise input_error(f"{rec.path}: [motor]", "missing pole_pairs", "the motor's pole pairs")
    p, s = int(motor["pole_pairs"]), motor.get("stator_slots")
    theta = motion_angle(rec)
    t = rec.columns["t"]
    runs = rec.runs
    n_per_rev = theta.size / max(np.ptp(theta) / (2 * np.pi), 1e-9)
    max_order = int(min(max_order, n_per_rev / 8))  # keep ≥ 4 samples per period per sign
    design_orders: list[int] = []
    if "commutation_states" in motor:
        step = int(motor["commutation_states"]) * p
        design_orders = list(range(step, max_order + 1, step))
    cands = candidate_orders(p, s, max_order)
    train, held = sector_split(theta - theta.min())

    # nuisance columns per run: 1, t, t², t³ (scaled)
    nuis = []
    for r in np.unique(runs):
        m = (runs == r).astype(float)
        tt = np.where(runs == r, t - t[runs == r].mean(), 0.0)
        tt = tt / max(np.ptp(t[runs == r]), 1e-12)
        nuis += [m * tt**k for k in range(4)]
    base_cols = np.column_stack([*nuis, fourier_columns(theta, design_orders)])

    def fit(names: tuple[str, ...]) -> dict:
        orders = (
            sorted(set().union(*[cands[n] for n in names]) - set(design_orders)) if names else []
        )
        X = np.column_stack([base_cols, fourier_columns(theta, orders)])
        coef, *_ = np.linalg.lstsq(X[train], theta[train], rcond=None)
        res = theta - X @ coef
        k0 = base_cols.shape[1]
        amps = {
            int(m): (float(coef[k0 + 2 * i]), float(coef[k0 + 2 * i + 1]))
            for i, m in enumerate(orders)
        }
        return {
            "names": names,
            "resid": res,
            "rms": rms(res[train]),
            "heldout_rms": rms(res[held]),
            "bic": bic(res[train], X.shape[1]),
            "coef": amps,
        }

    base, steps, rejected = forward_select(fit, list(cands), min_heldout_gain=min_heldout_gain)

    claimed: set[int] = set()
    effects = []
    confounding = []
    for st in steps:
        own = [m for m in cands[st.name] if m not in claimed and m not in design_orders]
        claimed |= set(own)
        coefs = st.fit["coef"]
        amp = {m: math.hypot(*coefs[m]) for m in own if m in coefs}
        top = sorted(amp, key=amp.get, reverse=True)[:8]
        params = {
            "orders": own,
            "angle_amplitude_rad": {str(m): amp[m] for m in top},
            "speed_ripple_relative": {str(m): m * amp[m] for m in top},
            "phase_rad": {str(m): math.atan2(-coefs[m][1], coefs[m][0]) for m in top},
        }
        effects.append(
            {
                "name": st.name,
                "params": params,
                "rms_after": st.rms_after,
                "heldout_rms_after": st.heldout_rms_after,
                "heldout_improvement": st.heldout_gain,
                "explanation": EXPLANATIONS[st.name]
                + f" Strongest orders: {', '.join(str(m) for m in top[:5])}.",
            }
        )
    for a in cands:
        for b in cands:
            if a < b:
                both = sorted(set(cands[a]) & set(cands[b]))
                if both:
                    confounding.append(
                        {
                            "effects": [a, b],
                            "shared_orders": both[:20],
                            "note": "orders common to both candidates are attributed to the "
                            "one accepted first; the data cannot split them",
                        }
                    )
    for r in rejected:
        taken = set(cands[r["name"]]) <= claimed | set(design_orders)
        if taken:
            owners = [st.name for st in steps if set(cands[r["name"]]) & set(cands[st.name])]
            r["reason"] = (
                f"all its orders {cands[r['name']][:6]} are already modelled by "
                f"{' and '.join(owners)}: confounded, this motor's data cannot tell them apart"
            )
    final = steps[-1].fit if steps else base
    scan_orders = list(range(2, max_order + 1))
    scan = order_scan(theta, final["resid"], scan_orders)
    left = [int(m) for m in scan.significant if m not in claimed and m not in design_orders]
    unexplained = []
    if left:
        amp = dict(zip(scan.orders.tolist(), scan.amplitude.tolist()))
        unexplained.append(
            {
                "where": {
                    "orders": left,
                    "frequencies_hz": [],
                    "heads": [],
                    "runs": [int(r) for r in np.unique(runs)],
                    "times_s": [],
                },
                "rms": float(math.sqrt(sum(amp[m] ** 2 / 2 for m in left))),
                "note": "significant angle harmonics that no accepted catalog effect covers",
                "coincides_with": {
                    r["name"]: [m for m in left if m in cands[r["name"]]]
                    for r in rejected
                    if any(m in cands[r["name"]] for m in left)
                },
            }
        )
    verdict = "missing_physics" if effects else ("unexplained" if unexplained else "consistent")
    speeds = [float(np.polyfit(t[runs == r], theta[runs == r], 1)[0]) for r in np.unique(runs)]
    out = {
        "recording": str(rec.path) if rec.path else None,
        "kind": "motion",
        "verdict": verdict,
        "rms_before": base["rms"],
        "heldout_rms_before": base["heldout_rms"],
        "effects": effects,
        "unexplained": unexplained,
        "base": {
            "pole_pairs": p,
            "stator_slots": s,
            "design_ripple_orders": design_orders,
            "mean_speed_rad_s": speeds,
            "max_order": max_order,
            "heldout": "every 5th of 40 angular sectors",
        },
        "rejected": rejected,
        "confounding": confounding,
        "not_testable": [
            {
                "name": "speed_control_loop",
                "reason": "needs runs at different speeds to tell ripple fixed in Hz from "
                "ripple fixed in order"
                if len(np.unique(np.round(speeds, 3))) < 2
                else "not modelled for motion recordings yet",
            }
        ],
        "spectrum": {
            "orders": scan_orders,
            "before": order_scan(theta, base["resid"], scan_orders).amplitude.tolist(),
            "after": scan.amplitude.tolist(),
        },
    }
    out["report"] = motion_report(out)
    if plots is not None:
        out["plots"] = [str(p) for p in plot_motion(out, theta, base, final, plots)]
    return out


def motion_report(d: dict) -> str:
    """One-page plain-text report of a motion diagnosis."""
    lines = [
        f"Diagnosis of {d['recording']} (motion)",
        f"verdict: {d['verdict']}",
        f"base model: constant speed + cubic speed drift per run; pole pairs "
        f"{d['base']['pole_pairs']}, slots {d['base']['stator_slots']}",
        f"residual RMS before: {d['rms_before'] * 1e3:.3f} mrad fitted, "
        f"{d['heldout_rms_before'] * 1e3:.3f} mrad held out",
    ]
    for e in d["effects"]:
        lines.append(
            f"  + {e['name']}: RMS {e['rms_after'] * 1e3:.3f} mrad fitted, "
            f"{e['heldout_rms_after'] * 1e3:.3f} mrad held out "
            f"({100 * e['heldout_improvement']:.0f} % better); {e['explanation']}"
        )
    for r in d["rejected"]:
        lines.append(f"  - {r['name']} rejected: {r['reason']}")
    for u in d["unexplained"]:
        lines.append(
            f"  ? unexplained: orders {u['where']['orders'][:12]} ({u['rms'] * 1e3:.3f} mrad RMS)"
        )
    for c in d["confounding"]:
        lines.append(
            f"  ~ {c['effects'][0]} / {c['effects'][1]} share orders {c['shared_orders'][:6]}"
        )
    for n in d["not_testable"]:
        lines.append(f"  . {n['name']}: not testable ({n['reason']})")
    return "\n".join(lines)


def plot_motion(d: dict, theta: np.ndarray, base: dict, final: dict, folder: str | Path) -> list:
    """Residual spectra before/after, residual vs angle, held-out RMS bars (PNG)."""
    from ..io._study import new_figure, save_figure
    from ._plots import rms_bars, rms_steps

    folder = Path(folder)
    stem = Path(d["recording"] or "motion").stem
    fig, ax = new_figure(3, 1, figsize=(9, 9))
    o = np.asarray(d["spectrum"]["orders"])
    ax[0].semilogy(o, np.asarray(d["spectrum"]["before"]) * 1e3, label="base model")
    ax[0].semilogy(o, np.asarray(d["spectrum"]["after"]) * 1e3, label="with named effects")
    ax[0].set(xlabel="order (cycles/rev)", ylabel="amplitude (mrad)", title=f"{stem}: residual")
    ax[0].legend()
    deg = np.degrees(theta - theta.min())
    ax[1].plot(deg, base["resid"] * 1e3, ",", label="base")
    ax[1].plot(deg, final["resid"] * 1e3, ",", label="after")
    ax[1].set(xlabel="shaft angle (deg)", ylabel="residual (mrad)")
    rms_bars(ax[2], *rms_steps(d), scale=1e3)
    ax[2].set(ylabel="RMS (mrad)")
    ax[2].legend()
    return [save_figure(fig, folder, f"{stem}-diagnosis.png")]
