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
