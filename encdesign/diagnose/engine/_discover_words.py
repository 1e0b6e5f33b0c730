"""Discovery's words (issue 41): what a discovered term's frame, modulation and order say of
its likely physical cause, as one sentence (:func:`reading`). Never a catalog name."""

from __future__ import annotations

import math

from ._discover_ring import ring_words
from ._settings import FinderSettings


def _order_reading(m: float, ctx_meta: dict, L: int) -> str:
    """What an integer order ``m`` is a multiple of (pole pairs, slots, their lcm, the
    signal period), in words; ``""`` when none."""
    motor = ctx_meta.get("motor") or {}
    p = int(motor.get("pole_pairs") or 0)
    s = int(motor.get("slots") or 0)
    mi = int(round(m))
    parts = []
    if L > 1 and mi % L == 0:
        parts.append(f"{mi // L} x the {L} signal periods")
    if p and s:
        lcm = p * s // math.gcd(p, s)
        if mi % lcm == 0:
            parts.append(f"{mi // lcm} x lcm({p} pole pairs, {s} slots)")
    if p and mi % p == 0:
        parts.append(f"{mi // p} x {p} pole pairs")
    elif p and (mi % p in (1, p - 1)):
        parts.append(
            f"a sideband of {p} pole pairs ({mi} = {round(mi / p)} x {p} "
            f"{'+' if mi % p == 1 else '-'} 1)"
        )
    if s and mi % s == 0:
        parts.append(f"{mi // s} x {s} slots")
    return "; ".join(parts)


FRAME_WORDS = {
    "disk": "the phase m psi_k of each head's azimuth: a property of the disk (its error "
    "function), not of the shaft's motion or of one head",
    "shaft": "one phase on every head: a motion of the shaft or of the reference, not an "
    "error of the disk or of a head",
    "hz": "fixed in Hz, its own phase in every run: a structure (vibration, supply) at its "
    "own frequency, not tied to the angle",
    "platform": "of the platform angle, one phase on every moving sensor: a motion or an "
    "error of the platform's positioning (a gear, a bearing, the reference), not of a sensor",
    "azimuth": "of phi + psi_m, every moving sensor with the phase m psi_m of its azimuth: "
    "a property of where the sensors sit in the fixed frame (what they pass over), not of "
    "one sensor or of the platform's motion",
}

MOD_WORDS = {
    "static": "the same amplitude in every run",
    "direction": "opposite sign in the two directions of rotation (hysteresis, backlash, a lag)",
    "forward": "in the positive direction only",
    "reverse": "in the negative direction only",
    "per_cell": "its own amplitude and phase in every run (intermittent)",
    "ringing": "its own amplitude and phase in every run, changing linearly within the run: a "
    "structural mode rung (by the start of the run, an impact) and decaying at its own Q, or "
    "building up",
    "growth": "growing linearly with the time across the record (a slow growth or drift)",
    "temperature": "linear in the temperature",
    "step": "switching on at one change time (a change of the set-up: a part that loosened, "
    "a replaced or re-plugged component)",
}


def _speed_cause(beta: float, se: float | None, n_se: float) -> str:
    s = se or 0.5
    for b0, words in (
        (-2.0, "a periodic torque filtered by the rotor's inertia"),
        (-1.0, "a periodic torque against damping / a velocity-loop stiffness"),
        (0.0, "a geometric error of the angle (independent of speed)"),
        (1.0, "a lag: a delay or a filter's time constant times the speed"),
        (2.0, "a centrifugal or inertial load growing with the speed squared"),
    ):
        if abs(beta - b0) <= n_se * s:
            return words
    return "no simple mechanism (exponent not near -2, -1, 0, 1 or 2)"


def reading(line, tm, meta: dict, L: int, cinfo: dict, C: int, settings: FinderSettings) -> str:
    """One sentence of the structure and its likely cause."""
    what = line.label()
    if line.kind == "order" and line.value > 0:
        extra = _order_reading(line.value, meta, L)
        if extra:
            what += f" = {extra}"
    fr = tm.frame
    if fr.startswith("head "):
        fw = f"on {fr} only: a property of that head (its reading or mounting), not of the disk"
    elif fr.startswith("sensor "):
        fw = (
            f"of the platform angle on moving {fr} only: an error in the frame of that sensor "
            "(its mounting, its edges' timing), not of the platform or of the disks"
        )
    else:
        fw = FRAME_WORDS.get(fr, fr)
    if line.kind == "order" and line.value == 0 and fr == "shaft":
        fw = "the same offset on every head: the reference or the shaft, not a head"
    if line.kind == "order" and line.value == 0 and fr.startswith("sensor "):
        fw = f"an offset of moving {fr} only: the timing of that sensor's edges"
    if line.kind == "order" and line.value == 0 and fr == "platform":
        fw = "the same offset on every moving sensor: the reference platform angle"
    if tm.modulation == "speed" and tm.beta is not None:
        S = len(cinfo["speed"])
        se = f" +- {tm.beta_se:.2g}" if tm.beta_se is not None else ""
        mw = f"amplitude ~ speed^({tm.beta:.2f}{se}) across {S} steady speeds: " + _speed_cause(
            tm.beta, tm.beta_se, settings.speed_cause_se
        )
    elif tm.modulation == "ringdown" and tm.decay is not None:
        mw = ring_words(tm.decay)
    elif tm.modulation.startswith("cell "):
        s = int(tm.modulation.split()[1])
        mw = f"in run {int(cinfo['run'][s])} only (intermittent)"
    else:
        mw = MOD_WORDS.get(tm.modulation, tm.modulation)
    return f"{what}, {fw}; {mw}."
