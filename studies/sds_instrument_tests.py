"""The seed's instrument tests of the SDS device, simulated, with the seed's numbers beside ours.

Seed 001 (Mikkelson), first example device (6 pole pairs, 2 + 2 sensors, 10,000 edges):

* noise test (fig. 9): the platform at rest, readings of one sensor pair (encoders 1 and 3),
  of the other pair, and of their average. Seed: 0.42 arcsec p-p per pair, < 0.02 arcsec
  for the average. The bearing runout of ``reference_errors()`` is a coherent whirl of a
  few components; the study measures the pair noise for that spectrum, for the same
  spectrum without its sub-synchronous (cage) components, and for the spectrum scaled by
  0.2, to show what sets the one-pair level;
* the offset between the two pairs' readings (seed: 89.5 arcsec, from the opposed
  sensors' placement off 180°, "about 0.00045 in at the edge of a 2 in disk");
* piezo steps (figs. 10–11): 1 nm at 84 mm is 2.46 mas; the square wave is detected in
  moving averages over half periods (seed: a ~2 mas triangle);
* piezo ramps (fig. 12): 16,383 steps over ~37 arcsec, line fits per ramp (seed: RMS
  8–15.3 mas);
* the linear-stage arcsine test (figs. 13–15): 63 mm at R = 305.811 mm, 1 mm lead-screw
  error; the arcsine model fitted by non-linear least squares (seed: ±0.75 arcsec; after a
  5° shift of the range the curves agree to 0.077 arcsec RMS);
* main-bearing lateral shift at a finite distance (seed: 0.0001 in at 10 ft = 0.17 arcsec).
"""

from __future__ import annotations

import math
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

import encdesign as ed
from encdesign.io import new_figure, save_figure, study_parser, write_results
from encdesign.physics import ARCSEC, bearing_noise_default

NAME = "sds-instrument-tests"
MAS = ARCSEC / 1000
INCH = 0.0254

SEED = {
    "noise_one_pair_pp_arcsec": 0.42,
    "noise_two_pairs_pp_arcsec": 0.02,
    "pair_offset_arcsec": 89.5,
    "pair_offset_inch_at_1in": 0.00045,
    "piezo_step_mas": 2.46,
    "piezo_triangle_mas": 2.0,
    "ramp_rms_mas": [8.0, 15.3],
    "arcsine_range_arcsec": 0.75,
    "arcsine_shift_rms_arcsec": 0.077,
    "bearing_shift_arcsec": 0.17,
}


def _progress(msg: str) -> None:
    print(f"[{NAME}] {msg}", file=sys.stderr, flush=True)


def noise_test(design, n_revs: int, key) -> dict:
    """Single-revolution readings at rest for three bearing-noise spectra."""
    bearing = bearing_noise_default()
    ratio = np.asarray(bearing["bearing_ratio"])
    amp = np.asarray(bearing["bearing_amplitude_m"])
    keep = ratio > 1.0
    rms_m = float(np.sqrt(np.sum(amp**2)))
    scale = 0.2
    variants = {
        "coherent_whirl": ed.reference_errors(systematic_only=True, **bearing),
        "whirl_without_cage": ed.reference_errors(
            systematic_only=True,
            bearing_amplitude_m=amp[keep],
            bearing_ratio=ratio[keep],
            bearing_phase_rad=np.asarray(bearing["bearing_phase_rad"])[keep],
        ),
        "whirl_scaled_0.2": ed.reference_errors(
            systematic_only=True,
            bearing_amplitude_m=amp * scale,
            bearing_ratio=ratio,
            bearing_phase_rad=np.asarray(bearing["bearing_phase_rad"]),
        ),
    }
    out = {"bearing_rms_m": rms_m, "cage_ratios": ratio[~keep].tolist(), "scale": scale}
    for name, err in variants.items():
        r = ed.simulate_readings(design, 0.3, n_revs, err, key=key)
        pair = np.asarray(r.pair_error_rad)  # (R, F, M)
        p13 = pair[:, 0, 0]
        p24 = pair[:, 1, 1]
        avg = 0.5 * (p13 + p24)
        out[name] = {
            "one_pair_pp_arcsec": float(np.ptp(p13)) / ARCSEC,
            "one_pair_std_arcsec": float(np.std(p13)) / ARCSEC,
            "other_pair_pp_arcsec": float(np.ptp(p24)) / ARCSEC,
            "average_pp_arcsec": float(np.ptp(avg)) / ARCSEC,
            "average_std_arcsec": float(np.std(avg)) / ARCSEC,
        }
    return out


def pair_offset(design, offset_arcsec: float, phis_rad) -> dict:
    """Move one moving sensor ``offset_arcsec`` off 180° (the instrument's zero constants
    still assume 180°) and read both pairs at several platform angles."""
    pair = np.asarray(
        ed.physics.moved_sensor_pair_errors(
            design, 1, offset_arcsec * ARCSEC, phis_rad, ed.reference_errors(systematic_only=True)
        )
    )
    offsets = [float(x) / ARCSEC for x in pair[:, 1, 1] - pair[:, 0, 0]]
    return {
        "placement_off_180_arcsec": offset_arcsec,
        "phi_deg": [math.degrees(p) for p in phis_rad],
        "pair_offset_arcsec": offsets,
        "pair_offset_mean_arcsec": float(np.mean(offsets)),
        "placement_at_1in_radius_inch": offset_arcsec * ARCSEC * 1.0,
    }


def piezo(noise_mas: float, rng) -> dict:
    """Square-wave steps and ramps, device noise per reading ``noise_mas``."""
    step_rad = 1e-9 / 0.084
    period = 40  # readings per square-wave period
    n = period * 30
    sq = step_rad * (np.arange(n) % period >= period // 2)
    y = sq + rng.normal(0, noise_mas * MAS, n)
    half = period // 2
    mov = np.convolve(y, np.ones(half) / half, mode="valid")
    # the expected triangle (moving average of the noiseless square wave), fitted by least
    # squares: its amplitude is what the eye reads off the seed's moving-average graph
    tri = np.convolve(sq, np.ones(half) / half, mode="valid")
    tri = tri - tri.mean()
    gain = float(np.dot(mov - mov.mean(), tri) / np.dot(tri, tri))
    tri_pp = gain * float(np.ptp(tri)) / MAS
    # standard error: the noise of one moving average, correlated over ``half`` samples
    tri_se = noise_mas / math.sqrt(half) * math.sqrt(half / mov.size) / (np.std(tri) / MAS)
    tri_se = float(tri_se * np.ptp(tri) / MAS)
    # ramps: 16,383 steps of full range 15 µm at 84 mm (~37 arcsec), ~15,000 readings each
    full = 15e-6 / 0.084
    m = 15_000
    x = np.linspace(0, full, m)
    lin = 1e-3  # the actuator's 0.1 % linearity, as a smooth bow
    rms = []
    for _ in range(8):
        bow = lin * full * np.sin(np.pi * x / full) * rng.uniform(-1, 1)
        yy = x + bow + rng.normal(0, noise_mas * MAS, m)
        coef = np.polyfit(x, yy, 1)
        rms.append(float(np.sqrt(np.mean((yy - np.polyval(coef, x)) ** 2))) / MAS)
    return {
        "step_mas": step_rad / MAS,
        "triangle_fitted_pp_mas": tri_pp,
        "triangle_fitted_pp_se_mas": tri_se,
        "ramp_rms_mas": rms,
        "device_noise_mas": noise_mas,
    }


def arcsine_test(err_fn, noise_arcsec: float, rng, n: int) -> dict:
    """Linear stage pushing a 305.811 mm arm; lead-screw error, fit of the arcsine model."""
    r_arm = 0.305811
    x = np.linspace(-0.033, 0.030, n)  # stage position relative to α = 0, m
    lead = 0.75e-6 * np.sin(2 * np.pi * x / 1e-3 + 0.3)  # 1 mm pitch error, m

    def run(shift_rad):
        alpha = np.arcsin((x + lead) / r_arm)
        phi = alpha + shift_rad
        meas = phi + err_fn(phi) + rng.normal(0, noise_arcsec * ARCSEC, n)

        def model(p):
            return np.arcsin((x - p[1]) / p[0]) + p[2]

        fit = scipy.optimize.least_squares(
            lambda p: (model(p) - meas) / ARCSEC, [r_arm * 1.001, 0.0, shift_rad]
        )
        return (meas - model(fit.x)) / ARCSEC

    a = run(0.0)
    b = run(math.radians(5.0))
    return {
        "residual_max_abs_arcsec": float(np.max(np.abs(a))),
        "shift_rms_difference_arcsec": float(np.sqrt(np.mean((a - b) ** 2))),
        "arcsec_per_um": 1e-6 / r_arm / ARCSEC,
        "samples": n,
    }


def main(argv: list[str] | None = None) -> int:
    p = study_parser(NAME, __doc__)
    p.add_argument("--marks", type=int, default=None, help="marks per revolution")
    p.add_argument("--revs", type=int, default=None, help="revolutions of the noise test")
    args = p.parse_args(argv)
    n_marks = args.marks or (1000 if args.quick else 10_000)
    n_revs = args.revs or (20 if args.quick else 300)
    t0 = time.time()
    key = jax.random.PRNGKey(args.seed)
    rng = np.random.default_rng(args.seed)
    design = ed.reference_design(2, 2, marks_per_rev=n_marks)
    _progress(f"noise test: {n_revs} revolutions, {n_marks} marks")
    noise = noise_test(design, n_revs, key)
    _progress(f"pair offset ({time.time() - t0:.0f} s)")
    offset = pair_offset(design, 89.5, np.deg2rad([17.0, 107.0, 197.0, 287.0]))
    two_pair_noise_mas = noise["coherent_whirl"]["average_std_arcsec"] * 1000
    pz = piezo(max(two_pair_noise_mas, 1e-3), rng)
    phi_error = jax.jit(ed.sds_phi_error)
    errs = ed.reference_errors(systematic_only=True)

    grid = np.linspace(-0.2, 0.3, 201)
    e_grid = np.asarray(phi_error(design, jnp.asarray(grid), errs))

    def err_fn(phi):
        return np.interp(phi, grid, e_grid)

    _progress(f"arcsine test ({time.time() - t0:.0f} s)")
    arc = arcsine_test(
        err_fn,
        noise["coherent_whirl"]["average_std_arcsec"],
        rng,
        20_000 if args.quick else 200_000,
    )
    shift = {
        "lateral_shift_inch": 1e-4,
        "distance_ft": 10.0,
        "angle_arcsec": math.atan(1e-4 * INCH / (10 * 12 * INCH)) / ARCSEC,
        # the seed's other two length/angle conversions
        "shaft_shift_0.0001in_at_1in_radius_arcsec": 1e-4 / 1.0 / ARCSEC,
        "settling_50mas_at_1.75in_radius_uin": 50 * MAS * 1.75 * 1e6,
    }
    summary = {
        "study": NAME,
        "quick": bool(args.quick),
        "marks_per_rev": n_marks,
        "noise_test": noise,
        "pair_offset": offset,
        "piezo": pz,
        "arcsine": arc,
        "bearing_shift": shift,
        "seed": SEED,
        "runtime_s": time.time() - t0,
    }
    figs = [] if args.no_plots else [_plot(args.out, noise)]
    write_results(args, NAME, summary, figs)
    return 0


def _plot(out, noise):
    fig, ax = new_figure(figsize=(7, 4))
    names = ["coherent_whirl", "whirl_without_cage", "whirl_scaled_0.2"]
    x = np.arange(len(names))
    ax.bar(x - 0.2, [noise[n]["one_pair_pp_arcsec"] for n in names], 0.4, label="one pair")
    ax.bar(x + 0.2, [noise[n]["average_pp_arcsec"] for n in names], 0.4, label="two pairs")
    ax.axhline(0.42, ls="--", c="k", lw=0.8, label="seed one pair")
    ax.set_xticks(x, names)
    ax.set_ylabel("p-p noise at rest (arcsec)")
    ax.legend()
    return save_figure(fig, out, "sds-instrument-tests-noise.png")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
