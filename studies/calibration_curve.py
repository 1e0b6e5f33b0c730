"""Calibration curves from dual-closure results and from a measured sensor (seed 001, claim 11).

The seed: with both sensor pairs the first device's error is "nearly a pure second
harmonic"; "the difference between the data values and the best fit sinusoid is less than
0.1 arcseconds" (fig. 19), and the second device's error "could be easily corrected using
a best fit low order trigonometric sum as a calibration curve" (figs. 23–24). This study:

* simulates the dual-closure tests of the seed's devices (SDS model, as in the ``closure``
  study): the first device with one pair and with both pairs (N = 72, 15 settings) and the
  second device (N = 72, 23 settings);
* fits the calibration curve (``encdesign.calibrate.curve_from_closure``: order chosen by
  held-out error, band from the closure covariance) and the seed's single best-fit
  sinusoid (constant + order 2), and reports each one's residual against the closure data
  and, after correction, against the true instrument error;
* writes the correction table, reads it back, applies it, and checks the round trip;
* fits a curve to a measured sensor against a reference (MagAlpha example,
  ``../shared/realdata``) when that file is present, to show the order choice on real data.
"""

from __future__ import annotations

import csv
import math
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import encdesign as ed
from encdesign.calibrate import (
    apply_correction_table,
    curve_from_closure,
    fit_curve,
    read_correction_table,
    solve_closure,
    write_correction_table,
)
from encdesign.io import new_figure, save_figure, study_parser, write_results
from encdesign.physics import ARCSEC
from encdesign.simulate import simulate_closure_readings

NAME = "calibration-curve"
CHUNK = 128
SEED_SINUSOID_RESIDUAL_ARCSEC = 0.1
_ROOT = Path(__file__).resolve().parent.parent
# the MagAlpha example (MIT licence, see ../shared/realdata/README.md): shipped copy first
MAGALPHA = [
    _ROOT / "data" / "real" / "magalpha_calibration_example.csv",
    _ROOT.parent / "shared" / "realdata" / "magalpha_calibration_example.csv",
    _ROOT.parent.parent / "shared" / "realdata" / "magalpha_calibration_example.csv",
]


def _progress(msg: str) -> None:
    print(f"[{NAME}] {msg}", file=sys.stderr, flush=True)


def _sinusoid_residual(theta, y, order=2):
    x = np.stack([np.ones_like(theta), np.cos(order * theta), np.sin(order * theta)], 1)
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    return y - x @ coef, coef


def _magalpha(path: Path):
    with open(path, encoding="utf-8", newline="") as fh:
        rows = list(csv.reader(fh))[1:]
    a = np.asarray([[float(v) for v in r] for r in rows if r], dtype=float)
    ref = np.deg2rad(a[:, 0])
    err = np.angle(np.exp(1j * (np.deg2rad(a[:, 1]) - ref)))
    return ref, err


def main(argv: list[str] | None = None) -> int:
    p = study_parser(NAME, __doc__)
    p.add_argument("--marks", type=int, default=None, help="marks per revolution")
    p.add_argument("--sigma-arcsec", type=float, default=0.01, help="reading noise per null")
    p.add_argument("--magalpha", type=Path, default=None, help="MagAlpha example CSV")
    args = p.parse_args(argv)
    n_marks = args.marks or (200 if args.quick else 10_000)
    t0 = time.time()
    key = jax.random.PRNGKey(args.seed)
    rng = np.random.default_rng(args.seed)
    errors = ed.reference_errors(systematic_only=True)
    m6, m5 = ed.physics.reference_motor(6), ed.physics.reference_motor(5)
    devices = {
        "first_one_pair": (ed.reference_design(1, 1, marks_per_rev=n_marks, key=key, motor=m6), 15),
        "first_two_pairs": (
            ed.reference_design(2, 2, marks_per_rev=n_marks, key=key, motor=m6),
            15,
        ),
        "second": (
            ed.reference_design(3, 3, pole_pairs=5, marks_per_rev=n_marks, key=key, motor=m5),
            23,
        ),
    }
    if args.quick:
        devices = {k: (d, 15) for k, (d, _) in devices.items() if k != "first_one_pair"}
    phi_error = jax.jit(ed.sds_phi_error)
    n = 72
    nominal = 2 * np.pi * np.arange(n) / n
    cases = {}
    plots = {}
    for i, (name, (design, s_count)) in enumerate(devices.items()):
        _progress(f"{name}: N = {n}, {s_count} settings ({time.time() - t0:.0f} s)")

        def err_fn(phi, design=design):
            flat = np.asarray(phi, dtype=float).reshape(-1)
            pad = (-flat.size) % CHUNK
            chunks = np.concatenate([flat, np.zeros(pad)]).reshape(-1, CHUNK)
            out = [np.asarray(phi_error(design, jnp.asarray(c), errors)) for c in chunks]
            return np.concatenate(out)[: flat.size].reshape(np.shape(phi))

        pos = list(range(s_count))
        face = rng.normal(0, 2 * ARCSEC, n)
        off = rng.uniform(-5, 5, s_count) * ARCSEC
        readings = simulate_closure_readings(
            err_fn,
            n,
            pos,
            face_error_rad=face,
            setting_offset_rad=off,
            sigma_reading_rad=args.sigma_arcsec * ARCSEC,
            key=jax.random.fold_in(key, i),
        )
        res = solve_closure(readings, pos)
        e_true = err_fn(nominal)
        e_true = e_true - e_true.mean()
        curve = curve_from_closure(res)
        fine = np.linspace(0, 2 * np.pi, 1441)[:-1]
        e_fine = err_fn(fine)
        e_fine = e_fine - e_fine.mean()
        sin_res, _ = _sinusoid_residual(nominal, res.instrument_error_rad)
        sin_true, _ = _sinusoid_residual(fine, e_fine)
        table_path = Path(args.out) / f"correction-{name}.csv"
        write_correction_table(table_path, curve, 3600)
        table = read_correction_table(table_path)
        # correction applied to readings of the true angle (reading = θ + e(θ))
        reading = fine + e_fine
        corrected = apply_correction_table(table, reading) - fine
        corrected = corrected - corrected.mean()
        cases[name] = {
            "n_settings": s_count,
            "order": curve.order,
            "orders_tried": curve.orders_tried,
            "heldout_rms_arcsec": [v / ARCSEC for v in curve.heldout_rms_rad],
            "chi2_per_dof": curve.chi2 / curve.dof,
            "band_max_arcsec": float(np.max(curve.band_rad(fine))) / ARCSEC,
            "truth_pp_arcsec": float(np.ptp(e_fine)) / ARCSEC,
            "curve_vs_closure_max_arcsec": float(
                np.max(np.abs(res.instrument_error_rad - curve(nominal)))
            )
            / ARCSEC,
            "corrected_residual_max_arcsec": float(np.max(np.abs(corrected))) / ARCSEC,
            "corrected_residual_rms_arcsec": float(np.sqrt(np.mean(corrected**2))) / ARCSEC,
            "sinusoid2_residual_vs_closure_max_arcsec": float(np.max(np.abs(sin_res))) / ARCSEC,
            "sinusoid2_residual_vs_truth_max_arcsec": float(np.max(np.abs(sin_true))) / ARCSEC,
            "seed_sinusoid_residual_arcsec": SEED_SINUSOID_RESIDUAL_ARCSEC,
            "table": str(table_path),
        }
        plots[name] = (nominal, res, curve, fine, corrected)
    real = None
    mag = args.magalpha or next((m for m in MAGALPHA if m.exists()), None)
    if mag is not None and Path(mag).exists():
        th, err = _magalpha(mag)
        c = fit_curve(th, err, max_order=12)
        real = {
            "file": str(mag),
            "samples": int(th.size),
            "order": c.order,
            "heldout_rms_deg": [math.degrees(v) for v in c.heldout_rms_rad],
            "raw_rms_deg": float(math.degrees(np.std(err))),
            "fitted_rms_deg": math.degrees(c.fitted_rms_rad),
            "quantization_rms_deg": 0.703125 / math.sqrt(12) * math.sqrt(2),
        }
        plots["magalpha"] = (th, err, c)
    summary = {
        "study": NAME,
        "quick": bool(args.quick),
        "marks_per_rev": n_marks,
        "cases": cases,
        "magalpha": real,
        "runtime_s": time.time() - t0,
    }
    figs = [] if args.no_plots else _plots(args.out, plots)
    write_results(args, NAME, summary, figs)
    return 0


def _plots(out, plots):
    names = [k for k in plots if k != "magalpha"]
    fig, axes = new_figure(2, len(names), figsize=(5 * len(names), 7), squeeze=False)
    for i, name in enumerate(names):
        nominal, res, curve, fine, corrected = plots[name]
        ax = axes[0, i]
        ax.errorbar(
            np.degrees(nominal),
            res.instrument_error_rad / ARCSEC,
            res.instrument_se_rad / ARCSEC,
            fmt="+",
            label="dual closure",
        )
        c, b = curve(fine) / ARCSEC, curve.band_rad(fine) / ARCSEC
        ax.plot(np.degrees(fine), c, "-", label=f"curve, order {curve.order}")
        ax.fill_between(np.degrees(fine), c - 2 * b, c + 2 * b, alpha=0.3)
        ax.set_title(name)
        ax.set_ylabel("error (arcsec)")
        ax.legend(fontsize=7)
        ax = axes[1, i]
        ax.plot(np.degrees(fine), corrected / ARCSEC)
        ax.set_xlabel("angle (deg)")
        ax.set_ylabel("corrected residual (arcsec)")
    paths = [save_figure(fig, out, "calibration-curve.png")]
    if "magalpha" in plots:
        th, err, c = plots["magalpha"]
        fig, (a1, a2) = new_figure(1, 2, figsize=(11, 4))
        a1.plot(np.degrees(th), np.degrees(err), ".", ms=3, label="MagAlpha − reference")
        grid = np.linspace(0, 2 * np.pi, 721)
        a1.plot(np.degrees(grid), np.degrees(c(grid)), "-", label=f"order {c.order}")
        a1.set_xlabel("reference angle (deg)")
        a1.set_ylabel("error (deg)")
        a1.legend()
        a2.plot(c.orders_tried, np.degrees(c.heldout_rms_rad), "o-")
        a2.set_xlabel("order")
        a2.set_ylabel("held-out RMS (deg)")
        paths.append(save_figure(fig, out, "calibration-curve-magalpha.png"))
    return paths


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
