"""Issue 41's acceptance, read from the JSONs of ``benchmarks/discovery.py`` (and of
``studies/conceal_benchmark.py``): one table per kind and overall.

It runs nothing: it reads the cases and clean records the benchmark wrote (``--json``),
pools them over files (several seeds, several kinds) and prints, per kind and over all:

* frame right over all cases (``frame_right``), over the oracle-detectable cases the
  catalog does not legitimately take (``frame_right_oracle_detectable``: the benchmark's
  definition, ``benchmarks/discovery.py``'s doc) and over the detectable, not confounded
  cases (``frame_right_detectable_not_confounded``);
* the speed exponent within 2 standard errors of the truth (``beta_within_2se``), read two
  ways: over the cases with a speed law whose discovered term stands (the benchmark's
  ``beta_within_2se``: discovery cases with a term at the truth's line), and strictly over
  every case whose truth has a speed law (a case with no term counts as a miss);
* the held-out gain at least 80 % of the true model's (``gain_ratio >= 0.8``, over the
  discovery cases with a ratio), and its median;
* clean records where discovery adds a term (``found_any``), per kind;
* the cases where the catalog named an effect beside the discovered term (every effect of
  the benchmark is out of the catalog, so each such name is a false one);
* every miss of the frame (class, size, kind, verdict, named effects, the oracle's
  noncentrality ``lambda`` against the true term's multiple-testing and the locating
  thresholds, the finder's noise over the true noise and, on SDS, its parts; a catalog take
  scored confounded only because nothing was located after it is marked so);
* the expected frame right of an ideal test (:func:`ideal_power`, session 42): the true
  structure's own columns at the finder's thresholds, with the true level known and, on SDS,
  with the level estimated from the finder's own degrees of freedom, and that at the
  threshold of the view that locates the structure (a growth or a step pays the
  ``modulated_orders`` view's search over shapes): the ceiling that the rate over all cases
  is to be read against;
* and, from conceal-benchmark JSONs (``--catalog``), the catalog's rates per kind.

The issue's lines: frame right >= 90 %, exponent within 2 SE >= 90 %, held-out gain >= 80 %
of the true model's, clean records with a term <= 2 % over >= 100 per kind. Usage::

    python benchmarks/discovery_acceptance.py benchmarks/discovery_s31_*.json \\
        --catalog benchmarks/discovery_s31_catalog_6602.json
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

FRAME_LINE, BETA_LINE, GAIN_LINE, CLEAN_LINE, CLEAN_N = 0.90, 0.90, 0.80, 0.02, 100


def load(paths: list[str]) -> tuple[list[dict], list[dict], list[str]]:
    """The cases, clean records and notes (a file's seed, kinds, complete or not) of the
    discovery JSONs at ``paths``."""
    cases: list[dict] = []
    clean: list[dict] = []
    notes: list[str] = []
    for p in paths:
        with open(p) as f:
            d = json.load(f)
        a, s = d.get("args", {}), d.get("summary", {})
        for c in d.get("cases", []):
            cases.append({**c, "_seed": a.get("seed"), "_file": p})
        clean += d.get("clean", [])
        notes.append(
            f"{p}: seed {a.get('seed')} kinds {a.get('kinds')} cases {len(d.get('cases', []))} "
            f"clean {len(d.get('clean', []))} complete {s.get('complete')}"
        )
    return cases, clean, notes


def _rate(xs: list[bool]) -> tuple[int, int]:
    return sum(bool(x) for x in xs), len(xs)


def _fmt(r: tuple[int, int]) -> str:
    k, n = r
    return f"{k}/{n} ({100 * k / n:.1f} %)" if n else "-"


def rates(cases: list[dict], clean: list[dict]) -> dict[str, Any]:
    """The acceptance's rates over ``cases`` and ``clean`` (``(k, n)`` pairs; the same
    subsets as ``benchmarks/discovery.summarise``)."""
    disc = [c for c in cases if not c["catalog"] and not c.get("base")]
    ident = [c for c in cases if not c.get("confounded")]
    fair = [c for c in ident if c.get("detectable")]
    oracle = [c for c in ident if c.get("oracle_detectable")]
    ratios = [c["gain_ratio"] for c in disc if c.get("gain_ratio") is not None]
    speed = [c for c in cases if c["truth"].get("beta") is not None]
    ratios_sorted = sorted(ratios)
    med = ratios_sorted[len(ratios) // 2] if len(ratios) % 2 else None
    if ratios and med is None:
        med = 0.5 * (ratios_sorted[len(ratios) // 2 - 1] + ratios_sorted[len(ratios) // 2])
    return {
        "cases": len(cases),
        "frame_all": _rate([c["frame_right"] for c in cases]),
        "frame_oracle": _rate([c["frame_right"] for c in oracle]),
        "frame_oracle_incl_confounded": _rate(
            [c["frame_right"] for c in cases if c.get("oracle_detectable")]
        ),
        "frame_detectable_nc": _rate([c["frame_right"] for c in fair]),
        "frame_not_confounded": _rate([c["frame_right"] for c in ident]),
        "beta_term": _rate([c["beta_within_2se"] for c in disc if "beta_within_2se" in c]),
        "beta_strict": _rate([c.get("beta_within_2se", False) for c in speed]),
        "gain": _rate([r >= 0.8 for r in ratios]),
        "gain_median": med,
        "confounded": sum(bool(c.get("confounded")) for c in cases),
        "confounded_at_line": sum(
            bool(c.get("confounded")) and c.get("confounded_at_truth_line") is not False
            for c in cases
        ),
        "catalog": sum(bool(c["catalog"]) for c in cases),
        "named_beside": sum(bool(c["effects"]) and not c["catalog"] for c in cases),
        "oracle_undetectable": sum(not c.get("oracle_detectable") for c in cases),
        "clean_term": _rate([c["found_any"] for c in clean]),
        "clean_not_consistent": _rate([c.get("verdict") != "consistent" for c in clean]),
        "ceiling_known": _ceiling(cases, estimated=False),
        "ceiling_estimated": _ceiling(cases, estimated=True),
        "ceiling_views": _ceiling(cases, estimated=True, views=True),
    }


def _view_routes(c: dict) -> list[tuple[float, float]]:
    """``(share, threshold)`` per way the finder's views can locate case ``c``'s structure
    (session 42): the ``orders`` view at ``threshold_locate_chi2`` (``alpha`` over its
    ``n`` order x channel tests) with the share of the structure's power a static fit keeps,
    and for a growth or a step the ``modulated_orders`` view at its own family's threshold
    (``modulated_orders_alpha / 2`` over ``2 n`` growth and decay tests, or ``2 K n`` switch
    tests at ``K`` = ``modulated_orders_steps`` edges; ``engine/_views_modulated``) with all of
    it. A static fit keeps 3/4 of a linear growth's power and ``1 - k / R`` of a step from
    row ``k`` of ``R`` (the latter taken as 1/2 where ``R`` is not in the JSON). Only
    ``[(1, threshold_locate_chi2)]`` for another modulation, ``[]`` without that threshold."""
    from scipy import stats

    from encdesign.diagnose.engine._settings import DEFAULT_SETTINGS as S

    lt = c.get("threshold_locate_chi2")
    if lt is None or not math.isfinite(lt):
        return []
    mod = (c.get("truth") or {}).get("modulation")
    if mod not in ("growth", "step"):
        return [(1.0, float(lt))]
    n = S.alpha / float(stats.chi2.sf(lt, 2))  # the orders view's count of tests
    count = 2 * n * (1 if mod == "growth" else S.modulated_orders_steps)
    mt = float(stats.chi2.isf(S.modulated_orders_alpha / 2 / count, 2))
    return [(0.75 if mod == "growth" else 0.5, float(lt)), (1.0, mt)]


def ideal_power(c: dict, estimated: bool, views: bool = False) -> float | None:
    """The chance that an ideal test finds case ``c``'s structure (session 42): the true
    structure's own columns (``true_dof`` of them), its noncentrality at the true noise
    (``oracle_noncentrality``), read at the finder's thresholds (the larger of
    ``threshold_true_raw_chi2`` and ``threshold_locate_chi2``, which already pay for the search
    over the library). ``estimated`` False: the true level known (the benchmark's
    ``oracle_power``, noncentral chi-square); True: the level estimated with the finder's own
    degrees of freedom (``noise_finder_run_means.dof``, SDS only; ``None`` elsewhere), the
    noncentral F-test at the same false-alarm probability: what no finder that estimates its
    level from that many degrees of freedom can beat on average. ``views``: the locating
    threshold is that of the view that can locate the structure (:func:`_view_routes`: a
    growth or a step pays the ``modulated_orders`` view's search over shapes, or is read by
    the static scan with part of its power), the best route kept. ``None`` where a number is
    missing."""
    from scipy import stats

    lam, q = c.get("oracle_noncentrality"), c.get("true_dof")
    rt = c.get("threshold_true_raw_chi2")
    routes = _view_routes(c) if views else []
    if not views:
        lt = c.get("threshold_locate_chi2")
        routes = [(1.0, float(lt))] if lt is not None and math.isfinite(lt) else []
    if rt is not None and math.isfinite(rt):
        routes = [(k, max(t, float(rt))) for k, t in routes] or [(1.0, float(rt))]
    if lam is None or not q or not routes or not math.isfinite(lam):
        return None
    nu = (c.get("noise_finder_run_means") or {}).get("dof")
    if estimated and not nu:
        return None
    best = 0.0
    for k, t in routes:
        nc = max(k * lam, 1e-12)
        if not estimated:
            best = max(best, float(stats.ncx2.sf(t, q, nc)))
        else:
            crit = stats.f.isf(stats.chi2.sf(t, q), q, nu)
            best = max(best, float(stats.ncf.sf(crit, q, nu, nc)))
    return best


def _ceiling(cases: list[dict], estimated: bool, views: bool = False) -> tuple[float, int] | None:
    """``(expected cases found, cases)``: :func:`ideal_power` summed over ``cases``; ``None``
    where a case has no number (the ceiling is read over all cases or not at all)."""
    p = [ideal_power(c, estimated, views) for c in cases]
    if not p or any(x is None for x in p):
        return None
    return float(sum(x for x in p if x is not None)), len(p)


def _met(r: tuple[int, int], line: float) -> str:
    return "met" if r[1] and r[0] / r[1] >= line else "NOT met"


def miss_line(c: dict) -> str:
    """One frame miss in words and numbers."""
    lam = c.get("oracle_noncentrality", math.nan)
    top = c["terms"][0] if c.get("terms") else None
    got = f"{top['frame']}/{top['modulation']}" if top else "no term"
    marks = [
        "oracle-detectable" if c.get("oracle_detectable") else "not oracle-detectable",
        "detectable" if c.get("detectable") else "not detectable",
    ]
    if c.get("catalog"):
        marks.append("catalog take, " + ("confounded" if c.get("confounded") else "not confounded"))
        if c.get("confounded") and c.get("confounded_at_truth_line") is False:
            marks.append(  # the located reading only: the truth's model at its line still gains
                "not confounded at the truth's line (gain "
                f"{c.get('gain_true_after_catalog_at_line_chi2', math.nan):.1f})"
            )
    parts = c.get("noise_finder_over_true_parts") or {}
    if parts:  # session 32: the SDS level ratio as its product
        marks.append(
            "noise ratio = estimate {estimate:.2f} x widening {widening:.2f} x common factor "
            "{common_factor:.2f} x level mix {level_mix:.2f}".format(**parts)
        )
    return (
        f"{c['kind']} {c['class']} {c['size']:g}x (seed {c.get('_seed')}): verdict "
        f"{c['verdict']}, named [{', '.join(c['effects'])}], term {got} vs truth "
        f"{c['truth']['frame']}/{c['truth']['modulation']}; lambda {lam:.1f} vs thresholds "
        f"{c.get('threshold_true_raw_chi2', math.nan):.1f} (name) / "
        f"{c.get('threshold_locate_chi2', math.nan):.1f} (locate); finder/true noise "
        f"{c.get('noise_finder_over_true', math.nan):.2f}; {', '.join(marks)}"
    )


def catalog_rates(path: str) -> list[str]:
    """The catalog benchmark's rates per kind (conceal-benchmark JSON)."""
    with open(path) as f:
        d = json.load(f)
    out = []
    blocks = dict(d.get("kinds", {}))
    if "sds" in d:
        blocks["sds"] = d["sds"]
    for k, b in blocks.items():
        pct = {
            key.removesuffix("_pct"): v
            for key, v in b.items()
            if key.endswith("_pct") and not isinstance(v, dict)
        }
        vals = ", ".join(
            f"{key} {v:.1f} %" if v is not None else f"{key} -" for key, v in pct.items()
        )
        out.append(f"{path} seeds {d.get('seeds')} {k} ({b.get('n_recordings')} records): {vals}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", nargs="+", help="benchmarks/discovery.py --json files")
    ap.add_argument("--catalog", nargs="*", default=[], help="conceal-benchmark JSONs")
    a = ap.parse_args(argv)
    cases, clean, notes = load(a.json)
    print("\n".join(notes))
    kinds = sorted({c["kind"] for c in cases} | {c["kind"] for c in clean})
    groups = [
        (k, [c for c in cases if c["kind"] == k], [c for c in clean if c["kind"] == k])
        for k in kinds
    ]
    groups.append(("all", cases, clean))
    head = (
        "| kind | cases | frame right, all | oracle-detectable | detectable, not confounded "
        "| exponent within 2 SE (term / every speed case) | gain >= 0.8 (median) "
        "| clean with a term |"
    )
    print("\n" + head + "\n|" + "---|" * 8)
    table = {}
    for name, cs, cl in groups:
        r = rates(cs, cl)
        table[name] = r
        med = f"{r['gain_median']:.3f}" if r["gain_median"] is not None else "-"
        print(
            f"| {name} | {r['cases']} | {_fmt(r['frame_all'])} | {_fmt(r['frame_oracle'])} "
            f"| {_fmt(r['frame_detectable_nc'])} | {_fmt(r['beta_term'])} / "
            f"{_fmt(r['beta_strict'])} | {_fmt(r['gain'])} ({med}) | {_fmt(r['clean_term'])} |"
        )
    print()
    for name, r in table.items():
        print(
            f"{name}: catalog takes {r['catalog']} (confounded {r['confounded']}; at the "
            f"truth's line {r['confounded_at_line']}), a catalog "
            f"name beside a discovered term {r['named_beside']}, not "
            f"oracle-detectable {r['oracle_undetectable']}, oracle-detectable incl. confounded "
            f"{_fmt(r['frame_oracle_incl_confounded'])}, clean not consistent "
            f"{_fmt(r['clean_not_consistent'])}"
        )
    print("\nexpected frame right of an ideal test (the true columns at the finder's thresholds):")
    for name, r in table.items():
        out = []
        for key, label in (
            ("ceiling_known", "level known"),
            ("ceiling_estimated", "level estimated with the finder's degrees of freedom"),
            ("ceiling_views", "the same at the locating view's own search threshold"),
        ):
            if r[key] is not None:
                e, n = r[key]
                out.append(f"{label} {e:.1f}/{n} ({100 * e / n:.1f} %)")
        print(f"  {name}: " + ("; ".join(out) or "-"))
    print("\nframe misses:")
    for c in cases:
        if not c["frame_right"]:
            print("  " + miss_line(c))
    print("\ncatalog names beside a discovered term (not in the truth: all out of catalog):")
    for c in cases:
        if c["effects"] and not c["catalog"]:
            top = c["terms"][0]
            print(
                f"  {c['kind']} {c['class']} {c['size']:g}x (seed {c.get('_seed')}): "
                f"[{', '.join(c['effects'])}] beside {top['frame']}/{top['modulation']}, frame "
                f"{'right' if c['frame_right'] else 'wrong'}"
            )
    print("\nspeed-exponent misses (a term stands, |beta - truth| > 2 SE, or no term):")
    for c in cases:
        if c["truth"].get("beta") is not None and not c.get("beta_within_2se"):
            sc = (c["terms"][0].get("scaling") if c.get("terms") else None) or {}
            print(
                f"  {c['kind']} {c['class']} {c['size']:g}x (seed {c.get('_seed')}): truth "
                f"{c['truth']['beta']}, found {sc.get('beta')} +- {sc.get('beta_se')}, "
                f"verdict {c['verdict']}"
            )
    print("\ngain ratio under 0.8:")
    for c in cases:
        g = c.get("gain_ratio")
        if g is not None and g < 0.8 and not c["catalog"] and not c.get("base"):
            print(f"  {c['kind']} {c['class']} {c['size']:g}x (seed {c.get('_seed')}): {g:.3f}")
    print("\nacceptance lines (issue 41), per kind and over all:")
    lines = (
        ("frame_all", "frame right >= 90 %, all cases", FRAME_LINE),
        ("frame_oracle", "frame right >= 90 %, oracle-detectable", FRAME_LINE),
        ("frame_detectable_nc", "frame right >= 90 %, detectable not confounded", FRAME_LINE),
        ("beta_term", "exponent within 2 SE >= 90 %, with a term", BETA_LINE),
        ("beta_strict", "exponent within 2 SE >= 90 %, every speed case", BETA_LINE),
        ("gain", "held-out gain >= 80 % of the true model's (rate)", None),
    )
    for key, label, line in lines:
        parts = []
        for name, t in table.items():
            r = t[key]
            if r[1]:
                parts.append(f"{name} {_fmt(r)}{'' if line is None else ' ' + _met(r, line)}")
        print(f"  {label}: " + ("; ".join(parts) or "no case"))
    for name, t in table.items():
        if name == "all":
            continue
        k, n = t["clean_term"]
        if n:
            ok = n >= CLEAN_N and k / n <= CLEAN_LINE
            print(
                f"  clean {name}: {_fmt((k, n))} with a term, {'met' if ok else 'NOT met'}"
                + ("" if n >= CLEAN_N else f" (only {n} < {CLEAN_N} records)")
            )
    for p in a.catalog:
        print("\n".join(catalog_rates(p)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
