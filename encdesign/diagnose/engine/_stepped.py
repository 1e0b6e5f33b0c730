"""Static stepped calibrations: a sensor against a reference recorded step by step.

A stepped calibration has no steady motion: the rig moves to an angle, settles, and one row
(or a few) is logged; ``t`` may be a step index rather than seconds, and consecutive angles
may be far apart, over several turns. The engine's segment finder
(:func:`~encdesign.diagnose.engine._engine.find_motion_segments`) finds no steady segment in such
a record and the record used to be refused ("no steady segment"). Here:

* :func:`is_stepped` tells such a record (one run at a time: the motion segments cover
  fewer than ``FinderSettings.stepped_max_steady_rows`` rows of it);
* :func:`stepped_segments` gives the segments instead: one per run and approach direction
  (the sign of the last move into the row's position), so the engine's direction views and
  the ``direction_hysteresis`` candidate see both directions if the record has them;
* :func:`static_candidates` marks the dynamic candidates (fixed in Hz, driven by the speed
  or by time) as not testable, with the reason.

What is left is what a static record measures: the error function vs angle (the base
model), the direction offset (if both directions), the LSB (the value lattice), scale and
interpolation errors (functions of the angle).

The threshold is ``FinderSettings.stepped_max_steady_rows``; the caller's settings are
passed to the segment finder.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._settings import DEFAULT_SETTINGS, FinderSettings

DYNAMIC_CANDIDATES = ("vibration", "thermal_drift", "reading_delay", "bearing_wobble")
"""Candidates a stepped record cannot test: ``vibration`` is fixed in Hz, ``reading_delay``
is driven by the speed, ``thermal_drift`` without ``temp_c`` by time (``t`` may be a step
index), ``bearing_wobble`` by the shaft's continuous turning (a cage's phase is lost between
steps)."""

STATIC_REASON = (
    "a static stepped record (no steady motion; t may be a step index): no time, "
    "frequency or speed to test it on"
)
"""Reason given for each dynamic candidate on a stepped record."""


def _run_slices(run: np.ndarray) -> list[np.ndarray]:
    """Row indices of each run, in order of first appearance (rows sorted by time within)."""
    ids, first = np.unique(run, return_index=True)
    return [np.flatnonzero(run == r) for r in ids[np.argsort(first)]]


def _sorted_rows(rows: np.ndarray, t: np.ndarray) -> np.ndarray:
    return rows[np.argsort(t[rows], kind="stable")]


def is_stepped(
    shaft: np.ndarray,
    t: np.ndarray,
    run: np.ndarray,
    tolerance: float,
    window: float,
    settings: FinderSettings = DEFAULT_SETTINGS,
) -> bool:
    """Whether a record has no steady motion (``settings.stepped_max_steady_rows``).

    Args:
        shaft: shaft angle per row (rad). t: time or step index per row. run: run id per row.
        tolerance, window: the kind's ``steady_tolerance`` and ``speed_window``.
        settings: the caller's :class:`~._settings.FinderSettings` (the segment finder's
            thresholds and ``stepped_max_steady_rows``).
    """
    from ._prepare import find_motion_segments

    steady = 0
    for rows in _run_slices(run):
        rows = _sorted_rows(rows, t)
        if rows.size < 8:  # the segment finder's own minimum (it returns one segment below)
            continue
        seg, _ = find_motion_segments(shaft[rows], t[rows], tolerance, window, settings)
        steady += int((seg >= 0).sum())
        if steady >= settings.stepped_max_steady_rows:
            return False
    return True


def approach_direction(shaft: np.ndarray) -> np.ndarray:
    """+1 / -1 per row (time order): the sign of the last non-zero move into the row's
    position (rows logged at the same position share it); the rows before the first move
    take the first move's sign (+1 if nothing moves)."""
    d = np.sign(np.diff(shaft))
    out = np.concatenate([[0.0], d])
    nz = np.flatnonzero(out)
    if nz.size == 0:
        return np.ones(shaft.size)
    # forward fill of the last non-zero sign
    idx = np.zeros(shaft.size, dtype=int)
    idx[nz] = nz
    idx = np.maximum.accumulate(idx)
    out = out[idx]
    out[: nz[0]] = out[nz[0]]
    return out


def stepped_segments(shaft: np.ndarray, t: np.ndarray, run: np.ndarray) -> np.ndarray:
    """Segment id per row (>= 0) of a stepped record: one per run and approach direction
    (:func:`approach_direction`), so the engine's speed per segment carries the direction."""
    seg = np.zeros(shaft.size, dtype=np.int64)
    sid = 0
    for rows in _run_slices(run):
        rows = _sorted_rows(rows, t)
        d = approach_direction(shaft[rows])
        for s in (1.0, -1.0):
            m = d == s
            if m.any():
                seg[rows[m]] = sid
                sid += 1
    return seg


def static_candidates(cands: tuple, stepped: bool) -> tuple:
    """``cands`` with the dynamic ones (:data:`DYNAMIC_CANDIDATES`) not testable on a stepped
    record (their ``applies`` gives :data:`STATIC_REASON`); unchanged otherwise."""
    if not stepped:
        return tuple(cands)
    return tuple(
        dataclasses.replace(c, applies=_not_static) if c.name in DYNAMIC_CANDIDATES else c
        for c in cands
    )


def _not_static(ctx) -> str:
    return STATIC_REASON
