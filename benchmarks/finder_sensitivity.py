"""Benchmark: how much the finder's rate of right verdicts depends on each decision threshold.

Every field of :class:`~encdesign.diagnose.FinderSettings` (or those given with
``--thresholds``) is moved to x0.5 and x2 of its default (integers rounded, ``n_folds`` at
least 2), one at a time, and every recording of a labelled set is diagnosed again. Each
recording carries its truth, so a verdict is *right* or not: a clean recording is right when
the verdict is ``consistent``; one with hidden effects when the named set is exactly the
truth (an SDS recording: when the first name is the hidden effect, or when the effect is
listed as not testable and the verdict is ``consistent``, as the concealed benchmark scores
it). Per threshold and factor the sweep counts the ``right`` verdicts and compares them with
the defaults' (``delta_right``, ``delta_rate``); a verdict also *flips* when the verdict or
the set of named effects differs from the one with the defaults (kept as before). A moved
value equal to the default (an integer 1 at x0.5) is not diagnosed again: its row is the
defaults' (``same_as_default``).

The recordings: ``--n`` concealed-benchmark recordings of each of ``--kinds``
(``draw_plan`` / ``simulate`` of :mod:`encdesign.simulate._conceal_bench`; ``sds``:
``write_concealed_sds`` at 12 platform positions, a catalog effect near the noise), their
cases taken in turn from ``--cases`` over all kinds, and ``--n-variations`` records of
``benchmarks/finder_variations.py`` (clean and single effects in turn). Prints one line per
threshold and factor, and the thresholds that move the rate of right verdicts by more than
``--flip`` (default 5 %) either way; ``--json`` is rewritten after each threshold
(``complete``: false until the last), so a stopped sweep keeps what it measured::

    python benchmarks/finder_sensitivity.py --kinds motion,sds --n 1 --cases single,clean \\
        --n-variations 2 --thresholds bic_min,heldout_min --json out.json

``--only NAME,...`` with ``--json`` of an earlier sweep (same kinds, ``--n``, ``--cases``,
``--n-variations``, seed and factors) measures only those thresholds and merges them into
that file: its rows for the other thresholds are kept as measured, not recomputed (the
defaults' verdicts are recomputed and must equal the file's).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from encdesign._errors import EncdesignInputError
from encdesign.diagnose import FinderSettings
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose.engine._settings import SETTINGS_FIELDS
from encdesign.simulate import SDS_CATALOG, draw_plan, write_concealed_sds
from encdesign.simulate import simulate_plan as simulate

CASES = ("clean", "single", "weak", "compound")
KINDS = ("multihead", "sensor", "motion", "quadrature", "sds")


def moved(settings: FinderSettings, name: str, factor: float) -> FinderSettings:
    """``settings`` with threshold ``name`` times ``factor`` (integers rounded, >= 1;
    ``n_folds`` >= 2)."""
    v = getattr(settings, name)
    if isinstance(v, int):
        nv = max(2 if name == "n_folds" else 1, int(round(v * factor)))
    else:
        nv = float(v) * factor
    return dataclasses.replace(settings, **{name: nv})


def _sds_recording(seed: int, i: int, case: str, tmp: Path):
    """An SDS recording (12 platform positions, phi_ref) and its truth: clean, or one catalog
    effect near the noise (``single``, ``weak``, ``compound`` alike: the SDS benches hold one
    hidden effect)."""
    effect = None if case == "clean" else SDS_CATALOG[(seed + i) % len(SDS_CATALOG)]
    rec, _ = write_concealed_sds(
        tmp / f"sds{i:03d}.toml",
        key=jax.random.key(seed * 1000 + 700 + i),
        effect=effect,
        concealment="near_noise",
        phi_ref=True,
        n_runs=12,
    )
    return rec, [effect] if effect else []


def recordings(
    kinds, n: int, n_var: int, seed: int, cases=CASES, tmp: Path | None = None
) -> list[tuple[str, object, dict]]:
    """``(label, Recording, truth)``: benchmark recordings of each kind (cases in turn over
    all kinds), then variations. ``truth``: ``effects`` (empty = clean) and ``rule``
    (``exact``: the named set; ``first``: the first name, SDS)."""
    out = []
    j = 0
    for kind in kinds:
        for i in range(n):
            case = cases[j % len(cases)]
            j += 1
            if kind == "sds":
                if tmp is None:
                    raise ValueError("sds recordings are written to disk: give tmp")
                rec, eff = _sds_recording(seed, i, case, tmp)
                out.append((f"sds/{case}/{i}", rec, dict(effects=eff, rule="first")))
                continue
            rng = np.random.default_rng([seed, KINDS.index(kind), i])
            plan = draw_plan(rng, kind, case)
            rec, truth = simulate(rng, plan)
            eff = sorted(truth["effects"])
            out.append((f"{kind}/{plan['case']}/{i}", rec, dict(effects=eff, rule="exact")))
    if n_var:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import finder_variations as fv

        for i in range(n_var):
            if i % 2:
                eff = fv.EFFECTS[(i // 2) % len(fv.EFFECTS)]
                rec, _ = fv.effect_record(np.random.default_rng([seed, 99, i]), eff)
                out.append((f"variation/{eff}/{i}", rec, dict(effects=[eff], rule="exact")))
            else:
                rec, _ = fv.clean_record(np.random.default_rng([seed, i]))
                out.append((f"variation/clean/{i}", rec, dict(effects=[], rule="exact")))
    return out


def outcome(rec, settings: FinderSettings) -> tuple[str, tuple[str, ...], tuple[str, ...]]:
    """The verdict, the named effects (in the document's order) and the effects listed as
    not testable; ``("input_error", (), ())`` when a moved threshold refuses the record
    itself (e.g. ``quad_sectors_min`` x2 asks for more sectors than there are)."""
    try:
        d = diagnose(rec, settings=settings).doc
    except EncdesignInputError:
        return "input_error", (), ()
    return (
        d["verdict"],
        tuple(e["name"] for e in d["effects"]),
        tuple(sorted(n["name"] for n in d.get("not_testable", []))),
    )


def is_right(out: tuple, truth: dict) -> bool:
    """Whether an outcome is the right verdict for the recording's truth."""
    verdict, named, untestable = out
    eff = truth["effects"]
    if not eff:
        return verdict == "consistent"
    if truth["rule"] == "first":
        if eff[0] in untestable:  # the record cannot show it: right when it says so
            return verdict == "consistent"
        return bool(named) and named[0] == eff[0]
    return set(named) == set(eff)


def _key(out: tuple) -> tuple:
    """What a flip compares: the verdict and the set of named effects."""
    return out[0], tuple(sorted(out[1]))


def sweep_meta(args, kinds, recs, ref) -> dict:
    """What identifies a sweep: its arguments, recordings, truths and the defaults' outcomes."""
    n_right = sum(is_right(ref[lab], truth) for lab, _, truth in recs)
    return dict(
        kinds=kinds,
        n=args.n,
        cases=args.cases.split(","),
        n_variations=args.n_variations,
        seed=args.seed,
        factors=[float(x) for x in args.factors.split(",")],
        flip=args.flip,
        recordings=[lab for lab, _, _ in recs],
        truth={lab: truth for lab, _, truth in recs},
        default={k: [v[0], list(v[1]), list(v[2])] for k, v in ref.items()},
        default_right=n_right,
        default_right_rate=n_right / max(len(recs), 1),
    )


def write_json(path, meta: dict, rows: list[dict], elapsed_s: float) -> None:
    """The sweep so far (``complete``: every threshold and factor done), written after each
    threshold so that a sweep stopped early still leaves what it measured."""
    done = {r["threshold"] for r in rows}
    out = dict(
        meta,
        complete=set(SETTINGS_FIELDS) <= done
        and all(
            any(r["threshold"] == t and r["factor"] == f for r in rows)
            for t in SETTINGS_FIELDS
            for f in meta["factors"]
        ),
        fields_total=len(SETTINGS_FIELDS),
        thresholds_done=sorted(done),
        thresholds_missing=sorted(set(SETTINGS_FIELDS) - done),
        elapsed_s=elapsed_s,
        rows=sorted(rows, key=lambda r: (r["threshold"], r["factor"])),
        **summarise(rows, meta["flip"]),
    )
    with open(path, "w") as f:
        json.dump(out, f, indent=1, default=str)


def merge(paths: list[str], out: str) -> dict:
    """Sweeps of the same recordings (run side by side on parts of the fields) as one: the
    arguments and the defaults' outcomes must agree; a later file's rows replace an earlier
    one's for the same threshold."""
    keys = ("kinds", "n", "cases", "n_variations", "seed", "factors", "flip", "default")
    parts = [json.loads(Path(p).read_text()) for p in paths]
    meta = {k: parts[0][k] for k in (*keys, "recordings", "truth", "default_right")}
    meta["default_right_rate"] = parts[0]["default_right_rate"]
    rows: dict[str, list[dict]] = {}
    for p, d in zip(paths, parts, strict=True):
        diff = [k for k in keys if d[k] != meta[k]]
        if diff:
            raise SystemExit(f"--merge: {p} differs from {paths[0]} in {diff}")
        for r in d["rows"]:
            rows.setdefault(r["threshold"], [])
        for t in {r["threshold"] for r in d["rows"]}:
            rows[t] = [r for r in d["rows"] if r["threshold"] == t]
    flat = [r for rs in rows.values() for r in rs]
    write_json(out, meta, flat, sum(float(d.get("elapsed_s") or 0.0) for d in parts))
    return json.loads(Path(out).read_text())


def _void() -> dict:
    """The measured fields of a row whose moved value the settings refuse: nothing was
    diagnosed, nothing changed (``right`` stays the defaults' count, filled in by the
    caller's ``delta`` of 0)."""
    return dict(
        same_as_default=False,
        flipped=0,
        share=0.0,
        right=None,
        right_rate=None,
        delta_right=0,
        delta_rate=0.0,
        flips=[],
        wrong=[],
        time_s=0.0,
        times_s={},
    )


def summarise(rows: list[dict], flip: float) -> dict:
    """Thresholds whose rate of right verdicts drops / rises by more than ``flip`` at some
    factor, and those that flip more than ``flip`` of the verdicts."""
    return dict(
        rate_drops=sorted({r["threshold"] for r in rows if r["delta_rate"] < -flip}),
        rate_rises=sorted({r["threshold"] for r in rows if r["delta_rate"] > flip}),
        over=sorted({r["threshold"] for r in rows if r["share"] > flip}),
        largest_drop=min((r["delta_rate"] for r in rows), default=0.0),
    )


def main(argv: list[str] | None = None) -> int:
    """Run the sweep; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default="multihead,sensor,motion,quadrature,sds")
    ap.add_argument("--n", type=int, default=4, help="benchmark recordings per kind")
    ap.add_argument("--cases", default=",".join(CASES), help="benchmark cases, in turn")
    ap.add_argument("--n-variations", type=int, default=4)
    ap.add_argument("--thresholds", default="", help="comma-separated fields (default: all)")
    ap.add_argument("--factors", default="0.5,2")
    ap.add_argument("--flip", type=float, default=0.05, help="share of verdicts / rate moved")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--only",
        default="",
        help="comma-separated fields: measure only these and merge them into --json",
    )
    ap.add_argument(
        "--merge",
        default="",
        help="comma-separated sweep JSONs of the same recordings: write them as one --json",
    )
    args = ap.parse_args(argv)
    if args.merge:
        if not args.json:
            ap.error("--merge writes --json")
        d = merge(args.merge.split(","), args.json)
        print(
            f"merged {args.merge} -> {args.json}: {len(d['thresholds_done'])} of "
            f"{d['fields_total']} thresholds, complete {d['complete']}",
            flush=True,
        )
        return 0
    old_rows: list[dict] = []
    if args.only:
        if not args.json or not Path(args.json).exists():
            ap.error("--only merges into an earlier sweep: give its --json")
        old = json.loads(Path(args.json).read_text())
        same = (
            old["kinds"],
            old["n"],
            old.get("cases"),
            old["n_variations"],
            old["seed"],
            old["factors"],
        )
        want = (
            args.kinds.split(","),
            args.n,
            args.cases.split(","),
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
    cases = [c for c in args.cases.split(",") if c]
    bad = [k for k in kinds if k not in KINDS] + [c for c in cases if c not in CASES]
    names = [t for t in args.thresholds.split(",") if t] or list(SETTINGS_FIELDS)
    bad += [t for t in names if t not in SETTINGS_FIELDS]
    if bad:
        ap.error(
            f"unknown kinds, cases or thresholds: {bad} (kinds {KINDS}, cases {CASES}, "
            f"thresholds {SETTINGS_FIELDS})"
        )
    factors = [float(f) for f in args.factors.split(",")]
    t0 = time.perf_counter()
    tmp = tempfile.TemporaryDirectory(prefix="finder-sensitivity-")
    recs = recordings(kinds, args.n, args.n_variations, args.seed, cases, Path(tmp.name))
    n = len(recs)
    base = FinderSettings()
    ref = {}
    for label, rec, truth in recs:
        t1 = time.perf_counter()
        ref[label] = outcome(rec, base)
        ok = "right" if is_right(ref[label], truth) else "WRONG"
        print(
            f"default {label}: {ref[label][0]} {list(ref[label][1])} truth "
            f"{truth['effects'] or 'clean'}: {ok} ({time.perf_counter() - t1:.1f} s)",
            flush=True,
        )
    n_right0 = sum(is_right(ref[lab], truth) for lab, _, truth in recs)
    if args.only:
        prev = {k: (v[0], tuple(v[1]), tuple(v[2])) for k, v in old["default"].items()}
        if prev != ref:
            raise SystemExit(f"--only: the defaults' verdicts differ from {args.json}'s")
    meta = sweep_meta(args, kinds, recs, ref)
    rows = list(old_rows)
    for name in names:
        for fac in factors:
            t1 = time.perf_counter()
            try:
                st = moved(base, name, fac)
            except ValueError as ex:  # outside the field's domain (a level of 0.95 x2)
                rows.append(
                    dict(threshold=name, factor=fac, value=None, invalid=str(ex), **_void())
                )
                print(f"{name} x{fac:g}: not a valid value ({ex})", flush=True)
                continue
            same = getattr(st, name) == getattr(base, name)
            flips = []
            wrong = []
            times = {}
            n_right = 0
            for label, rec, truth in recs:
                t2 = time.perf_counter()
                got = ref[label] if same else outcome(rec, st)
                times[label] = round(time.perf_counter() - t2, 2)
                if _key(got) != _key(ref[label]):
                    flips.append(dict(recording=label, default=ref[label], moved=got))
                if is_right(got, truth):
                    n_right += 1
                else:
                    wrong.append(dict(recording=label, got=got))
            rows.append(
                dict(
                    threshold=name,
                    factor=fac,
                    value=getattr(st, name),
                    same_as_default=same,
                    flipped=len(flips),
                    share=len(flips) / max(n, 1),
                    right=n_right,
                    right_rate=n_right / max(n, 1),
                    delta_right=n_right - n_right0,
                    delta_rate=(n_right - n_right0) / max(n, 1),
                    flips=flips,
                    wrong=wrong,
                    time_s=time.perf_counter() - t1,
                    times_s=times,
                )
            )
            print(
                f"{name} x{fac:g} = {getattr(st, name)!r}: right {n_right} / {n} "
                f"(defaults {n_right0}), {len(flips)} verdicts change"
                + "".join(f"\n    {f['recording']}: {f['default']} -> {f['moved']}" for f in flips),
                flush=True,
            )
        if args.json:
            write_json(args.json, meta, rows, el0 + time.perf_counter() - t0)
    summary = summarise(rows, args.flip)
    n_done = len({r["threshold"] for r in rows})
    print(
        f"defaults right {n_right0} / {n}; of {n_done} thresholds at "
        f"x{' or x'.join(f'{f:g}' for f in factors)}, the rate of right verdicts drops more "
        f"than {100 * args.flip:.0f} % for {summary['rate_drops']}, rises for "
        f"{summary['rate_rises']}; verdicts flip for {summary['over']} "
        f"({time.perf_counter() - t0:.0f} s)",
        flush=True,
    )
    if args.json:
        write_json(args.json, meta, rows, el0 + time.perf_counter() - t0)
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
