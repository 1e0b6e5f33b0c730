"""Benchmark (issue 43): a long record diagnosed on block means against the same record
diagnosed row by row, in one process.

The record is ``benchmarks/diagnose.py``'s generator (4 heads, 4 runs at 0.6-1.8 rev/s,
0.5 urad noise, disk orders 1-5; ``--effect``: a catalog effect or ``clean``) sampled at
``--rate`` Hz. It is diagnosed twice: unreduced (``FinderSettings.reduce_min_rows`` above the
record) and reduced (the threshold at 1,000 rows). Printed (one JSON line): both verdicts,
named effects, wall times and stage times, the reduction (``reduced``), and per parameter of
the base (``terms``), of the base refitted with the effects (``terms_with_effects``) and of
each named effect: the largest ``|reduced - unreduced| / se`` (``se`` the unreduced
standard error) and the median ratio of the standard errors.

    python benchmarks/reduce_agreement.py --rows 1e6 --rate 50000 --effect vibration --seed 5
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np


def _generator():
    spec = importlib.util.spec_from_file_location("bd", Path(__file__).with_name("diagnose.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod._bench_recording


def _z(a_terms: dict, b_terms: dict) -> dict:
    out = {}
    for name, terms in a_terms.items():
        for p, v in terms.items():
            if not isinstance(v, dict) or v.get("se") is None or name not in b_terms:
                continue
            a = np.asarray(v["value"], float)
            b = np.asarray(b_terms[name][p]["value"], float)
            se = np.asarray(v["se"], float)
            se_b = np.asarray(b_terms[name][p].get("se") or np.nan, float)
            if a.shape != b.shape:
                out[f"{name}.{p}"] = {"shape": [list(a.shape), list(b.shape)]}
                continue
            out[f"{name}.{p}"] = {
                "max_diff_over_se": float(np.max(np.abs(a - b) / se)),
                "se_ratio_reduced_to_full": float(np.median(se_b / se)),
            }
    return out


def main(argv: list[str] | None = None) -> int:
    """Run; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=float, default=1e6)
    ap.add_argument("--rate", type=float, default=50_000.0)
    ap.add_argument("--effect", default="vibration")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--heads", type=int, default=4)
    args = ap.parse_args(argv)
    from encdesign.diagnose import diagnose
    from encdesign.diagnose.engine._settings import FinderSettings

    eff = False if args.effect == "clean" else args.effect
    rec = _generator()(int(args.rows), args.heads, args.seed, eff, rate_hz=args.rate)
    docs, res = {}, {}
    for mode, s in (
        ("reduced", FinderSettings(reduce_min_rows=1000)),
        ("full", FinderSettings(reduce_min_rows=10 * rec.n_rows)),
    ):
        t0 = time.perf_counter()
        doc = diagnose(rec, settings=s).doc
        docs[mode] = doc
        res[mode] = {
            "wall_s": time.perf_counter() - t0,
            "verdict": doc["verdict"],
            "named": [e["name"] for e in doc["effects"]],
            "timings_s": doc["timings_s"],
            "reduced": doc["reduced"],
        }
        print(json.dumps({mode: res[mode]}), file=sys.stderr, flush=True)
    f, r = docs["full"], docs["reduced"]
    res["agreement"] = {
        "same_verdict": f["verdict"] == r["verdict"],
        "same_named": res["full"]["named"] == res["reduced"]["named"],
        "base": _z(f["base"]["terms"], r["base"]["terms"]),
        "base_with_effects": _z(f["base"]["terms_with_effects"], r["base"]["terms_with_effects"]),
        "effects": _z(
            {e["name"]: e["params"] for e in f["effects"]},
            {e["name"]: e["params"] for e in r["effects"]},
        ),
    }
    res["record"] = dict(rows=rec.n_rows, heads=args.heads, rate_hz=args.rate, effect=args.effect)
    res["record"]["seed"] = args.seed
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
