"""Benchmark: every kind of located change point against the truth (issue 44 C acceptance:
a located change point falls within its stated interval in at least 90 % of cases).

Generated records with ONE change point each, from the project's own generators (no
pipeline per kind: one extractor reads every located time a diagnosis reports), in classes
that together cover every recording kind that locates a time:

* ``mh_head_step`` / ``mh_ecc_shift``: ``tests/test_located_times.change_record`` with the
  test's own variation (``case``): whole turns, 2-5 heads, 1-3 runs, a clock per run or one
  clock with pauses, a reference in 3 of 4; a head's offset step of 0.5-1.5x the noise or
  an eccentricity shift of 0.6-2x (near the threshold);
* ``mh_arcs_noref``: ``tests/helpers.shift_arcs_record`` (the class of
  ``benchmarks/change_coverage.py``): 2-3 runs of part of a turn, 2-4 heads, no reference,
  a shift of 10-15x the noise in a pause, at a run's start or inside a run;
* ``mh_bench_jump`` / ``mh_bench_shift``: ``encdesign.simulate._conceal`` (3+1 or 2+1 heads
  with base errors, 1-3 runs at different speeds, with or without a reference): a head's
  ``count_jump`` (3x the amplitude) or an ``eccentricity_shift``, the amplitude 0.15-1.5x
  (jump) or 0.3-2x (shift) the noise;
* ``mh_part_ref``: ``encdesign.simulate._conceal_bench`` multihead, part of a turn (0.4-0.95)
  with a reference, 2-6 heads: an ``eccentricity_shift`` of 1.5x an amplitude of 0.4-2x;
* ``sensor_step``: ``_conceal_bench`` sensor (one sensor against a reference):
  ``step_one_head`` of 4x an amplitude of 0.25-1.5x the noise;
* ``sds_delay_step``: ``write_concealed_sds`` ``sensor_delay_step``, 8-16 runs, 2-4 moving
  sensors, with and without ``phi_ref``, 2-12x the per-pair noise;
* ``quad_amp_step``: ``_conceal_bench`` quadrature in time order, an amplitude step of 2-8x
  the noise.

The classes have equal shares (``--n`` records each per seed): the acceptance line is about
located change points in general, and no class is weighted to reach a number. Record ``i``
of class ``c`` (index ``k`` in :data:`CLASSES`) of seed ``S`` draws from
``default_rng([S, 44, 24, k, i])``.

Per record, every located time the diagnosis reports (each view's strongest finding with a
``located_time`` in ``findings_before`` and ``unexplained``; each effect's time parameter
with an interval) is checked against the truth on the recording's own ``t``
(``engine._located.in_interval``; a change between SDS runs: ``r0 < run <= r1``). A record
whose change is not located is counted ``not located`` (not a miss), with its
detectability: ``step_chi2``, the chi-square a step of the change's RMS size takes out of
white noise on the rows it is defined on with no other model (``d^2 a b / (a + b)`` per
channel, ``a`` / ``b`` rows before / after; an upper bound on its evidence), and ``size``
in noise units. Discovery's step times (no interval) are counted apart, with whether the
truth lies between the rows they name. The coverage is summarized over three sets of
located times (:func:`summarize`): every distinct one of the JSON, each view's strongest
of the base residual with the reported ones (the rule of ``change_coverage.py`` and
``located_times.py``), and the reported ones (what the text report states with an
interval: the effects' time parameters, the ``unexplained`` findings'). Not located here:
the SDS drift onset (an SE, no interval) and a reversal's time (``direction_hysteresis``
has no time parameter)::

    python benchmarks/change_points.py --seed 6440 --n 4 [--classes a,b] [--json out.json]
    python benchmarks/change_points.py --combine a.json b.json ... --json summary.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from encdesign import Recording  # noqa: E402
from encdesign.diagnose._dispatch import diagnose  # noqa: E402
from encdesign.diagnose.engine._located import in_interval  # noqa: E402
from encdesign.simulate._conceal import simulate_concealed_bench  # noqa: E402
from encdesign.simulate._conceal_bench import (  # noqa: E402
    draw_plan,
    draw_quadrature_plan,
    fix_plan,
    simulate_plan,
)
from encdesign.simulate._conceal_sds import write_concealed_sds  # noqa: E402
from tests.helpers import WHERE, shift_arcs_record  # noqa: E402
from tests.test_located_times import case, change_record  # noqa: E402


def step_chi2(after: np.ndarray, d_rms: float, n_ch: int = 1) -> float:
    """``n_ch d^2 a b / (a + b)``: ``after`` (bool over the rows the step is defined on)."""
    a, b = int(np.sum(~after)), int(np.sum(after))
    return float(n_ch * d_rms**2 * a * b / max(a + b, 1))


def _change_record(rng, change: str):
    s = 2 * int(rng.integers(10**6)) + (change == "ecc_shift")  # case() draws by parity
    c = case(s)
    rec, truth = change_record(s, **c)
    t, run = rec.columns["t"], rec.columns["run"]
    i0 = int(np.flatnonzero((run == truth["run"]) & (t == truth["t_s"]))[0])
    if change == "head_step":
        on = run == truth["run"]
        after = np.arange(t.size)[on] >= i0
        chi = step_chi2(after, c["size"])
    else:
        after = np.arange(t.size) >= i0
        chi = step_chi2(after, c["size"] / math.sqrt(2), c["H"])
    desc = {k: c[k] for k in ("H", "R", "n", "clock", "ref")} | {"record_seed": s}
    return rec, dict(t_s=truth["t_s"], run=truth["run"], size=c["size"], step_chi2=chi, desc=desc)


def mh_head_step(rng):
    return _change_record(rng, "head_step")


def mh_ecc_shift(rng):
    return _change_record(rng, "ecc_shift")


def mh_arcs_noref(rng):
    where = WHERE[int(rng.integers(3))]
    rec, tr = shift_arcs_record(rng, where)
    t = rec.columns["t"]
    # the shift's size: 10-15x the noise (the generator's draw; 12.5 its middle)
    H = tr["desc"]["H"]
    chi = step_chi2(t >= tr["t_s"], 12.5 / math.sqrt(2), H)
    return rec, dict(
        t_s=tr["t_s"], run=tr["run"], size=12.5, step_chi2=chi, desc=tr["desc"] | {"where": where}
    )


def _bench(rng, effect: str, amp: float):
    R = int(rng.integers(1, 4))
    key = jax.random.key(int(rng.integers(2**31)))
    ref = bool(rng.random() < 0.5)
    layout = str(rng.choice(["3+1", "2+1"]))
    n = int(rng.choice([600, 1000, 1500]))
    speeds = (0.6, 1.0, 1.45)[:R]
    cols, enc, tr = simulate_concealed_bench(
        key=key,
        effect=effect,
        layout=layout,
        speeds_rev_s=speeds,
        samples_per_run=n,
        amplitude=amp,
        theta_ref=ref,
    )
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    rec = Recording("multihead", meta, cols)
    p = tr["params"]
    t, run = cols["t"], cols["run"]
    H = len(enc["head_angles_deg"])
    if effect == "count_jump":
        t_s, r = p["time_s"], p["run"]
        on = run == r
        chi = step_chi2(t[on] >= t_s, abs(p["jump_rad"]) / tr["noise_rad"])
        size = abs(p["jump_rad"]) / tr["noise_rad"]
    else:
        t_s, r = p["shift_time_s"], p["shift_run"]
        after = (run > r) | ((run == r) & (t >= t_s))
        size = amp  # the order-1 amplitude it adds, in noise units
        chi = step_chi2(after, size / math.sqrt(2), H)
    desc = dict(H=H, R=R, n=n, layout=layout, ref=ref)
    return rec, dict(t_s=float(t_s), run=int(r), size=float(size), step_chi2=chi, desc=desc)


def mh_bench_jump(rng):
    return _bench(rng, "count_jump", float(10 ** rng.uniform(math.log10(0.15), math.log10(1.5))))


def mh_bench_shift(rng):
    return _bench(rng, "eccentricity_shift", float(10 ** rng.uniform(math.log10(0.3), 0.3)))


def _plan_record(rng, kind: str, effect: str, amp: float, **fixed):
    plan = draw_plan(rng, kind, "single")
    plan.update(effects=[effect], amplitude=amp, **fixed)
    plan = fix_plan(plan, rng)
    rec, tr = simulate_plan(rng, plan)
    return rec, tr, plan


def mh_part_ref(rng):
    amp = float(10 ** rng.uniform(math.log10(0.4), 0.3))
    turns = float(rng.uniform(0.4, 0.95))
    rec, tr, plan = _plan_record(
        rng, "multihead", "eccentricity_shift", amp, turns=turns, theta_ref=True
    )
    at = tr["shift_at"]
    t, run = rec.columns["t"], rec.columns["run"]
    after = (run > at["run"]) | ((run == at["run"]) & (t >= at["time_s"]))
    H = plan["n_heads"]
    desc = dict(H=H, R=plan["n_runs"], turns=round(turns, 2), transient=plan["transient"])
    size = 1.5 * amp
    chi = step_chi2(after, size / math.sqrt(2), H)
    return rec, dict(t_s=at["time_s"], run=at["run"], size=size, step_chi2=chi, desc=desc)


def sensor_step(rng):
    amp = float(10 ** rng.uniform(math.log10(0.25), math.log10(1.5)))
    rec, tr, plan = _plan_record(rng, "sensor", "step_one_head", amp)
    w = tr["where"]
    t_s, r = w["times_s"][0], w["runs"][0]
    t, run = rec.columns["t"], rec.columns["run"]
    on = run == r
    desc = dict(
        R=plan["n_runs"],
        turns=plan["turns"],
        both=plan["both_directions"],
        sensor=plan["sensor"],
        transient=plan["transient"],
    )
    size = 4 * amp
    return rec, dict(t_s=t_s, run=r, size=size, step_chi2=step_chi2(t[on] >= t_s, size), desc=desc)


def sds_delay_step(rng):
    amp = float(10 ** rng.uniform(math.log10(2.0), math.log10(12.0)))
    R = int(rng.choice([8, 12, 16]))
    M = int(rng.integers(2, 5))
    ref = bool(rng.random() < 0.5)
    key = jax.random.key(int(rng.integers(2**31)))
    with tempfile.TemporaryDirectory() as d:
        rec, tr = write_concealed_sds(
            Path(d) / "sds.toml",
            key=key,
            effect="sensor_delay_step",
            phi_ref=ref,
            n_runs=R,
            n_moving=M,
            amplitude_noise=amp,
        )
    k = int(tr["params"]["first_run"])
    desc = dict(n_runs=R, n_moving=M, phi_ref=ref)
    return rec, dict(t_s=None, run=k, size=amp, step_chi2=None, desc=desc)


def quad_amp_step(rng):
    plan = draw_quadrature_plan(rng, "out_of_catalog")
    step = float(10 ** rng.uniform(math.log10(2.0), math.log10(8.0)))
    plan.update(timed=True, effects=["amplitude_step"], step_noise=step)
    rec, tr = simulate_plan(rng, plan)
    t_s = tr["where"]["times_s"][0]
    t = rec.columns["t"]
    desc = dict(n=plan["n"], samples_per_period=plan["samples_per_period"])
    desc["transient"] = plan["transient"]
    return rec, dict(t_s=t_s, run=0, size=step, step_chi2=step_chi2(t >= t_s, step), desc=desc)


CLASSES = {
    "mh_head_step": mh_head_step,
    "mh_ecc_shift": mh_ecc_shift,
    "mh_arcs_noref": mh_arcs_noref,
    "mh_bench_jump": mh_bench_jump,
    "mh_bench_shift": mh_bench_shift,
    "mh_part_ref": mh_part_ref,
    "sensor_step": sensor_step,
    "sds_delay_step": sds_delay_step,
    "quad_amp_step": quad_amp_step,
}


def located(doc: dict) -> list[dict]:
    """Every located time with an interval a diagnosis reports, once each: the findings
    with a ``located_time`` in ``findings_before`` and ``unexplained`` (``rank``: 0 for a
    view's strongest in its list) and each effect's time parameter (``t_s``: the
    parameter's own, or its ``value``); a located time reported again with the same time
    and interval (a finding of the base residual left unexplained) is one, its other
    places in ``also``."""
    out: list[dict] = []
    for key in ("findings_before", "unexplained"):
        rank: dict[str, int] = {}
        for f in doc.get(key) or []:
            if f.get("located_time"):
                k = rank[f["view"]] = rank.get(f["view"], -1) + 1
                out.append(dict(what=f"{key}.{f['view']}", rank=k, lt=f["located_time"]))
    for e in doc.get("effects") or []:
        for k, p in (e.get("params") or {}).items():
            if isinstance(p, dict) and "interval_s" in p and "run" in p:
                lt = {**p, "t_s": float(p.get("t_s", p["value"]))}
                out.append(dict(what=f"{e['name']}.{k}", rank=0, lt=lt))
    once: dict[tuple, dict] = {}
    for x in out:
        lt = x["lt"]
        key = (float(lt["t_s"]), int(lt["run"]), *map(float, lt["interval_s"]))
        key += tuple(int(r) for r in lt["interval_runs"])
        if key in once:
            once[key]["also"].append(x["what"])
            once[key]["rank"] = min(once[key]["rank"], x["rank"])
        else:
            once[key] = {**x, "also": []}
    return list(once.values())


def discovery_steps(doc: dict) -> list[dict]:
    """Discovery's step times (no interval): ``time_before_s``, ``time_s``, ``run``."""
    out = []
    for u in doc.get("unexplained") or []:
        for term in (u.get("model") or {}).get("terms") or []:
            if isinstance(term, dict) and "step" in term:
                out.append(term["step"])
    return out


def covered(lt: dict, truth: dict) -> bool:
    """The truth inside a located time's interval; a change between runs (``t_s`` None,
    ``run`` the first run after it): the interval's runs ``r0 < run <= r1``."""
    if truth["t_s"] is None:
        r0, r1 = lt["interval_runs"]
        return bool(r0 < truth["run"] <= r1)
    return bool(in_interval(lt, truth["t_s"], truth["run"]))


def wilson(k: int, n: int, z: float = 1.959964) -> list[float] | None:
    """Wilson score interval (95 %) of ``k`` successes in ``n``."""
    if n == 0:
        return None
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return [round(mid - half, 4), round(mid + half, 4)]


def _cover(lts: list[dict]) -> dict:
    k = sum(x["covered"] for x in lts)
    n = len(lts)
    return dict(
        located_times=n,
        covered=k,
        coverage=round(k / n, 4) if n else None,
        wilson95=wilson(k, n),
    )


def reported(x: dict) -> bool:
    """A located time the text report states with its interval: an effect's time parameter
    or an ``unexplained`` finding's."""
    return any(not w.startswith("findings_before.") for w in [x["what"], *x["also"]])


def summarize(rows: list[dict]) -> dict:
    """Per class and overall: records, located records, and the coverage (covered, share,
    Wilson interval) of three sets of located times: ``reported`` (the effects' time
    parameters and the ``unexplained`` findings' located times: what the text report
    states with an interval), ``strongest`` (those and each view's strongest finding of the
    base residual: the rule of ``change_coverage.py`` and ``located_times.py``) and every
    distinct located time of the JSON (the top level); records whose located times are all
    covered; the records whose change is not located, with their detectability."""
    out = {}
    for c in [*CLASSES, "all"]:
        rs = [r for r in rows if c == "all" or r["class"] == c]
        if not rs:
            continue
        lts = [x for r in rs for x in r["located"]]
        rep = [x for x in lts if reported(x)]
        strong = [x for x in lts if reported(x) or x["rank"] == 0]
        out[c] = dict(
            records=len(rs),
            located_records=sum(bool(r["located"]) for r in rs),
            **_cover(lts),
            strongest=_cover(strong),
            reported=_cover(rep),
            strongest_records_all_covered=sum(
                bool(r["located"])
                and all(x["covered"] for x in r["located"] if reported(x) or x["rank"] == 0)
                for r in rs
            ),
            records_all_covered=sum(
                bool(r["located"]) and all(x["covered"] for x in r["located"]) for r in rs
            ),
            not_located=[
                dict(
                    seed=r["seed"],
                    i=r["i"],
                    size=r["truth"]["size"],
                    step_chi2=r["truth"]["step_chi2"],
                )
                for r in rs
                if not r["located"]
            ],
            discovery_steps=sum(len(r["discovery_steps"]) for r in rs),
            by_what={
                w: [
                    sum(x["covered"] for x in lts if x["what"] == w),
                    sum(x["what"] == w for x in lts),
                ]
                for w in sorted({x["what"] for x in lts})
            },
        )
    return out


def run_record(seed: int, cls: str, i: int) -> dict:
    k = list(CLASSES).index(cls)
    rng = np.random.default_rng([seed, 44, 24, k, i])
    rec, truth = CLASSES[cls](rng)
    c0 = time.process_time()
    doc = diagnose(rec).doc
    cpu = time.process_time() - c0
    lts = []
    for x in located(doc):
        lt = x["lt"]
        lts.append(
            dict(
                what=x["what"],
                also=x["also"],
                rank=x["rank"],
                covered=covered(lt, truth),
                t_s=float(lt["t_s"]),
                run=int(lt["run"]),
                interval_s=[float(v) for v in lt["interval_s"]],
                interval_runs=[int(v) for v in lt["interval_runs"]],
            )
        )
    steps = [
        dict(
            time_before_s=s["time_before_s"],
            time_s=s["time_s"],
            run=s["run"],
            at_truth=truth["t_s"] is not None
            and s["run"] == truth["run"]
            and s["time_before_s"] < truth["t_s"] <= s["time_s"],
        )
        for s in discovery_steps(doc)
    ]
    return dict(
        seed=seed,
        i=i,
        **{"class": cls},
        truth=truth,
        verdict=doc["verdict"],
        effects=[e["name"] for e in doc["effects"]],
        located=lts,
        discovery_steps=steps,
        cpu_s=round(cpu, 2),
    )


def main(argv: list[str] | None = None) -> int:
    """Run one seed (``--n`` records per class); returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=6440)
    ap.add_argument("--n", type=int, default=1, help="records per class")
    ap.add_argument("--classes", default=",".join(CLASSES))
    ap.add_argument("--only", type=int, default=None, help="run only record i of each class")
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--combine", nargs="+", default=None, help="JSONs of this script: one summary of them"
    )
    a = ap.parse_args(argv)
    if a.combine:
        docs = [json.loads(Path(p).read_text()) for p in a.combine]
        rows = [r for d in docs for r in d["rows"]]
        summ = summarize(rows)
        for c, s in summ.items():
            print(c, json.dumps({k: v for k, v in s.items() if k != "not_located"}), flush=True)
        if a.json:
            seeds = [d["seed"] for d in docs]
            out = dict(seeds=seeds, n=docs[0]["n"], files=a.combine, summary=summ)
            Path(a.json).write_text(json.dumps(out, indent=1, default=float))
        return 0
    rows = []
    for cls in a.classes.split(","):
        for i in range(a.n) if a.only is None else [a.only]:
            r = run_record(a.seed, cls, i)
            rows.append(r)
            tr = r["truth"]
            cell = " ".join(
                f"{x['what']}:{'in' if x['covered'] else 'OUT'}"
                f"[{x['interval_s'][0]:.4g}({x['interval_runs'][0]}),"
                f"{x['interval_s'][1]:.4g}({x['interval_runs'][1]})]"
                for x in r["located"]
            )
            print(
                f"{a.seed}/{i} {cls} truth {tr['t_s']} (run {tr['run']}) size {tr['size']:.3g} "
                f"step_chi2 {tr['step_chi2']} {r['verdict']} {r['effects']} "
                f"{r['cpu_s']} s CPU | {cell or 'NOT LOCATED'}",
                flush=True,
            )
    summ = summarize(rows)
    for c, s in summ.items():
        st, rp = s["strongest"], s["reported"]
        print(
            f"seed {a.seed} {c}: strongest {st['covered']}/{st['located_times']}, reported "
            f"{rp['covered']}/{rp['located_times']}, all {s['covered']}/{s['located_times']} "
            f"located times covered; {s['located_records']}/{s['records']} records located",
            flush=True,
        )
    if a.json:
        doc = dict(seed=a.seed, n=a.n, classes=a.classes.split(","), summary=summ, rows=rows)
        Path(a.json).write_text(json.dumps(doc, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
