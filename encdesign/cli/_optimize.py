"""``encdesign optimize PROBLEM.toml``: solve a design problem with its driver."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ..design import CaseRecorder, load_problem, solve_problem
from ..distributed import add_launch_flags, is_main_process, process_index, shutdown, start
from ..io import write_json
from ._main import guard_outputs, int_arg

MAX_FRESH_REPLICATES = 10_000
"""Most ``--fresh-replicates`` (each replicate re-runs the objective's builds twice)."""

HELP = "solve a design problem (TOML): variables, objective, constraints, driver"


def add_common(parser: argparse.ArgumentParser) -> None:
    """Flags shared by ``optimize`` and ``sweep``."""
    parser.add_argument("problem", type=Path, help="problem file (TOML, see docs/optimization.md)")
    parser.add_argument("--json", type=Path, default=None, help="write the summary JSON here")
    parser.add_argument(
        "--cases", type=Path, default=None, help="record every case here (.jsonl or .csv)"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    parser.add_argument(
        "--fresh-replicates",
        type=int_arg(0, MAX_FRESH_REPLICATES),
        default=8,
        metavar="R",
        help="out-of-sample check of a Monte Carlo optimum: the best design and the start "
        "design on R fresh replicates of the objective's builds (independent seeds, the same "
        "for both); 0: none, 1 is refused (no spread), at most "
        f"{MAX_FRESH_REPLICATES} (default 8)",
    )
    add_launch_flags(parser)


def configure(parser: argparse.ArgumentParser) -> None:
    add_common(parser)


def print_result(summary: dict, stream=None) -> None:
    """Readable table of the per-combination results and the best design."""
    out = stream or sys.stdout
    units = summary["units"]
    print(f"problem   {summary['problem']}  ({summary['objective']}, {summary['sense']})", file=out)
    print(f"status    {summary['status']}: {summary['message']}", file=out)
    for r in summary["results"]:
        disc = " ".join(f"{k}={v}" for k, v in r["discrete"].items())
        ins = " ".join(f"{k}={v:.6g} {units[k]}" for k, v in r["inputs_display"].items())
        outs = " ".join(
            f"{k}={v:.6g}" if v is not None and math.isfinite(v) else f"{k}=nan"
            for k, v in r["outputs"].items()
        )
        print(f"  [{r['status']}] {disc} {ins} -> {outs}".replace("  ", " ", 1), file=out)
    best = summary["best"]
    if best is not None:
        disc = " ".join(f"{k}={v}" for k, v in best["discrete"].items())
        ins = " ".join(f"{k}={v:.6g} {units[k]}" for k, v in best["inputs_display"].items())
        print(f"best      {disc} {ins}".rstrip(), file=out)
    fresh = summary.get("fresh")
    if fresh is not None:
        print(
            f"fresh     {fresh['objective']} on {fresh['n']} fresh replicates x "
            f"{fresh['builds_per_replicate']} builds (lower is better"
            f"{', negated' if fresh['sense_adjusted'] else ''}): best {fresh['chosen']:.6g} "
            f"+- {fresh['chosen_stderr']:.2g}, start {fresh['baseline']:.6g} +- "
            f"{fresh['baseline_stderr']:.2g}, start - best {fresh['difference']:.3g} +- "
            f"{fresh['difference_stderr']:.2g}: {fresh['verdict']}",
            file=out,
        )


def run_and_report(args: argparse.Namespace, solve, *, resume: Path | None = None) -> int:
    """Load ``args.problem``, run ``solve(problem, recorder=, progress=)``, record the cases,
    print the result and write the ``--json`` summary; exit 0 when ``result.ok`` (an answer:
    ``success``, or ``at_bound``, which is printed as the status), else 1.

    Output paths are checked against the inputs before any work (``guard_outputs``).

    With the launch flags (``--processes``, ``--coordinator``…, ``docs/scale.md``) the run is
    distributed: every process runs it, process 0 prints and writes the files. ``resume``:
    the case file to resume from (cases recorded there are not evaluated again).
    """
    cases = resume if resume is not None else args.cases
    with guard_outputs(
        [("problem", args.problem)],
        [("--json", args.json), ("--cases" if resume is None else "--resume", cases)],
    ):
        rc = start(args, getattr(args, "command_argv", None) or [])
        if rc is not None:  # spawned the processes, or could not join the runtime
            return rc
        rc = _report(args, solve, resume)
        shutdown()
        return rc


def _report(args: argparse.Namespace, solve, resume: Path | None) -> int:
    from ..errors import input_error

    reps = int(getattr(args, "fresh_replicates", 0) or 0)
    if reps == 1 or reps < 0:
        raise input_error("--fresh-replicates", f"{reps}", "0 (no check) or an integer >= 2")
    problem = load_problem(args.problem)
    cases = resume if resume is not None else args.cases
    main = is_main_process()
    rec = CaseRecorder(
        cases, resume=resume is not None, write=main, process=process_index(), problem=problem
    )
    with rec:
        result = solve(problem, recorder=rec, progress=not args.quiet, fresh_replicates=reps)
    if not main:
        return 0 if result.ok else 1
    summary = result.summary()
    summary["n_cases"] = len(rec.cases)
    summary["cases_file"] = None if cases is None else str(cases)
    if resume is not None:
        summary["n_cases_reused"] = rec.n_reused
    print_result(summary)
    if cases is not None:
        extra = f", {rec.n_reused} reused from the earlier run" if resume is not None else ""
        print(f"wrote {cases} ({len(rec.all_cases())} cases{extra})")
    if args.json is not None:
        print(f"wrote {write_json(args.json, summary)}")
    return 0 if result.ok else 1


def run(args: argparse.Namespace) -> int:
    return run_and_report(args, solve_problem)
