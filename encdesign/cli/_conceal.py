"""``encdesign conceal OUT.toml --effect NAME [--seed N] [...]``: a bench recording with a
hidden effect (or none), for testing the discrepancy finder."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._main import SEED, float_arg, guard_outputs, int_arg

HELP = "write a simulated bench recording with one physics effect hidden (or none)"

MAX_SAMPLES_PER_RUN = 10_000_000
MAX_AMPLITUDE = 1e4  # in units of the noise: beyond it the "hidden" effect hides nothing


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments."""
    from ..simulate import CONCEALMENTS, HIDDEN, LAYOUTS

    parser.add_argument("out", type=Path, help="recording TOML to write (CSV beside it)")
    parser.add_argument("--effect", default="none", choices=["none", *HIDDEN])
    parser.add_argument("--concealment", default="near_noise", choices=list(CONCEALMENTS))
    parser.add_argument("--layout", default="3+1", choices=list(LAYOUTS))
    parser.add_argument("--seed", type=SEED, default=0, help="PRNG seed (0 … 2^63-1)")
    parser.add_argument(
        "--amplitude",
        type=float_arg(0.0, MAX_AMPLITUDE),
        default=2.0,
        help=f"in units of the noise (0 … {MAX_AMPLITUDE:g})",
    )
    parser.add_argument(
        "--samples-per-run",
        type=int_arg(16, MAX_SAMPLES_PER_RUN),
        default=2000,
        help=f"samples per run (16 … {MAX_SAMPLES_PER_RUN})",
    )
    parser.add_argument("--no-theta-ref", action="store_true")
    parser.add_argument("--truth", type=Path, default=None, help="write the hidden truth here")


def run(args: argparse.Namespace) -> int:
    """Write the recording (and the truth JSON when asked)."""
    import jax

    from ..io import recording_output_files, write_json
    from ..simulate import write_concealed

    outputs = [("OUT", p) for p in recording_output_files(args.out, label="OUT")]
    outputs.append(("--truth", args.truth))
    with guard_outputs([], outputs):
        _, truth = write_concealed(
            args.out,
            key=jax.random.key(args.seed),
            effect=None if args.effect == "none" else args.effect,
            concealment=args.concealment,
            layout=args.layout,
            amplitude=args.amplitude,
            samples_per_run=args.samples_per_run,
            theta_ref=not args.no_theta_ref,
        )
        if args.truth is not None:
            write_json(args.truth, truth)
    print(f"wrote {args.out}")
    return 0
