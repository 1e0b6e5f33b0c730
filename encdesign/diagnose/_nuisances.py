"""Nuisances of measured benches (issue 22, item 4): plain functions the engine calls.

The excluded-share threshold is set by the issue (:data:`EXCLUDED_SHARE_WARN`); the
others are :class:`~._settings.FinderSettings` fields.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

LATE_STAMPS_REASON = "late time stamps after a logger gap (buffered samples stamped on arrival)"
"""The ``excluded_segments[].reason`` of the first rows after a gap whose host time stamps
are late (:func:`late_stamp_rows`)."""


def late_stamp_rows(dt_after: np.ndarray, dt_median: float, ratio: float) -> int:
    """How many rows at the start of a stretch after a logger gap carry late time stamps.

    A logger that stamps samples with the host's clock on arrival stamps the samples it
    buffered during a stall (a gap in ``t``) all at about the same late time: the first
    intervals after the gap are much shorter than the record's sampling interval, and the
    shaft seems to jump ahead in them (speed far from steady). Those rows are the leading run
    of intervals shorter than ``ratio`` times the median interval (the row that ends the
    run is stamped on time and is kept).

    Args:
        dt_after: the time intervals (s) from the first row after the gap on.
        dt_median: the run's median sampling interval (s).
        ratio: ``FinderSettings.late_stamp_ratio``.
    """
    short = np.asarray(dt_after) < ratio * dt_median
    if short.size == 0 or not short[0]:
        return 0
    return int(short.size if short.all() else np.argmin(short))


EXCLUDED_SHARE_WARN = 1.0 / 3.0
"""Share of a record's rows left out of every fit (non-steady motion, gaps, masks, glitches)
above which the diagnosis says so prominently, with the reasons (issue 22: "excluding more
than a third of a record is reported prominently with the reason"). Set by the issue, not
tuned: a third of the rows is where the kept part no longer stands for the record."""


def excluded_share(n_rows: int, n_kept: int, excluded: Sequence[dict]) -> dict | None:
    """The prominent note on a record mostly left out of the fit, or ``None``.

    Args:
        n_rows: rows of the record. n_kept: rows kept for the fit.
        excluded: the engine's excluded stretches (``n_rows``, ``reason`` each).

    Returns:
        ``{"share", "n_rows_excluded", "threshold", "reasons": {reason: rows}, "note"}``
        when more than :data:`EXCLUDED_SHARE_WARN` of the rows are excluded.
    """
    if n_rows <= 0:
        return None
    share = 1.0 - n_kept / n_rows
    if share <= EXCLUDED_SHARE_WARN:
        return None
    reasons: dict[str, int] = {}
    for e in excluded:
        reasons[str(e["reason"])] = reasons.get(str(e["reason"]), 0) + int(e["n_rows"])
    listed = sum(reasons.values())
    if n_rows - n_kept > listed:  # glitches and rows not in any listed stretch
        reasons["other (glitches, settling)"] = n_rows - n_kept - listed
    top = sorted(reasons.items(), key=lambda kv: -kv[1])
    note = f"{share:.0%} of the record is excluded from the fit (more than a third): " + "; ".join(
        f"{why} ({k} rows)" for why, k in top
    )
    return dict(
        share=share,
        n_rows_excluded=int(n_rows - n_kept),
        threshold=EXCLUDED_SHARE_WARN,
        reasons=dict(top),
        note=note,
    )


TIME_DRIFTS = ("thermal_drift",)
"""Candidates that are a slow drift over the record when no ``temp_c`` column drives them
(the row column ``driver`` is then the time)."""


def drifts_in_time(prep, name: str) -> bool:
    """Whether candidate ``name`` is, in this record, a slow drift in time (issue 22, item
    4: ``thermal_drift`` without ``temp_c``). Such a drift makes no step at a reversal or a
    change of speed, so a step located there (left to the direction / speed terms for every
    other candidate, ``FinderSettings.step_change_rows``) is an alternative it must beat too:
    it is never a stand-in for a direction offset the catalog has no term for."""
    return name in TIME_DRIFTS and prep.ctx.consts.get("driver_name") == "time"


def _direction_word(d: float) -> str:
    return "forward" if d > 0 else "backward"


def step_context(prep, entry: dict) -> dict | None:
    """Where a located step (an ``unexplained`` entry of the ``time`` view with a step)
    lies in the motion: its time, run, and the direction of rotation before and after it,
    and whether it is at a reversal, at a change of speed or within steady motion (issue 22,
    item 4: a step in the error at a load reversal no catalog effect covers is reported
    located in time and direction).

    The change of direction or speed is looked for within the rows the selection exempts
    steps there (``max(FinderSettings.step_change_rows, kept rows / 64)``), so "at a
    reversal" here is the same judgement as there. Returns ``None`` for other entries.
    """
    det = entry.get("detail") or {}
    if entry.get("view") != "time" or not (
        det.get("shape") == "step" or det.get("step_significant")
    ):
        return None
    runs = entry["where"]["runs"]
    hit = np.flatnonzero(prep.run_ids == runs[0]) if runs else np.array([], int)
    tau0 = det.get("global_step_time_s")
    if hit.size == 0 or tau0 is None:
        return None
    rows = np.flatnonzero((prep.run == int(hit[0])) & prep.keep)
    if rows.size < 2:
        return None
    i = int(np.clip(np.searchsorted(prep.rows.take("tau", rows), float(tau0)), 1, rows.size - 1))
    d = np.asarray(prep.rows.take("direction", rows), float)
    w = np.asarray(prep.rows.take("omega", rows), float)
    near = max(prep.settings.step_change_rows, rows.size // 64)
    lo, hi = max(i - near, 1), min(i + near + 1, rows.size)
    span = np.arange(lo, hi)
    rev = span[d[span] != d[span - 1]]
    fast = np.abs(w[span] - w[span - 1]) > 0.05 * np.maximum(np.abs(w[span]), np.abs(w[span - 1]))
    spd = span[fast]
    j = int(rev[np.argmin(np.abs(rev - i))]) if rev.size else None
    if j is not None:
        at = f"at a reversal ({_direction_word(d[j - 1])} to {_direction_word(d[j])})"
    elif spd.size:
        j = int(spd[np.argmin(np.abs(spd - i))])
        at = f"at a change of speed ({abs(w[j - 1]):.4g} to {abs(w[j]):.4g} rad/s)"
    else:
        at = f"within steady {_direction_word(d[i])} motion (no reversal, no change of speed)"
    k = i if j is None else j
    return dict(
        t_s=det.get("step_time_s", tau0),
        run=runs[0],
        heads=list(entry["where"]["heads"]),
        direction_before=_direction_word(d[k - 1]),
        direction_after=_direction_word(d[k]),
        at=at,
        note=f"a step at t = {float(det.get('step_time_s', tau0)):.6g} s (run {runs[0]}) {at}",
    )
