"""``encdesign sweep PROBLEM.toml``: evaluate a design problem on a grid or Latin hypercube."""

from __future__ import annotations

import argparse

from ._cases import CaseRecorder
from ._cmd_optimize import add_common, print_result
from ._problem import load_problem
from ._solve import sweep_problem
from ._study import write_json

HELP = "evaluate a design problem on its [sweep] grid or Latin hypercube, recording cases"


def configure(parser: argparse.ArgumentParser) -> None:
    add_common(parser)
    parser.add_argument(
        "--kind", choices=["grid", "lhs"], default=None, help="override [sweep] kind"
    )


def run(args: argparse.Namespace) -> int:
    problem = load_problem(args.problem)
    with CaseRecorder(args.cases) as rec:
        result = sweep_problem(problem, kind=args.kind, recorder=rec, progress=not args.quiet)
    summary = result.summary()
    summary["n_cases"] = len(rec.cases)
    summary["cases_file"] = None if args.cases is None else str(args.cases)
    print_result(summary)
    if args.cases is not None:
        print(f"wrote {args.cases} ({len(rec.cases)} cases)")
    if args.json is not None:
        print(f"wrote {write_json(args.json, summary)}")
    return 0 if result.status == "success" else 1
