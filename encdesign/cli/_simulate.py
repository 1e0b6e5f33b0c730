"""``encdesign simulate DESIGN.toml --out REC.toml [--seed N] [--like REC.toml]``."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "simulate a bench recording (multihead) from a design file"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the sub-command's arguments."""
    parser.add_argument("design", type=Path, help="design file (TOML, docs/design-file.md)")
    parser.add_argument("--out", type=Path, required=True, help="output recording NAME.toml")
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed of the read noise")
    parser.add_argument(
        "--like",
        type=Path,
        default=None,
        help="reuse the samples (t, run, theta_ref) of this multihead recording",
    )
    parser.add_argument("--gzip", action="store_true", help="write the table as .csv.gz")


def run(args: argparse.Namespace) -> int:
    """Load the design, simulate, write the recording; 0 on success."""
    from ..design._design import load_design, simulate_recording

    design = load_design(args.design)
    rec = simulate_recording(design, args.out, seed=args.seed, like=args.like, compress=args.gzip)
    data = rec.meta["data"]
    print(
        f"wrote {args.out} ({rec.n_rows} samples, {design.n_heads} heads, "
        f"{len(set(rec.runs.tolist()))} run(s); table {data})"
    )
    return 0
