"""``encdesign simulate DESIGN.toml --out REC.toml [--seed N] [--like REC.toml]
[--gzip | --parquet]``."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._main import SEED, guard_outputs

HELP = "simulate a bench recording (multihead) from a design file"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the sub-command's arguments."""
    parser.add_argument("design", type=Path, help="design file (TOML, docs/design-file.md)")
    parser.add_argument("--out", type=Path, required=True, help="output recording NAME.toml")
    parser.add_argument("--seed", type=SEED, default=0, help="PRNG seed of the read noise")
    parser.add_argument(
        "--like",
        type=Path,
        default=None,
        help="reuse the samples (t, run, theta_ref) of this multihead recording",
    )
    table = parser.add_mutually_exclusive_group()
    table.add_argument("--gzip", action="store_true", help="write the table as .csv.gz")
    table.add_argument(
        "--parquet", action="store_true", help="write the table as Parquet (NAME.parquet)"
    )


def run(args: argparse.Namespace) -> int:
    """Load the design, simulate, write the recording; 0 on success."""
    import numpy as np

    from ..design import load_design
    from ..io import recording_input_files, recording_output_files
    from ..simulate import simulate_recording

    inputs = [("design", args.design)]
    if args.like is not None:
        inputs += [("--like", p) for p in recording_input_files(args.like)]
    outputs = [
        ("--out", p)
        for p in recording_output_files(
            args.out, compress=args.gzip, parquet=args.parquet, label="--out"
        )
    ]
    with guard_outputs(inputs, outputs):
        design = load_design(args.design)
        rec = simulate_recording(
            design,
            args.out,
            seed=args.seed,
            like=args.like,
            compress=args.gzip,
            parquet=args.parquet,
        )
    data = rec.meta["data"]
    print(
        f"wrote {args.out} ({rec.n_rows} samples, {design.n_heads} heads, "
        f"{np.unique(rec.runs).size} run(s); table {data})"
    )
    return 0
