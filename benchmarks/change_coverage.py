"""Benchmark: located change points against the truth (issue 44 C acceptance: a located
change point falls within its stated interval in at least 90 % of cases).

Records of ``tests/helpers.shift_arcs_record`` (2-3 runs of part of a turn, 2-4 heads
without a reference, an eccentricity shift of 10-15x the noise in a pause between runs, at
a run's first row or inside a run, ``WHERE[i % 3]``), record ``i`` of seed ``S`` from
``default_rng([S, 44, 23, i])``. Per record, every located time is checked against the
truth on the recording's own ``t``: the strongest ``order_step`` finding of the base
residual (its ``located_time``) and every named effect's time parameter with an interval
(``shift_time_s``)::

    python benchmarks/change_coverage.py --seed 6390 --n 10 [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from helpers import WHERE, shift_arcs_record  # noqa: E402

from encdesign.diagnose._dispatch import diagnose  # noqa: E402
from encdesign.diagnose.engine._located import in_interval  # noqa: E402


def located(doc: dict) -> list[tuple[str, dict]]:
    """``(what, located_time)`` of the record's located times: the first ``order_step``
    finding of the base residual, then each effect's time parameters with an interval."""
    out = []
    for f in doc.get("findings_before") or []:
        if f.get("view") == "order_step" and f.get("located_time"):
            out.append(("order_step", f["located_time"]))
            break
    for e in doc.get("effects") or []:
        for k, p in (e.get("params") or {}).items():
            if isinstance(p, dict) and "interval_s" in p and "run" in p:
                out.append((f"{e['name']}.{k}", {**p, "t_s": p["value"]}))
    return out


def main(argv: list[str] | None = None) -> int:
    """Run one seed; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=6390)
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--only", type=int, default=None, help="run only record i")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    rows = []
    for i in range(args.n) if args.only is None else [args.only]:
        rec, truth = shift_arcs_record(np.random.default_rng([args.seed, 44, 23, i]), WHERE[i % 3])
        t0 = time.process_time()
        doc = diagnose(rec).doc
        names = [e["name"] for e in doc["effects"]]
        for what, lt in located(doc):
            ok = in_interval(lt, truth["t_s"], truth["run"])
            iv = [round(float(x), 4) for x in lt["interval_s"]]
            rows.append(
                dict(
                    i=i,
                    what=what,
                    covered=bool(ok),
                    t_s=float(lt["t_s"]),
                    run=int(lt["run"]),
                    interval_s=iv,
                    interval_runs=list(lt["interval_runs"]),
                    truth_s=truth["t_s"],
                    truth_run=truth["run"],
                    where=truth["where"],
                )
            )
            print(
                i,
                truth["where"],
                what,
                "in " if ok else "OUT",
                f"truth {truth['t_s']:.4f} (run {truth['run']})",
                f"located {float(lt['t_s']):.4f} (run {lt['run']}) {iv} runs {lt['interval_runs']}",
                flush=True,
            )
        print(
            i,
            doc["verdict"],
            names,
            f"{time.process_time() - t0:.1f} s CPU",
            truth["desc"],
            flush=True,
        )
    for what in ("order_step", "effects"):
        sel = [r for r in rows if (r["what"] == "order_step") == (what == "order_step")]
        n_in = sum(r["covered"] for r in sel)
        print(f"seed {args.seed} {what}: {n_in} / {len(sel)} within the interval", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"seed": args.seed, "n": args.n, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
