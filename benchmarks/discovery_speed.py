"""Benchmark: what discovery adds to a 4-head x 16,000-sample diagnosis (issue 41: at most
50 %). The records of ``benchmarks/diagnose.py`` (clean, a vibration) and out-of-catalog
records of ``encdesign/simulate/_outside.py`` at 5x the noise; one process, compilation
warmed up on the first record (with and without discovery).

Each record is diagnosed twice: without discovery (the engine's ``discover`` replaced by
one that models nothing) and with it. Times are CPU seconds (user + system of the process,
every thread: the number to compare on a loaded machine) and wall seconds:

* ``cpu_without_s`` / ``cpu_with_s``: the whole diagnosis;
* ``discovery_cpu_s``: discovery's own stage in the run with it;
* ``added_share_cpu``: ``discovery_cpu_s / (cpu_with_s - discovery_cpu_s)`` (the stage's
  share over the rest of the same run: no noise from a second run);
* ``added_share_cpu_runs``: ``cpu_with_s / cpu_without_s - 1`` (the two runs compared;
  biased low: the run without discovery comes first and carries the compilation for the
  record's own sizes, so this can be negative; ``added_share_cpu`` is the number)::

    python benchmarks/discovery_speed.py torque_ripple,head_defect,direction_lag --out out.json
"""

import argparse
import json
import resource
import sys
import time

sys.path.insert(0, "benchmarks")
import diagnose as BD  # noqa: E402
import discovery as B  # noqa: E402
import numpy as np  # noqa: E402

from encdesign.diagnose._dispatch import diagnose  # noqa: E402
from encdesign.diagnose.engine import _discover as D  # noqa: E402
from encdesign.diagnose.engine import _engine  # noqa: E402
from encdesign.simulate._outside import classes_for  # noqa: E402


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


_T: dict = {}


def _with(prep, fitter, terms, resid, findings):
    c0 = cpu()
    out = D.discover(prep, fitter, terms, resid, findings)
    _T["discovery_cpu_s"] = cpu() - c0
    return out


def _without(prep, fitter, terms, resid, findings):  # noqa: ARG001 - discover's contract
    return [None] * len(findings)


def _run(rec, disc) -> tuple[float, float, str]:
    _engine.discover = disc
    _T.clear()
    t0, c0 = time.perf_counter(), cpu()
    d = diagnose(rec)
    return time.perf_counter() - t0, cpu() - c0, d.verdict


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "classes",
        nargs="?",
        default="torque_ripple,head_defect,direction_lag",
        help="comma-separated out-of-catalog classes of a multihead bench (default: %(default)s)",
    )
    ap.add_argument("--out", default="benchmarks/discovery_speed.json", help="JSON written")
    ap.add_argument("--rows", type=int, default=16000, help="samples per record (4 heads)")
    ap.add_argument("--seed", type=int, default=7, help="generator seed of the outside records")
    args = ap.parse_args(argv)
    known = classes_for("multihead")
    classes = [c for c in args.classes.split(",") if c]
    if set(classes) - set(known):
        ap.error(f"unknown classes {sorted(set(classes) - set(known))}; expected {known}")
    out = []
    warm = BD._bench_recording(args.rows, 4, 5, False)
    _run(warm, _without)  # warm-up (compilation)
    _run(warm, _with)
    cases = [
        ("bench clean", lambda: BD._bench_recording(args.rows, 4, 5, False)),
        ("bench vibration", lambda: BD._bench_recording(args.rows, 4, 5, True)),
    ]
    for cls in classes:
        cases.append(
            (
                cls + " 5x",
                lambda cls=cls: B.outside_record(
                    np.random.default_rng(args.seed), cls, 5.0, "multihead", args.rows
                )[0],
            )
        )
    for name, mk in cases:
        rec = mk()
        w0, c0, v0 = _run(rec, _without)
        w1, c1, v1 = _run(rec, _with)
        dc = _T.get("discovery_cpu_s", 0.0)
        row = dict(
            case=name,
            rows=rec.n_rows,
            cpu_without_s=c0,
            cpu_with_s=c1,
            discovery_cpu_s=dc,
            added_share_cpu=dc / max(c1 - dc, 1e-9),
            added_share_cpu_runs=c1 / max(c0, 1e-9) - 1.0,
            wall_without_s=w0,
            wall_with_s=w1,
            verdict_without=v0,
            verdict=v1,
        )
        out.append(row)
        print(json.dumps(row), flush=True)
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
