"""Located times against the truth (issue 44 C): generated records with one change (a step
in a head's offset, an eccentricity shift; 2-5 heads, 1-3 runs, a clock per run or one
clock with pauses, with and without a reference; ``tests/test_located_times.case``), each
located time checked against the truth within its stated interval
(``FinderSettings.change_time_level``).

    PYTHONPATH=$PWD python benchmarks/located_times.py --seeds 720-759 [--json out.json]

Prints one line per record and the coverage (share of located times whose interval holds
the truth), per kind of located time, the median of ``|error| / half-width`` (<= 1 inside)
and the spread of the interval widths.

Seeds: 701-710 were used while building (s14-times), 700-719 are the test's; the coverage
is reported on 720-759, seen first in that run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from encdesign.diagnose._dispatch import diagnose  # noqa: E402
from tests.test_located_times import case, change_record, scores  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="720-759", help="a-b (inclusive)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    lo, hi = (int(x) for x in a.seeds.split("-"))
    rows = []
    for seed in range(lo, hi + 1):
        c = case(seed)
        rec, truth = change_record(seed, **c)
        t0 = time.time()
        doc = diagnose(rec).doc
        sc = scores(doc, truth)
        rows.append(dict(seed=seed, case=c, truth=truth, scores=sc, verdict=doc["verdict"]))
        cell = " ".join(
            f"{s['where']}:{'in' if s['inside'] else 'OUT'}({s['ratio']:.2f},{s['width_s']:.3g}s)"
            for s in sc
        )
        print(
            f"{seed} {c['change']} H{c['H']} R{c['R']} {c['clock']} ref={c['ref']} "
            f"size={c['size']:.2f} {doc['verdict']} {time.time() - t0:.1f}s | "
            f"{cell or 'NOT LOCATED'}",
            flush=True,
        )
    allsc = [s for r in rows for s in r["scores"]]
    located = sum(bool(r["scores"]) for r in rows)
    print(f"records {len(rows)}, located {located}")
    kinds = sorted({s["where"] for s in allsc})
    summary = {}
    for k in [*kinds, "all"]:
        ss = [s for s in allsc if k == "all" or s["where"] == k]
        ins = [s["inside"] for s in ss]
        rat = np.array([s["ratio"] for s in ss], float)
        w = np.array([s["width_s"] for s in ss], float)
        w = w[np.isfinite(w)]
        summary[k] = dict(
            n=len(ss),
            inside=int(sum(ins)),
            coverage=float(np.mean(ins)) if ins else None,
            median_ratio=float(np.median(rat)) if rat.size else None,
            width_s_min_median_max=[float(np.min(w)), float(np.median(w)), float(np.max(w))]
            if w.size
            else None,
        )
        print(f"{k}: {summary[k]}")
    if a.json:
        Path(a.json).write_text(
            json.dumps(dict(seeds=a.seeds, summary=summary, records=rows), indent=1, default=str)
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
