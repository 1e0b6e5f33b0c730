"""Issue 43: a long record reduced to block means before the engine sees it.

A record of more than ``FinderSettings.reduce_min_rows`` rows (of a kind in
:data:`REDUCIBLE_KINDS`) is cut into blocks of ``B`` consecutive rows on a fixed grid (rows
``[k B, (k + 1) B)`` of the record, counted from its first row); a block that would cross a
run, a gap in ``t`` (a step over ``GAP_STEPS`` sampling intervals), a reversal of the shaft
or a jump of a reading over half a turn (the start of a new *stretch*) is left out, and so are
the last ``N mod B`` rows. Each block kept becomes one row holding the mean of every column
(the run its own); the rows left out (fewer than ``2 B`` per stretch) are counted. The grid
does not depend on where a stretch starts, so a record split into shares (row groups,
processes: :mod:`._reduce_stream`) is cut into the same blocks whatever the split.
The engine then runs on ``N / B`` rows; its noise estimate, taken from the reduced rows, is
the block mean's (``sigma / sqrt(B)`` for white noise), so the weights
follow without a correction.

The error is bounded and stated: the mean of ``B`` rows multiplies a sinusoid of frequency
``f`` by ``D = sin(pi f B dt) / (B sin(pi f dt))`` (:func:`attenuation`; ``1 - D`` is
``(B^2 - 1) (pi f dt)^2 / 6`` to leading order). ``B`` is the largest block for which the
highest frequency any view or candidate needs is attenuated by at most
``FinderSettings.reduce_attenuation_max``: the highest order the views scan on the base of
the declared order (:func:`scan_orders_reached`, session 27: not the orders the base could
grow to) times the fastest shaft rate, and ``FinderSettings.reduce_line_hz`` (the band of
lines in Hz kept within the bound). The block keeps every order up to ``orders_kept``
(:func:`orders_kept`) within the bound; a growth of the base whose views would scan past it
stops the engine, and the record is reduced again with the block for every order the base
can grow to (:mod:`._reduce_restart`; ``reduced.restart`` in the JSON), so no order or
line that a view tested is attenuated past the bound. Orders
``L`` and ``2 L`` of the signal period (``interpolation_error``, the ``line_phase`` view) are
far above that band: a reduced record cannot test them, and its diagnosis says so
(``not_testable``). When ``B`` comes out below 2 the record is left as it is
(``reduced.applied`` false, with the reason).

Session 32: stage 2 (:mod:`._decimate`, a FIR low-pass and decimation of the block means)
follows where it can (a factor of 2 or more, :data:`MIN_ROWS_OUT` rows left); the block then
takes half of ``reduce_attenuation_max`` (``block_attenuation_max``) and the filter the rest.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ...io._recording import Recording
from ._settings import FinderSettings

REDUCIBLE_KINDS = ("multihead",)
"""Kinds whose observations are smooth functions of the block's mean angle and time (the
quadrature kind's raw signals, the sds and motion kinds' fine structure are not)."""

GAP_STEPS = 1.5
"""A time step over this many median sampling intervals ends a stretch (a gap)."""

SPEED_QUANTILE = 0.99
"""The fastest shaft rate is this quantile of ``|d shaft / dt|`` over the rows (a glitch or
a count jump cannot set it)."""

RATE_OVER_NEEDED = 3.0
"""Stage 2 (:mod:`._decimate`): the output rate is at least this multiple of
``f_needed_hz`` (the transition band, from ``f_needed_hz`` to ``rate_out - f_needed_hz``,
at least ``f_needed_hz`` wide)."""

MIN_ROWS_OUT = 4096
"""Stage 2 is not applied where it would leave fewer rows than this (the engine's folds,
spectra and segments want rows)."""

PASS_ROWS = 1 << 20
"""Rows per slice of the reduction's passes (bounded temporary memory)."""


def scan_orders_reached(default_order: int, grows: bool, settings: FinderSettings) -> int:
    """Highest integer order the engine can scan on a record from a base of
    ``default_order``: with ``grows``, the base grows at most twice (to the orders the views
    find, each time up to twice its order or ``scan_order_min``); the views scan twice the
    final order (at least ``scan_order_min``)."""
    o = int(default_order)
    for _ in range(2 if grows else 0):
        o = max(2 * o, settings.scan_order_min)
    return max(2 * o, settings.scan_order_min)


def attenuation(f_hz: float, dt: float, B: int) -> float:
    """``1 - D``: how much the mean of ``B`` rows sampled every ``dt`` s attenuates a
    sinusoid of ``f_hz`` Hz (``D = sin(pi f B dt) / (B sin(pi f dt))``, the Dirichlet
    kernel; ``(B^2 - 1) (pi f dt)^2 / 6`` to leading order)."""
    x = math.pi * f_hz * dt
    if B <= 1 or x == 0.0:
        return 0.0
    return 1.0 - math.sin(B * x) / (B * math.sin(x))


def _longest_block(f_hz: float, dt: float, tol: float, B_max: int) -> int:
    """The longest block (rows, at most ``B_max``) whose mean attenuates ``f_hz`` by at most
    ``tol`` (:func:`attenuation`): from the leading order, then checked exactly."""
    x = math.pi * f_hz * dt
    if not (dt > 0 and x > 0):
        return 1
    B = max(1, min(B_max, int(math.sqrt(1.0 + 6.0 * tol / x**2))))
    while B > 1 and attenuation(f_hz, dt, B) > tol:
        B -= 1
    while B < B_max and attenuation(f_hz, dt, B + 1) <= tol:
        B += 1
    return B


def orders_kept(rate: float, dt: float, B: int, tol: float, least: int) -> int | None:
    """The highest integer order (at least ``least``, which the block was chosen for) whose
    frequency at the fastest shaft rate ``rate`` (rev/s) the mean of ``B`` rows sampled every
    ``dt`` s attenuates by at most ``tol`` (:func:`attenuation`); ``None`` for a shaft that
    does not turn (no order has a frequency)."""
    if not (math.isfinite(rate) and rate > 0 and dt > 0 and B > 1):
        return None
    # from the leading order (1 - D = (B^2 - 1) x^2 / 6, at most the exact 1 - D), then
    # checked exactly; 1 - D grows with f up to the kernel's first zero, far above tol
    x = math.sqrt(6.0 * tol / (B * B - 1.0))
    m = max(int(least), int(x / (math.pi * dt * rate)))
    while m > least and attenuation(m * rate, dt, B) > tol:
        m -= 1
    while attenuation((m + 1) * rate, dt, B) <= tol:
        m += 1
    return m


def decimation_factor(fs_in: float, f_need: float, settings: FinderSettings) -> int:
    """Stage 2's decimation factor ``R`` (:mod:`._decimate`) for rows at ``fs_in`` Hz: the
    largest integer with ``fs_in / R`` at least :data:`RATE_OVER_NEEDED` x ``f_need`` (Hz),
    at most ``settings.reduce_decimation_max``."""
    if not (fs_in > 0 and f_need > 0):
        return 1
    R = int(fs_in / (RATE_OVER_NEEDED * f_need))
    return max(1, min(int(settings.reduce_decimation_max), R))


def _staged(n: int, B: int, dt: float, f_need: float, settings: FinderSettings) -> bool:
    """Whether stage 2 (:mod:`._decimate`) can follow blocks of ``B`` rows of a record of
    ``n`` rows sampled every ``dt`` s: a factor of 2 or more, and at least
    :data:`MIN_ROWS_OUT` rows left (before the stretches' edges)."""
    if not dt > 0:
        return False
    R = decimation_factor(1.0 / (B * dt), f_need, settings)
    return R > 1 and n // (B * R) >= MIN_ROWS_OUT


def _angle_columns(rec: Recording) -> list[str]:
    cols = list(rec.head_columns)
    return [*cols, "theta_ref"] if "theta_ref" in rec.columns else cols


def shaft_of(cols: dict, heads: list[str]) -> np.ndarray:
    """The shaft angle of rows ``cols``: ``theta_ref``, or the heads' mean without it."""
    if "theta_ref" in cols:
        return np.asarray(cols["theta_ref"], float)
    return np.mean([np.asarray(cols[h], float) for h in heads], 0)


def step_stats(t: np.ndarray, shaft: np.ndarray) -> tuple[float, float]:
    """``(median time step, SPEED_QUANTILE of |shaft step|)`` of consecutive rows (nan
    where none is finite)."""
    dtt = np.diff(np.asarray(t, float))
    ok = np.isfinite(dtt) & (dtt > 0)
    dsh = np.abs(np.diff(shaft))
    fin = np.isfinite(dsh) & (dsh < math.pi)
    return (
        float(np.median(dtt[ok])) if ok.any() else math.nan,
        float(np.quantile(dsh[fin], SPEED_QUANTILE)) if fin.any() else math.nan,
    )


def stretch_starts(cols: dict, angles: list[str], shaft: np.ndarray, dt: float) -> np.ndarray:
    """A flag per row of ``cols`` (consecutive rows; the first is flagged) that starts a new
    stretch: a new run, a time step off the sampling interval, a jump of a reading by half a
    turn or more, a reversal of the shaft."""
    n = len(shaft)
    start = np.zeros(n, bool)
    start[0] = True
    s = start[1:]
    if "run" in cols:
        s |= np.diff(np.asarray(cols["run"])) != 0
    s |= ~(np.abs(np.diff(np.asarray(cols["t"], float))) <= GAP_STEPS * dt)
    for c in angles:
        s |= ~(np.abs(np.diff(np.asarray(cols[c], float))) < math.pi)
    sg = np.where(s, 0.0, np.sign(np.diff(shaft)))  # a step across a boundary has no direction
    prev = np.concatenate([[0.0], sg[:-1]])
    s |= (sg * prev) < 0  # a reversal
    return start


def _slices(rec: Recording):
    """``(lo, b, cols)`` per slice of :data:`PASS_ROWS` rows, each starting one row early
    (its first step joins it to the slice before); ``cols`` are views of the columns."""
    n = rec.n_rows
    for a in range(0, n, PASS_ROWS):
        lo, b = max(a - 1, 0), min(n, a + PASS_ROWS)
        yield lo, b, {c: rec.columns[c][lo:b] for c in rec.columns}


def _boundaries(rec: Recording) -> tuple[np.ndarray, float, float]:
    """``(starts, dt, rate)``: a flag per row that starts a new stretch
    (:func:`stretch_starts`), the median sampling interval (s) and the fastest shaft rate
    (rev/s, :data:`SPEED_QUANTILE`), in slices of :data:`PASS_ROWS` rows."""
    angles = _angle_columns(rec)
    stats = [step_stats(part["t"], shaft_of(part, rec.head_columns)) for *_, part in _slices(rec)]
    dt = float(np.nanmedian([d for d, _ in stats]))
    rates = [r for _, r in stats if np.isfinite(r)]
    rate = float(np.max(rates)) / dt / (2 * math.pi) if rates else 0.0
    start = np.zeros(rec.n_rows, bool)
    for lo, b, part in _slices(rec):
        st = stretch_starts(part, angles, shaft_of(part, rec.head_columns), dt)
        start[lo + 1 : b] = st[1:]
    start[0] = True
    return start, dt, rate


def plan_for(
    kind: str,
    n: int,
    default_order: int,
    grows: bool,
    settings: FinderSettings,
    steps: Callable[[], tuple[float, float]],
    grown: bool = False,
) -> dict:
    """The ``reduced`` entry of a record of kind ``kind`` and ``n`` rows (without
    ``block_rows`` when it is not reduced for its kind or size); ``steps``: a function that
    returns the record's ``(dt, rate)`` (s, rev/s), called only when they are needed. The
    block keeps the orders the views scan on the base of ``default_order``; with ``grown``
    (a restart, :mod:`._reduce_restart`) every order the base can grow to (``grows``)."""
    tol = float(settings.reduce_attenuation_max)
    out: dict = {"applied": False, "rows": int(n), "min_rows": int(settings.reduce_min_rows)}
    if kind not in REDUCIBLE_KINDS:
        out["reason"] = f"kind {kind!r} is not reduced (only {', '.join(REDUCIBLE_KINDS)})"
        return out
    if n <= settings.reduce_min_rows:
        out["reason"] = (
            f"{n} rows, at most FinderSettings.reduce_min_rows = {settings.reduce_min_rows}"
        )
        return out
    dt, rate = steps()
    M = scan_orders_reached(default_order, grows and grown, settings)
    f_need = max(M * rate, float(settings.reduce_line_hz))
    # stage 2 (_decimate, a FIR and decimation) takes half the bound where it can apply
    B = _longest_block(f_need, dt, 0.5 * tol, int(settings.reduce_min_rows))
    staged = B > 1 and _staged(n, B, dt, f_need, settings)  # (else the block as before)
    if not staged:
        B = _longest_block(f_need, dt, tol, int(settings.reduce_min_rows))
    out.update(
        block_rows=B,
        dt_s=dt,
        shaft_rate_max_rev_s=rate,
        planned_for="every order the base can grow to"
        if grows and grown
        else f"the views' scan of the base of order {int(default_order)}",
        base_grows=bool(grows),
        planned_for_growth=bool(grows and grown),
        orders_needed=int(M),
        orders_kept=orders_kept(rate, dt, B, tol, M),
        line_band_hz=float(settings.reduce_line_hz),
        f_needed_hz=f_need,
        attenuation_max=tol,
        block_attenuation_max=0.5 * tol if staged else tol,
        attenuation_at_f_needed=attenuation(f_need, dt, B),
        bound="the mean of B rows sampled every dt multiplies a sinusoid of frequency f by "
        "D = sin(pi f B dt) / (B sin(pi f dt)) (its phase at the block's mean time); 1 - D "
        "grows with f, and at the highest frequency needed (orders_needed x "
        "shaft_rate_max_rev_s, and line_band_hz) it is at most attenuation_max "
        "(FinderSettings.reduce_attenuation_max); so it is at every order up to orders_kept, "
        "and a base grown so that the views would scan past orders_kept restarts the "
        "diagnosis on the block planned for every order the base can grow to (restart)",
    )
    if B < 2:
        out["reason"] = (
            f"a block of 2 rows attenuates {f_need:.4g} Hz by more than "
            f"FinderSettings.reduce_attenuation_max = {tol:g} at {1 / dt:.4g} Hz sampling"
        )
        return out
    out["applied"] = True
    return out


def plan(
    rec: Recording, default_order: int, grows: bool, settings: FinderSettings, grown: bool = False
) -> dict:
    """Whether and how ``rec`` is reduced: the JSON entry ``reduced`` of the diagnosis
    (``applied``, ``block_rows``, the bound, the frequencies it covers, the reason), with the
    row flags ``_starts`` (removed before the document); ``grown``: :func:`plan_for`."""
    found: dict = {}

    def steps() -> tuple[float, float]:
        found["starts"], dt, rate = _boundaries(rec)
        return dt, rate

    out = plan_for(rec.kind, rec.n_rows, default_order, grows, settings, steps, grown)
    if out["applied"]:
        out["_starts"] = found["starts"]
    return out


def signal_period_tests(meta: dict, info: dict) -> dict:
    """``meta`` of the reduced record: without the signal period (its orders ``L``, ``2 L``
    are averaged out), and ``info["not_testable"]`` saying so."""
    meta = dict(meta)
    enc = dict(meta.get("encoder", {}))
    L = int(enc.get("signal_periods_per_rev", enc.get("grating_lines", 0)) or 0)
    if L > 0:
        info["not_testable"] = [
            {
                "name": "interpolation_error",
                "reason": f"orders L = {L} and 2L of the signal period are averaged out by "
                f"blocks of {info['block_rows']} rows (the reduced record keeps "
                f"{info['f_needed_hz']:.4g} Hz)",
                "rule": "reduce_attenuation_max",
            }
        ]
        for k in ("signal_periods_per_rev", "grating_lines"):
            enc.pop(k, None)
    meta["encoder"] = enc
    return meta


def full_blocks(starts: np.ndarray, B: int) -> np.ndarray:
    """Which blocks of ``B`` consecutive rows (``starts``: the rows' stretch-start flags, a
    whole number of blocks) hold one stretch: no row but a block's first starts one."""
    return np.logical_not(starts.reshape(-1, B)[:, 1:].any(1))


def block_means(v: np.ndarray, B: int, full: np.ndarray, first: bool = False) -> np.ndarray:
    """The means of the blocks ``full`` (:func:`full_blocks`) of column ``v`` (a whole
    number of blocks of ``B`` rows), or with ``first`` their first values (the run). Each
    block's mean is the same bits wherever it lies in ``v`` (a contiguous row of the kept
    blocks, reduced on its own), so any split of the record gives the same means."""
    m = np.asarray(v).reshape(-1, B)
    if first:
        return m[full, 0]
    # every block's mean, then the kept ones: no copy of the kept rows (issue 43, the read's
    # memory traffic); a block's mean is its own row's reduction either way
    means = m.mean(1)
    return means if full.all() else means[full]


def reduce_recording(rec: Recording, info: dict) -> Recording:
    """The record of block means ``info`` plans (:func:`plan`); ``info`` gains the counts
    (``reduced_rows``, ``rows_left_out``, ``stretches``) and ``not_testable``."""
    B = int(info["block_rows"])
    starts = info.pop("_starts")
    n = rec.n_rows
    end = n // B * B  # the last n mod B rows make no whole block
    step = max(PASS_ROWS // B, 1) * B  # slices of whole blocks (bounded temporaries)
    cuts = [(a, min(a + step, end)) for a in range(0, end, step)]
    keep = [full_blocks(starts[a:b], B) for a, b in cuts]
    n_blocks = int(sum(int(k.sum()) for k in keep))
    cols: dict[str, np.ndarray] = {}
    for name, col in rec.columns.items():
        first = name == "run"
        out = np.empty(n_blocks, np.asarray(col[:1]).dtype if first else float)
        at = 0
        for (a, b), full in zip(cuts, keep):
            v = np.asarray(col[a:b]) if first else np.asarray(col[a:b], float)
            m = block_means(v, B, full, first)
            out[at : at + m.size] = m
            at += m.size
        cols[name] = out
    info.update(
        reduced_rows=n_blocks,
        rows_left_out=int(n - n_blocks * B),
        stretches=int(np.count_nonzero(starts)),
    )
    meta = signal_period_tests(rec.meta, info)
    return Recording(rec.kind, meta, cols, path=rec.path)
