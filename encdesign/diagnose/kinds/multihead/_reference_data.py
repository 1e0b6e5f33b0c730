"""Data helpers of the sensor-against-reference finder (NumPy, not traced): the reference
velocity per sample, the smoothing width of the direction sign, a record's summary before any
fit and the dominant orders of a fitted error function. The value lattice of a column
(:func:`detect_lsb`) is the engine's (:mod:`encdesign.diagnose.engine._lattice`).
"""

from __future__ import annotations

import math

import numpy as np

from ...engine._lattice import Lattice, detect_lsb
from ...engine._settings import FinderSettings

__all__ = [
    "reference_velocity_rad_s",
    "velocity_width_rad_s",
    "Lattice",
    "detect_lsb",
    "reference_summary",
    "dominant_orders",
]


def reference_velocity_rad_s(
    t_s: np.ndarray, theta_ref_rad: np.ndarray, run: np.ndarray | None = None
) -> np.ndarray:
    """Reference velocity per sample (rad/s): central differences within each run.

    A run of one sample gets zero velocity. Data preparation (NumPy), not a traced term.
    """
    t = np.asarray(t_s, dtype=np.float64)
    th = np.asarray(theta_ref_rad, dtype=np.float64)
    run = np.zeros(t.size, dtype=np.int64) if run is None else np.asarray(run)
    out = np.zeros_like(th)
    for r in np.unique(run):
        idx = np.flatnonzero(run == r)
        if idx.size >= 2:
            out[idx] = np.gradient(th[idx], t[idx])
    return out


def velocity_width_rad_s(velocity_rad_s: np.ndarray, fraction: float = 0.05) -> float:
    """Smoothing width of the direction sign: ``fraction`` of the median ``|omega|`` (rad/s).

    Falls back to 1 rad/s for a record that does not move (the term is then zero anyway).
    """
    w = np.abs(np.asarray(velocity_rad_s, dtype=np.float64))
    w = w[w > 0]
    med = float(np.median(w)) if w.size else 0.0
    return fraction * med if med > 0 else 1.0


def reference_summary(
    t_s: np.ndarray,
    theta_ref_rad: np.ndarray,
    reading_rad: np.ndarray,
    run: np.ndarray | None = None,
    *,
    settings: FinderSettings,
) -> dict:
    """What a sensor-against-reference record is, before any fit (JSON-ready).

    Returns a dict with ``span_turns`` (per run), ``directions`` (``forward``, ``backward``
    or ``both`` per run, from the sign of the reference velocity), ``speed_rad_s`` (median
    ``|omega|`` per run), ``sensor_lattice`` and ``reference_lattice`` (:func:`detect_lsb`,
    with ``floor_rms_rad = lsb / sqrt(12)`` when a lattice is found).
    """
    t = np.asarray(t_s, dtype=np.float64)
    th = np.asarray(theta_ref_rad, dtype=np.float64)
    rd = np.asarray(reading_rad, dtype=np.float64)
    run = np.zeros(t.size, dtype=np.int64) if run is None else np.asarray(run)
    w = reference_velocity_rad_s(t, th, run)
    span, dirs, speed = {}, {}, {}
    for r in np.unique(run):
        m = run == r
        span[str(int(r))] = float(np.ptp(th[m]) / (2 * np.pi))
        fwd, bwd = bool(np.any(w[m] > 0)), bool(np.any(w[m] < 0))
        dirs[str(int(r))] = "both" if fwd and bwd else ("forward" if fwd else "backward")
        speed[str(int(r))] = float(np.median(np.abs(w[m])))
    out = {"span_turns": span, "directions": dirs, "speed_rad_s": speed}
    for name, vals in (("sensor_lattice", rd), ("reference_lattice", th)):
        lat = detect_lsb(vals, run, settings=settings).as_dict()
        lat["floor_rms_rad"] = None if lat["lsb_rad"] is None else lat["lsb_rad"] / math.sqrt(12)
        out[name] = lat
    return out


def dominant_orders(
    cos_rad: np.ndarray,
    sin_rad: np.ndarray,
    se_cos_rad: np.ndarray | None = None,
    se_sin_rad: np.ndarray | None = None,
    n: int = 5,
) -> list[dict]:
    """The ``n`` largest orders of a Fourier error function ``sum a_m cos m th + b_m sin m th``.

    Returns ``[{"order", "amplitude_rad", "se_rad", "share"}, ...]`` by decreasing amplitude
    ``sqrt(a^2 + b^2)``; ``share`` is the order's part of the function's mean square
    (``amp^2 / sum amp^2``); ``se_rad`` the amplitude's standard error (linear propagation,
    ``None`` without standard errors).
    """
    a = np.asarray(cos_rad, dtype=np.float64)
    b = np.asarray(sin_rad, dtype=np.float64)
    amp = np.hypot(a, b)
    tot = float(np.sum(amp**2))
    out = []
    for i in np.argsort(amp)[::-1][:n]:
        se = None
        if se_cos_rad is not None and se_sin_rad is not None and amp[i] > 0:
            sa, sb = float(np.asarray(se_cos_rad)[i]), float(np.asarray(se_sin_rad)[i])
            se = float(np.hypot(a[i] * sa, b[i] * sb) / amp[i])
            se = se if np.isfinite(se) else None
        out.append(
            {
                "order": int(i + 1),
                "amplitude_rad": float(amp[i]),
                "se_rad": se,
                "share": float(amp[i] ** 2 / tot) if tot > 0 else 0.0,
            }
        )
    return out
