"""``encdesign sweep PROBLEM.toml``: evaluate a design problem on a grid or Latin hypercube."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..design import sweep_problem
from ..errors import input_error
from ._optimize import add_common, run_and_report

HELP = "evaluate a design problem on its [sweep] grid or Latin hypercube, recording cases"


def configure(parser: argparse.ArgumentParser) -> None:
    add_common(parser)
    parser.add_argument(
        "--kind", choices=["grid", "lhs"], default=None, help="override [sweep] kind"
    )
    parser.add_argument(
        "--resume",
        type=Path,
        default=None,
        metavar="CASES",
        help="continue an interrupted sweep: cases already in CASES (same inputs and seed) "
        "are not evaluated again; the final CASES is that of an uninterrupted run",
    )


def run(args: argparse.Namespace) -> int:
    if args.resume is not None and args.cases is not None and args.cases != args.resume:
        raise input_error(
            "--resume", f"{args.resume} differs from --cases {args.cases}", "one case file"
        )
    return run_and_report(
        args,
        lambda problem, **kw: sweep_problem(problem, kind=args.kind, **kw),
        resume=args.resume,
    )
