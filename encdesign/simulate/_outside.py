"""Recordings with physics outside the finder's catalog (issue 41's discovery benchmark).

:func:`outside_record` draws a multihead bench (4 heads and a reference angle, ``multihead``)
or one sensor against a reference (``sensor``), 3 steady runs at different speeds (and, for
the direction classes, both directions), with a disk error of orders 1-5, white noise, and
one structure of a class nobody wrote into the catalog. The truth says the frame and
modulation a correct model has, and the speed exponent where there is one.
"""

from __future__ import annotations

import numpy as np

from ..io import Recording

NOISE_RAD = 0.5e-6
"""Noise std of every reading (rad)."""

CLASSES = (
    "torque_ripple",
    "head_defect",
    "one_direction",
    "fixed_hz",
    "slow_growth",
    "intermittent",
    "direction_lag",
    "speed_lag",
)
"""The out-of-catalog classes: torque ripple at a drive order falling as speed^-2 (a shaft
motion); a defect of one head; an error in one direction only; a structure at a fixed
frequency with its own Q (excited in every run with its own phase); a slow growth over the
record; an order present in one run only; an error of opposite sign in the two directions;
a lag growing as speed^+1."""

KINDS = ("multihead", "sensor")

POLE_PAIRS = 7


def _truth(cls: str, C: int, rng) -> dict:
    m = int(rng.choice([9, 11, 13, 17]))
    if cls == "torque_ripple":
        return dict(line=("order", 2 * POLE_PAIRS), frame="shaft", modulation="speed", beta=-2.0)
    if cls == "head_defect":
        k = int(rng.integers(0, C))
        return dict(line=("order", m), frame=f"head {k}" if C > 1 else "shaft", modulation="static")
    if cls == "one_direction":
        return dict(line=("order", m), frame="shaft", modulation="forward")
    if cls == "fixed_hz":
        return dict(line=("hz", float(rng.uniform(23.0, 37.0))), frame="hz", modulation="per_cell")
    if cls == "slow_growth":
        return dict(line=("order", m), frame="disk" if C > 1 else "shaft", modulation="growth")
    if cls == "intermittent":
        return dict(
            line=("order", m), frame="shaft", modulation="cell", run=int(rng.integers(0, 3))
        )
    if cls == "direction_lag":
        return dict(line=("order", m), frame="shaft", modulation="direction")
    if cls == "speed_lag":
        return dict(line=("order", m), frame="shaft", modulation="speed", beta=1.0)
    raise ValueError(f"unknown class {cls!r}; expected one of {CLASSES}")


def outside_record(
    rng: np.random.Generator,
    cls: str,
    size: float,
    kind: str = "multihead",
    n_rows: int = 6000,
) -> tuple[Recording, dict]:
    """``(recording, truth)``: a bench of ``kind`` with one structure of class ``cls``
    (:data:`CLASSES`; ``"clean"``: none) of peak amplitude ``size`` x the noise.

    ``truth``: ``line`` (``("order", m)`` or ``("hz", f)``), ``frame``, ``modulation``,
    ``beta`` (speed exponent, where the class has one), ``alpha`` (head azimuths, rad)."""
    C = 4 if kind == "multihead" else 1
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r}; expected one of {KINDS}")
    R = 3
    n = n_rows // R
    fs = 500.0
    both = cls in ("one_direction", "direction_lag")
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.4, 5.9, C - 1))]) if C > 1 else np.zeros(1)
    truth = {"alpha": alpha, "class": cls, "size": size, "kind": kind}
    if cls != "clean":
        truth.update(_truth(cls, C, rng))
    speeds = np.array([1.0, 1.7, 2.9]) * 2 * np.pi * rng.uniform(0.8, 1.2)
    signs = np.array([1.0, -1.0, 1.0]) if both else np.ones(R)
    if both:
        speeds = np.array([1.0, 1.0, 1.7]) * speeds[0]
    ts, ths, runs, ws = [], [], [], []
    for r in range(R):
        t = np.arange(n) / fs
        w = signs[r] * speeds[r]
        ts.append(t)
        ths.append(w * t + rng.uniform(0, 2 * np.pi))
        runs.append(np.full(n, r))
        ws.append(np.full(n, w))
    t, th, run, om = map(np.concatenate, (ts, ths, runs, ws))
    err = np.zeros((t.size, C))
    for m in range(1, 6):
        err += 8 * NOISE_RAD / m * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6))
    A = size * NOISE_RAD
    ph = rng.uniform(0, 2 * np.pi)
    if cls != "clean":
        kind_l, val = truth["line"]
        g0 = np.exp(np.mean(np.log(speeds)))
        if kind_l == "hz":
            phr = rng.uniform(0, 2 * np.pi, R)[run]
            s = A * np.sin(2 * np.pi * val * t + phr)[:, None] * np.ones(C)
        else:
            fr = truth["frame"]
            if fr == "disk":
                s = np.sin(val * (th[:, None] - alpha[None, :]) + ph)
            else:
                s = np.sin(val * th + ph)[:, None] * np.ones(C)
                if fr.startswith("head "):
                    s = s * (np.arange(C) == int(fr.split()[1]))[None, :]
            mod = truth["modulation"]
            if mod == "speed":
                g = (np.abs(om) / g0) ** truth["beta"]
            elif mod == "forward":
                g = (om > 0) * 1.0
            elif mod == "direction":
                g = np.sign(om)
            elif mod == "growth":
                tau = t + run * (n / fs + 1.0)
                g = tau / tau.max()
            elif mod == "cell":
                g = (run == truth["run"]) * 1.0
            else:
                g = np.ones(t.size)
            s = A * s * g[:, None]
        err += s
    read = th[:, None] + err + rng.normal(0, NOISE_RAD, err.shape)
    cols = {"t": t, "run": run, "theta_ref": th.copy()}
    for k in range(C):
        cols[f"h{k}"] = read[:, k]
    enc = {"head_angles_deg": np.degrees(alpha).tolist()}
    if C > 1:
        enc["optical_radius_m"] = 0.02
    else:
        enc["sensor"] = "magnetic"
    meta = {
        "format": "encdesign-recording/1",
        "kind": "multihead",
        "encoder": enc,
        "motor": {"pole_pairs": POLE_PAIRS},
    }
    truth["speeds_rad_s"] = speeds
    return Recording("multihead", meta, cols), truth
