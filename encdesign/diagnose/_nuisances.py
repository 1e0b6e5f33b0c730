"""Nuisances of measured benches (issue 22, item 4): plain functions the engine calls.

The thresholds live at the top of this module (to move into the finder's settings).
"""

from __future__ import annotations

from collections.abc import Sequence

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
