"""A located step near a change of direction or speed, settled on the model (issue 44,
session 24): :func:`._steps.at_change` leaves a step to the direction / speed terms when
the time view located it within half a time-view block (kept rows / 64) of a reversal or a
speed change, the view's resolution. The view often places a step on its row; a step a
dozen rows after a reversal (e.g. after an excluded dwell) is then not a direction offset,
which changes at the reversal itself. :func:`off_change` decides it by the fit: the best
step at the change against the best step off it, the model so far held."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

OFF_CHANGE_GRID = 48
"""Rows off the change the scan tries (evenly over the window, plus the located row and
its neighbours; not a threshold: a bound on the work, as ``_steps.refine_step``'s 48)."""


def off_change(
    chi2_of: Callable[[np.ndarray], np.ndarray],
    settings,
    n: int,
    i: int,
    ch_rows: np.ndarray,
    near: int,
) -> bool:
    """Whether a step starting at kept row ``i`` (of ``n`` kept rows of its run) is a step
    off the changes ``ch_rows`` (kept-row indices of the first row after a change of
    direction or speed): a step at the best row more than ``settings.step_change_rows``
    from every change, within ``near`` rows of the located row, lowers chi-square by more
    than ``settings.step_off_change_chi2`` below the best step within ``step_change_rows``
    of a change. ``chi2_of(rows)``: the model's chi-square with a step at each of those
    kept rows (the model held: :meth:`._fit.Fitter.column_chi2`)."""
    k = settings.step_change_rows
    ch_rows = np.asarray(ch_rows, int)
    at = np.unique(np.clip(ch_rows[:, None] + np.arange(-k, k + 1)[None, :], 1, n - 1))
    lo, hi = max(i - near, 1), min(i + near, n - 1)
    grid = np.unique(
        np.concatenate([np.linspace(lo, hi, OFF_CHANGE_GRID).astype(int), [i - 1, i, i + 1]])
    )
    grid = grid[(grid >= 1) & (grid <= n - 1)]
    dist = np.min(np.abs(grid[:, None] - ch_rows[None, :]), axis=1)
    off = grid[dist > k]
    if not off.size or not at.size:
        return False
    chi = np.asarray(chi2_of(np.concatenate([at, off])), float)
    return bool(np.min(chi[: at.size]) - np.min(chi[at.size :]) > settings.step_off_change_chi2)
