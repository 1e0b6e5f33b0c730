"""``encdesign sds simulate|measure``: shifted-delta-sum recordings from the command line.

* ``encdesign sds simulate --out REC.toml [--pole-pairs 6] [--fixed 2] [--moving 2]
  [--marks 10000] [--phi-deg 0 90 …] [--revs 3] [--errors none|reference] [--seed N]
  [--gzip]``: simulate the reference device (``docs/sds.md``) and write an ``sds``
  recording, one run per platform angle.
* ``encdesign sds measure REC.toml [--revs-per-reading N] [--json FILE]``: measure φ per
  run from the edge times (shifted delta sum, pair average) and, when the recording has
  ``phi_ref``, the error (absolute and zeroed at the first run).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

HELP = "shifted-delta-sum recordings: simulate the reference device, or measure phi from edges"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the sub-command's arguments."""
    sub = parser.add_subparsers(dest="action", required=True)
    s = sub.add_parser("simulate", help="simulate an sds recording of the reference device")
    s.add_argument("--out", type=Path, required=True, help="output recording NAME.toml")
    s.add_argument("--pole-pairs", type=int, default=6, help="motor pole pairs (3·p coils)")
    s.add_argument("--fixed", type=int, default=2, help="fixed sensors, equally spaced")
    s.add_argument("--moving", type=int, default=2, help="moving sensors, equally spaced")
    s.add_argument("--marks", type=int, default=10_000, help="marks (edges) per revolution")
    s.add_argument(
        "--phi-deg",
        type=float,
        nargs="+",
        default=[0.0, 90.0, 180.0, 270.0],
        help="platform angles, one run each (deg)",
    )
    s.add_argument("--revs", type=int, default=3, help="revolutions (readings) per run")
    s.add_argument(
        "--errors",
        choices=["none", "reference"],
        default="reference",
        help="error physics besides ripple and mark errors (reference_errors())",
    )
    s.add_argument("--seed", type=int, default=0, help="PRNG seed of disks and jitter")
    s.add_argument("--gzip", action="store_true", help="write the table as .csv.gz")
    m = sub.add_parser("measure", help="measure phi per run from an sds recording")
    m.add_argument("recording", type=Path, help="recording NAME.toml of kind sds")
    m.add_argument("--revs-per-reading", type=int, default=1, help="revolutions per reading")
    m.add_argument("--json", type=Path, default=None, help="also write the result as JSON")


def run(args: argparse.Namespace) -> int:
    """Run the action; 0 on success (bad input raises EncdesignInputError -> exit 2)."""
    import jax

    from .._errors import input_error
    from ..io._recording import load_recording
    from ..io._sds_recording import sds_readings_from_recording, simulate_sds_recording
    from ..physics._sds import reference_design, reference_errors
    from ..physics._sds_errors import ARCSEC, SDSErrors

    if args.action == "simulate":
        for name in ("pole_pairs", "fixed", "moving", "marks", "revs"):
            v = getattr(args, name)
            if v < 1:
                raise input_error(f"--{name.replace('_', '-')}", f"got {v}", ">= 1")
        key = jax.random.PRNGKey(args.seed)
        k_disk, k_noise = jax.random.split(key)
        design = reference_design(
            args.fixed,
            args.moving,
            pole_pairs=args.pole_pairs,
            marks_per_rev=args.marks,
            key=k_disk,
        )
        errors = reference_errors() if args.errors == "reference" else SDSErrors()
        phis = [math.radians(p) for p in args.phi_deg]
        rec = simulate_sds_recording(
            args.out,
            design,
            phis,
            args.revs,
            errors,
            key=k_noise,
            compress=args.gzip,
            description=f"simulated SDS reference device, {args.pole_pairs} pole pairs, "
            f"{args.fixed}+{args.moving} sensors, errors={args.errors}",
        )
        print(
            f"wrote {args.out} ({rec.n_rows} edges, {len(phis)} run(s); table {rec.meta['data']})"
        )
        return 0

    res = sds_readings_from_recording(
        load_recording(args.recording), revs_per_reading=args.revs_per_reading
    )
    rows = []
    for i, r in enumerate(res.runs):
        row = {
            "run": int(r),
            "phi_deg": math.degrees(float(res.phi_rad[i])),
            "readings": int(len(res.readings_rad[i])),
            "reading_std_arcsec": float(res.readings_rad[i].std() / ARCSEC),
        }
        if res.error_rad is not None:
            row["error_arcsec"] = float(res.error_rad[i] / ARCSEC)
            row["error_zeroed_arcsec"] = float(res.error_zeroed_rad[i] / ARCSEC)
        rows.append(row)
        extra = (
            f'  error {row["error_arcsec"]:+.4f}"  zeroed {row["error_zeroed_arcsec"]:+.4f}"'
            if "error_arcsec" in row
            else ""
        )
        print(
            f"run {row['run']:3d}: phi {row['phi_deg']:12.7f} deg  ({row['readings']} "
            f'readings, std {row["reading_std_arcsec"]:.4f}"){extra}'
        )
    if args.json is not None:
        from ..io._study import write_json

        write_json(args.json, {"recording": str(args.recording), "runs": rows})
        print(f"wrote {args.json}")
    return 0
