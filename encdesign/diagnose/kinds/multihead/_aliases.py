"""Shaft orders a sampled line can be at one speed, aliases included (issue 44).

At one steady speed a line fixed in time and a rotation-locked error at shaft order ``m`` are
the same samples when ``m`` times the turning frequency, folded by the sampling, lands on the
line. The nearest integer to the apparent order is one such ``m``; the catalog's orders far
above the base model are others: ``interpolation_error``'s ``L`` and ``2 L`` (``L`` signal
periods per turn) fold to any apparent frequency. A line there is that order until the data
show otherwise (two speeds separate them).
"""

from __future__ import annotations

import numpy as np

from ...engine._candidates import Context


def sample_interval_s(ctx: Context) -> float | None:
    """The sampling interval (s) of the kept rows: the median step of ``t`` within a run
    (``None`` without two rows of a run in sequence)."""
    t = np.asarray(ctx.rows["t"], float)
    run = np.argmax(np.asarray(ctx.rows["run_onehot"], float), axis=1)
    dt = np.diff(t)[(np.diff(run) == 0) & (np.diff(t) > 0)]
    return float(np.median(dt)) if dt.size else None


def folded_hz(f_hz: float, interval_s: float) -> float:
    """The apparent frequency (Hz, ``0 … fs / 2``) of a line at ``f_hz`` sampled every
    ``interval_s``."""
    fs = 1.0 / interval_s
    return float(abs(f_hz - fs * round(f_hz / fs)))


def catalog_orders_at(ctx: Context, f_hz: float, speed_rad_s: float, tol_hz: float) -> list[int]:
    """The catalog's rotation-locked orders above the base model (``L``, ``2 L`` of the
    signal periods) that the sampling folds onto a line at apparent ``f_hz`` within
    ``tol_hz``, at the steady ``speed_rad_s``."""
    L = int(ctx.signal_periods)
    dt = sample_interval_s(ctx)
    if L <= 0 or dt is None or speed_rad_s <= 0:
        return []
    f_rot = speed_rad_s / (2 * np.pi)
    return [m for m in (L, 2 * L) if abs(folded_hz(m * f_rot, dt) - f_hz) <= tol_hz]
