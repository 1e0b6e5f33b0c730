"""Deeper checks of ``sds`` recordings, run by ``load_recording`` for every ``sds`` file.

Sensor ids declared in the TOML, mark indices in range, no missing edge within a sensor's
sequence, strictly increasing times per sensor, one ``phi_ref`` per run. Plain NumPy: this
module sits below :mod:`encdesign.io._recording` and imports no physics.
"""

from __future__ import annotations

import re

import numpy as np

from .._errors import input_error
from ._table import row_at

# ----------------------------------------------------------------------------- checks


def sensor_counts(meta: dict) -> tuple[int, int, int]:
    enc = meta["encoder"]
    return (
        int(enc["marks_per_rev"]),
        len(enc["fixed_sensor_angles_deg"]),
        len(enc["moving_sensor_angles_deg"]),
    )


def _sensor_index(ids: np.ndarray, n_fixed: int) -> np.ndarray:
    """Sensor id -> 0…F−1 (fixed), F…F+M−1 (moving); −1 when malformed."""
    out = np.full(len(ids), -1, dtype=np.int64)
    for s in np.unique(ids):
        m = re.fullmatch(r"([fm])(\d+)", str(s))
        if m is None:
            continue
        out[ids == s] = int(m.group(2)) + (n_fixed if m.group(1) == "m" else 0)
    return out


def check_sds_columns(where: str, meta: dict, cols: dict) -> None:
    """Deeper checks of an ``sds`` table (registered for kind ``sds``).

    Raises:
        EncdesignInputError: naming the file, line and column and what was expected.
    """
    n_marks, n_fixed, n_moving = sensor_counts(meta)
    sensors = cols["sensor"]
    allowed = [f"f{i}" for i in range(n_fixed)] + [f"m{i}" for i in range(n_moving)]
    ok = np.isin(sensors, allowed)
    if not np.all(ok):
        i = int(np.flatnonzero(~ok)[0])
        raise input_error(
            f"{where}, {row_at(where, i)}, column 'sensor'",
            f"sensor {str(sensors[i])!r} is not declared in the TOML",
            f"one of {', '.join(allowed)} (fixed_sensor_angles_deg lists {n_fixed}, "
            f"moving_sensor_angles_deg lists {n_moving})",
        )
    mark = cols["mark"]
    bad = np.flatnonzero((mark < 0) | (mark >= n_marks))
    if bad.size:
        i = int(bad[0])
        raise input_error(
            f"{where}, {row_at(where, i)}, column 'mark'",
            f"mark index {int(mark[i])} out of range",
            f"0 … {n_marks - 1} (marks_per_rev = {n_marks})",
        )
    run = cols.get("run", np.zeros(len(mark), dtype=np.int64))
    # per run when each run's rows are contiguous (as written by simulate and by benches):
    # the sort and difference temporaries then scale with one run, not the whole table
    cuts = np.flatnonzero(run[1:] != run[:-1]) + 1
    starts = np.concatenate([[0], cuts])
    if np.unique(run[starts]).size == starts.size:
        bounds = list(zip(starts.tolist(), [*cuts.tolist(), len(mark)]))
    else:
        bounds = [(0, len(mark))]
    for lo, hi in bounds:
        _check_sequences(where, n_marks, n_fixed, n_moving, sensors, mark, cols["t"], run, lo, hi)
    if "phi_ref" in cols:
        phi = cols["phi_ref"]
        for r in np.unique(run):
            idx = np.flatnonzero(run == r)
            vals = phi[idx]
            if np.any(vals != vals[0]):
                j = int(idx[np.flatnonzero(vals != vals[0])[0]])
                raise input_error(
                    f"{where}, {row_at(where, j)}, column 'phi_ref'",
                    f"phi_ref changes within run {int(r)} "
                    f"({float(vals[0])!r} then {float(phi[j])!r})",
                    "one platform angle per run (the platform is at rest during a run)",
                )


def _check_sequences(
    where: str,
    n_marks: int,
    n_fixed: int,
    n_moving: int,
    sensors_all: np.ndarray,
    mark_all: np.ndarray,
    t_all: np.ndarray,
    run_all: np.ndarray,
    lo: int,
    hi: int,
) -> None:
    """Strictly increasing times and consecutive marks per sensor and run, rows lo..hi."""
    sensors, mark, run = sensors_all[lo:hi], mark_all[lo:hi], run_all[lo:hi]
    sidx = _sensor_index(sensors, n_fixed)
    _, run_id = np.unique(run, return_inverse=True)
    group = run_id * (n_fixed + n_moving) + sidx
    order = np.argsort(group, kind="stable")
    g = group[order]
    same = g[1:] == g[:-1]
    t = t_all[lo:hi][order]
    dt = np.diff(t)
    badt = np.flatnonzero(same & (dt <= 0))
    if badt.size:
        a, b = lo + int(order[badt[0]]), lo + int(order[badt[0] + 1])
        raise input_error(
            f"{where}, {row_at(where, b)}, column 't'",
            f"time of sensor {sensors_all[b]} goes backwards or repeats "
            f"({float(t[badt[0]])!r} at {row_at(where, a)}, "
            f"then {float(t[badt[0] + 1])!r}) within run {int(run_all[b])}",
            "strictly increasing edge times for each sensor within a run",
        )
    mk = mark[order]
    step = np.mod(np.diff(mk), n_marks)
    badm = np.flatnonzero(same & (step != 1))
    if badm.size:
        a, b = lo + int(order[badm[0]]), lo + int(order[badm[0] + 1])
        missing = int((step[badm[0]] - 1) % n_marks)
        raise input_error(
            f"{where}, {row_at(where, b)}, column 'mark'",
            f"sensor {sensors_all[b]} jumps from mark {int(mk[badm[0]])} "
            f"({row_at(where, a)}) to mark "
            f"{int(mk[badm[0] + 1])} in run {int(run_all[b])}: {missing} edge(s) missing"
            if missing
            else f"sensor {sensors_all[b]} repeats mark {int(mk[badm[0]])} "
            f"in run {int(run_all[b])}",
            "every edge of a revolution, mark indices increasing by one (mod marks_per_rev)",
        )
