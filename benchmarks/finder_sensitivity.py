"""Benchmark: how much the finder's verdicts depend on each decision threshold.

Every field of :class:`~encdesign.diagnose.FinderSettings` (or those given with
``--thresholds``) is moved to x0.5 and x2 of its default (integers rounded, ``n_folds`` at
least 2), one at a time, and every recording is diagnosed again. A verdict *flips* when the
verdict or the set of named effects differs from the one with the defaults. The recordings:
``--n`` concealed-benchmark recordings of each of ``--kinds`` (``draw_plan`` / ``simulate``
of :mod:`encdesign.simulate._conceal_bench`, cases cycling over clean, single, weak,
compound) and ``--n-variations`` records of ``benchmarks/finder_variations.py`` (clean and
single effects). Prints one line per threshold and factor, and how many thresholds flip
more than ``--flip`` (default 5 %) of the verdicts; ``--json`` is rewritten after each
threshold (``complete``: false until the last), so a stopped sweep keeps what it measured::

    python benchmarks/finder_sensitivity.py --kinds motion,multihead --n 2 \\
        --n-variations 2 --thresholds bic_min,heldout_min --json out.json

``--only NAME,...`` with ``--json`` of an earlier sweep (same kinds, ``--n``,
``--n-variations``, seed and factors) measures only those thresholds and merges them into
that file: its rows for the other thresholds are kept as measured, not recomputed (the
defaults' verdicts are recomputed and must equal the file's).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from encdesign._errors import EncdesignInputError
from encdesign.diagnose import FinderSettings
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose.engine._settings import SETTINGS_FIELDS
from encdesign.simulate import draw_plan
from encdesign.simulate import simulate_plan as simulate

CASES = ("clean", "single", "weak", "compound")
KINDS = ("multihead", "sensor", "motion", "quadrature")


def moved(settings: FinderSettings, name: str, factor: float) -> FinderSettings:
    """``settings`` with threshold ``name`` times ``factor`` (integers rounded, >= 1;
    ``n_folds`` >= 2)."""
    v = getattr(settings, name)
    if isinstance(v, int):
        nv = max(2 if name == "n_folds" else 1, int(round(v * factor)))
    else:
        nv = float(v) * factor
    return dataclasses.replace(settings, **{name: nv})


def recordings(kinds, n: int, n_var: int, seed: int) -> list[tuple[str, object]]:
    """``(label, Recording)`` pairs: benchmark recordings of each kind, then variations."""
    out = []
    for kind in kinds:
        for i in range(n):
            rng = np.random.default_rng([seed, KINDS.index(kind), i])
            plan = draw_plan(rng, kind, CASES[i % len(CASES)])
            rec, _ = simulate(rng, plan)
            out.append((f"{kind}/{plan['case']}/{i}", rec))
    if n_var:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import finder_variations as fv

        for i in range(n_var):
            if i % 2:
                eff = fv.EFFECTS[(i // 2) % len(fv.EFFECTS)]
                rec, _ = fv.effect_record(np.random.default_rng([seed, 99, i]), eff)
                out.append((f"variation/{eff}/{i}", rec))
            else:
                rec, _ = fv.clean_record(np.random.default_rng([seed, i]))
                out.append((f"variation/clean/{i}", rec))
    return out


def outcome(rec, settings: FinderSettings) -> tuple[str, tuple[str, ...]]:
    """The verdict and the named effects; ``("input_error", ())`` when a moved threshold
    refuses the record itself (e.g. ``quad_sectors_min`` x2 asks for more sectors than
    there are)."""
    try:
        d = diagnose(rec, settings=settings).doc
    except EncdesignInputError:
        return "input_error", ()
    return d["verdict"], tuple(sorted(e["name"] for e in d["effects"]))


def write_json(path, args, kinds, recs, ref, rows, over, complete, elapsed_s) -> None:
    """The sweep so far (``complete``: every threshold and factor done), written after each
    threshold so that a sweep stopped early still leaves what it measured."""
    with open(path, "w") as f:
        json.dump(
            dict(
                kinds=kinds,
                n=args.n,
                n_variations=args.n_variations,
                seed=args.seed,
                factors=[float(x) for x in args.factors.split(",")],
                flip=args.flip,
                complete=complete,
                thresholds_done=sorted({r["threshold"] for r in rows}),
                elapsed_s=elapsed_s,
                recordings=[lab for lab, _ in recs],
                default={k: [v[0], list(v[1])] for k, v in ref.items()},
                rows=rows,
                over=over,
            ),
            f,
            indent=1,
            default=str,
        )


def main(argv: list[str] | None = None) -> int:
    """Run the sweep; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default="multihead,sensor,motion,quadrature")
    ap.add_argument("--n", type=int, default=4, help="benchmark recordings per kind")
    ap.add_argument("--n-variations", type=int, default=4)
    ap.add_argument("--thresholds", default="", help="comma-separated fields (default: all)")
    ap.add_argument("--factors", default="0.5,2")
    ap.add_argument("--flip", type=float, default=0.05, help="share of verdicts that flip")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--only",
        default="",
        help="comma-separated fields: measure only these and merge them into --json",
    )
    args = ap.parse_args(argv)
    old_rows: list[dict] = []
    if args.only:
        if not args.json or not Path(args.json).exists():
            ap.error("--only merges into an earlier sweep: give its --json")
        old = json.loads(Path(args.json).read_text())
        same = (old["kinds"], old["n"], old["n_variations"], old["seed"], old["factors"])
        want = (
            args.kinds.split(","),
            args.n,
            args.n_variations,
            args.seed,
            [float(x) for x in args.factors.split(",")],
        )
        if same != tuple(want):
            ap.error(f"--only: {args.json} was measured with {same}, not {want}")
        args.thresholds = args.only
        only = set(args.only.split(","))
        old_rows = [r for r in old["rows"] if r["threshold"] not in only]
        el0 = float(old.get("elapsed_s") or 0.0)  # the earlier sweep's time, kept in the sum
    else:
        el0 = 0.0
    kinds = [k for k in args.kinds.split(",") if k]
    bad = [k for k in kinds if k not in KINDS]
    names = [t for t in args.thresholds.split(",") if t] or list(SETTINGS_FIELDS)
    bad += [t for t in names if t not in SETTINGS_FIELDS]
    if bad:
        ap.error(
            f"unknown kinds or thresholds: {bad} (kinds {KINDS}, thresholds {SETTINGS_FIELDS})"
        )
    factors = [float(f) for f in args.factors.split(",")]
    t0 = time.perf_counter()
    recs = recordings(kinds, args.n, args.n_variations, args.seed)
    base = FinderSettings()
    ref = {}
    for label, rec in recs:
        ref[label] = outcome(rec, base)
        print(f"default {label}: {ref[label][0]} {list(ref[label][1])}", flush=True)
    if args.only:
        prev = {k: (v[0], tuple(v[1])) for k, v in old["default"].items()}
        if prev != ref:
            raise SystemExit(f"--only: the defaults' verdicts differ from {args.json}'s")
    rows = list(old_rows)
    for name in names:
        for fac in factors:
            st = moved(base, name, fac)
            flips = []
            for label, rec in recs:
                got = outcome(rec, st)
                if got != ref[label]:
                    flips.append(dict(recording=label, default=ref[label], moved=got))
            share = len(flips) / max(len(recs), 1)
            rows.append(
                dict(
                    threshold=name,
                    factor=fac,
                    value=getattr(st, name),
                    flipped=len(flips),
                    share=share,
                    flips=flips,
                )
            )
            print(
                f"{name} x{fac:g} = {getattr(st, name)!r}: {len(flips)} / {len(recs)} "
                f"verdicts change"
                + "".join(f"\n    {f['recording']}: {f['default']} -> {f['moved']}" for f in flips),
                flush=True,
            )
        if args.json:
            done = sorted({r["threshold"] for r in rows if r["share"] > args.flip})
            el = el0 + time.perf_counter() - t0
            write_json(args.json, args, kinds, recs, ref, rows, done, False, el)
    over = sorted({r["threshold"] for r in rows if r["share"] > args.flip})
    n_done = len({r["threshold"] for r in rows})
    print(
        f"{len(over)} of {n_done} thresholds flip more than {100 * args.flip:.0f} % of "
        f"{len(recs)} verdicts at x{' or x'.join(f'{f:g}' for f in factors)}: {over} "
        f"({time.perf_counter() - t0:.0f} s)",
        flush=True,
    )
    if args.json:
        el = el0 + time.perf_counter() - t0
        complete = set(SETTINGS_FIELDS) <= {r["threshold"] for r in rows}
        write_json(args.json, args, kinds, recs, ref, rows, over, complete, el)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
