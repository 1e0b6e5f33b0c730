"""Generate bench recordings (multihead kind) with one physics-catalog effect concealed.

A realistic bench (seed 000's 2.54 cm optical radius; 3+1 or 2+1 heads; several runs at
different speeds; a slowly varying ``temp_c``; white read noise) carries the base errors
(eccentricity of a few um, tilt, grating errors of orders 2..8, head placement errors) and,
optionally, one hidden effect, at an amplitude of about the per-sample noise:

The base errors come from the kinematic model (``encdesign.physics._kinematics``, seed 000
section V.A); the hidden effects are the reading-space terms of ``encdesign.physics._effects``.

* ``beam_tilt_axial``: axial runout at order 1 (masked by the much larger eccentricity) or
  2..3, seen through tangential beam tilts of a few mrad;
* ``bearing_wobble``: radial runout at a cage ratio 0.35..0.45 of the shaft speed;
* ``vibration``: a structural frequency, sometimes above the Nyquist frequency (aliased by
  coarse sampling) or present in only some runs;
* ``thermal_drift``: per-head rates of the order of seed 001's 0.7 arcsec/K;
* ``interpolation_error``: signal offsets / amplitude / phase errors of the heads'
  quadrature signals, 10000 lines sampled far below the line rate (aliased);
* ``eccentricity_shift``: the disk slips by tens of nm at one instant (part of the record).

Out-of-catalog effects (``count_jump``: one head's reading steps at one instant;
``chirp``: an oscillation whose frequency sweeps during each run) test that the finder
reports what it cannot name as ``unexplained``.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import input_error
from ..io._recording import Recording, write_recording
from ..physics import _effects as fx
from ..physics._kinematics import head_errors, make_model

OUT_OF_CATALOG = ("count_jump", "chirp")
HIDDEN = (*fx.CATALOG_MULTIHEAD, *OUT_OF_CATALOG)
CONCEALMENTS = ("near_noise", "masked", "aliased", "partial")

LAYOUTS = {"3+1": [0.0, 120.0, 240.0, 50.0], "2+1": [0.0, 180.0, 75.0]}


def simulate_concealed_bench(
    *,
    key: jax.Array,
    effect: str | None = None,
    layout: str = "3+1",
    speeds_rev_s: tuple[float, ...] = (0.6, 1.0, 1.45),
    samples_per_run: int = 2000,
    sample_rate_hz: float = 200.0,
    noise_rad: float = 0.5e-6,
    amplitude: float = 2.0,
    concealment: str = "near_noise",
    theta_ref: bool = True,
    grating_lines: int = 10000,
) -> tuple[dict[str, np.ndarray], dict[str, Any], dict[str, Any]]:
    """Simulate a multihead bench recording.

    Args:
        key: JAX PRNG key (all randomness).
        effect: hidden effect (catalog name, ``count_jump``, ``chirp``) or ``None``.
        layout: ``"3+1"`` or ``"2+1"`` heads.
        speeds_rev_s: shaft speed of each run, rev/s.
        samples_per_run: rows per run.
        sample_rate_hz: sampling rate, Hz.
        noise_rad: read-noise std, rad.
        amplitude: hidden-effect error amplitude in units of ``noise_rad``.
        concealment: how it is hidden (``near_noise``, ``masked``, ``aliased``, ``partial``).
        theta_ref: write a reference-angle column.
        grating_lines: lines per revolution.

    Returns:
        ``(columns, encoder_table, truth)``.
    """
    if effect is not None and effect not in HIDDEN:
        raise input_error("effect", f"got {effect!r}", f"one of {list(HIDDEN)}")
    if layout not in LAYOUTS:
        raise input_error("layout", f"got {layout!r}", f"one of {list(LAYOUTS)}")
    rng = np.random.default_rng(np.asarray(jax.random.key_data(key)).ravel().tolist())
    R_m = 0.0254
    angles_deg = np.asarray(LAYOUTS[layout])
    angles_deg[-1] += rng.uniform(-10, 10)
    H = angles_deg.size
    alpha = np.deg2rad(angles_deg)
    L = grating_lines
    R = len(speeds_rev_s)
    n = samples_per_run * R
    dt = 1.0 / sample_rate_hz
    run = np.repeat(np.arange(R), samples_per_run)
    t_run = np.tile(np.arange(samples_per_run) * dt, R)
    dur = samples_per_run * dt
    tau = run * (dur + dt) + t_run
    theta = np.empty(n)
    speeds_rev_s = tuple(float(sp * rng.uniform(0.98, 1.02)) for sp in speeds_rev_s)
    for r, sp in enumerate(speeds_rev_s):
        rows = run == r
        theta[rows] = rng.uniform(0, 2 * np.pi) + 2 * np.pi * sp * t_run[rows]
    # temperature: slow wander of about 1 K
    temp = 21.0 + rng.uniform(0.4, 1.0) * np.sin(
        2 * np.pi * tau / (tau[-1] * rng.uniform(1.2, 2.5)) + rng.uniform(0, 2 * np.pi)
    )
    # base errors through the kinematic model (seed 000 section V.A): eccentricity, tilt,
    # grating errors of orders 2..8, head placement errors
    M = 8
    ecc_m = rng.uniform(1e-6, 5e-6)
    ecc_ph = rng.uniform(0, 2 * np.pi)
    tilt = rng.uniform(1e-3, 6e-3)
    tilt_ph = rng.uniform(0, 2 * np.pi)
    gs = np.zeros(M)
    gc = np.zeros(M)
    for m in range(2, M + 1):
        amp = 5e-6 / m * rng.uniform(0.3, 1.0)
        ph = rng.uniform(0, 2 * np.pi)
        gs[m - 1], gc[m - 1] = amp * np.cos(ph), amp * np.sin(ph)
    placement = np.concatenate([[0.0], rng.normal(0, 1e-3, H - 1)])
    model = make_model(
        R_m,
        jnp.asarray(alpha),
        eccentricity_m=(ecc_m * np.cos(ecc_ph), ecc_m * np.sin(ecc_ph)),
        tilt_rad=(tilt * np.cos(tilt_ph), tilt * np.sin(tilt_ph)),
        grating_sin_rad=gs,
        grating_cos_rad=gc,
        placement_error_rad=placement,
    )
    th = jnp.asarray(theta)
    err = np.asarray(head_errors(model, th))
    A = amplitude * noise_rad
    truth: dict[str, Any] = {"effect": effect, "concealment": concealment, "params": {}}
    extra = np.zeros((n, H))
    interp = None
    if effect == "beam_tilt_axial":
        order = 1 if concealment == "masked" else int(rng.integers(2, 4))
        beta = rng.uniform(2e-3, 8e-3, H) * rng.choice([-1, 1], H)
        beta -= beta.mean() * (0 if theta_ref else 1)
        z = A * R_m / np.max(np.abs(beta))
        ph = rng.uniform(0, 2 * np.pi)
        zc = np.zeros(order)
        zs = np.zeros(order)
        zc[-1], zs[-1] = z * np.cos(ph), z * np.sin(ph)
        extra += np.asarray(
            fx.beam_tilt_axial_rad(
                th,
                R_m,
                jnp.asarray(beta),
                jnp.asarray(zc),
                jnp.asarray(zs),
                jnp.arange(1.0, order + 1),
            )
        )
        truth["params"] = dict(
            runout_orders=[order],
            beam_tilt_rad=beta.tolist(),
            axial_runout_m=z,
            error_amplitude_rad=(np.abs(beta) * z / R_m).tolist(),
        )
    elif effect == "bearing_wobble":
        nu = rng.uniform(0.35, 0.45)
        rho = A * R_m
        phs = rng.uniform(0, 2 * np.pi, R)
        Ar, Br = rho * np.cos(phs), rho * np.sin(phs)
        extra += np.asarray(
            fx.bearing_wobble_rad(
                th, jnp.asarray(alpha), R_m, nu, jnp.asarray(Ar[run]), jnp.asarray(Br[run])
            )
        )
        truth["params"] = dict(frequency_ratio=nu, runout_m=rho)
    elif effect == "vibration":
        nyq = sample_rate_hz / 2
        f = rng.uniform(1.2, 1.7) * nyq if concealment == "aliased" else rng.uniform(0.2, 0.8) * nyq
        amp = A * rng.uniform(0.5, 1.0, H)
        amp[int(rng.integers(H))] = A
        present = np.ones(R, bool)
        if concealment == "partial":
            present[: R - 1] = False
            present[int(rng.integers(R - 1))] = True
        ph = rng.uniform(0, 2 * np.pi, (R, H))
        C = (amp[None, :] * np.sin(ph)) * present[:, None]
        S = (amp[None, :] * np.cos(ph)) * present[:, None]
        extra += np.asarray(
            fx.vibration_rad(jnp.asarray(t_run), f, jnp.asarray(C[run]), jnp.asarray(S[run]))
        )
        alias = abs(f - sample_rate_hz * round(f / sample_rate_hz))
        truth["params"] = dict(
            frequency_hz=f,
            apparent_frequency_hz=alias,
            amplitude_rad_per_head=amp.tolist(),
            runs_present=np.flatnonzero(present).tolist(),
        )
    elif effect == "thermal_drift":
        kap = rng.uniform(-1.0, 1.0, H) * 0.7 * fx.ARCSEC_RAD
        kap[int(rng.integers(H))] = 0.7 * fx.ARCSEC_RAD * rng.choice([-1, 1])
        if not theta_ref:
            kap -= kap.mean()
        scale = A / (np.max(np.abs(kap)) * np.std(temp)) if concealment == "near_noise" else 1.0
        kap *= scale
        extra += np.asarray(fx.thermal_drift_rad(jnp.asarray(kap), jnp.asarray(temp - temp.mean())))
        truth["params"] = dict(rate_rad_per_k=kap.tolist())
    elif effect == "interpolation_error":
        o = A * L * rng.uniform(0.5, 1.0, (4, H)) * rng.choice([-1, 1], (4, H))
        interp = o
        truth["params"] = dict(
            offset_a=o[0].tolist(),
            offset_b=o[1].tolist(),
            amplitude_error=o[2].tolist(),
            phase_error_rad=o[3].tolist(),
        )
    elif effect == "eccentricity_shift":
        ts = tau[0] + (tau[-1] - tau[0]) * rng.uniform(0.25, 0.75)
        d = A * R_m
        ph = rng.uniform(0, 2 * np.pi)
        w = 0.5 * dt
        extra += np.asarray(
            fx.eccentricity_shift_rad(
                th, jnp.asarray(tau), jnp.asarray(alpha), R_m, ts, d * np.cos(ph), d * np.sin(ph), w
            )
        )
        i = int(np.searchsorted(tau, ts))
        truth["params"] = dict(
            shift_m=d,
            shift_time_s=float(t_run[i]),
            shift_run=int(run[i]),
            shift_global_time_s=float(ts),
        )
    elif effect == "count_jump":
        k = int(rng.integers(H))
        ts = tau[0] + (tau[-1] - tau[0]) * rng.uniform(0.25, 0.75)
        jump = 3 * A * rng.choice([-1, 1])
        extra[:, k] += jump * (tau >= ts)
        i = int(np.searchsorted(tau, ts))
        truth["params"] = dict(head=k, jump_rad=jump, time_s=float(t_run[i]), run=int(run[i]))
        truth["where"] = dict(heads=[k], times_s=[float(t_run[i])], runs=[int(run[i])])
    elif effect == "chirp":
        k = int(rng.integers(H))
        f0, f1 = 0.15 * sample_rate_hz, 0.35 * sample_rate_hz
        phase = 2 * np.pi * (f0 * t_run + 0.5 * (f1 - f0) / dur * t_run**2)
        extra[:, k] += 2 * A * np.sin(phase + rng.uniform(0, 2 * np.pi))
        truth["params"] = dict(head=k, f_start_hz=f0, f_end_hz=f1)
        truth["where"] = dict(heads=[k], frequencies_hz=[f0, f1])
    readings_true = theta[:, None] + err + extra
    if interp is not None:
        extra_i = np.asarray(
            fx.interpolation_error_exact_rad(
                jnp.asarray(readings_true), L, *[jnp.asarray(v) for v in interp]
            )
        )
        readings_true = readings_true + extra_i
    pitch = 2 * np.pi / L
    const = rng.integers(-1000, 1000, H) * pitch
    noise = rng.normal(0, noise_rad, (n, H))
    readings = readings_true + const[None, :] + noise
    cols: dict[str, np.ndarray] = {"t": t_run, "run": run}
    if theta_ref:
        cols["theta_ref"] = theta
    for k in range(H):
        cols[f"h{k}"] = readings[:, k]
    cols["temp_c"] = temp
    encoder = dict(
        optical_radius_m=R_m,
        head_angles_deg=[float(x) for x in angles_deg],
        reference_head=H - 1,
        grating_lines=L,
    )
    truth.update(
        layout=layout, noise_rad=noise_rad, theta_ref=theta_ref, speeds_rev_s=list(speeds_rev_s)
    )
    return cols, encoder, truth


def write_concealed(
    path: str | os.PathLike, *, key: jax.Array, **kwargs: Any
) -> tuple[Recording, dict[str, Any]]:
    """Simulate a bench (:func:`simulate_concealed_bench` arguments) and write it as a recording.

    The truth is written into the TOML's ``[provenance]`` table (a blind benchmark must
    not read it; the finder never does).
    """
    cols, enc, truth = simulate_concealed_bench(key=key, **kwargs)
    prov = {
        "generator": "encdesign.simulate._conceal",
        "hidden": str(truth["effect"]),
        "concealment": truth["concealment"],
    }
    rec = write_recording(
        path,
        "multihead",
        cols,
        encoder=enc,
        description=f"simulated bench, hidden: {truth['effect']}",
        provenance=prov,
    )
    return rec, truth
