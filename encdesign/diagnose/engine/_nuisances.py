"""Nuisances of measured benches (issue 22, item 4): plain functions the engine calls.

Every threshold is a :class:`~._settings.FinderSettings` field (the excluded share,
``excluded_share_warn``, is set by the issue).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ._settings import DEFAULT_SETTINGS, FinderSettings

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


def excluded_share(
    n_rows: int,
    n_kept: int,
    excluded: Sequence[dict],
    settings: FinderSettings = DEFAULT_SETTINGS,
) -> dict | None:
    """The prominent note on a record mostly left out of the fit, or ``None``.

    Args:
        n_rows: rows of the record. n_kept: rows kept for the fit.
        excluded: the engine's excluded stretches (``n_rows``, ``reason`` each).

    Returns:
        ``{"share", "n_rows_excluded", "threshold", "reasons": {reason: rows}, "note"}``
        when more than ``settings.excluded_share_warn`` of the rows are excluded.
    """
    if n_rows <= 0:
        return None
    share = 1.0 - n_kept / n_rows
    warn = settings.excluded_share_warn
    if share <= warn:
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
        threshold=warn,
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
    return name in TIME_DRIFTS and prep.ctx.driver_name == "time"


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
    fast = np.abs(w[span] - w[span - 1]) > prep.settings.speed_change_min * np.maximum(
        np.abs(w[span]), np.abs(w[span - 1])
    )
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


def _clusters(phi: np.ndarray, tol: float) -> list[np.ndarray]:
    """Indices of ``phi`` (rad, in [0, 2 pi)) grouped where consecutive sorted angles are
    within ``tol`` (circular: the last group joins the first across 2 pi)."""
    order = np.argsort(phi)
    p = phi[order]
    cut = np.flatnonzero(np.diff(p) > tol) + 1
    groups = [g for g in np.split(order, cut) if g.size]
    if len(groups) > 1 and p[0] + 2 * np.pi - p[-1] <= tol:
        groups = [np.concatenate([groups[-1], groups[0]]), *groups[1:-1]]
    return groups


def angle_steps(jumps: list[dict], theta: np.ndarray, settings) -> tuple[list[dict], list[dict]]:
    """Count jumps that are steps of the sensor's error function of the angle (issue 22,
    item 4: a potentiometer's track, a magnet's segment), and the jumps left.

    A channel's jumps are grouped by the shaft angle at which they occur (within
    ``FinderSettings.angle_step_tol_turns`` of a turn, or 3 rows' advance); a group is an
    angle step when it recurs on at least ``angle_step_passes`` passes with one size (the
    jump times the direction of rotation: a pass backwards crosses the step the other way,
    each within half the group's median). The groups of a channel are steps of the angle
    only together, when their sizes close over a turn (their sum within
    ``angle_step_close`` of the sum of their magnitudes): missed counts at a disk defect
    also recur at one angle but accumulate, and stay count jumps.

    Args:
        jumps: the prepared count jumps (``index``, ``channel_index``, ``size``, ...).
        theta: the angle per prepared row (rad; the reference, else the shaft).
        settings: the :class:`~._settings.FinderSettings`.

    Returns:
        ``(steps, jumps left)``; each step ``{channel_index, angle_rad, size_rad,
        passes}`` (``size_rad``: the error's change crossing the angle forwards).
    """
    if not jumps:
        return [], jumps
    step = float(np.median(np.abs(np.diff(theta)))) if theta.size > 1 else 0.0
    tol = max(2 * np.pi * settings.angle_step_tol_turns, 3 * step)
    used: set[int] = set()
    out: list[dict] = []
    for k in sorted({int(j["channel_index"]) for j in jumps}):
        mine = [q for q, j in enumerate(jumps) if int(j["channel_index"]) == k and k >= 0]
        if len(mine) < 2 * settings.angle_step_passes:
            continue
        idx = np.asarray([jumps[q]["index"] for q in mine])
        lo, hi = np.clip(idx - 1, 0, theta.size - 1), np.clip(idx + 1, 0, theta.size - 1)
        fwd = np.where(theta[hi] >= theta[lo], 1.0, -1.0)
        size = np.asarray([jumps[q]["size"] for q in mine], float) * fwd
        phi = np.mod(0.5 * (theta[lo] + theta[idx]), 2 * np.pi)  # between the two rows
        found = []
        for g in _clusters(phi, tol):
            med = float(np.median(size[g]))
            if g.size >= settings.angle_step_passes and np.all(
                np.abs(size[g] - med) <= settings.angle_step_size_tol * abs(med)
            ):
                ang = float(np.angle(np.mean(np.exp(1j * phi[g]))) % (2 * np.pi))
                found.append((g, ang, med))
        if len(found) < 2:
            continue
        total = sum(m for _, _, m in found)
        if abs(total) > settings.angle_step_close * sum(abs(m) for _, _, m in found):
            continue
        for g, ang, med in found:
            used.update(mine[i] for i in g.tolist())
            out.append(dict(channel_index=k, angle_rad=ang, size_rad=med, passes=int(g.size)))
    return out, [j for q, j in enumerate(jumps) if q not in used]
