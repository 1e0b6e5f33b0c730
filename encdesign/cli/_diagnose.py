"""``encdesign diagnose REC.toml --json OUT.json [--plots DIR] [--report FILE]``.

Multihead recordings go to :func:`encdesign.diagnose`; sds, quadrature and motion recordings
to their own finders (``encdesign.diagnose._dispatch``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._main import guard_outputs, int_arg

HELP = "find where a recording and the model disagree, name the missing physics, fit it"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments."""
    parser.add_argument("recording", type=Path, help="recording TOML file")
    parser.add_argument("--json", type=Path, required=True, help="write the diagnosis here")
    parser.add_argument("--plots", type=Path, default=None, help="write PNG figures here")
    parser.add_argument("--report", type=Path, default=None, help="write the text report here")
    parser.add_argument(
        "--max-order",
        type=int_arg(1, 100_000),
        default=12,
        help="base model's highest order (at most (samples per head - 1) / 2)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def max_order_limit(n_rows: int) -> int:
    """Highest base-model order ``n_rows`` samples support: a Fourier series of order ``K``
    has ``2K + 1`` coefficients per head, so ``K <= (n_rows - 1) // 2``."""
    return max((int(n_rows) - 1) // 2, 0)


def run(args: argparse.Namespace) -> int:
    """Diagnose; exit 0 with the JSON written (bad input raises -> exit 2)."""
    from ..io._paths import recording_input_files

    inputs = [("recording", p) for p in recording_input_files(args.recording)]
    outputs = [("--json", args.json), ("--report", args.report)]
    with guard_outputs(inputs, outputs, folders=[("--plots", args.plots)]):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from .._errors import input_error
    from ..io._paths import atomic_write_text
    from ..io._recording import check_runs_contiguous, load_recording
    from ..io._study import write_json

    rec = load_recording(args.recording)
    if rec.kind in ("quadrature", "motion", "sds"):
        # timing, signal-level and shaft-motion recordings have their own finders
        from ..diagnose._dispatch import diagnose_any

        doc = diagnose_any(rec, plots=args.plots)
        write_json(args.json, doc)
        if args.report is not None and "report" in doc:
            atomic_write_text(args.report, doc["report"])
        print(f"verdict: {doc['verdict']}")
        print(f"wrote {args.json}", file=sys.stderr)
        return 0
    limit = max_order_limit(rec.n_rows)
    if args.max_order > limit:
        raise input_error(
            "--max-order",
            f"{args.max_order} needs at least {2 * args.max_order + 1} samples per head but "
            f"{args.recording} has {rec.n_rows}",
            f"--max-order <= {limit} for this recording",
        )
    check_runs_contiguous(rec)
    from ..diagnose._multihead import diagnose, report_text, write_plots

    d = diagnose(rec, max_order=args.max_order, verbose=not args.quiet)
    doc = d.to_json()
    text = report_text(d)
    if args.plots is not None:
        doc["plots"] = [str(p) for p in write_plots(d, args.plots)]
    write_json(args.json, doc)
    if args.report is not None:
        atomic_write_text(args.report, text)
    print(text, end="")
    print(f"wrote {args.json}", file=sys.stderr)
    return 0
