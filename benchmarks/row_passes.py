"""Benchmark: where a diagnosis passes over the rows (issue 43), pass by pass.

Diagnoses one recording in this process and times (CPU s) every call of
``engine._stats_pass.run_passes`` that needs the rows: one line per pass with the engine
function that asked for it and its requests (``J`` with the Jacobian, ``V`` values only;
the terms with free nonlinear parameters; ``/sP``: the static block's free scalars), then
the CPU s per asking function. E.g. on the long-record benchmark's record (written by
``benchmarks/diagnose.py``'s generator, ``--write N``: 4 heads, the 31 Hz vibration, 50 kHz)::

    python benchmarks/row_passes.py /tmp/rec1e6 --write 1000000 --reduce-min-rows 500000

Session 23 (10^6 rows, 142,854 block means, main 01b0a20): 66 passes; the trial fits 19
rounds, 6.0 s; the located-share rule's fits (``_kept_fit``) 10 passes, 3.2 s (after
s23-speed43: 3 rounds, 2.3 s); the located step's fits 4 passes, 2.0 s; the base fit 5
passes, 1.5 s; of 21 s CPU. After s23-starts43 (a candidate's screened starts side by side,
``engine/_starts.py``; main 5c32af5 against c35b4cc): the trial fits 19 rounds 5.98 s -> 16
rounds 5.28 s CPU, the diagnosis 20.2 -> 18.8 s CPU, the document equal to the last bit.
"""

from __future__ import annotations

import argparse
import collections
import sys
import time
import traceback
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    """Run; returns the CLI's exit status."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="holds rec.toml (written with --write)")
    ap.add_argument("--write", type=int, default=0, help="write the benchmark's record first")
    ap.add_argument("--reduce-min-rows", type=int, default=0)
    ap.add_argument("--json", default=None, help="the diagnosis document (FOLDER/doc.json)")
    args = ap.parse_args(argv)
    if args.write:
        sys.path.insert(0, str(Path(__file__).parent))
        import diagnose as bench  # (this folder's benchmarks/diagnose.py)

        args.folder.mkdir(parents=True, exist_ok=True)
        bench._write_bench_parquet(args.folder, args.write, 4, "vibration", 50000.0)
    import encdesign.diagnose._dispatch as dispatch
    import encdesign.diagnose.engine._fit as fit_mod
    import encdesign.diagnose.engine._stats_pass as sp
    from encdesign.cli import main as cli
    from encdesign.diagnose.engine._settings import FinderSettings

    if args.reduce_min_rows:
        dispatch.DEFAULT_SETTINGS = FinderSettings(reduce_min_rows=args.reduce_min_rows)
    rows: list[tuple[float, str, str]] = []
    run_passes = sp.run_passes
    skip = {"drive", "drive_many", "run_passes", "stats", "fit", "fit_steps", "timed"}

    def timed(passes):
        live = [s for s in passes if s.done is None]
        t0 = time.process_time()
        out = run_passes(passes)
        if live:
            stack = traceback.extract_stack(limit=12)[:-1]
            who = [f.name for f in reversed(stack) if "encdesign" in f.filename]
            who = [n for n in who if n not in skip]
            what = ";".join(
                ("J" if s.jac else "V") + ":" + ",".join(t.cand.name for t in s.dyn) + f"/s{s.p_s}"
                for s in live
            )
            rows.append((time.process_time() - t0, who[0] if who else "?", what))
        return out

    sp.run_passes = timed
    fit_mod.run_passes = timed
    doc = args.json or str(args.folder / "doc.json")
    t0 = time.process_time()
    rc = cli(["diagnose", str(args.folder / "rec.toml"), "--quiet", "--json", doc])
    total = time.process_time() - t0
    by: dict[str, list[float]] = collections.defaultdict(lambda: [0, 0.0])
    for dt, who, what in rows:
        print(f"{dt:7.3f} {who:24s} {what}")
        by[who][0] += 1
        by[who][1] += dt
    for who, (n, s) in by.items():
        print(f"{who:24s} {int(n):3d} passes {s:7.2f} s CPU")
    print(f"diagnosis {total:.2f} s CPU, of which passes {sum(r[0] for r in rows):.2f} s")
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
