"""``encdesign diagnose REC.toml --json OUT.json [--plots DIR] [--report FILE]``.

Multihead recordings go to :func:`encdesign.diagnose`; sds, quadrature and motion recordings
to their own finders (``encdesign.diagnose._dispatch``)."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

HELP = "find where a recording and the model disagree, name the missing physics, fit it"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments."""
    parser.add_argument("recording", type=Path, help="recording TOML file")
    parser.add_argument("--json", type=Path, required=True, help="write the diagnosis here")
    parser.add_argument("--plots", type=Path, default=None, help="write PNG figures here")
    parser.add_argument("--report", type=Path, default=None, help="write the text report here")
    parser.add_argument("--max-order", type=int, default=12, help="base model's highest order")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def _write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".txt")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def run(args: argparse.Namespace) -> int:
    """Diagnose; exit 0 with the JSON written (bad input raises -> exit 2)."""
    from .._errors import input_error
    from ..diagnose._multihead import diagnose, report_text, write_plots
    from ..io._study import write_json

    if args.max_order < 1:
        raise input_error("--max-order", f"got {args.max_order}", "a positive integer")
    from ..io._recording import load_recording

    rec = load_recording(args.recording)
    if rec.kind in ("quadrature", "motion", "sds"):
        # timing, signal-level and shaft-motion recordings have their own finders
        from ..diagnose._dispatch import diagnose_any

        doc = diagnose_any(rec, plots=args.plots)
        write_json(args.json, doc)
        if args.report is not None and "report" in doc:
            _write_text(args.report, doc["report"])
        print(f"verdict: {doc['verdict']}")
        print(f"wrote {args.json}", file=sys.stderr)
        return 0
    d = diagnose(rec, max_order=args.max_order, verbose=not args.quiet)
    doc = d.to_json()
    if args.plots is not None:
        doc["plots"] = [str(p) for p in write_plots(d, args.plots)]
    write_json(args.json, doc)
    text = report_text(d)
    if args.report is not None:
        _write_text(args.report, text)
    print(text, end="")
    print(f"wrote {args.json}", file=sys.stderr)
    return 0
