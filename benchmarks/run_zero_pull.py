"""Diagnosis (issue 44 C): on heads without a reference on part of a turn, does the change
pull the runs' angle zeros of the base?

Records of ``tests/helpers.shift_arcs_record`` (record ``i`` of seed ``S`` from
``default_rng([S, 44, 23, i])``, as ``benchmarks/change_coverage.py``; ``--test S``: the
record ``tests/test_order_step_part_turn.shift_record(S)``). Per record:

* the finder's fitted ``run_angle_offset_rad`` against the truth's (``run_zeros_rad``: the
  runs' head constants' means, the head-mean shaft angle's zero), wrapped to (-pi, pi];
* whether the ``order_step`` view's located change holds the truth;
* the chi-square of the base alone, refitted linearly on the head-projected readings (a
  constant per run and head, the disk orders ``1..M`` of the truth) as each later run's
  zero moves over a grid (the others at the truth), without and with the shift's two
  columns at the true time: its minimum, where it lies, and its value at the true zero.

A run zero that the base alone puts away from the truth while the base with the step puts
it at the truth is pulled by the step: the change of the disk error's order 1 between runs
(or within one) is partly mimicked by rotating a run's disk error, and the ``order_step``
view, which projects out only the zero's tangent at the fitted value, cannot undo a pull of
radians::

    python benchmarks/run_zero_pull.py --seed 7740 --only 7
    python benchmarks/run_zero_pull.py --test 7620
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from helpers import WHERE, shift_arcs_record  # noqa: E402

from encdesign.diagnose._dispatch import diagnose  # noqa: E402
from encdesign.diagnose.engine._located import in_interval  # noqa: E402

GRID = 720
"""Grid points of a run zero over one turn."""


def wrap(x):
    """Angles (rad) wrapped to (-pi, pi]."""
    return (np.asarray(x, float) + np.pi) % (2 * np.pi) - np.pi


def base_chi2(rec, truth, zeros: np.ndarray, step: bool) -> float:
    """Chi-square of the head-projected readings (the head mean removed per row) after a
    linear fit of a constant per run and head and the disk orders ``1..M`` (the truth's
    ``M``) at the head-mean shaft angle plus the run zeros ``zeros`` (R - 1,) (rad); with
    ``step``, also the shift's ``sin, cos (theta - alpha_k)`` from the true time on."""
    cols = rec.columns
    H = truth["desc"]["H"]
    y = np.stack([np.asarray(cols[f"h{k}"], float) for k in range(H)], 1)
    run = np.asarray(cols["run"], int)
    t = np.asarray(cols["t"], float)
    al = np.radians(np.asarray(rec.meta["encoder"]["head_angles_deg"], float))
    R = int(run.max()) + 1
    th = y.mean(1) + np.concatenate([[0.0], zeros])[run]
    P = y - y.mean(1, keepdims=True)
    B = [
        ((run == r)[:, None] & (np.arange(H) == k)[None, :]).astype(float)
        for r in range(R)
        for k in range(H)
    ]
    arg = th[:, None] - al[None, :]
    for m in range(1, truth["desc"]["M"] + 1):
        B += [np.sin(m * arg), np.cos(m * arg)]
    if step:
        on = (t >= truth["t_s"])[:, None]
        B += [on * np.sin(arg), on * np.cos(arg)]
    A = np.stack([(b - b.mean(1, keepdims=True)).ravel() for b in B], 1)
    res = P.ravel() - A @ np.linalg.lstsq(A, P.ravel(), rcond=None)[0]
    return float(res @ res) / truth["desc"]["noise"] ** 2


def profile(rec, truth) -> list[str]:
    """Per later run: the base's chi-square over its zero, without and with the step."""
    z0 = np.asarray(truth["run_zeros_rad"], float)
    grid = np.linspace(-np.pi, np.pi, GRID, endpoint=False)
    out = []
    for r in range(z0.size):
        for step in (False, True):
            vals = []
            for x in grid:
                z = z0.copy()
                z[r] = x
                vals.append(base_chi2(rec, truth, z, step))
            k = int(np.argmin(vals))
            at = base_chi2(rec, truth, z0, step)
            out.append(
                f"  run {r + 1} zero, {'with' if step else 'without'} the step: chi2 min "
                f"{vals[k]:.1f} at {wrap(grid[k] - z0[r]):+.3f} rad from the truth, "
                f"{at:.1f} at the truth"
            )
    return out


def one(rng, where: str, label: str) -> None:
    """Diagnose one record and print its run zeros and profiles."""
    rec, truth = shift_arcs_record(rng, where)
    t0 = time.process_time()
    doc = diagnose(rec).doc
    cpu = time.process_time() - t0
    lt = next(
        (
            f["located_time"]
            for f in doc.get("findings_before") or []
            if f.get("view") == "order_step" and f.get("located_time")
        ),
        None,
    )
    base = doc["base"]["terms"].get("base", {})
    fz = np.asarray(base.get("run_angle_offset_rad", {}).get("value", []), float)
    err = wrap(fz - truth["run_zeros_rad"]) if fz.size else np.zeros(0)
    state = (
        "none" if lt is None else ("in" if in_interval(lt, truth["t_s"], truth["run"]) else "OUT")
    )
    print(
        label,
        where,
        truth["desc"],
        f"order_step {state}",
        f"located {lt['t_s']:.4f}" if lt else "",
        f"truth {truth['t_s']:.4f}",
        f"fitted zero - truth {np.round(err, 4).tolist()} rad",
        f"{cpu:.1f} s CPU",
        flush=True,
    )
    for line in profile(rec, truth):
        print(line, flush=True)


def main(argv: list[str] | None = None) -> int:
    """Run one seed's records; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--only", type=int, default=None, help="run only record i")
    ap.add_argument("--test", type=int, default=None, help="shift_record(S) of the test")
    args = ap.parse_args(argv)
    if args.test is not None:
        s = args.test
        one(np.random.default_rng([s, 44, 22]), WHERE[s % 3], f"test {s}")
        return 0
    for i in range(args.n) if args.only is None else [args.only]:
        one(np.random.default_rng([args.seed, 44, 23, i]), WHERE[i % 3], f"{args.seed}/{i}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
