"""``encdesign check-gradients PROBLEM.toml``: AD gradients against finite differences."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from ..design import check_gradients, load_problem
from ..io import write_json
from ._main import float_arg, guard_outputs

HELP = "compare AD gradients of a problem's outputs with central finite differences"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("problem", type=Path, help="problem file (TOML)")
    parser.add_argument("--json", type=Path, default=None, help="write the table as JSON here")
    parser.add_argument(
        "--rel-step",
        type=float_arg(0.0, 0.1, lower_open=True),
        default=1e-5,
        help="FD step relative to the variable's scale (0 < step <= 0.1)",
    )
    parser.add_argument(
        "--rtol",
        type=float_arg(0.0, 1.0, lower_open=True),
        default=1e-4,
        help="relative tolerance for 'ok' (0 < rtol <= 1)",
    )
    parser.add_argument(
        "--atol",
        type=float_arg(0.0, None, lower_open=True),
        default=None,
        help="absolute tolerance (output units per SI unit of the variable) where both "
        "derivatives are below it (default 1e-3 * rtol * |output| / variable scale)",
    )


def run(args: argparse.Namespace) -> int:
    with guard_outputs([("problem", args.problem)], [("--json", args.json)]):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from ..errors import input_error

    problem = load_problem(args.problem)
    if not problem.continuous:
        raise input_error(
            str(args.problem),
            "the problem has no continuous variables: there is no gradient to check",
            "at least one [variables.NAME] with start/lower/upper",
        )
    rows = check_gradients(problem, rel_step=args.rel_step, rtol=args.rtol, atol=args.atol)
    print(f"problem {problem.name}: d(output)/d(variable), output units per SI unit")
    head = f"{'output':22s} {'variable':20s} {'at':>12s} {'AD':>14s} {'FD':>14s} {'error':>13s}"
    print(head)
    print("-" * len(head))
    for r in rows:
        flag = "ok" if r.ok else "MISMATCH"
        if r.basis == "absolute":  # both near zero: a relative error would mean nothing
            err = f"abs {r.abs_error:9.2e}"
            flag += f" (|AD|, |FD| <= atol {r.atol:.2e}: absolute test)"
        else:
            err = f"rel {r.rel_error:9.2e}"
        print(
            f"{r.output:22s} {r.variable:20s} {r.at:12.5g} {r.ad:14.6e} {r.fd:14.6e} {err} {flag}"
        )
    n_bad = sum(not r.ok for r in rows)
    n_abs = sum(r.basis == "absolute" for r in rows)
    print(
        f"{len(rows) - n_bad}/{len(rows)} gradients agree (rtol {args.rtol:g}; {n_abs} judged "
        "on the absolute tolerance, both derivatives below it)"
    )
    if args.json is not None:
        data = {
            "problem": problem.name,
            "rtol": args.rtol,
            "atol": args.atol,
            "rows": [dataclasses.asdict(r) for r in rows],
            "all_ok": n_bad == 0,
        }
        print(f"wrote {write_json(args.json, data)}")
    return 0 if n_bad == 0 else 1
