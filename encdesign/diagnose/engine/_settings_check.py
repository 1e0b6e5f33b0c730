"""The checks of a :class:`~encdesign.diagnose.engine._settings.FinderSettings` at
construction (out of ``_settings.py``, which holds the fields and their evidence)."""

from __future__ import annotations

import dataclasses
import math

MAY_BE_ZERO = (
    "discover",
    "discover_max_aliases",
    "vibration_staircase_harmonics",
    "sds_level_common_share",
    "sds_level_common_direct",
    "sds_level_per_component",
    "sds_clock_lock_level",
)
"""Counts where 0 turns a search off, and switches (checked as integers >= 0)."""


def check_settings(s) -> None:
    """Raise ``ValueError`` naming the field when a setting is not a finite number > 0 (an
    integer >= 0 in :data:`MAY_BE_ZERO`), the
    K-fold has fewer than two folds, or the change-time level is not below 1."""
    for f in dataclasses.fields(s):
        v = getattr(s, f.name)
        if f.name in MAY_BE_ZERO:
            if not (isinstance(v, int) and v >= 0):
                raise ValueError(f"FinderSettings.{f.name}: got {v!r}, expected an integer >= 0")
            continue
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ValueError(f"FinderSettings.{f.name}: got {v!r}, expected a number > 0")
    if s.n_folds < 2:
        raise ValueError(f"FinderSettings.n_folds: got {s.n_folds}, expected >= 2")
    if s.change_time_level >= 1:
        raise ValueError(
            f"FinderSettings.change_time_level: got {s.change_time_level!r}, expected < 1"
        )
