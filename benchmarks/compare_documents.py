"""Dump diagnosis documents and compare two dumps number by number (issue 43: a speed-up
must leave every document as it was).

``dump-long N OUT``: the long-record benchmark's record (``benchmarks/diagnose.py``'s
generator: 4 heads, a 31 Hz vibration, ``--rate`` Hz, ``--reduce-min-rows``) diagnosed in
this process; its document to ``OUT`` and one JSON line (CPU s of the diagnosis, the
engine's ``timings_cpu_s``, peak RSS) to stdout. ``dump-variations SEED N OUT``: the
documents of ``finder_variations.py --set effects --seed SEED --n N`` (a list).
``compare A B``: every verdict, name and string equal, every number within ``--rtol``
relative (the timings and the report's ``status`` line, which holds the wall time, left
out); prints the largest relative difference and each difference beyond ``--rtol``;
exit status 1 when there is one::

    python benchmarks/compare_documents.py dump-long 1000000 main.json
    python benchmarks/compare_documents.py dump-variations 7520 3 var.json
    python benchmarks/compare_documents.py compare main.json branch.json --rtol 1e-12
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import sys
import time
from pathlib import Path
from typing import Any

TIMING_KEYS = frozenset({"time_s", "timings_s", "timings_cpu_s"})
"""Keys whose values are timings (never compared)."""


def _untimed_report(text: str) -> str:
    """The report without its ``status`` line (it ends with the wall time)."""
    return "\n".join(ln for ln in text.splitlines() if not ln.startswith("status:"))


def differences(a: Any, b: Any, rtol: float, path: str = "") -> tuple[float, list[str]]:
    """``(largest relative difference of two numbers, differences beyond rtol)`` between
    the JSON values ``a`` and ``b``: dicts by key, lists by position, strings and
    booleans equal, numbers within ``rtol`` relative (NaN equals NaN)."""
    worst, out = 0.0, []
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            out.append(f"{path}: keys {sorted(set(a) ^ set(b))}")
        for k in sorted(set(a) & set(b)):
            if k in TIMING_KEYS:
                continue
            u, v = a[k], b[k]
            if k == "report" and isinstance(u, str) and isinstance(v, str):
                u, v = _untimed_report(u), _untimed_report(v)
            w, d = differences(u, v, rtol, f"{path}/{k}")
            worst, out = max(worst, w), out + d
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return worst, [f"{path}: length {len(a)} != {len(b)}"]
        for i, (u, v) in enumerate(zip(a, b)):
            w, d = differences(u, v, rtol, f"{path}[{i}]")
            worst, out = max(worst, w), out + d
    elif isinstance(a, bool) or isinstance(b, bool) or a is None or b is None:
        if a != b:
            out.append(f"{path}: {a!r} != {b!r}")
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)):
        if a != b and not (math.isnan(a) and math.isnan(b)):
            rel = abs(a - b) / max(abs(a), abs(b))
            worst = max(worst, rel)
            if not rel <= rtol:
                out.append(f"{path}: {a!r} != {b!r} (relative {rel:.3g})")
    elif a != b:
        out.append(f"{path}: {str(a)[:80]!r} != {str(b)[:80]!r}")
    return worst, out


def _dump_long(n_rows: int, out: Path, rate_hz: float, reduce_min_rows: int) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import diagnose as bench  # benchmarks/diagnose.py: the generator

    from encdesign.diagnose import diagnose
    from encdesign.diagnose.engine._settings import FinderSettings

    rec = bench._bench_recording(n_rows, 4, 5, True, rate_hz=rate_hz)
    c0 = time.process_time()
    got = os.environ.get("ENCDESIGN_REDUCE_DECIMATION_MAX")  # session 32: stage 2 (1: off)
    dec = FinderSettings().reduce_decimation_max if got is None else int(got)
    s = FinderSettings(reduce_min_rows=reduce_min_rows, reduce_decimation_max=dec)
    d = diagnose(rec, verbose=False, settings=s)
    cpu = time.process_time() - c0
    out.write_text(json.dumps(d.doc, default=str), encoding="utf-8")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    line = dict(n_rows=n_rows, cpu_s_diagnose=cpu, stages_cpu_s=d.doc.get("timings_cpu_s"))
    print(json.dumps(dict(line, peak_rss_bytes=rss, verdict=d.verdict)))


def _dump_variations(seed: int, n: int, out: Path) -> None:
    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import finder_variations as fv

    from encdesign.diagnose._dispatch import diagnose

    docs = []
    for i in range(n):
        eff = fv.EFFECTS[i % len(fv.EFFECTS)]
        rec, _ = fv.effect_record(np.random.default_rng([seed, 99, i]), eff)
        d = diagnose(rec).doc
        print(i, eff, d["verdict"], [e["name"] for e in d["effects"]], flush=True)
        docs.append(d)
    out.write_text(json.dumps(docs, default=str), encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    """Run one command; 0, or 1 when ``compare`` finds a difference."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("dump-long")
    p.add_argument("n_rows", type=int)
    p.add_argument("out", type=Path)
    p.add_argument("--rate", type=float, default=50000.0)
    p.add_argument("--reduce-min-rows", type=int, default=500000)
    p = sub.add_parser("dump-variations")
    p.add_argument("seed", type=int)
    p.add_argument("n", type=int)
    p.add_argument("out", type=Path)
    p = sub.add_parser("compare")
    p.add_argument("a", type=Path)
    p.add_argument("b", type=Path)
    p.add_argument("--rtol", type=float, default=1e-12)
    args = ap.parse_args(argv)
    if args.cmd == "dump-long":
        _dump_long(args.n_rows, args.out, args.rate, args.reduce_min_rows)
        return 0
    if args.cmd == "dump-variations":
        _dump_variations(args.seed, args.n, args.out)
        return 0
    a = json.loads(args.a.read_text(encoding="utf-8"))
    b = json.loads(args.b.read_text(encoding="utf-8"))
    worst, diff = differences(a, b, args.rtol)
    print(f"largest relative difference {worst:.3g}; {len(diff)} beyond {args.rtol:g}")
    for line in diff:
        print(" ", line)
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main())
