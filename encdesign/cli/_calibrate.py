"""``encdesign calibrate closure|curve``: dual-closure calibration and calibration curves.

* ``encdesign calibrate closure REC.toml [--json F] [--plots DIR] [--sigma-arcsec S]
  [--weighting gls|ols] [--allow-rank-deficient]``: solve a ``closure`` recording
  (``docs/calibration.md``) by least squares; print the counts, rank, residual σ and the
  instrument and polygon errors with standard errors. A rank-deficient system is refused
  (exit 2, naming the undetermined harmonics) unless ``--allow-rank-deficient``.
* ``encdesign calibrate curve REC.toml --table OUT.csv [--json F] [--plots DIR]
  [--max-order K] [--order K] [--folds F] [--points P]``: fit a calibration curve
  (order by held-out error) to a ``closure`` result or to a ``multihead`` recording with
  ``theta_ref`` (error of the heads' average), write the correction table.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ._main import float_arg, guard_outputs, int_arg

HELP = "calibration: dual-closure polygon tests and calibration curves (correction tables)"

ARCSEC = math.pi / (180 * 3600)

MAX_SIGMA_ARCSEC = 3600.0 * 180
"""Largest ``--sigma-arcsec`` (half a turn: beyond it a reading noise means nothing)."""
MAX_ORDER = 10_000
"""Largest ``--order`` / ``--max-order`` (the record's sample count caps it further)."""
MAX_POINTS = 1_000_000
"""Most rows of a correction table (``--points``)."""
MAX_FOLDS = 1000


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the sub-command's arguments."""
    sub = parser.add_subparsers(dest="action", required=True)
    c = sub.add_parser("closure", help="solve a dual-closure recording (kind closure)")
    c.add_argument("recording", type=Path, help="recording NAME.toml of kind closure")
    c.add_argument("--json", type=Path, default=None, help="write the result as JSON")
    c.add_argument("--plots", type=Path, default=None, help="write PNG figures here")
    c.add_argument(
        "--sigma-arcsec",
        type=float_arg(0.0, MAX_SIGMA_ARCSEC, lower_open=True),
        default=None,
        help=f"known reading noise, arcsec (0 < S <= {MAX_SIGMA_ARCSEC:g}; default: residual)",
    )
    c.add_argument("--weighting", choices=["gls", "ols"], default="gls", help="least squares")
    c.add_argument(
        "--allow-rank-deficient",
        action="store_true",
        help="return the minimum-norm solution of a rank-deficient test (flagged)",
    )
    k = sub.add_parser("curve", help="fit a calibration curve and write a correction table")
    k.add_argument("recording", type=Path, help="closure recording, or multihead with theta_ref")
    k.add_argument("--table", type=Path, required=True, help="correction table CSV to write")
    k.add_argument("--json", type=Path, default=None, help="write the curve as JSON")
    k.add_argument("--plots", type=Path, default=None, help="write PNG figures here")
    k.add_argument(
        "--max-order",
        type=int_arg(0, MAX_ORDER),
        default=None,
        help=f"highest order tried (0 … {MAX_ORDER}, capped at what the samples resolve)",
    )
    k.add_argument(
        "--order", type=int_arg(0, MAX_ORDER), default=None, help="force this order (>= 0)"
    )
    k.add_argument(
        "--folds", type=int_arg(2, MAX_FOLDS), default=4, help="cross-validation folds (>= 2)"
    )
    k.add_argument(
        "--points",
        type=int_arg(4, MAX_POINTS),
        default=3600,
        help=f"rows of the correction table (4 … {MAX_POINTS})",
    )


def _closure_json(res, path) -> dict:
    return {
        "recording": str(path),
        "status": res.status,
        "counts": vars(res.counts),
        "rank": res.rank,
        "dof": res.dof,
        "weighting": res.weighting,
        "undetermined_harmonics": res.undetermined_harmonics,
        "sigma_reading_arcsec": res.sigma_reading_rad / ARCSEC,
        "sigma_residual_arcsec": res.sigma_residual_rad / ARCSEC,
        "chi2": res.chi2,
        "setting_positions": res.setting_positions.tolist(),
        "closure_mismatch_arcsec": (res.closure_mismatch_rad / ARCSEC).tolist(),
        "positions_deg": (res.positions_rad * 180 / math.pi).tolist(),
        "instrument_error_arcsec": (res.instrument_error_rad / ARCSEC).tolist(),
        "instrument_se_arcsec": (res.instrument_se_rad / ARCSEC).tolist(),
        "face_error_arcsec": (res.face_error_rad / ARCSEC).tolist(),
        "face_se_arcsec": (res.face_se_rad / ARCSEC).tolist(),
        "harmonic_se_arcsec": {
            str(k): [v[0] / ARCSEC, v[1] / ARCSEC] for k, v in res.harmonic_se_rad.items()
        },
    }


def _plot_closure(res, out: Path) -> Path:
    import numpy as np

    from ..calibrate import harmonic_amplitudes
    from ..io import new_figure, save_figure

    deg = res.positions_rad * 180 / math.pi
    fig, (a1, a2) = new_figure(2, 1, figsize=(7, 6))
    a1.errorbar(deg, res.instrument_error_rad / ARCSEC, res.instrument_se_rad / ARCSEC, fmt="+")
    a1.errorbar(deg, res.face_error_rad / ARCSEC, res.face_se_rad / ARCSEC, fmt="x")
    a1.legend(["instrument", "polygon faces"])
    a1.set_xlabel("position (deg)")
    a1.set_ylabel("error (arcsec)")
    amp = harmonic_amplitudes(res.instrument_error_rad) / ARCSEC
    a2.bar(np.arange(amp.size)[1:], amp[1:])
    a2.set_xlabel("order")
    a2.set_ylabel("instrument amplitude (arcsec)")
    return save_figure(fig, out, "closure.png")


def run(args: argparse.Namespace) -> int:
    """Run the action; 0 on success (bad input raises EncdesignInputError -> exit 2).

    Outputs are checked against the recording (its TOML and table) and one another before
    any work; a failed run leaves none of them behind."""
    from ..io import recording_input_files

    inputs = [("recording", p) for p in recording_input_files(args.recording)]
    outputs = [("--json", args.json)]
    if args.action == "curve":
        outputs.insert(0, ("--table", args.table))
    with guard_outputs(inputs, outputs, folders=[("--plots", args.plots)]):
        return _run(args)


_FLAGS = {"order": "--order", "max_order": "--max-order", "fit_curve n_folds": "--folds"}


def _curve(rec, args):
    from ..calibrate import curve_from_recording
    from ..errors import EncdesignInputError

    try:
        return curve_from_recording(
            rec, max_order=args.max_order, order=args.order, n_folds=args.folds
        )
    except EncdesignInputError as exc:  # name the flag, not the library's argument
        msg = str(exc)
        for key, flag in _FLAGS.items():
            if msg.startswith(f"{key}:"):
                raise EncdesignInputError(flag + msg[len(key) :]) from None
        raise


def _run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..calibrate import closure_from_recording, write_correction_table
    from ..io import load_recording, write_json

    rec = load_recording(args.recording)
    if args.action == "closure":
        sigma = None
        if args.sigma_arcsec is not None:
            sigma = args.sigma_arcsec * ARCSEC
        res = closure_from_recording(
            rec,
            sigma_reading_rad=sigma,
            weighting=args.weighting,
            throw=not args.allow_rank_deficient,
        )
        c = res.counts
        print(
            f"{args.recording}: N = {c.n_faces} faces, {c.n_settings} settings: "
            f"{c.n_measurements} measurements, {c.n_equations} equations, {c.n_unknowns} unknowns"
        )
        print(
            f"status {res.status}, rank {res.rank}, dof {res.dof}, residual sigma "
            f'{res.sigma_residual_rad / ARCSEC:.4g}"'
            + (
                f", undetermined harmonics {res.undetermined_harmonics}"
                if res.status != "ok"
                else ""
            )
        )
        print(
            f'instrument error p-p {np.ptp(res.instrument_error_rad) / ARCSEC:.4g}" '
            f'(mean se {res.instrument_se_rad.mean() / ARCSEC:.3g}"), polygon faces p-p '
            f'{np.ptp(res.face_error_rad) / ARCSEC:.4g}" '
            f'(mean se {res.face_se_rad.mean() / ARCSEC:.3g}")'
        )
        if args.json is not None:
            write_json(args.json, _closure_json(res, args.recording))
            print(f"wrote {args.json}")
        if args.plots is not None:
            print(f"wrote {_plot_closure(res, args.plots)}")
        return 0

    curve, theta, err, band_src = _curve(rec, args)
    path = write_correction_table(args.table, curve, args.points)
    resid = err - curve(theta)
    print(
        f"{args.recording}: order {curve.order} chosen by held-out error (tried "
        f"{curve.orders_tried[0]}…{curve.orders_tried[-1]}); fitted RMS "
        f'{curve.fitted_rms_rad / ARCSEC:.4g}", corrected residual max '
        f'{np.max(np.abs(resid)) / ARCSEC:.4g}" ({band_src})'
    )
    print(f"wrote {path}")
    if args.json is not None:
        write_json(
            args.json,
            {
                "recording": str(args.recording),
                "source": band_src,
                "status": curve.status,
                "order": curve.order,
                "orders_tried": curve.orders_tried,
                "heldout_rms_arcsec": [v / ARCSEC for v in curve.heldout_rms_rad],
                "coef_arcsec": (curve.coef_rad / ARCSEC).tolist(),
                "fitted_rms_arcsec": curve.fitted_rms_rad / ARCSEC,
                "corrected_max_arcsec": float(np.max(np.abs(resid)) / ARCSEC),
                "chi2": curve.chi2,
                "dof": curve.dof,
                "table": str(path),
            },
        )
        print(f"wrote {args.json}")
    if args.plots is not None:
        from ..io import new_figure, save_figure

        grid = np.linspace(0, 2 * np.pi, 721)
        fig, ax = new_figure(figsize=(7, 4))
        ax.plot(np.degrees(theta), err / ARCSEC, "+", label="data")
        c, b = curve(grid) / ARCSEC, curve.band_rad(grid) / ARCSEC
        ax.plot(np.degrees(grid), c, "-", label=f"curve, order {curve.order}")
        ax.fill_between(np.degrees(grid), c - 2 * b, c + 2 * b, alpha=0.3, label="±2 se")
        ax.set_xlabel("angle (deg)")
        ax.set_ylabel("error (arcsec)")
        ax.legend()
        print(f"wrote {save_figure(fig, args.plots, 'curve.png')}")
    return 0
