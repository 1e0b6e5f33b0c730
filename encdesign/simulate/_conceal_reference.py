"""Simulated benches of one sensor read against a reference angle (``multihead``, one head).

A magnetic angle sensor, a resolver, a capacitive encoder or an optical head is turned by a
drive whose angle a reference (an encoder, a rotary table, a commanded stepper angle)
records as ``theta_ref``. The simulation is physical, not a sum of the finder's terms:

* the shaft follows a trajectory ``theta(t)`` per run: ``forward`` or ``backward`` at a
  steady speed, ``both`` (forward over the span, then back: a reversal in the middle of the
  run) or ``oscillating`` (``theta0 + pi S (1 - cos 2 pi t / T)``: both directions at a
  speed that varies, so a reading delay and a direction offset can be told apart);
* the sensor sees ``theta_s = theta(t - tau) + (h / 2) sign(omega(t - tau))``
  (``reading_delay`` ``tau``, ``direction_hysteresis`` ``h`` as an exact step), advances
  ``(1 + s)`` turns per turn (``scale_error`` ``s``), adds its own error function of the
  shaft angle (Fourier orders, the base model) and the exact arctangent interpolation error
  of its ``P``-period signal (``interpolation_error``), its zero of the run and white noise;
  the result is rounded to its LSB (``quantization``) when that effect is present;
* ``theta_ref = theta(t) + z_ref,r`` (the reference's zero of the run: none, whole turns or
  any amount).

:func:`simulate_sensor_reference` returns ``(columns, encoder, truth)``;
:func:`write_sensor_reference` writes a recording; :func:`random_reference_bench` draws a
whole bench (sensor, span, speeds, directions, effect sizes relative to the noise) for
benchmarks.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import numpy as np

from .._errors import input_error
from ..io._recording import Recording, write_recording
from ..physics import _sensor_effects as rt

SENSORS: dict[str, dict[str, Any]] = {
    # signal periods per turn, read noise (rad), base error amplitudes of orders 1, 2, 3 (rad)
    "magnetic": {"periods_per_rev": 1, "noise_rad": 3e-4, "base_rad": (3e-3, 2e-3, 4e-4)},
    "resolver": {"periods_per_rev": 4, "noise_rad": 1e-4, "base_rad": (1e-3, 6e-4, 2e-4)},
    "capacitive": {"periods_per_rev": 32, "noise_rad": 2e-5, "base_rad": (2e-4, 1e-4, 4e-5)},
    "optical": {"periods_per_rev": 2048, "noise_rad": 2e-6, "base_rad": (2e-5, 8e-6, 3e-6)},
}
"""Typical sensors: signal periods per turn, read noise and base error sizes."""

DIRECTIONS = ("forward", "backward", "both", "oscillating")
ZEROS = ("none", "turns", "any")


def _rng(key: jax.Array) -> np.random.Generator:
    return np.random.default_rng(np.asarray(jax.random.key_data(key)).ravel().tolist())


def _check_effects(effects: Mapping[str, Mapping[str, float]] | None) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for name, params in (effects or {}).items():
        if name not in rt.REFERENCE_PARAM_UNITS:
            raise input_error(
                "effects", f"unknown effect {name!r}", f"one of {list(rt.CATALOG_REFERENCE)}"
            )
        units = rt.REFERENCE_PARAM_UNITS[name]
        unknown = sorted(set(params) - set(units))
        if unknown:
            raise input_error(
                f"effects.{name}", f"unknown parameter(s) {unknown}", f"some of {sorted(units)}"
            )
        vals = {}
        for k, v in params.items():
            if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
                raise input_error(f"effects.{name}.{k}", f"got {v!r}", "a finite number")
            vals[k] = float(v)
        if name == "quantization" and not vals.get("lsb_rad", 0.0) > 0:
            raise input_error("effects.quantization.lsb_rad", f"got {params}", "a step > 0 rad")
        out[name] = vals
    return out


def _trajectory(t: np.ndarray, direction: str, omega: float, duration: float, theta0: float):
    """Shaft angle (rad) and velocity (rad/s) at times ``t`` (may be < 0: extended)."""
    if direction == "forward":
        return theta0 + omega * t, np.full_like(t, omega)
    if direction == "backward":
        return theta0 - omega * t, np.full_like(t, -omega)
    if direction == "both":
        half = 0.5 * duration
        up = t < half
        th = np.where(up, theta0 + omega * t, theta0 + omega * (2 * half - t))
        return th, np.where(up, omega, -omega)
    # oscillating: mean |omega| over the cycle equals omega
    amp = 0.25 * omega * duration  # pi S with S = span turns: 2 pi S = omega T / 2
    w = 2 * np.pi / duration
    return theta0 + amp * (1 - np.cos(w * t)), amp * w * np.sin(w * t)


def _zeros(rng: np.random.Generator, how: str, n: int, what: str) -> np.ndarray:
    if how not in ZEROS:
        raise input_error(what, f"got {how!r}", f"one of {list(ZEROS)}")
    if how == "none":
        return np.zeros(n)
    turns = 2 * np.pi * rng.integers(-3, 4, n)
    if how == "turns":
        return turns.astype(np.float64)
    return turns + rng.uniform(-np.pi, np.pi, n)


def simulate_sensor_reference(
    *,
    key: jax.Array,
    sensor: str = "magnetic",
    periods_per_rev: int | None = None,
    span_turns: float = 1.0,
    directions: str = "both",
    speeds_rev_s: Sequence[float] = (1.0,),
    samples_per_run: int = 1000,
    noise_rad: float | None = None,
    base_rad: Sequence[float] | None = None,
    effects: Mapping[str, Mapping[str, float]] | None = None,
    run_zeros: str = "any",
    reference_zeros: str = "turns",
    optical_radius_m: float | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, Any], dict[str, Any]]:
    """Simulate a sensor-against-reference recording (``multihead`` with one head).

    Args:
        key: JAX PRNG key (all randomness: phases, zeros, noise).
        sensor: ``magnetic``, ``resolver``, ``capacitive`` or ``optical`` (defaults of
            :data:`SENSORS`).
        periods_per_rev: signal periods per turn ``P`` (default: the sensor's).
        span_turns: turns swept per direction (``< 1``: part of a turn).
        directions: ``forward``, ``backward``, ``both`` or ``oscillating``.
        speeds_rev_s: mean shaft speed of each run, rev/s (one run each).
        samples_per_run: rows per run.
        noise_rad: white read noise std, rad (default: the sensor's).
        base_rad: amplitudes (rad) of the sensor's error function at orders 1, 2, …
            (random phases; default: the sensor's).
        effects: effect name -> parameters (``physics._sensor_effects.REFERENCE_PARAM_UNITS``):
            ``direction_hysteresis`` (``hysteresis_rad``), ``reading_delay`` (``delay_s``),
            ``quantization`` (``lsb_rad``; the lattice is at the sensor's zero),
            ``scale_error`` (``scale``), ``interpolation_error`` (``offset_a``,
            ``offset_b``, ``amplitude_ratio``, ``phase_error_rad``).
        run_zeros: the sensor's zero per run: ``none``, ``turns`` or ``any``.
        reference_zeros: the reference's zero per run, likewise. Anything but whole turns
            shifts the sensor's periodic error against ``theta_ref`` from run to run.
        optical_radius_m: written to ``[encoder]`` when given.

    Returns:
        ``(columns, encoder, truth)``: the data table, the ``[encoder]`` table and what was
        simulated (effect parameters with units, base coefficients, zeros, noise).
    """
    if sensor not in SENSORS:
        raise input_error("sensor", f"got {sensor!r}", f"one of {list(SENSORS)}")
    if directions not in DIRECTIONS:
        raise input_error("directions", f"got {directions!r}", f"one of {list(DIRECTIONS)}")
    if not span_turns > 0:
        raise input_error("span_turns", f"got {span_turns!r}", "> 0 turns")
    if not speeds_rev_s or any(not v > 0 for v in speeds_rev_s):
        raise input_error("speeds_rev_s", f"got {speeds_rev_s!r}", "speeds > 0 rev/s")
    if samples_per_run < 8:
        raise input_error("samples_per_run", f"got {samples_per_run!r}", "at least 8")
    eff = _check_effects(effects)
    dflt = SENSORS[sensor]
    P = int(periods_per_rev or dflt["periods_per_rev"])
    sigma = float(dflt["noise_rad"] if noise_rad is None else noise_rad)
    amps = np.asarray(dflt["base_rad"] if base_rad is None else base_rad, dtype=np.float64)
    rng = _rng(key)
    n_runs = len(speeds_rev_s)
    ph = rng.uniform(0, 2 * np.pi, amps.size)
    bc, bs = amps * np.cos(ph), amps * np.sin(ph)
    orders = np.arange(1, amps.size + 1)
    zs = _zeros(rng, run_zeros, n_runs, "run_zeros")
    zr = _zeros(rng, reference_zeros, n_runs, "reference_zeros")
    tau = eff.get("reading_delay", {}).get("delay_s", 0.0)
    hyst = eff.get("direction_hysteresis", {}).get("hysteresis_rad", 0.0)
    scale = eff.get("scale_error", {}).get("scale", 0.0)
    interp = eff.get("interpolation_error")
    lsb = eff.get("quantization", {}).get("lsb_rad")
    cols: dict[str, list[np.ndarray]] = {"t": [], "run": [], "theta_ref": [], "h0": []}
    for r, v in enumerate(speeds_rev_s):
        omega = 2 * np.pi * float(v)
        n_dir = 2 if directions in ("both", "oscillating") else 1
        duration = n_dir * 2 * np.pi * span_turns / omega
        dt = duration / samples_per_run
        t = np.arange(samples_per_run) * dt
        theta0 = rng.uniform(0, 2 * np.pi)
        theta, _ = _trajectory(t, directions, omega, duration, theta0)
        th_d, w_d = _trajectory(t - tau, directions, omega, duration, theta0)
        theta_s = th_d + 0.5 * hyst * np.sign(w_d)
        err = np.zeros_like(theta_s)
        for m, c, s in zip(orders, bc, bs):
            err += c * np.cos(m * theta_s) + s * np.sin(m * theta_s)
        if interp is not None:
            err += np.asarray(rt.interpolation_exact_rad(theta_s, P, **interp))
        reading = (1 + scale) * theta_s + err + zs[r] + rng.normal(0.0, sigma, t.size)
        if lsb is not None:
            reading = np.asarray(rt.quantize_rad(reading, lsb, 0.0))
        cols["t"].append(t)
        cols["run"].append(np.full(t.size, r, dtype=np.int64))
        cols["theta_ref"].append(theta + zr[r])
        cols["h0"].append(reading)
    columns = {k: np.concatenate(v) for k, v in cols.items()}
    if n_runs == 1:
        del columns["run"]
    encoder: dict[str, Any] = {
        "head_angles_deg": [0.0],
        "sensor": sensor,
        "signal_periods_per_rev": P,
    }
    if optical_radius_m is not None:
        encoder["optical_radius_m"] = float(optical_radius_m)
    truth: dict[str, Any] = {
        "sensor": sensor,
        "signal_periods_per_rev": P,
        "effects": {
            k: {"params": dict(p), "units": rt.REFERENCE_PARAM_UNITS[k]} for k, p in eff.items()
        },
        "base": {
            "orders": orders.tolist(),
            "cos_rad": bc.tolist(),
            "sin_rad": bs.tolist(),
        },
        "noise_rad": sigma,
        "span_turns": float(span_turns),
        "directions": directions,
        "speeds_rev_s": [float(v) for v in speeds_rev_s],
        "sensor_zeros_rad": zs.tolist(),
        "reference_zeros_rad": zr.tolist(),
    }
    return columns, encoder, truth


def effect_rms_params(
    effect: str,
    rms_rad: float,
    *,
    speeds_rev_s: Sequence[float],
    span_turns: float,
    periods_per_rev: int,
    rng: np.random.Generator,
) -> dict[str, float]:
    """Parameters of ``effect`` whose error has an RMS of about ``rms_rad`` (rad).

    Closed forms: ``direction_hysteresis`` ``+-h/2`` (RMS ``h/2``); ``reading_delay``
    ``-omega tau`` (RMS ``omega_rms tau``); ``quantization`` uniform over one LSB (RMS
    ``q / sqrt 12``); ``scale_error`` a ramp over ``2 pi S`` (RMS ``s 2 pi S / sqrt 12``);
    ``interpolation_error`` four first-order coefficients of size ``c`` (RMS ``c sqrt2 / P``).
    """
    sign = float(rng.choice([-1.0, 1.0]))
    if effect == "direction_hysteresis":
        return {"hysteresis_rad": sign * 2.0 * rms_rad}
    if effect == "reading_delay":
        w = 2 * np.pi * np.sqrt(np.mean(np.square(speeds_rev_s)))
        return {"delay_s": abs(rms_rad / w)}
    if effect == "quantization":
        return {"lsb_rad": float(np.sqrt(12.0) * rms_rad)}
    if effect == "scale_error":
        return {"scale": sign * np.sqrt(12.0) * rms_rad / (2 * np.pi * span_turns)}
    if effect == "interpolation_error":
        c = rms_rad * periods_per_rev / np.sqrt(2.0)
        s = rng.choice([-1.0, 1.0], 4) * rng.uniform(0.7, 1.0, 4)
        return {
            "offset_a": float(c * s[0]),
            "offset_b": float(c * s[1]),
            "amplitude_ratio": float(1.0 + 2.0 * c * s[2]),
            "phase_error_rad": float(2.0 * c * s[3]),
        }
    raise input_error("effect", f"got {effect!r}", f"one of {list(rt.CATALOG_REFERENCE)}")


def random_reference_bench(
    *,
    key: jax.Array,
    effects: Sequence[str] = (),
    amplitude: float = 1.0,
    sensor: str | None = None,
    samples_per_run: int = 2000,
) -> tuple[dict[str, np.ndarray], dict[str, Any], dict[str, Any]]:
    """Draw a sensor-against-reference bench carrying ``effects`` (names of the catalog).

    The sensor (random unless given), span (0.3 to 20 turns), speeds (one to three runs),
    directions (steady: ``forward``, ``backward`` or ``both``) and zeros are drawn from
    ``key``; each effect gets an error RMS of ``amplitude`` times the read noise
    (:func:`effect_rms_params`). Effects that need a direction change within a run
    (``direction_hysteresis``, ``reading_delay``) get ``both``; ``reading_delay`` gets two or
    three speeds, so that it is not the same as a direction offset.
    ``scale_error`` gets ``both`` directions (in one direction at one speed it is the same
    as a drift in time). ``interpolation_error`` is drawn on a multipole magnetic ring (16 to
    40 pole pairs) or a capacitive encoder (32 periods), with at least 8 samples per signal
    period: at small ``P`` its orders are the base model's (the sensor's error function) and
    cannot be told apart, which is physics, not a benchmark case.
    """
    rng = _rng(key)
    k_sim = jax.random.fold_in(key, 1)
    unknown = sorted(set(effects) - set(rt.CATALOG_REFERENCE))
    if unknown:
        raise input_error("effects", f"unknown {unknown}", f"some of {rt.CATALOG_REFERENCE}")
    interp = "interpolation_error" in effects
    if sensor is None:
        # interpolation_error is drawn where it can be told from the base orders: a
        # multipole magnetic ring or a capacitive encoder with P well above them
        sensor = str(rng.choice(["magnetic", "capacitive"] if interp else list(SENSORS)))
    if sensor not in SENSORS:
        raise input_error("sensor", f"got {sensor!r}", f"one of {list(SENSORS)}")
    P = int(SENSORS[sensor]["periods_per_rev"])
    if sensor == "magnetic" and interp:
        P = int(rng.integers(16, 41))  # a multipole ring (pole pairs)
    span = float(np.exp(rng.uniform(np.log(0.3), np.log(20.0))))
    n_runs = int(rng.integers(1, 4))
    directions = str(rng.choice(["forward", "backward", "both"]))
    if {"direction_hysteresis", "reading_delay"} & set(effects):
        directions = "both"
    if "reading_delay" in effects:
        n_runs = max(n_runs, 2)
    if "scale_error" in effects:
        # in one direction at one speed s*theta is a drift in time: both directions
        directions = "both"
        span = max(span, 2.0)  # over one turn a ramp is mostly a base order-1 error
    if interp:
        # at least 8 samples per signal period and one turn
        n_dir = 2 if directions == "both" else 1
        span = float(np.clip(span, 1.0, max(1.0, samples_per_run / (8.0 * P * n_dir))))
    speeds = np.sort(rng.uniform(0.2, 3.0, n_runs))
    if n_runs > 1:
        speeds = np.geomspace(0.3, 3.0, n_runs) * rng.uniform(0.8, 1.25)
    sigma = float(SENSORS[sensor]["noise_rad"])
    eff = {
        e: effect_rms_params(
            e,
            amplitude * sigma,
            speeds_rev_s=speeds,
            span_turns=span,
            periods_per_rev=P,
            rng=rng,
        )
        for e in effects
    }
    cols, enc, truth = simulate_sensor_reference(
        key=k_sim,
        sensor=sensor,
        periods_per_rev=P,
        span_turns=span,
        directions=directions,
        speeds_rev_s=tuple(float(v) for v in speeds),
        samples_per_run=samples_per_run,
        effects=eff,
        run_zeros=str(rng.choice(["turns", "any"])),
        reference_zeros="turns",
    )
    truth["amplitude_noise"] = float(amplitude)
    return cols, enc, truth


def write_sensor_reference(
    path: str | os.PathLike, *, key: jax.Array, **kwargs: Any
) -> tuple[Recording, dict[str, Any]]:
    """Simulate (:func:`simulate_sensor_reference` arguments) and write a recording.

    The effect names go into ``[provenance]`` (a blind benchmark must not read it).
    """
    cols, enc, truth = simulate_sensor_reference(key=key, **kwargs)
    names = sorted(truth["effects"])
    rec = write_recording(
        path,
        "multihead",
        cols,
        encoder=enc,
        description=f"simulated {truth['sensor']} sensor against a reference",
        provenance={
            "generator": "encdesign.simulate._conceal_reference",
            "hidden": ", ".join(names) if names else "none",
        },
    )
    return rec, truth
