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

from ._main import SEED, float_arg, guard_outputs, int_arg

MAX_EDGES = 20_000_000
"""Most edges ``sds simulate`` writes (sensors x marks x (revs + 1) x runs)."""

HELP = "shifted-delta-sum recordings: simulate the reference device, or measure phi from edges"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the sub-command's arguments."""
    sub = parser.add_subparsers(dest="action", required=True)
    s = sub.add_parser("simulate", help="simulate an sds recording of the reference device")
    s.add_argument("--out", type=Path, required=True, help="output recording NAME.toml")
    s.add_argument(
        "--pole-pairs", type=int_arg(1, 1000), default=6, help="motor pole pairs (3·p coils)"
    )
    s.add_argument("--fixed", type=int_arg(1, 64), default=2, help="fixed sensors, equally spaced")
    s.add_argument(
        "--moving", type=int_arg(1, 64), default=2, help="moving sensors, equally spaced"
    )
    s.add_argument(
        "--marks", type=int_arg(2, 10_000_000), default=10_000, help="marks (edges) per revolution"
    )
    s.add_argument(
        "--phi-deg",
        type=float_arg(-1e6, 1e6),
        nargs="+",
        default=[0.0, 90.0, 180.0, 270.0],
        help="platform angles, one run each (deg)",
    )
    s.add_argument(
        "--revs", type=int_arg(1, 100_000), default=3, help="revolutions (readings) per run"
    )
    s.add_argument(
        "--errors",
        choices=["none", "reference"],
        default="reference",
        help="error physics besides ripple and mark errors (reference_errors())",
    )
    s.add_argument("--seed", type=SEED, default=0, help="PRNG seed of disks and jitter")
    table = s.add_mutually_exclusive_group()
    table.add_argument("--gzip", action="store_true", help="write the table as .csv.gz")
    table.add_argument(
        "--parquet", action="store_true", help="write the table as Parquet (NAME.parquet)"
    )
    m = sub.add_parser("measure", help="measure phi per run from an sds recording")
    m.add_argument("recording", type=Path, help="recording NAME.toml of kind sds")
    m.add_argument(
        "--revs-per-reading",
        type=int_arg(1, 100_000),
        default=1,
        help="revolutions per reading",
    )
    m.add_argument("--json", type=Path, default=None, help="also write the result as JSON")


def run(args: argparse.Namespace) -> int:
    """Run the action; 0 on success (bad input raises EncdesignInputError -> exit 2)."""
    from ..errors import input_error
    from ..io import recording_input_files, recording_output_files

    if args.action == "simulate":
        n_edges = (args.fixed + args.moving) * args.marks * (args.revs + 1) * len(args.phi_deg)
        if n_edges > MAX_EDGES:
            raise input_error(
                "--fixed/--moving/--marks/--revs/--phi-deg",
                f"{n_edges} edges",
                f"at most {MAX_EDGES} edges ((fixed + moving) x marks x (revs + 1) x runs)",
            )
        outputs = [
            ("--out", p)
            for p in recording_output_files(
                args.out, compress=args.gzip, parquet=args.parquet, label="--out"
            )
        ]
        with guard_outputs([], outputs):
            return _simulate(args)
    inputs = [("recording", p) for p in recording_input_files(args.recording)]
    with guard_outputs(inputs, [("--json", args.json)]):
        return _measure(args)


def _simulate(args: argparse.Namespace) -> int:
    import jax

    from ..physics import SDSErrors, reference_design, reference_errors
    from ..simulate import simulate_sds_recording

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
        parquet=args.parquet,
        description=f"simulated SDS reference device, {args.pole_pairs} pole pairs, "
        f"{args.fixed}+{args.moving} sensors, errors={args.errors}",
    )
    print(f"wrote {args.out} ({rec.n_rows} edges, {len(phis)} run(s); table {rec.meta['data']})")
    return 0


def _measure(args: argparse.Namespace) -> int:
    from ..diagnose import sds_readings_from_recording
    from ..io import load_recording
    from ..physics import ARCSEC

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
        from ..io import write_json

        write_json(args.json, {"recording": str(args.recording), "runs": rows})
        print(f"wrote {args.json}")
    return 0
