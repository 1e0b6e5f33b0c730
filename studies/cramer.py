"""Cramer's simulation cases: encoder theorem and self-compensation on a 3+1 encoder.

Reproduces seed 000, section V.B (figs. 5-8) with the kinematic model: optical radius
2.54 cm, 5 um centering error, 6 mrad disk tilt, 5 urad grating mode 3 and 2.5 urad
grating mode 4, three heads at 0/120/240 deg plus an asymmetric reference head.

* fig. 5: centering error alone -> order 1 of amplitude e/R;
* fig. 6: tilt alone -> order 2 of amplitude ~ tilt^2/4;
* fig. 7: all four effects; the three-head average keeps only mode 3 (encoder theorem);
* fig. 8: symmetry averaging plus self-compensation (cotangent equations, encoder map):
  what is left is a tiny mode 6.

It also shows modal leakage: with misplaced heads the modes that should cancel leak
through; the transfer of each order is computed in closed form and measured on the model.

Outputs (``--out``): ``cramer.json`` and the figures ``error_vs_angle.png``,
``mode_spectra.png`` and ``modal_leakage.png``.
"""

from __future__ import annotations

import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from encdesign.io import int_arg, new_figure, save_figure, study_parser, write_results
from encdesign.physics import (
    apply_map,
    averaged_error,
    encoder_map,
    head_errors,
    head_readings,
    make_model,
    mode_amplitudes,
    model_mode_transfer,
    self_compensate,
    surviving_orders,
)

NAME = "cramer"
RADIUS_M = 0.0254
ECC_M = 5e-6
TILT_RAD = 6e-3
MODE3_RAD = 5e-6
MODE4_RAD = 2.5e-6
SYM_DEG = (0.0, 120.0, 240.0)
REF_DEG = 22.0  # near the least cotangent noise amplification for 3+1 (study reference-head)
SPECTRUM_ORDERS = 12
REPORT_ORDERS = 6
LEAK_PLACEMENT_RAD = (0.0, 2e-3, -1.5e-3)  # exaggerated misplacement to show modal leakage


def _log(msg: str) -> None:
    print(f"[cramer] {msg}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    """Run the study; returns 0."""
    p = study_parser(NAME, __doc__)
    p.add_argument(
        "--max-order",
        type=int_arg(1, 1000),
        default=12,
        help="self-compensation order M (1 … 1000)",
    )
    args = p.parse_args(argv)
    n = 256 if args.quick else 4096
    t0 = time.perf_counter()
    theta = jnp.arange(n) * (2 * jnp.pi / n)
    angles = np.deg2rad([*SYM_DEG, REF_DEG])
    ref = 3
    grating = [0.0, 0.0, MODE3_RAD, MODE4_RAD]

    # --- figs. 5 and 6: one effect at a time, one head at azimuth 0
    _log(f"kinematic model, {n} angles per revolution")
    m_ecc = make_model(RADIUS_M, [0.0], eccentricity_m=(ECC_M, 0.0))
    m_tilt = make_model(RADIUS_M, [0.0], tilt_rad=(TILT_RAD, 0.0))
    e_ecc = head_errors(m_ecc, theta)[:, 0]
    e_tilt = head_errors(m_tilt, theta)[:, 0]
    amp_ecc = mode_amplitudes(theta, e_ecc, SPECTRUM_ORDERS)
    amp_tilt = mode_amplitudes(theta, e_tilt, SPECTRUM_ORDERS)

    # --- fig. 7: everything, single head and three-head symmetry average
    model = make_model(
        RADIUS_M,
        angles,
        eccentricity_m=(ECC_M, 0.0),
        tilt_rad=(TILT_RAD, 0.0),
        grating_sin_rad=grating,
    )
    readings = head_readings(model, theta)
    errors = readings - theta[:, None]
    e_head = errors[:, 0]
    e_avg = averaged_error(errors[:, :3])
    amp_head = mode_amplitudes(theta, e_head, SPECTRUM_ORDERS)
    amp_avg = mode_amplitudes(theta, e_avg, SPECTRUM_ORDERS)

    # --- fig. 8: self-compensation from head differences only. No reference encoder: the
    # abscissa is the symmetric heads' averaged reading, as on a real encoder.
    _log(f"self-compensation, reference head at {REF_DEG} deg, orders 1..{args.max_order}")
    avg_reading = averaged_error(readings[:, :3])
    sc = self_compensate(avg_reading, readings, angles, ref, args.max_order)
    emap = encoder_map(sc, angles[:3])
    corrected = apply_map(emap, avg_reading)
    resid = corrected - theta
    resid = resid - jnp.mean(resid)  # each head's zero is arbitrary
    amp_sc = mode_amplitudes(theta, resid, SPECTRUM_ORDERS)
    map_table_theta, map_table = emap.table(360)

    # --- modal leakage: misplaced heads, closed form vs model
    _log("modal leakage: closed form vs kinematic model")
    leak_model = make_model(RADIUS_M, angles[:3], placement_error_rad=LEAK_PLACEMENT_RAD)
    t_analytic = surviving_orders(angles[:3] + np.asarray(LEAK_PLACEMENT_RAD), SPECTRUM_ORDERS)
    t_model = model_mode_transfer(leak_model, SPECTRUM_ORDERS, n_angles=min(n, 512))
    nominal_transfer = surviving_orders(angles[:3], SPECTRUM_ORDERS)

    u = 1e6
    orders = list(range(1, REPORT_ORDERS + 1))
    summary = {
        "study": NAME,
        "description": "Cramer figs. 5-8: r = 2.54 cm, 5 um centering, 6 mrad tilt, "
        "5 urad mode 3, 2.5 urad mode 4, 3+1 heads",
        "samples_per_rev": n,
        "orders": orders,
        "head_mode_amplitude_urad": np.asarray(amp_head[:REPORT_ORDERS]) * u,
        "averaged_mode_amplitude_urad": np.asarray(amp_avg[:REPORT_ORDERS]) * u,
        "selfcomp_mode_amplitude_urad": np.asarray(amp_sc[:REPORT_ORDERS]) * u,
        "selfcomp_residual_max_urad": float(jnp.max(jnp.abs(resid))) * u,
        "averaged_residual_max_urad": float(jnp.max(jnp.abs(e_avg - jnp.mean(e_avg)))) * u,
        "head_error_max_urad": float(jnp.max(jnp.abs(e_head - jnp.mean(e_head)))) * u,
        "eccentricity_only_order1_urad": float(amp_ecc[0]) * u,
        "eccentricity_closed_form_urad": ECC_M / RADIUS_M * u,
        "tilt_only_order2_urad": float(amp_tilt[1]) * u,
        "tilt_closed_form_urad": TILT_RAD**2 / 4 * u,
        "reference_head_deg": REF_DEG,
        "selfcomp_max_order": args.max_order,
        "selfcomp_reference_sin_urad": np.asarray(sc.sin_rad[:REPORT_ORDERS]) * u,
        "selfcomp_reference_cos_urad": np.asarray(sc.cos_rad[:REPORT_ORDERS]) * u,
        "selfcomp_pair_spread_max_urad": float(jnp.max(sc.spread_rad)) * u,
        "encoder_map_peak_urad": float(jnp.max(jnp.abs(map_table))) * u,
        "leakage_placement_error_rad": list(LEAK_PLACEMENT_RAD),
        "leakage_transfer_analytic": np.asarray(t_analytic),
        "leakage_transfer_model": np.asarray(t_model),
        "leakage_transfer_max_abs_difference": float(jnp.max(jnp.abs(t_model - t_analytic))),
        "runtime_s": time.perf_counter() - t0,
    }

    figures = []
    if not args.no_plots:
        figures = _plots(
            args.out,
            theta,
            e_ecc,
            e_tilt,
            e_head,
            e_avg,
            resid,
            (map_table_theta, map_table),
            (amp_head, amp_avg, amp_sc),
            (nominal_transfer, t_analytic, t_model),
        )
    write_results(args, NAME, summary, figures)
    return 0


def _plots(out, theta, e_ecc, e_tilt, e_head, e_avg, resid, map_tab, amps, transfers):
    deg = np.rad2deg(np.asarray(theta))
    u = 1e6

    def centred(x):
        x = np.asarray(x)
        return (x - x.mean()) * u

    fig, axes = new_figure(2, 2, figsize=(11, 7.5))
    ax = axes[0, 0]
    ax.plot(deg, centred(e_ecc), color="C0")
    ax.set_title(f"fig. 5: centering error {ECC_M * 1e6:.0f} µm (one head)")
    ax.set_ylabel("error (µrad)")
    ax = axes[0, 1]
    ax.plot(deg, centred(e_tilt), color="C1")
    ax.set_title(f"fig. 6: disk tilt {TILT_RAD * 1e3:.0f} mrad (one head)")
    ax = axes[1, 0]
    ax.plot(deg, centred(e_head), color="C0", label="head 0 alone")
    ax.plot(deg, centred(e_avg), color="C3", lw=2, label="3-head average (mode 3 left)")
    ax.set_title("fig. 7: all effects, symmetry averaging")
    ax.set_ylabel("error (µrad)")
    ax.legend(loc="upper right", fontsize=8)
    ax = axes[1, 1]
    ax.plot(deg, centred(resid) * 1e3, color="C2", label="after averaging + self-comp.")
    ax.set_title("fig. 8: averaging + self-compensation")
    ax.set_ylabel("residual (nrad)")
    ax2 = ax.twinx()
    ax2.plot(
        np.rad2deg(np.asarray(map_tab[0])),
        np.asarray(map_tab[1]) * u,
        color="0.6",
        ls="--",
        label="encoder map m(θ)",
    )
    ax2.set_ylabel("map (µrad)", color="0.4")
    lines = ax.get_legend_handles_labels()
    lines2 = ax2.get_legend_handles_labels()
    ax.legend(lines[0] + lines2[0], lines[1] + lines2[1], loc="upper right", fontsize=8)
    for a in axes.flat:
        a.set_xlabel("shaft angle θ (deg)")
        a.set_xlim(0, 360)
        a.set_xticks(range(0, 361, 60))
        a.grid(alpha=0.3)
    f1 = save_figure(fig, out, "error_vs_angle.png")

    fig, ax = new_figure(figsize=(9, 4.8))
    orders = np.arange(1, SPECTRUM_ORDERS + 1)
    floor = 1e-10
    labels = ("single head", "3-head average", "average + self-compensation")
    for i, (a, lab) in enumerate(zip(amps, labels)):
        ax.bar(
            orders + (i - 1) * 0.27,
            np.maximum(np.asarray(a) * u, floor),
            width=0.27,
            label=lab,
            color=f"C{[0, 3, 2][i]}",
        )
    ax.set_yscale("log")
    ax.set_ylim(floor, 1e3)
    ax.set_xticks(orders)
    ax.set_xlabel("Fourier order m (cycles per revolution)")
    ax.set_ylabel("amplitude (µrad)")
    ax.set_title("Error spectrum: 2.54 cm disk, 5 µm centering, 6 mrad tilt, modes 3 and 4")
    ax.axhline(1e-6, color="0.5", lw=0.8, ls=":")
    ax.text(SPECTRUM_ORDERS + 0.4, 1.3e-6, "1 prad", fontsize=7, color="0.4", ha="right")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    f2 = save_figure(fig, out, "mode_spectra.png")

    fig, ax = new_figure(figsize=(9, 4.2))
    nominal, analytic, model = (np.asarray(x) for x in transfers)
    ax.plot(orders, np.maximum(nominal, 1e-17), "o", color="0.6", label="equal spacing")
    ax.plot(orders, analytic, "s", mfc="none", ms=9, color="C3", label="misplaced: closed form")
    ax.plot(orders, model, "x", ms=8, color="C0", label="misplaced: kinematic model")
    ax.set_yscale("log")
    ax.set_ylim(1e-17, 3)
    ax.set_xticks(orders)
    ax.set_xlabel("Fourier order m")
    ax.set_ylabel("|transfer| through 3-head average")
    pl = ", ".join(f"{x * 1e3:g}" for x in LEAK_PLACEMENT_RAD)
    ax.set_title(f"Modal leakage: heads misplaced by ({pl}) mrad")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    f3 = save_figure(fig, out, "modal_leakage.png")
    return [f1, f2, f3]


if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)
    sys.exit(main())
