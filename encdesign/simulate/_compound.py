"""Multihead bench records with several catalog effects at once (issue 44 B).

A bench with ``H`` heads and a reference column (``theta_ref``), several runs at different
speeds, a disk error of a few orders that every head sees phase-shifted by its azimuth, and
any of ``vibration`` (a structural line fixed in Hz), ``beam_tilt_axial`` (an axial runout of
several orders seen through tangentially tilted beams) and ``interpolation_error``
(imperfect quadrature signals, interpolated by arctangent). The effects are written from
``physics._effects``, never with the finder's own terms.

Geometries (``GEOMETRIES``): head azimuths in degrees before a per-record jitter.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from .._errors import input_error
from ..io._recording import Recording
from ..physics import _effects as fx

GEOMETRIES = {
    "4+1": (0.0, 90.0, 180.0, 270.0),
    "4i+1": (0.0, 83.0, 171.0, 262.0),
    "3+1": (0.0, 115.0, 250.0),
    "5+1": (0.0, 70.0, 150.0, 215.0, 290.0),
}
"""Head azimuths (deg) of each layout; every layout has a ``theta_ref`` column (the ``+1``)."""

COMPOUND_EFFECTS = ("vibration", "beam_tilt_axial", "interpolation_error")
"""The effects :func:`simulate_compound` can conceal together."""

AMPLITUDES = {"vibration": 8.0, "beam_tilt_axial": 8.0, "interpolation_error": 1.5}
"""Default size of each effect (its largest error, in units of the read noise)."""


def simulate_compound(
    rng: np.random.Generator,
    *,
    geometry: str = "4+1",
    effects: tuple[str, ...] = COMPOUND_EFFECTS,
    jitter_deg: float = 6.0,
    speeds_rev_s: tuple[float, ...] = (0.6, 1.0, 1.45),
    samples_per_run: int = 2000,
    sample_rate_hz: float = 200.0,
    noise_rad: float = 0.5e-6,
    amplitudes: dict[str, float] | None = None,
    runout_orders: int = 3,
    runout_falloff: tuple[float, float] = (1.0, 2.0),
    grating_lines: int = 10000,
    one_head_order: float = 0.0,
) -> tuple[Recording, dict[str, Any]]:
    """A multihead recording with ``effects`` at once; returns ``(recording, truth)``.

    Args:
        rng: all randomness.
        geometry: a key of :data:`GEOMETRIES`.
        effects: a subset of :data:`COMPOUND_EFFECTS`.
        jitter_deg: each head's azimuth moves by up to this much (deg).
        speeds_rev_s: shaft speed of each run, rev/s.
        samples_per_run: rows per run; sample_rate_hz: its rate, Hz.
        noise_rad: read-noise std, rad.
        amplitudes: each effect's largest error in units of ``noise_rad`` (default
            :data:`AMPLITUDES`: two strong effects and a weak one).
        runout_orders: the axial runout of ``beam_tilt_axial`` has orders ``1..runout_orders``
            of amplitude ``m**-p`` times that of order 1, ``p`` drawn from ``runout_falloff``.
        grating_lines: lines per revolution (``interpolation_error`` at orders L and 2L).
        one_head_order: when > 0, an out-of-catalog structure of this size (in units of
            ``noise_rad``): an integer order 5-8 on one head (truth ``where``), which no
            catalog effect explains and the finder must leave ``unexplained``.
    """
    if geometry not in GEOMETRIES:
        raise input_error("geometry", f"got {geometry!r}", f"one of {list(GEOMETRIES)}")
    bad = [e for e in effects if e not in COMPOUND_EFFECTS]
    if bad:
        raise input_error("effects", f"got {bad}", f"a subset of {list(COMPOUND_EFFECTS)}")
    R_m = 0.0254
    deg = np.asarray(GEOMETRIES[geometry], float)
    deg = deg + np.concatenate([[0.0], rng.uniform(-jitter_deg, jitter_deg, deg.size - 1)])
    alpha = np.deg2rad(deg)
    H = alpha.size
    R = len(speeds_rev_s)
    n = samples_per_run * R
    dt = 1.0 / sample_rate_hz
    run = np.repeat(np.arange(R), samples_per_run)
    t = np.tile(np.arange(samples_per_run) * dt, R)
    theta = np.empty(n)
    for r, sp in enumerate(speeds_rev_s):
        rows = run == r
        theta[rows] = rng.uniform(0, 2 * np.pi) + 2 * np.pi * sp * rng.uniform(0.98, 1.02) * t[rows]
    # the disk error: orders 1..6, every head sees it shifted by its azimuth
    err = np.zeros((n, H))
    for m in range(1, 7):
        a = 30 * noise_rad / m * rng.uniform(0.3, 1.0)
        ph = rng.uniform(0, 2 * np.pi)
        err += a * np.sin(m * (theta[:, None] - alpha[None, :]) + ph)
    amp_of = {**AMPLITUDES, **(amplitudes or {})}
    truth: dict[str, Any] = {"effects": list(effects), "geometry": geometry, "alpha_deg": deg}
    th = jnp.asarray(theta)
    if "vibration" in effects:
        f = rng.uniform(0.2, 0.8) * sample_rate_hz / 2
        A = amp_of["vibration"] * noise_rad
        amp = A * rng.uniform(0.6, 1.0, H)
        ph = rng.uniform(0, 2 * np.pi, (R, H))
        C = amp[None, :] * np.sin(ph)
        S = amp[None, :] * np.cos(ph)
        err += np.asarray(fx.vibration_rad(jnp.asarray(t), f, jnp.asarray(C[run]), S[run]))
        truth["vibration_hz"] = float(f)
    if "beam_tilt_axial" in effects:
        A = amp_of["beam_tilt_axial"] * noise_rad
        beta = rng.uniform(2e-3, 8e-3, H) * rng.choice([-1, 1], H)
        orders = np.arange(1.0, runout_orders + 1)
        z = A * R_m / np.max(np.abs(beta)) * orders ** -rng.uniform(*runout_falloff)
        ph = rng.uniform(0, 2 * np.pi, orders.size)
        err += np.asarray(
            fx.beam_tilt_axial_rad(
                th,
                R_m,
                jnp.asarray(beta),
                jnp.asarray(z * np.cos(ph)),
                jnp.asarray(z * np.sin(ph)),
                jnp.asarray(orders),
            )
        )
        truth["runout_orders"] = orders.astype(int).tolist()
    if one_head_order > 0:
        k = int(rng.integers(H))
        m = int(rng.integers(5, 9))
        err[:, k] += one_head_order * noise_rad * np.sin(m * theta + rng.uniform(0, 2 * np.pi))
        truth["where"] = {"heads": [k], "orders": [m]}
    readings = theta[:, None] + err
    if "interpolation_error" in effects:
        L = grating_lines
        A = amp_of["interpolation_error"] * noise_rad
        o = A * L * rng.uniform(0.5, 1.0, (4, H)) * rng.choice([-1, 1], (4, H))
        readings = readings + np.asarray(
            fx.interpolation_error_exact_rad(jnp.asarray(readings), L, *[jnp.asarray(v) for v in o])
        )
    pitch = 2 * np.pi / grating_lines
    readings = readings + rng.integers(-1000, 1000, H)[None, :] * pitch
    readings = readings + rng.normal(0, noise_rad, (n, H))
    cols: dict[str, np.ndarray] = {"t": t, "run": run, "theta_ref": theta.copy()}
    for k in range(H):
        cols[f"h{k}"] = readings[:, k]
    enc = {
        "optical_radius_m": R_m,
        "head_angles_deg": [float(x) for x in deg],
        "grating_lines": int(grating_lines),
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    truth["noise_rad"] = noise_rad
    return Recording("multihead", meta, cols), truth
