"""``encdesign diagnose REC.toml --json OUT.json [--plots DIR] [--report FILE] [--html FILE]
[--export-candidates F.py]``.

Every kind goes through :func:`encdesign.diagnose.diagnose` (``encdesign.diagnose._dispatch``);
the JSON follows ``encdesign/diagnose/diagnosis.schema.json``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..distributed import add_launch_flags, is_main_process, shutdown, start
from ._main import guard_outputs, int_arg

HELP = "find where a recording and the model disagree, name the missing physics, fit it"


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments."""
    parser.add_argument("recording", type=Path, help="recording TOML file")
    parser.add_argument("--json", type=Path, required=True, help="write the diagnosis here")
    parser.add_argument("--plots", type=Path, default=None, help="write PNG figures here")
    parser.add_argument("--report", type=Path, default=None, help="write the text report here")
    parser.add_argument(
        "--html",
        type=Path,
        default=None,
        help="write a self-contained HTML report here (figures embedded, opens offline)",
    )
    parser.add_argument(
        "--max-order",
        type=int_arg(1, 100_000),
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
    parser.add_argument(
        "--export-candidates",
        type=Path,
        default=None,
        help="write what discovery models outside the catalog as a --candidates file (a "
        "later diagnosis of a similar record then tests it like a catalog effect)",
    )
    parser.add_argument(
        "--max-effects", type=int_arg(0, 100), default=3, help="most effects to name"
    )
    parser.add_argument(
        "--no-discover",
        action="store_true",
        help="the catalog only: no discovery of structure outside the catalog, so no named "
        "effect is re-tested beside a discovered model (faster; FinderSettings.discover = 0)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_launch_flags(parser)


def run(args: argparse.Namespace) -> int:
    """Diagnose; exit 0 with the JSON written (bad input raises -> exit 2).

    Inputs and outputs are checked before any work: no output may be an input (by path or
    resolved identity), and outputs are written atomically."""
    from ..io import recording_input_files

    inputs = [("recording", p) for p in recording_input_files(args.recording)]
    if args.candidates is not None:
        inputs.append(("--candidates", args.candidates))
    outputs = [
        ("--json", args.json),
        ("--report", args.report),
        ("--html", args.html),
        ("--export-candidates", args.export_candidates),
    ]
    with guard_outputs(inputs, outputs, folders=[("--plots", args.plots)]):
        # --processes N / --coordinator: the fit's row passes split over the processes,
        # every process runs the diagnosis, process 0 writes it (docs/scale.md)
        rc = start(args, getattr(args, "command_argv", None) or [])
        if rc is not None:  # spawned the processes, or could not join the runtime
            return rc
        rc = _run(args) if is_main_process() else _run_helper(args)
        shutdown()
        return rc


def _settings(args: argparse.Namespace):
    """The finder's settings the flags ask for (``None``: the defaults)."""
    from ..diagnose import FinderSettings

    return FinderSettings(discover=0) if args.no_discover else None


def _run_helper(args: argparse.Namespace) -> int:
    """A process other than 0: the same diagnosis (its share of the row passes), silent,
    nothing written."""
    from ..diagnose import diagnose, load_candidates, open_recording
    from ..io import check_runs_contiguous

    cands = load_candidates(args.candidates) if args.candidates is not None else ()
    rec, reduced = open_recording(args.recording, max_order=args.max_order)
    check_runs_contiguous(rec)
    diagnose(
        rec,
        reduced=reduced,
        max_order=args.max_order,
        max_effects=args.max_effects,
        candidates=cands,
        verbose=False,
        plots=None,
        settings=_settings(args),
    )
    return 0


def _run(args: argparse.Namespace) -> int:
    from ..diagnose import diagnose, load_candidates, open_recording
    from ..io import atomic_write_text, check_runs_contiguous, write_json

    cands = load_candidates(args.candidates) if args.candidates is not None else ()
    rec, reduced = open_recording(args.recording, max_order=args.max_order)
    check_runs_contiguous(rec)
    d = diagnose(
        rec,
        reduced=reduced,
        max_order=args.max_order,
        max_effects=args.max_effects,
        candidates=cands,
        verbose=not args.quiet,
        plots=args.plots,
        settings=_settings(args),
    )
    doc = d.doc
    write_json(args.json, doc)
    text = doc.get("report", "")
    if args.report is not None:
        atomic_write_text(args.report, text)
    if args.export_candidates is not None:
        from ..diagnose import export_candidates

        names = export_candidates(doc, args.export_candidates)
        if names:
            print(f"wrote {args.export_candidates}: {', '.join(names)}", file=sys.stderr)
        else:
            print("--export-candidates: nothing discovered, no file written", file=sys.stderr)
    if args.html is not None:
        from ..diagnose import write_diagnosis_html as write_html

        write_html(d, args.html)
        print(f"wrote {args.html}", file=sys.stderr)
    print(text if text else f"verdict: {doc['verdict']}", end="" if text.endswith("\n") else "\n")
    print(f"wrote {args.json}", file=sys.stderr)
    return 0
