"""``encdesign sweep PROBLEM.toml``: evaluate a design problem on a grid or Latin hypercube."""

from __future__ import annotations

import argparse

from ..design._solve import sweep_problem
from ._optimize import add_common, run_and_report

HELP = "evaluate a design problem on its [sweep] grid or Latin hypercube, recording cases"


def configure(parser: argparse.ArgumentParser) -> None:
    add_common(parser)
    parser.add_argument(
        "--kind", choices=["grid", "lhs"], default=None, help="override [sweep] kind"
    )


def run(args: argparse.Namespace) -> int:
    return run_and_report(args, lambda problem, **kw: sweep_problem(problem, kind=args.kind, **kw))
