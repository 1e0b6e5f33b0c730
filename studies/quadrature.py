"""Quadrature signals under vibration: ellipse fit, LUT and compensation (seed 002).

Reproduces Lopez & Artes' methodology on simulated signals of a 20 um pitch linear encoder
sampled at 16,384 Hz:

1. a run without vibration along the travel (offsets, amplitude ratio and phase drifting
   slightly along it: the Lissajous "line width"); the direct least-squares ellipse gives
   the metrological errors; the reading error shows components at the line frequency
   (offsets) and twice it (amplitude and phase), compared with eq. 4;
2. a shaker sweep at a fixed position (100 m/s^2, 200-2,000 Hz, several repeats averaged)
   turns the Lissajous point into arcs whose angle gives the LUT ``delta_gm(f_exc)``;
3. runs at 0.8-3.4 mm/s with vibration at 700-1,400 Hz: the line frequency, the excitation
   frequency and the vibration phase are estimated from the doublet in ``S_A`` (no
   accelerometer), the compensation signal of eq. 4 + 6 is subtracted from the arctangent
   reading, and the area enclosed by the error curve is compared before and after
   (``error_area_reduction``, seed Fig. 6: 50-80 %).

The truth includes what the method cannot model: parameter drift along the travel, a 10 %
second harmonic of the vibration, shaker-to-machine amplitude scatter and signal noise.
"""

from __future__ import annotations

import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import encdesign as ed
from encdesign.io import new_figure, save_figure, study_parser, write_results

NAME = "quadrature"
PITCH_M = 20e-6
FS_HZ = 16384.0
AMPLITUDE_V = 0.5  # 1 Vpp signals
NOISE_V = 0.003
ACCEL_M_S2 = 100.0
MOUNT_FN_HZ = 2500.0  # head-mount resonance of the simulated encoder
MOUNT_ZETA = 0.05
TRUE_ERRORS = {"offset_a": 0.04, "offset_b": -0.03, "amplitude_ratio": 0.94, "phase": 0.07}
CASES = [(700.0, 0.8e-3), (700.0, 2.0e-3), (700.0, 3.4e-3), (1000.0, 0.8e-3), (1400.0, 0.8e-3)]


def mount_displacement_m(f_hz, accel_m_s2=ACCEL_M_S2):
    """Relative head/scale displacement amplitude (m) of a base-excited 1-dof mount."""
    w = 2 * np.pi * np.asarray(f_hz)
    r = np.asarray(f_hz) / MOUNT_FN_HZ
    return accel_m_s2 / w**2 * r**2 / np.sqrt((1 - r**2) ** 2 + (2 * MOUNT_ZETA * r) ** 2)


def drifting_errors(x_m):
    """True signal errors along the travel (slow drift: the Lissajous line width)."""
    return ed.SignalErrors(
        TRUE_ERRORS["offset_a"] + 0.006 * jnp.sin(2 * jnp.pi * x_m / 1.3e-3),
        TRUE_ERRORS["offset_b"] + 0.004 * jnp.cos(2 * jnp.pi * x_m / 0.9e-3),
        TRUE_ERRORS["amplitude_ratio"] + 0.008 * jnp.sin(2 * jnp.pi * x_m / 1.1e-3 + 1.0),
        TRUE_ERRORS["phase"] + 0.005 * jnp.sin(2 * jnp.pi * x_m / 1.7e-3 + 2.0),
    )


def signals(t, x_nominal, vibs, key):
    """Signals of the moving scale with relative vibrations ``vibs`` (list) and noise."""
    x = x_nominal + sum((v.displacement_m(t) for v in vibs), jnp.zeros_like(t))
    psi = 2 * jnp.pi * x / PITCH_M
    sa, sb = ed.quadrature_signals(psi, drifting_errors(x_nominal), AMPLITUDE_V)
    ka, kb = jax.random.split(key)
    return (
        sa + NOISE_V * jax.random.normal(ka, sa.shape),
        sb + NOISE_V * jax.random.normal(kb, sb.shape),
    )


def harmonic_amplitudes(t, e, freqs):
    """Least-squares amplitudes of ``e(t)`` at ``freqs`` (same unit as ``e``)."""
    cols = [np.ones_like(t)]
    for f in freqs:
        cols += [np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)]
    c, *_ = np.linalg.lstsq(np.stack(cols, 1), e, rcond=None)
    return [float(np.hypot(c[1 + 2 * k], c[2 + 2 * k])) for k in range(len(freqs))]


def progress(msg):
    print(f"[quadrature] {msg}", file=sys.stderr, flush=True)


def main(argv=None) -> int:
    args = study_parser(NAME, __doc__).parse_args(argv)
    t_start = time.time()
    key = jax.random.PRNGKey(args.seed)
    rng = np.random.default_rng(args.seed)
    quick = args.quick

    # ---- step 1: no vibration, fit the ellipse -------------------------------------
    n1 = 4096 if quick else 16384
    v1 = 4e-3
    t1 = np.arange(n1) / FS_HZ
    x1 = 2e-6 + v1 * t1
    key, k = jax.random.split(key)
    sa1, sb1 = signals(jnp.asarray(t1), jnp.asarray(x1), [], k)
    fit = ed.fit_ellipse(sa1, sb1, method="direct")
    fitted = fit.params.to_signal_errors()
    true_mean = ed.SignalErrors(
        TRUE_ERRORS["offset_a"],
        TRUE_ERRORS["offset_b"],
        TRUE_ERRORS["amplitude_ratio"],
        TRUE_ERRORS["phase"],
    )
    reading1 = np.asarray(ed.physics.position_from_signals_m(sa1, sb1, PITCH_M))
    err1 = reading1 - x1
    f_line1 = v1 / PITCH_M
    meas = harmonic_amplitudes(t1, err1, [f_line1, 2 * f_line1])
    k_m = PITCH_M / (2 * np.pi)
    eq4_1 = k_m * float(np.hypot(true_mean.offset_a, true_mean.offset_b))
    eq4_2 = k_m * 0.5 * float(np.hypot(true_mean.amplitude_ratio - 1, true_mean.phase_error_rad))
    progress(f"ellipse fitted (rms radial residual {float(fit.rms_radial_residual):.2e})")

    # ---- step 2: shaker sweep at a fixed position, LUT -----------------------------
    f_lut = np.arange(200.0, 2001.0, 200.0 if quick else 50.0)
    repeats = 3 if quick else 10
    n2 = 1024 if quick else 2048
    t2 = np.arange(n2) / FS_HZ
    luts = []
    arc_example = None
    for _ in range(repeats):
        rows_a, rows_b = [], []
        for f in f_lut:
            amp = mount_displacement_m(f) * (1 + 0.05 * rng.standard_normal())
            vib = ed.Vibration(amp, f, rng.uniform(0, 2 * np.pi))
            key, k = jax.random.split(key)
            sa, sb = signals(jnp.asarray(t2), jnp.full(n2, 0.3 * PITCH_M), [vib], k)
            rows_a.append(sa)
            rows_b.append(sb)
        arcs_a, arcs_b = jnp.stack(rows_a), jnp.stack(rows_b)
        if arc_example is None:
            i = int(np.argmin(np.abs(f_lut - 1400.0)))
            arc_example = (np.asarray(arcs_a[i]), np.asarray(arcs_b[i]), float(f_lut[i]))
        luts.append(ed.physics.build_vibration_lut(f_lut, t2, arcs_a, arcs_b, fit.params, PITCH_M))
    lut = ed.physics.VibrationLUT(
        jnp.asarray(f_lut), jnp.mean(jnp.stack([lu.delta_gm_m for lu in luts]), 0), ACCEL_M_S2
    )
    progress(f"LUT built ({len(f_lut)} frequencies x {repeats} repeats)")

    # ---- step 3: vibration while moving, compensation -----------------------------
    n3 = 2048 if quick else 4096
    t3 = np.arange(n3) / FS_HZ
    cases = []
    traces = []
    spectrum_example = None
    for fe, v in CASES:
        name = f"{fe:.0f}Hz_{v * 1e3:.1f}mm_s"
        amp = mount_displacement_m(fe) * (1 + 0.05 * rng.standard_normal())
        ph = rng.uniform(0, 2 * np.pi)
        vibs = [
            ed.Vibration(amp, fe, ph),
            ed.Vibration(0.1 * amp, 2 * fe, rng.uniform(0, 2 * np.pi)),
        ]
        x3 = 3e-6 + v * t3
        key, k = jax.random.split(key)
        sa, sb = signals(jnp.asarray(t3), jnp.asarray(x3), vibs, k)
        reading = np.asarray(ed.physics.position_from_signals_m(sa, sb, PITCH_M))
        est = ed.physics.estimate_excitation(t3, sa)
        delta_gm = float(lut(est.f_exc_hz))
        measured_phase = 2 * np.pi * reading / PITCH_M
        comp = np.asarray(
            ed.physics.compensation_signal_m(
                t3,
                measured_phase,
                PITCH_M,
                fitted,
                delta_gm_m=delta_gm,
                f_exc_hz=est.f_exc_hz,
                vibration_phase_rad=est.vibration_phase_rad,
            )
        )
        err_before = reading - x3
        err_after = reading - comp - x3
        # Heydemann variant: corrected arctangent + eq. 6 vibration term only
        reading_h = np.asarray(ed.physics.position_from_signals_m(sa, sb, PITCH_M, fit.params))
        u_vib = np.asarray(
            ed.physics.vibration_compensation_m(t3, delta_gm, est.f_exc_hz, est.vibration_phase_rad)
        )
        err_h = reading_h - u_vib - x3
        # the seed's frequency resolution: doublet and fundamental at FFT bins, no refinement
        est_fft = ed.physics.estimate_excitation(t3, sa, refine=False, throw=False)
        comp_fft = np.asarray(
            ed.physics.compensation_signal_m(
                t3,
                measured_phase,
                PITCH_M,
                fitted,
                delta_gm_m=float(lut(est_fft.f_exc_hz)),
                f_exc_hz=est_fft.f_exc_hz,
                vibration_phase_rad=est_fft.vibration_phase_rad,
            )
        )
        area_fft = float(np.trapezoid(np.abs(reading - comp_fft - x3), t3))
        area_b = float(np.trapezoid(np.abs(err_before), t3))
        area_a = float(np.trapezoid(np.abs(err_after), t3))
        area_h = float(np.trapezoid(np.abs(err_h), t3))
        cases.append(
            {
                "case": name,
                "f_exc_hz": fe,
                "speed_mm_s": v * 1e3,
                "line_frequency_hz": v / PITCH_M,
                "estimated_f_exc_hz": est.f_exc_hz,
                "estimated_line_frequency_hz": est.f_signal_hz,
                "doublet_hz": [est.f_lower_hz, est.f_upper_hz],
                "true_vibration_amplitude_um": amp * 1e6,
                "lut_half_delta_gm_um": 0.5 * delta_gm * 1e6,
                "doublet_vibration_amplitude_um": est.phase_amplitude_rad * k_m * 1e6,
                "vibration_phase_true_rad": ph,
                "vibration_phase_estimated_rad": est.vibration_phase_rad,
                "max_error_before_um": float(np.max(np.abs(err_before))) * 1e6,
                "max_error_after_um": float(np.max(np.abs(err_after))) * 1e6,
                "error_area_before_um_s": area_b * 1e6,
                "error_area_after_um_s": area_a * 1e6,
                "error_area_reduction": 1 - area_a / area_b,
                "error_area_reduction_heydemann": 1 - area_h / area_b,
                "estimated_f_exc_hz_fft_only": est_fft.f_exc_hz,
                "error_area_reduction_fft_only": 1 - area_fft / area_b,
            }
        )
        traces.append((name, err_before, err_after))
        if spectrum_example is None:
            spectrum_example = (name, np.asarray(sa), est)
        progress(
            f"{name}: f_exc {est.f_exc_hz:.2f} Hz, error area reduced by "
            f"{100 * (1 - area_a / area_b):.0f} %"
        )

    summary = {
        "study": NAME,
        "quick": quick,
        "seed": args.seed,
        "config": {
            "signal_period_m": PITCH_M,
            "sample_rate_hz": FS_HZ,
            "amplitude_v": AMPLITUDE_V,
            "noise_v": NOISE_V,
            "shaker_acceleration_m_s2": ACCEL_M_S2,
            "mount_resonance_hz": MOUNT_FN_HZ,
            "record_s": n3 / FS_HZ,
        },
        "ellipse": {
            "true_mean": true_mean.as_dict(),
            "fitted": {k: v for k, v in fitted.as_dict().items() if not k.startswith("harmonics")},
            "rms_radial_residual": fit.rms_radial_residual,
            "seed_terms": {k: v for k, v in fit.params.seed_terms(AMPLITUDE_V).items()},
        },
        "error_components_no_vibration_um": {
            "line_frequency_measured": meas[0] * 1e6,
            "line_frequency_eq4": eq4_1 * 1e6,
            "twice_line_frequency_measured": meas[1] * 1e6,
            "twice_line_frequency_eq4": eq4_2 * 1e6,
        },
        "lut": {"frequency_hz": f_lut, "delta_gm_um": np.asarray(lut.delta_gm_m) * 1e6},
        "cases": cases,
        "error_area_reduction": {c["case"]: c["error_area_reduction"] for c in cases},
        "elapsed_s": time.time() - t_start,
    }

    figures = []
    if not args.no_plots:
        figures = make_plots(args.out, sa1, sb1, fit, arc_example, lut, traces, t3, cases)
        figures += spectrum_plot(args.out, t3, spectrum_example)
        figures += eq4_plot(args.out, fitted)
    write_results(args, NAME, summary, figures)
    return 0


def make_plots(out, sa1, sb1, fit, arc_example, lut, traces, t3, cases):
    figs = []
    fig, axs = new_figure(1, 2, figsize=(10, 5))
    ax = axs[0]
    ax.plot(
        np.asarray(sa1)[::2], np.asarray(sb1)[::2], ".", ms=1, color="tab:blue", label="samples"
    )
    ea, eb = fit.params.points()
    ax.plot(ea, eb, "k-", lw=1.2, label="fitted ellipse")
    c = np.linspace(0, 2 * np.pi, 361)
    ax.plot(AMPLITUDE_V * np.sin(c), AMPLITUDE_V * np.cos(c), "g--", lw=0.8, label="ideal circle")
    ax.plot([float(fit.params.offset_a)], [float(fit.params.offset_b)], "k+")
    ax.set_aspect("equal")
    ax.set_xlabel("S_A (V)")
    ax.set_ylabel("S_B (V)")
    ax.set_title("Lissajous figure without vibration")
    ax.legend(loc="upper right", fontsize=8)
    ax = axs[1]
    sa, sb, f = arc_example
    ax.plot(np.asarray(sa1)[::4], np.asarray(sb1)[::4], ".", ms=0.5, color="0.8")
    ax.plot(sa, sb, ".", ms=2, color="tab:red", label=f"shaker arc, {f:.0f} Hz, fixed position")
    ax.plot(ea, eb, "k-", lw=1.0, label="fitted ellipse")
    ax.set_aspect("equal")
    ax.set_xlabel("S_A (V)")
    ax.set_ylabel("S_B (V)")
    ax.set_title("Vibration at a fixed position: an arc")
    ax.legend(loc="upper right", fontsize=8)
    figs.append(save_figure(fig, out, "lissajous.png"))

    fig, axs = new_figure(len(traces), 1, figsize=(9, 2.0 * len(traces)), sharex=True)
    for ax, (name, eb_, ea_), c in zip(axs, traces, cases):
        ax.plot(t3 * 1e3, eb_ * 1e6, "r--", lw=0.8, label="uncompensated")
        ax.plot(t3 * 1e3, ea_ * 1e6, "b-", lw=0.8, label="compensated")
        ax.set_ylabel("error (um)")
        ax.set_title(
            f"{name.replace('_', ' ')}: error area -{100 * c['error_area_reduction']:.0f} %",
            fontsize=9,
        )
    axs[0].legend(loc="upper right", fontsize=8)
    axs[-1].set_xlabel("time (ms)")
    figs.append(save_figure(fig, out, "error_before_after.png"))

    fig, axs = new_figure(1, 2, figsize=(11, 4))
    ax = axs[0]
    names = [c["case"].replace("_", " ") for c in cases]
    x = np.arange(len(cases))
    ax.bar(
        x - 0.2, [c["error_area_before_um_s"] for c in cases], 0.4, color="tab:red", label="before"
    )
    ax.bar(
        x + 0.2, [c["error_area_after_um_s"] for c in cases], 0.4, color="tab:blue", label="after"
    )
    ax.set_xticks(x, names, rotation=20, fontsize=8)
    ax.set_ylabel("error area (um s)")
    ax.set_title("Area enclosed by the error curve (seed Fig. 6)")
    ax.legend()
    ax = axs[1]
    fl = np.asarray(lut.frequency_hz)
    ff = np.linspace(fl[0], fl[-1], 400)
    ax.plot(ff, 2e6 * mount_displacement_m(ff), "k-", lw=0.8, label="mount model (truth)")
    ax.plot(fl, np.asarray(lut.delta_gm_m) * 1e6, "o", ms=3, label="LUT from shaker arcs")
    ax.set_xlabel("excitation frequency (Hz)")
    ax.set_ylabel("delta_gm, peak to peak (um)")
    ax.set_title(f"Vibration LUT at {ACCEL_M_S2:.0f} m/s^2 (seed Fig. 3)")
    ax.legend()
    figs.append(save_figure(fig, out, "error_area_lut.png"))
    return figs


def spectrum_plot(out, t3, example):
    name, sa, est = example
    freq, spec = ed.physics.signal_spectrum(t3, sa)
    fig, ax = new_figure(figsize=(8, 4))
    ax.semilogy(freq, spec, lw=0.7)
    for f, lab in (
        (est.f_signal_hz, "f"),
        (est.f_lower_hz, "f_exc - f"),
        (est.f_upper_hz, "f_exc + f"),
    ):
        ax.axvline(f, color="r", lw=0.5, ls=":")
        ax.text(f, ax.get_ylim()[1] * 0.3, lab, fontsize=8, rotation=90, va="top")
    ax.set_xlim(0, 2.2 * est.f_exc_hz)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("amplitude of S_A (V)")
    ax.set_title(f"{name.replace('_', ' ')}: doublet at f_exc +- f, f_exc = {est.f_exc_hz:.1f} Hz")
    return [save_figure(fig, out, "spectrum.png")]


def eq4_plot(out, fitted):
    psi = np.linspace(0, 2 * np.pi, 361)
    k = PITCH_M / (2 * np.pi) * 1e6
    exact = np.asarray(ed.phase_error_exact_rad(psi, fitted)) * k
    terms = ed.physics.phase_error_eq4_rad(psi, fitted)
    fig, ax = new_figure(figsize=(8, 4))
    ax.plot(np.degrees(psi), exact, "k-", lw=1.5, label="exact arctangent error")
    ax.plot(np.degrees(psi), np.asarray(terms.total) * k, "y--", lw=1.2, label="eq. 4 sum")
    ax.plot(np.degrees(psi), np.asarray(terms.offset) * k, "r--", lw=0.8, label="u_off")
    ax.plot(np.degrees(psi), np.asarray(terms.amplitude) * k, "g:", lw=0.8, label="u_amp")
    ax.plot(np.degrees(psi), np.asarray(terms.phase) * k, "b-.", lw=0.8, label="u_ph")
    ax.set_xlabel("line phase (deg)")
    ax.set_ylabel("interpolation error (um)")
    ax.set_title("Metrological errors over one signal period (fitted parameters, seed Fig. 2d)")
    ax.legend(fontsize=8)
    return [save_figure(fig, out, "eq4_errors.png")]


if __name__ == "__main__":
    raise SystemExit(main())
