"""``encdesign diagnose REC.toml --json OUT.json [--plots DIR] [--report FILE]``.

Every kind goes through :func:`encdesign.diagnose.diagnose` (``encdesign.diagnose._dispatch``);
the JSON follows ``encdesign/diagnose/diagnosis.schema.json``."""

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
    parser.add_argument(
        "--max-order",
        type=int,
        default=None,
        help="base model's highest order (default: the kind's, capped at what the record "
        "resolves; beyond that it is refused with the limit)",
    )
    parser.add_argument(
        "--candidates",
        type=Path,
        default=None,
        help="a Python file defining CANDIDATES = [Candidate(...), ...]: your own effects",
    )
    parser.add_argument("--max-effects", type=int, default=3, help="most effects to name")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


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
    from ..diagnose._dispatch import diagnose, load_candidates
    from ..io._recording import load_recording
    from ..io._study import write_json

    if args.max_order is not None and args.max_order < 1:
        raise input_error("--max-order", f"got {args.max_order}", "a positive integer")
    if args.max_effects < 0:
        raise input_error("--max-effects", f"got {args.max_effects}", "0 or more")
    cands = load_candidates(args.candidates) if args.candidates is not None else ()
    rec = load_recording(args.recording)
    d = diagnose(
        rec,
        max_order=args.max_order,
        max_effects=args.max_effects,
        candidates=cands,
        verbose=not args.quiet,
        plots=args.plots,
    )
    doc = d.doc
    write_json(args.json, doc)
    text = doc.get("report", "")
    if args.report is not None:
        _write_text(args.report, text)
    print(text if text else f"verdict: {doc['verdict']}", end="" if text.endswith("\n") else "\n")
    print(f"wrote {args.json}", file=sys.stderr)
    return 0
