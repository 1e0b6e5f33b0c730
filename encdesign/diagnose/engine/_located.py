"""Located times and their uncertainty (issue 44 C).

A change point (a step in time, a change of an order, a parameter that is a time) is
located by a profile: chi-square of the model with the change at each candidate row, the
other parameters refitted. Its uncertainty is the set of candidate rows whose
``delta chi2 = chi2(row) - chi2(best)`` is at most ``c``, reported as an interval of the
recording's own ``t`` with the runs its ends fall in.

The level: a change point is not a regular parameter, and ``delta chi2 <= 1`` is not a 68 %
interval. Near the true change, the log-likelihood ratio of a change ``k`` rows off is a
two-sided random walk with drift, ``W(s) - |s| / 2`` in units ``s = k delta^2`` (``delta``:
the step over the noise); its maximum on each side is exponential with mean 1, so
``P(delta chi2(truth) <= c) = (1 - exp(-c / 2))^2`` (``delta chi2 <= 1`` covers 15 %).
``c = -2 ln(1 - sqrt(level))``, ``level = FinderSettings.change_time_level``; on rows
(a discrete walk) and for large steps the interval is conservative.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

CONVENTION = (
    "profile of chi-square over the change time (the other parameters refitted): the "
    "candidate rows with delta chi2 <= c, c = -2 ln(1 - sqrt(level)) (a change point's "
    "likelihood ratio: two one-sided random walks with drift); the interval runs from the "
    "last row before the earliest such change to the first row after the latest"
)

CLOCK = "the recording's t"


def change_chi2(level: float) -> float:
    """The ``delta chi2`` bound ``c`` of a change-point interval at ``level`` (see module)."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"change_time_level: got {level!r}, expected 0 < level < 1")
    return -2.0 * math.log(1.0 - math.sqrt(level))


def interval_of(
    idx: np.ndarray, chi2: np.ndarray, c: float, best: int | None = None
) -> tuple[int, int, int]:
    """``(best, lo, hi)`` from a profile ``chi2`` at candidate indices ``idx`` (not
    necessarily contiguous): ``best`` the lowest (or the given one, an index of ``idx``),
    ``[lo, hi]`` every index within ``c`` of it, widened over the gaps of the scan (to the
    index after the nearest evaluated one outside: a conservative bound)."""
    idx = np.asarray(idx, int)
    chi2 = np.asarray(chi2, float)
    o = np.argsort(idx)
    idx, chi2 = idx[o], chi2[o]
    b = int(np.argmin(chi2)) if best is None else int(np.flatnonzero(idx == best)[0])
    inside = chi2 - chi2[b] <= c
    pos = np.flatnonzero(inside)
    a, z = int(pos.min()), int(pos.max())
    lo = int(idx[a - 1]) + 1 if a > 0 else int(idx[0])
    hi = int(idx[z + 1]) - 1 if z + 1 < idx.size else int(idx[-1])
    return int(idx[b]), min(lo, int(idx[a])), max(hi, int(idx[z]))


def scan_indices(best: int, lo: int, hi: int, near: int = 24) -> np.ndarray:
    """Candidate indices in ``[lo, hi]`` for a profile around ``best``: every index within
    ``near`` of it, then offsets growing by half each step (a bound on the work; the
    interval is widened over the gaps, :func:`interval_of`)."""
    offs = list(range(near + 1))
    d = float(near)
    while d < hi - lo:
        d = d * 1.5
        offs.append(int(d))
    o = np.asarray(offs)
    return np.unique(np.clip(np.concatenate([best - o, best + o]), lo, hi))


def profile_scan(
    chi2_of: Callable[[np.ndarray], np.ndarray], best: int, lo: int, hi: int, c: float
) -> tuple[int, int, int]:
    """``(best, lo, hi)``: the interval of a profile ``chi2_of(indices)`` scanned around
    ``best`` over ``[lo, hi]`` (once more around a better row the scan finds)."""
    idx = scan_indices(best, lo, hi)
    chi = np.asarray(chi2_of(idx), float)
    b = int(idx[int(np.argmin(chi))])
    if abs(b - best) > 24:  # the profile's best is elsewhere: scan around it too
        more = np.setdiff1d(scan_indices(b, lo, hi), idx)
        if more.size:
            idx = np.concatenate([idx, more])
            chi = np.concatenate([chi, np.asarray(chi2_of(more), float)])
    return interval_of(idx, chi, c)


def located_time(prep, rows: np.ndarray, best: int, lo: int, hi: int) -> dict:
    """The ``located_time`` entry of a change whose first row after it is ``rows[best]``
    (``rows``: kept row indices in time order, the candidates), its interval from the last
    row before ``rows[lo]`` to ``rows[hi]``: on the recording's own ``t``, with runs."""
    t = prep.rows["t"]

    def at(i: int) -> tuple[float, int]:
        j = int(rows[int(np.clip(i, 0, rows.size - 1))])
        return float(t[j]), int(prep.run_ids[prep.run[j]])

    tb, rb = at(best)
    t0, r0 = at(lo - 1)
    t1, r1 = at(hi)
    return {
        "t_s": tb,
        "run": rb,
        "interval_s": [t0, t1],
        "interval_runs": [r0, r1],
        "level": float(prep.settings.change_time_level),
        "clock": CLOCK,
        "convention": CONVENTION,
    }


def in_interval(lt: dict, t_s: float, run: int) -> bool:
    """Whether a time ``t_s`` of run ``run`` lies inside a ``located_time`` interval
    (runs ordered by their ids, each with its own clock)."""
    (t0, t1), (r0, r1) = lt["interval_s"], lt["interval_runs"]
    if not r0 <= run <= r1:
        return False
    return (run > r0 or t_s >= t0) and (run < r1 or t_s <= t1)


def describe(lt: dict) -> str:
    """One line: ``t = 4.745 s (run 1), 95 % interval [4.70, 4.79] s``."""
    (t0, t1), (r0, r1) = lt["interval_s"], lt["interval_runs"]
    lvl = f"{100 * lt['level']:.0f} %"
    if r0 == r1:
        iv = f"[{t0:.6g}, {t1:.6g}] s"
    else:
        iv = f"[{t0:.6g} s (run {r0}), {t1:.6g} s (run {r1})]"
    return f"t = {lt['t_s']:.6g} s (run {lt['run']}), {lvl} interval {iv}"


def change_row(x: np.ndarray, parts: list[np.ndarray], jb: int) -> tuple[int, np.ndarray]:
    """Row index (into the run's kept rows ``x``) of the most likely single step in ``x``,
    searched over the blocks next to block edge ``jb``: the first row after the step; and
    the chi-square a step takes out at each row ``1 .. n - 1`` (its profile)."""
    n = x.size
    lo = int(sum(p.size for p in parts[: max(jb - 1, 0)]))
    hi = int(sum(p.size for p in parts[: min(jb + 1, len(parts))]))
    cs = np.cumsum(x - x.mean())[:-1]  # S_i: sum of the first i + 1 rows
    i = np.arange(1, n, dtype=float)
    stat = cs**2 * n / (i * (n - i))
    lo, hi = max(lo, 1), min(max(hi, lo + 2), n)
    return int(lo + np.argmax(stat[lo - 1 : hi - 1])), stat


def value_in_interval(entry: dict, lt: dict) -> dict:
    """A time parameter's JSON ``entry`` (``value`` on the recording's ``t``, ``run``) given
    its profile ``lt`` (:func:`._steps.time_param_interval`): where the fitted value lies
    outside its own interval, the fit stopped on a step of chi-square away from where the
    data put the change (the profile's best is more than ``c`` lower; the time enters the
    model through a step between rows, so its gradient sees only the step's width): the
    value becomes the profile's best ``t_s`` and ``run``, the fit's kept as
    ``fitted_value`` and ``fitted_run`` (issue 44 C, session 22: generated records with a
    shift on part of a turn, ``tests/test_order_step_part_turn.py``)."""
    v = entry.get("value")
    if np.ndim(v) != 0 or "run" not in entry:
        return entry
    if in_interval(lt, float(v), int(entry["run"])):
        return entry
    return {
        **entry,
        "value": float(lt["t_s"]),
        "run": int(lt["run"]),
        "fitted_value": float(v),
        "fitted_run": int(entry["run"]),
    }
