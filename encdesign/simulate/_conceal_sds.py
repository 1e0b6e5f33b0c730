"""Generate ``sds`` bench recordings with one physics-catalog effect concealed.

A realistic shifted-delta-sum bench (seed 001's device, scaled down to ``marks_per_rev``
marks so that a recording simulates and diagnoses in seconds): a 6-pole-pair, 18-coil,
six-step motor at 10 rev/s whose design ripple sits at multiples of 6 (magnets, commutation,
cogging), two disks with eccentricity 2e-3, ellipticity 8e-4 and random mark errors, 2 fixed
+ 3 moving sensors (three, so that axis tilt and beam tilt × axial runout differ), 24
platform positions stepped by the golden angle (no subset of runs aliases the motor's
orders), 1 ns timing jitter and a 100 MHz clock. One hidden effect, at ``amplitude``
times the per-pair reading noise (``near_noise``: 4; ``clear``: 40, for tests), or only in
the later runs (``partial``):

* ``axis_tilt``: tilt β with β²/4 = amplitude × noise;
* ``thermal_drift``: a temperature ramp moving the moving sensors by amplitude × noise over
  the record (``partial``: the ramp starts half-way, from 0 K, and moves them as far by the
  record's end: a drift with an onset, continuous there; ``drift_onset_run`` sets another
  first run);
* ``bearing_wobble``: one radial runout component at a cage ratio 0.35–0.45;
* ``beam_tilt_axial``: 0.01 rad beam tilt on the moving sensors, platform axial runout at
  orders 1 and 3;
* ``coil_mismatch``: torque ripple at orders 1 … 5 (unequal coils);
* ``timing_quantization``: the bench stamps on a clock 5× (near_noise) or 20× (clear)
  coarser than the 100 MHz the TOML declares (``clock_factor`` sets another ratio, e.g. 2.5);
* ``sensor_delay_step``: moving sensor ``m1``'s edges delayed by amplitude / Ω from one run
  on (a changed cable or comparator delay).

Out of catalog (reported ``unexplained`` by a correct finder): ``run_step`` (one moving
sensor's bracket shifted in one run only, restored in the next: a one-run transient; a
change that persists from a run on is the catalog's ``sensor_delay_step``, so naming a
``run_step`` a delay step is wrong physics, and the benchmark scores it so) and ``order_5``
(an error 5 times per platform turn, common to the moving sensors, e.g. a platform gear;
with golden-angle steps it is nearly a trend over the runs, so a finder must not call it a
drift in time without saying that the two are confounded).
"""

from __future__ import annotations

import math
import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import input_error
from ..io._recording import Recording, write_recording
from ..physics._motor import Motor
from ..physics._sds import SDSDesign, equally_spaced, reference_disk
from ..physics._sds_errors import SDSErrors
from ._sds import RUN_SPACING_REVS, sds_bench_columns, sds_encoder_table

__all__ = [
    "SDS_CATALOG",
    "SDS_CONCEALMENTS",
    "SDS_HIDDEN",
    "SDS_OUT_OF_CATALOG",
    "sds_bench_design",
    "write_concealed_sds",
]

SDS_CATALOG = (
    "axis_tilt",
    "thermal_drift",
    "bearing_wobble",
    "beam_tilt_axial",
    "coil_mismatch",
    "timing_quantization",
    "sensor_delay_step",
)
SDS_OUT_OF_CATALOG = ("run_step", "order_5")
SDS_HIDDEN = (*SDS_CATALOG, *SDS_OUT_OF_CATALOG)
SDS_CONCEALMENTS = ("near_noise", "partial", "clear")

NOISE_RAD = (
    9e-9  # typical per-pair reading noise of this bench (500 marks, 1 ns jitter, 10 ns clock)
)
CLOCK_S = 1e-8
SPEED_RAD_S = 2 * math.pi * 10.0


def sds_bench_design(
    key: jax.Array,
    marks_per_rev: int = 500,
    coil_torque: float = 0.0,
    n_moving: int = 3,
    n_fixed: int = 2,
    coil_max_order: int = 5,
    speed_rad_s: float = SPEED_RAD_S,
):
    """The bench's instrument (see module doc); ``coil_torque`` adds coil-mismatch ripple at
    orders ``1 … coil_max_order``; ``n_fixed`` fixed and ``n_moving`` moving sensors, each set
    equally spaced; the motor's mean speed ``speed_rad_s`` (rad/s)."""
    torque_c = {6: 0.01, 12: 0.005, 18: 0.0033, 36: 0.02}
    torque_s = {6: 0.004, 12: -0.002, 18: 0.001, 36: 0.005}
    if coil_torque:
        for n in range(1, coil_max_order + 1):
            torque_c[n] = coil_torque / n
            torque_s[n] = 0.5 * coil_torque / n
    motor = Motor(
        6, 18, 6, speed_rad_s=speed_rad_s, torque_cos=torque_c, torque_sin=torque_s,
        corner_order=4.0,
    )  # fmt: skip
    ka, kb = jax.random.split(key)
    return SDSDesign(
        motor,
        reference_disk(ka, marks_per_rev, n_harmonics=12, random_rad=1e-6),
        reference_disk(kb, marks_per_rev, n_harmonics=12, random_rad=1e-6),
        equally_spaced(n_fixed),
        equally_spaced(n_moving),
    )


def write_concealed_sds(
    path: str | os.PathLike,
    *,
    key: jax.Array,
    effect: str | None = None,
    concealment: str = "near_noise",
    phi_ref: bool = True,
    n_runs: int = 24,
    n_revs: int = 5,
    marks_per_rev: int = 500,
    n_moving: int = 3,
    n_fixed: int = 2,
    clock_factor: float | None = None,
    amplitude_noise: float | None = None,
    coil_max_order: int = 5,
    speed_offset: float = 0.0,
    coil_beside_noise: float | None = None,
    drift_onset_run: int | None = None,
) -> tuple[Recording, dict[str, Any]]:
    """Simulate an sds bench with one hidden effect and write it (TOML + CSV).

    Args:
        path: output TOML path.
        key: ``jax.random`` key (all randomness).
        effect: one of :data:`SDS_HIDDEN` or ``None`` (clean).
        concealment: ``near_noise`` (about 4× the reading noise), ``partial`` (only in the
            later half of the runs, where the effect allows) or ``clear`` (40×).
        phi_ref: write the reference platform angle column.
        n_runs: platform positions (runs), >= 4.
        n_revs: revolutions per run (the first, where the sensors' windows do not start
            together, is not a complete reading).
        marks_per_rev: marks per disk.
        n_moving: moving sensors (equally spaced). With two opposed moving sensors an axis
            tilt (order 2 in φ + ψ_m) and a beam tilt × axial runout at order 2 in φ give
            the same pattern; three or more separate them.
        n_fixed: fixed sensors (equally spaced), >= 1.
        clock_factor: ``timing_quantization`` only: the bench clock period over the declared
            one (default 5 for ``near_noise`` / ``partial``, 20 for ``clear``).
        amplitude_noise: the effect's amplitude in multiples of the per-pair reading noise
            (about 9 nrad), in place of the concealment's (4, 6 or 40); e.g. for
            ``axis_tilt`` the tilt is ``2 sqrt(amplitude_noise × noise)`` rad.
        coil_max_order: ``coil_mismatch`` only: the torque ripple's highest order (1-5; 1:
            order 1 alone, the effect a detection bound of order 1 is about).
        speed_offset: the motor's mean speed relative to the nominal 10 rev/s, minus 1
            (|offset| < 0.01). At 0 a revolution is exactly 10^7 ticks of the 10 ns clock and
            a mark spacing 2 10^4: every revolution's edges fall at the same clock phases, and
            the clock's rounding of a run's mean is a fixed function of the edges' sub-tick
            phases, lower than a clock not locked to the motor gives. Any effect that moves
            the edges by a tick re-draws it at the unlocked level (an order-1
            ``coil_mismatch`` of 0.5-2 noise units raised the clock's share of a 12-run
            bench's run means from 3.5-4.4 to 4.4-5.6 nrad RMS). A real clock is not locked
            to the motor; an offset (e.g. 1e-4) gives clean and effect records one level.
        coil_beside_noise: a second effect, a ``coil_mismatch`` (orders 1 …
            ``coil_max_order``) at this many noise units beside ``effect`` (not itself
            ``coil_mismatch``); it draws nothing, so the record of a key with and without it
            has the same platform positions, disks, noise and ``effect`` (``truth["beside"]``).
        drift_onset_run: ``thermal_drift`` only: the temperature ramp starts with this run
            (0 … ``n_runs`` − 1; default half-way for ``partial``, else 0), from 0 K, so the
            drift is continuous at its onset (``truth["params"]["onset_s"]``, on ``t``); it
            draws nothing, so the record of a key differs only in the drift.

    Returns:
        ``(recording, truth)``; ``truth`` holds the effect, its parameters and where it is.
    """
    if effect is not None and effect not in SDS_HIDDEN:
        raise input_error("effect", f"got {effect!r}", f"one of {list(SDS_HIDDEN)} or None")
    if concealment not in SDS_CONCEALMENTS:
        raise input_error("concealment", f"got {concealment!r}", f"one of {SDS_CONCEALMENTS}")
    if n_runs < 4:
        raise input_error("n_runs", f"got {n_runs}", ">= 4")
    if not abs(speed_offset) < 0.01:
        raise input_error("speed_offset", f"got {speed_offset!r}", "|speed_offset| < 0.01")
    speed = SPEED_RAD_S * (1.0 + speed_offset)
    amp = {"near_noise": 4.0, "partial": 6.0, "clear": 40.0}[concealment] * NOISE_RAD
    if amplitude_noise is not None:
        if not amplitude_noise > 0:
            raise input_error("amplitude_noise", f"got {amplitude_noise!r}", "> 0")
        amp = float(amplitude_noise) * NOISE_RAD
    kd, kp, ke, kj = jax.random.split(key, 4)
    rng = np.random.default_rng(np.asarray(jax.random.randint(ke, (), 0, 2**31 - 1)).item())
    coil = 0.0
    if effect == "coil_mismatch":
        coil = amp / 2e-3 * 1.2  # φ error ≈ speed ripple × eccentricity 2e-3
    if coil_beside_noise is not None:
        if effect == "coil_mismatch" or not coil_beside_noise > 0:
            raise input_error(
                "coil_beside_noise",
                f"got {coil_beside_noise!r} beside {effect!r}",
                "> 0, beside an effect other than coil_mismatch",
            )
        coil = float(coil_beside_noise) * NOISE_RAD / 2e-3 * 1.2
    if n_moving < 2:
        raise input_error("n_moving", f"got {n_moving}", ">= 2")
    if n_fixed < 1:
        raise input_error("n_fixed", f"got {n_fixed}", ">= 1")
    if not 1 <= coil_max_order <= 5:
        raise input_error("coil_max_order", f"got {coil_max_order!r}", "1 to 5")
    design = sds_bench_design(kd, marks_per_rev, coil, n_moving, n_fixed, coil_max_order, speed)
    # platform positions stepped by the golden angle (about 137.5°, jittered by ±2°): every
    # subset of runs (e.g. the held-out folds) covers the circle without aliasing the
    # motor's orders (multiples of 6) onto a constant, as an equally spaced grid would
    golden = np.pi * (3 - math.sqrt(5))
    phis = golden * np.arange(n_runs) + np.radians(rng.uniform(-2, 2, n_runs))
    phis = np.mod(phis + rng.uniform(0, 2 * np.pi), 2 * np.pi)
    period = 2 * np.pi / speed
    t_end = n_runs * (n_revs + 1 + RUN_SPACING_REVS) * period
    kw: dict[str, Any] = dict(clock_period_s=CLOCK_S, jitter_s=1e-9)
    truth: dict[str, Any] = {"effect": effect, "concealment": concealment, "params": {}}
    first_partial = n_runs // 2 if concealment == "partial" else 0
    if drift_onset_run is not None:
        if effect != "thermal_drift" or not 0 <= int(drift_onset_run) < n_runs:
            raise input_error(
                "drift_onset_run",
                f"got {drift_onset_run!r} for {effect!r}",
                f"0 … {n_runs - 1}, with thermal_drift",
            )
        first_partial = int(drift_onset_run)
    if effect == "axis_tilt":
        beta = 2 * math.sqrt(amp)
        kw.update(axis_tilt_rad=beta, axis_tilt_azimuth_rad=rng.uniform(0, np.pi))
        truth["params"] = {"tilt_rad": beta, "azimuth_rad": kw["axis_tilt_azimuth_rad"]}
    elif effect == "thermal_drift":
        t0 = first_partial * (n_revs + 1 + RUN_SPACING_REVS) * period
        rate_k_s = 1.0 / (t_end - t0)  # 1 K from the onset to the record's end
        kappa = amp / 1.0
        kw.update(
            thermal_drift_rad_per_k=kappa,
            temperature_rate_k_per_s=rate_k_s,
            temperature_offset_k=-rate_k_s * t0,
        )
        truth["params"] = {"drift_rate_rad_per_s": kappa * rate_k_s, "onset_s": t0}
    elif effect == "bearing_wobble":
        rho = rng.uniform(0.35, 0.45)
        a_rad = amp / float(np.sinc(rho))
        kw.update(
            bearing_amplitude_m=[a_rad * 0.0254],
            bearing_ratio=[rho],
            bearing_phase_rad=[rng.uniform(0, 2 * np.pi)],
        )
        truth["params"] = {
            "frequency_ratio": rho,
            "amplitude_rad": a_rad,
            "runout_m": a_rad * 0.0254,
        }
    elif effect == "beam_tilt_axial":
        gamma = 0.01
        z1, z3 = amp * 0.0254 / gamma, 0.5 * amp * 0.0254 / gamma
        ph1, ph3 = rng.uniform(0, 2 * np.pi, 2)
        kw.update(
            optical_tilt_moving_rad=gamma,
            axial_runout_cos_m=[z1 * math.cos(ph1), 0.0, z3 * math.cos(ph3)],
            axial_runout_sin_m=[z1 * math.sin(ph1), 0.0, z3 * math.sin(ph3)],
        )
        truth["params"] = {"order_1_amplitude_rad": amp, "order_3_amplitude_rad": 0.5 * amp}
    elif effect == "coil_mismatch":
        truth["params"] = {"torque_order_1": coil}
        eps_c, eps_s = design.motor.speed_ripple()
        o = list(design.motor.orders).index(1)
        truth["params"]["speed_ripple_order_1"] = float(jnp.hypot(eps_c[o], eps_s[o]))
    elif effect == "timing_quantization":
        k = {"near_noise": 5, "partial": 5, "clear": 20}[concealment]
        if clock_factor is not None:
            k = float(clock_factor)
        kw.update(clock_period_s=CLOCK_S * k)
        truth["params"] = {"clock_period_s": CLOCK_S * k}
    base_kw = dict(clock_period_s=CLOCK_S, jitter_s=1e-9)
    if effect == "bearing_wobble":
        base_kw.update(bearing_amplitude_m=[0.0], bearing_ratio=[0.4], bearing_phase_rad=[0.0])
    if effect in ("order_5", "run_step", "sensor_delay_step"):
        # the shift is added to the exact edge times, which are then stamped once
        kw["clock_period_s"] = base_kw["clock_period_s"] = 0.0
    errors_on = SDSErrors(**kw)
    errors_off = SDSErrors(**base_kw)
    step_run = int(rng.integers(1, n_runs - 1))
    per_run = [
        errors_on
        if (i >= first_partial or effect == "timing_quantization")
        and not (effect == "thermal_drift" and i < first_partial)
        else errors_off
        for i in range(n_runs)
    ]

    def hook(i: int, phi: float, f: np.ndarray, m: np.ndarray):
        if effect == "order_5":
            m = m + amp * math.sin(5 * phi + 0.7) / speed
        if effect == "run_step" and i == step_run:
            m[1] = m[1] + 8 * amp / speed
        if effect == "sensor_delay_step" and i >= step_run:
            m[1] = m[1] + amp / speed
        if effect in ("order_5", "run_step", "sensor_delay_step"):
            f, m = np.ceil(f / CLOCK_S) * CLOCK_S, np.ceil(m / CLOCK_S) * CLOCK_S
        return f, m

    data = sds_bench_columns(design, phis, n_revs, per_run, key=kj, edge_hook=hook)
    if effect == "order_5":
        truth["params"] = {"order": 5, "amplitude_rad": amp}
    if effect == "run_step":
        truth["where"] = {"runs": [step_run], "heads": ["m1"]}
    if effect == "order_5":
        truth["where"] = {"orders": [5]}
    if effect == "sensor_delay_step":
        truth["where"] = {"runs": [step_run], "heads": ["m1"]}
        truth["params"] = {"delay_step_s": amp / speed, "first_run": step_run}
    if coil_beside_noise is not None:
        eps_c, eps_s = design.motor.speed_ripple()
        o = list(design.motor.orders).index(1)
        truth["beside"] = {
            "effect": "coil_mismatch",
            "torque_order_1": coil,
            "speed_ripple_order_1": float(jnp.hypot(eps_c[o], eps_s[o])),
        }
    if not phi_ref:
        del data["phi_ref"]
    encoder = sds_encoder_table(design, CLOCK_S)
    rec = write_recording(
        path,
        "sds",
        data,
        encoder=encoder,
        description="simulated shifted-delta-sum bench (encdesign conceal)",
        provenance={"simulated_by": "encdesign.write_concealed_sds"},
    )
    return rec, truth
