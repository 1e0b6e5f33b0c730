"""SDS error budget of the reference device: each error source alone, then all together.

Seed 001 (Mikkelson), first example device: 6 pole pairs, 18 coils, six-step open-loop
drive, 2,500-line disks in quadrature (10,000 edges), 10 rev/s. The error of φ over a full
turn of the platform is simulated from edge times (Newton-inverted shaft motion, shifted
delta sum, pair average) for

* sensor layouts with the *same* motor ripple and mark errors: one fixed + one moving
  sensor, two opposed pairs (0°/180°), three sensors per disk (120°); their order
  amplitudes compare with the seed's figs. 17–20 and 23–24 (one pair: strong order 1; two
  opposed pairs: mostly order 2; three sensors: order 2 reduced);
* a 20 arcsec axis tilt alone (seed eq. 26, fig. 27: below half a milli-arcsecond);
* the error budget of the two-pair device: motor ripple × mark errors, axis tilt, axial
  shift seen through tilted optical axes, bearing runout, thermal drift, clock
  quantization and jitter, each alone, then all together (systematic curve = mean over
  revolutions, noise = std of single-revolution readings).
"""

from __future__ import annotations

import math
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import encdesign as ed
from encdesign.io import new_figure, save_figure, study_parser, write_results
from encdesign.physics import ARCSEC

NAME = "sds-errors"
MAS = ARCSEC / 1000


def _orders(err: np.ndarray, n_max: int) -> np.ndarray:
    """Amplitudes of orders 0…n_max of a curve sampled on an equally spaced φ grid."""
    spec = np.abs(np.fft.rfft(err)) / len(err)
    spec[1:] *= 2
    return spec[: n_max + 1]


def _progress(msg: str) -> None:
    print(f"[{NAME}] {msg}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    p = study_parser(NAME, __doc__)
    p.add_argument("--marks", type=int, default=None, help="marks per revolution")
    args = p.parse_args(argv)
    n_marks = args.marks or (200 if args.quick else 10_000)
    n_phi = 16 if args.quick else 72
    n_phi_budget = 4 if args.quick else 36
    n_revs = 2 if args.quick else 3
    key = jax.random.PRNGKey(args.seed)
    k_disk, k_noise = jax.random.split(key)
    phi = 2 * jnp.pi * jnp.arange(n_phi) / n_phi
    t0 = time.time()

    motor = ed.physics.reference_motor(6)
    layouts = {"single_pair": 1, "two_pairs": 2, "three_sensor": 3}
    designs = {
        name: ed.reference_design(m, m, marks_per_rev=n_marks, key=k_disk, motor=motor)
        for name, m in layouts.items()
    }
    for d in designs.values():
        ed.physics.validate_design(d)
    phi_error = jax.jit(ed.sds_phi_error)

    # --- layouts: same ripple and marks
    cases = {}
    curves = {}
    for name, d in designs.items():
        _progress(f"{name}: {d.n_fixed}+{d.n_moving} sensors, {n_phi} platform angles")
        err = np.asarray(phi_error(d, phi))
        pred = np.asarray(ed.physics.predict_speed_mark_error(d, phi).phi_error_rad)
        err_c = err - err.mean()
        amp = _orders(err, 12) / ARCSEC
        curves[name] = err_c / ARCSEC
        cases[name] = {
            "sensors_per_disk": layouts[name],
            "rms_arcsec": float(np.sqrt(np.mean(err_c**2)) / ARCSEC),
            "peak_to_peak_arcsec": float(np.ptp(err) / ARCSEC),
            "order_amplitudes_arcsec": amp[1:].tolist(),
            "prediction_eq46_53_max_deviation_arcsec": float(np.max(np.abs(err - pred)) / ARCSEC),
        }

    # --- axis tilt alone (20 arcsec), two-pair layout, constant speed, perfect disks
    still = ed.Motor(6, 18, 6, speed_rad_s=motor.speed_rad_s)
    d_tilt = ed.SDSDesign(
        still,
        ed.physics.perfect_disk(n_marks),
        ed.physics.perfect_disk(n_marks),
        ed.physics.equally_spaced(2),
        ed.physics.equally_spaced(2),
    )
    tilt = 20 * ARCSEC
    err_tilt = np.asarray(phi_error(d_tilt, phi, ed.SDSErrors(axis_tilt_rad=tilt)))
    formula = np.asarray(ed.physics.axis_tilt_error(phi, tilt))

    # --- budget of the two-pair device
    ref = ed.reference_errors()
    zero = jax.tree_util.tree_map(jnp.zeros_like, ref)

    def only(*fields):
        out = zero
        for f in fields:
            out = eqx.tree_at(lambda e, f=f: getattr(e, f), out, getattr(ref, f))
        return out

    bearing = ("bearing_amplitude_m", "bearing_ratio", "bearing_phase_rad")
    sources = {
        "motor_velocity_ripple": (True, zero),
        "axis_tilt": (False, only("axis_tilt_rad", "axis_tilt_azimuth_rad")),
        "beam_tilt_axial": (
            False,
            only("optical_tilt_fixed_rad", "optical_tilt_moving_rad", "axial_runout_cos_m"),
        ),
        "bearing_wobble": (False, only(*bearing)),
        "thermal_drift": (False, only("thermal_drift_rad_per_k", "temperature_rate_k_per_s")),
        "timing_quantization": (False, only("clock_period_s", "jitter_s")),
        "all": (True, ref),
    }
    base = designs["two_pairs"]
    flat = eqx.tree_at(
        lambda d: (d.motor.torque_cos, d.motor.torque_sin),
        base,
        (jnp.zeros_like(base.motor.torque_cos), jnp.zeros_like(base.motor.torque_sin)),
    )
    phi_b = 2 * jnp.pi * jnp.arange(n_phi_budget) / n_phi_budget

    @jax.jit
    def budget_curve(design, errors, key):
        def one(args):
            i, ph = args
            r = ed.simulate_readings(
                design, ph, n_revs, errors, key=jax.random.fold_in(key, i), first_rev=i * n_revs
            )
            return r.error_rad

        return jax.lax.map(one, (jnp.arange(n_phi_budget), phi_b))

    budget = {}
    budget_curves = {}
    for name, (ripple, errs) in sources.items():
        _progress(f"budget: {name} ({time.time() - t0:.0f} s)")
        d = base if ripple else flat
        readings = np.asarray(budget_curve(d, errs, k_noise))  # (n_phi, n_revs)
        curve = readings.mean(axis=1)
        curve_c = curve - curve.mean()
        budget_curves[name] = curve_c / MAS
        budget[name] = {
            "systematic_rms_mas": float(np.sqrt(np.mean(curve_c**2)) / MAS),
            "systematic_peak_to_peak_mas": float(np.ptp(curve) / MAS),
            "noise_std_mas": float(np.mean(readings.std(axis=1, ddof=1)) / MAS),
            "order_amplitudes_mas": (_orders(curve, 4)[1:] / MAS).tolist(),
        }

    summary = {
        "study": NAME,
        "device": {
            "pole_pairs": motor.pole_pairs,
            "stator_coils": motor.stator_coils,
            "commutation_states": motor.commutation_states,
            "marks_per_rev": n_marks,
            "speed_rev_s": float(motor.speed_rad_s / (2 * math.pi)),
            "read_radius_m": float(base.radius_m),
            "speed_ripple_rel": {
                int(n): float(a)
                for n, a in zip(motor.orders, np.hypot(*map(np.asarray, motor.speed_ripple())))
            },
        },
        "platform_angles": n_phi,
        "axis_tilt_20arcsec_max_mas": float(np.max(np.abs(err_tilt)) / MAS),
        "axis_tilt_formula_max_mas": float(np.max(np.abs(formula)) / MAS),
        "axis_tilt_max_deviation_from_eq26_mas": float(np.max(np.abs(err_tilt - formula)) / MAS),
        "single_pair_order1_arcsec": cases["single_pair"]["order_amplitudes_arcsec"][0],
        "two_pairs_order1_arcsec": cases["two_pairs"]["order_amplitudes_arcsec"][0],
        "two_pairs_order2_arcsec": cases["two_pairs"]["order_amplitudes_arcsec"][1],
        "three_sensor_order2_arcsec": cases["three_sensor"]["order_amplitudes_arcsec"][1],
        "layouts": cases,
        "budget_two_pairs": budget,
        "budget_platform_angles": n_phi_budget,
        "budget_revolutions_per_angle": n_revs,
        "seconds": time.time() - t0,
    }
    figures = []
    if not args.no_plots:
        figures = _plots(args.out, np.asarray(phi), curves, cases, budget_curves, budget, phi_b)
    write_results(args, NAME, summary, figures)
    return 0


def _plots(out, phi, curves, cases, budget_curves, budget, phi_b):
    deg = np.degrees(phi)
    fig, axes = new_figure(1, 2, figsize=(12, 4.2))
    for name, c in curves.items():
        axes[0].plot(deg, c, marker="o", ms=3, label=name.replace("_", " "))
    axes[0].set_xlabel("platform angle φ (deg)")
    axes[0].set_ylabel("error of φ, mean removed (arcsec)")
    axes[0].set_title("motor ripple × mark errors, reference device")
    axes[0].legend()
    width = 0.27
    orders = np.arange(1, len(next(iter(cases.values()))["order_amplitudes_arcsec"]) + 1)
    for i, (name, case) in enumerate(cases.items()):
        axes[1].bar(orders + (i - 1) * width, case["order_amplitudes_arcsec"], width, label=name)
    axes[1].set_yscale("log")
    axes[1].set_xlabel("order (cycles per platform turn)")
    axes[1].set_ylabel("amplitude (arcsec)")
    axes[1].set_title("spectrum of the error of φ")
    axes[1].set_xticks(orders)
    axes[1].legend()
    f1 = save_figure(fig, out, "sds-errors-layouts.png")

    fig, axes = new_figure(1, 3, figsize=(16, 4.2))
    big = [n for n in budget_curves if budget[n]["systematic_rms_mas"] > 10]
    for ax, group, title in (
        (axes[0], big, "large sources"),
        (axes[1], [n for n in budget_curves if n not in big], "small sources"),
    ):
        for name in group:
            ax.plot(np.degrees(phi_b), budget_curves[name], marker=".", label=name)
        ax.set_xlabel("platform angle φ (deg)")
        ax.set_ylabel("systematic error, mean removed (mas)")
        ax.set_title(f"error budget, two opposed pairs: {title}")
        ax.legend(fontsize=7)
    names = list(budget)
    sys_rms = np.asarray([budget[n]["systematic_rms_mas"] for n in names])
    noise = np.asarray([budget[n]["noise_std_mas"] for n in names])
    x = np.arange(len(names))
    shown = noise > 1e-6  # deterministic sources have no revolution-to-revolution noise
    axes[2].bar(x - 0.2, sys_rms, 0.4, label="systematic RMS")
    axes[2].bar(x[shown] + 0.2, noise[shown], 0.4, label="noise std (1 revolution)")
    axes[2].set_yscale("log")
    axes[2].set_xticks(x)
    axes[2].set_xticklabels(names, rotation=30, ha="right", fontsize=8)
    axes[2].set_ylabel("mas")
    axes[2].legend()
    f2 = save_figure(fig, out, "sds-errors-budget.png")
    return [f1, f2]


if __name__ == "__main__":
    raise SystemExit(main())
