"""Doubt rules of ``vibration`` that test the line on the data against what else makes a
line in a sampled record (issue 44).

A vibration is a line fixed in time (Hz). Two catalog structures are lines in time too:

* At one steady speed a rotation-locked error at shaft order ``m`` is a line at
  ``m f_rot``. Over whole turns the integer orders are orthogonal and the nearest one (and
  the catalog's orders far above the base that the sampling folds onto the line:
  ``interpolation_error``'s ``L``, ``2 L``) is the alternative. Over part of a turn (an arc
  of ``c`` turns) they are not: a line at apparent order ``nu`` is a sum of the integer
  orders within about ``1 / c`` of it (the arc's resolution in orders), and only the rows
  that see the same angle at other times (a return, a second pass) or another speed tell the
  line from them. :func:`locked_margin` fits those orders as the alternative.
* A quantized sensor (its readings on a value lattice of step ``q``) carries a staircase of
  period ``q`` in its own reading angle ``s``: harmonics ``k 2 pi / q`` of ``s``, which at a
  steady speed, sampled, fold to lines at any apparent frequency. The quantization term
  rebuilds ``s`` from the reading; a reading delay shifts the staircase by ``omega tau`` in
  each direction, so whatever of the staircase its fit leaves has its own phase in each run
  and direction. :func:`staircase_margin` is what the line takes beyond those harmonics.
"""

from __future__ import annotations

import math

import numpy as np

from ...engine._candidates import Context
from ._aliases import catalog_orders_at
from ._runout import _gain, split_gains

REFINE_ROUNDS = 2
""":func:`locked_margin`: finer frequency grids after the first (each 21 frequencies over +-1
step of the grid before, a tenth of its step): numerical resolution of the line's frequency
(a thousandth of a Rayleigh bin), not a decision threshold."""

NO_DOUBT = 1e9
"""The margin reported where a rule does not apply (not at one speed, no value lattice)."""


def one_speed(ctx: Context) -> float | None:
    """The steady speed (rad/s) when every kept row turns at one |speed|, else ``None``."""
    w = np.abs(np.asarray(ctx.rows["omega"], float))
    w = w[w > 0]
    if w.size and np.ptp(w) <= ctx.settings.one_speed_spread * np.max(w):
        return float(np.median(w))
    return None


def run_durations(ctx: Context) -> np.ndarray:
    """Each run's span of ``t`` (s) over the kept rows (0 for a run without rows)."""
    oh = ctx.rows["run_onehot"] > 0
    t = ctx.rows["t"]
    return np.array([np.ptp(t[oh[:, r]]) if oh[:, r].any() else 0.0 for r in range(oh.shape[1])])


def order_res(ctx: Context) -> float:
    """The span's resolution in shaft orders (``integer_order_tol`` if wider)."""
    return max(ctx.settings.integer_order_tol, 1.0 / max(float(np.sum(ctx.revolutions)), 1e-9))


def covered_turns(ctx: Context) -> float:
    """The share of the circle (turns, at most 1) the kept rows' shaft angles cover: one less
    the largest gap between them around the circle, over ``2 pi``."""
    th = np.sort(np.mod(np.asarray(ctx.rows["theta"], float), 2 * np.pi))
    if th.size < 2:
        return 0.0
    gaps = np.diff(np.concatenate([th, th[:1] + 2 * np.pi]))
    return float(1.0 - np.max(gaps) / (2 * np.pi))


def arc_orders(ctx: Context, order: float) -> list[int]:
    """The integer orders (``>= 1``) a line at apparent ``order`` is a sum of on part of a
    turn: those within the arc's resolution of it, ``1 / c - 1 / 2`` orders for an arc of
    ``c`` turns (the main lobe ``1 / c`` of a line on the arc, less the half order the
    nearest integer is within anyway: over a whole turn none but the nearest). Only where the
    kept rows pass over the arc ``arc_passes_min`` times (their travel over ``c``): seen once,
    a line and those orders are the same samples to any test on the data, and the rule stays
    silent (as before it)."""
    c = covered_turns(ctx)
    if c <= 0 or float(np.sum(ctx.revolutions)) < ctx.settings.arc_passes_min * c:
        return []
    h = 1.0 / c - 0.5
    return [m for m in range(max(1, math.ceil(order - h)), math.floor(order + h) + 1)]


def left_out_orders(ctx: Context, order: float) -> list[int]:
    """On part of a turn seen once (where :func:`arc_orders` is silent): the integer orders
    within the arc's main lobe (``1 / c`` orders for an arc of ``c`` turns) of a line at
    apparent ``order`` that the base residual showed as integer orders and the base's growth
    left out (``Context.orders_left_out``, above the base's order now). Seen once, a line
    and the orders of its lobe are the same samples; where the record itself showed those
    orders missing from the base (the growth undone because other structure, a step of the
    disk on its hub say, dominated what the views located: session 38, training seeds 6707
    and 6729 of ``benchmarks/short_arcs.py --set effects``, record 1, an eccentricity shift
    read as a vibration among disk orders 13-16 the base left out), the line is not its own
    unless it beats them."""
    c = covered_turns(ctx)
    left = [m for m in ctx.orders_left_out if m > int(ctx.max_order)]
    if not left or not 0 < c < 1 or arc_orders(ctx, order):
        return []
    return [m for m in left if abs(m - order) <= 1.0 / c]


def locked_orders(ctx: Context, order: float) -> list[int]:
    """The rotation-locked orders a line at apparent ``order`` (one speed) is tested against:
    the nearest integer (``>= 1``) and, on part of a turn, :func:`arc_orders` (or, seen
    once, :func:`left_out_orders`)."""
    m = round(order)
    arc = set(arc_orders(ctx, order)) | set(left_out_orders(ctx, order))
    return sorted(({m} if m >= 1 else set()) | arc)


def _whitened(ctx: Context, resid: np.ndarray) -> np.ndarray:
    """The residual over the noise, less each run's constant (the base's)."""
    oh = np.asarray(ctx.rows["run_onehot"], float)
    n = oh.shape[0]
    rw = np.asarray(resid, float).reshape(n, -1) / np.asarray(ctx.noise)[None, :]
    return rw - oh @ np.linalg.lstsq(oh, rw, rcond=None)[0]


def _orders_cols(th: np.ndarray, orders: list[int]) -> np.ndarray:
    """``cos m theta, sin m theta`` of every order, shape ``(n, 2 len(orders))``."""
    if not orders:
        return np.zeros((th.size, 0))
    return np.concatenate([np.stack([np.cos(m * th), np.sin(m * th)], 1) for m in orders], 1)


def _line_cols(
    t: np.ndarray, oh: np.ndarray, f_hz: float, more: np.ndarray | None = None
) -> np.ndarray:
    """A line at ``f_hz`` with its own amplitude and phase in every run, then the columns
    ``more`` where given (written in place: no joined copy, issue 43)."""
    c, s_ = np.cos(2 * np.pi * f_hz * t), np.sin(2 * np.pi * f_hz * t)
    R = oh.shape[1]
    k = 0 if more is None else more.shape[1]
    out = np.empty((t.size, 2 * R + k))
    np.multiply(c[:, None], oh, out=out[:, :R])
    np.multiply(s_[:, None], oh, out=out[:, R : 2 * R])
    if k:
        out[:, 2 * R :] = more
    return out


def locked_margin(ctx: Context, resid: np.ndarray, f_hz: float) -> tuple[float, float]:
    """``(frequency, margin)``: the line's frequency refined on a grid of +-2 Rayleigh bins
    (the spectrum's peak of a record with excluded stretches, set to zero, can split in two
    and sit a bin off: a frequency fit started there does not find the line), then, where
    the margin is measured, the line's gain on finer grids about the best
    (:data:`REFINE_ROUNDS`, each a tenth of the step before: a thousandth of a bin, a phase
    error of at most 0.003 rad over the run; session 37: on a strong line the grid's own
    step, up to 0.16 rad of phase over the run, cost the line more chi-square than the
    nearest integer order's mismatch did, and a true vibration at apparent order 811.03
    over 0.79 turn was refused as order 811, training seed 6716 of
    ``benchmarks/short_arcs.py --set effects``; the frequency returned, the fit's start,
    stays the first grid's: a start moved by the refinement flipped a one-speed sensor's
    numerical tie between ``vibration`` and ``bearing_wobble``, the same model there, fresh
    seed 6732 of ``--kinds sensor,quadrature`` record 9), and at one
    speed by how much (whitened chi-square less ``k ln N`` for its parameters) a line fixed
    in time at it beats rotation-locked errors at :func:`locked_orders` (the same phase in
    every run: ``cos m theta, sin m theta`` per channel). A line at a non-integer order
    that the record resolves beats them clearly; a rotation-locked error (any number of
    turns) or a line that the span cannot tell from one (``|order - m| * turns`` small, or
    part of a turn seen once) does not. Orders the base model has are already fitted, so
    they are refitted with the line (as the engine's trial fit does) and with each
    alternative: what the line takes beyond them is its own. :data:`NO_DOUBT` when not at
    one speed."""
    t = np.asarray(ctx.rows["t"], float)
    th = np.asarray(ctx.rows["theta"], float)
    oh = np.asarray(ctx.rows["run_onehot"], float)
    rw = _whitened(ctx, resid)
    T = float(np.max(run_durations(ctx)))
    if T <= 0:
        return f_hz, NO_DOUBT
    N = rw.size
    w = one_speed(ctx)
    orders = locked_orders(ctx, f_hz / (w / (2 * np.pi))) if w is not None else []
    in_base = [m for m in orders if m <= int(ctx.max_order)]
    beyond = [m for m in orders if m > int(ctx.max_order)]
    B = _orders_cols(th, in_base)
    g0 = _gain(rw, B) if in_base else 0.0

    def over_base(X: np.ndarray) -> float:
        return _gain(rw, np.concatenate([X, B], 1)) - g0 if in_base else _gain(rw, X)

    def grid(fs: np.ndarray) -> list:
        def sets(a: int, b: int) -> list:  # rows a:b of the base's orders, then of each line
            Bs, o, ta = B[a:b], oh[a:b], t[a:b]
            return ([Bs] if in_base else []) + [_line_cols(ta, o, float(f), Bs) for f in fs]

        # the frequency grid's gains with the rows split over the processes (split_gains, a
        # tall-skinny QR: the same on any number of processes); over the base's orders
        # refitted with the line where it has them
        gains = split_gains(t.size, sets, rw)
        gb = gains.pop(0) if in_base else 0.0
        return [(g - gb, float(f)) for g, f in zip(gains, fs)]

    step = 0.1 / T  # the first grid's: 41 frequencies over +-2 bins
    first = grid(f_hz + np.linspace(-2.0, 2.0, 41) / T)
    best = max(first)
    f_best = best[1]  # the fit's start (the fit refines it)
    if w is None or not orders:
        return f_best, NO_DOUBT
    for _ in range(REFINE_ROUNDS):  # finer grids about the best, a tenth of the step each
        fine = grid(best[1] + np.linspace(-step, step, 21))
        best = max([best, *fine])
        step /= 10.0
    g_vib = best[0]  # the line's gain at its refined frequency
    k_vib = 2 * oh.shape[1] * rw.shape[1]
    own = g_vib - k_vib * math.log(N)
    # each alternative less k ln N for its own parameters; the line must beat every one:
    # each order beyond the base alone, and all of them together (on part of a turn). In
    # the base model an order is already fitted: what the line takes beyond it is its own
    # (the alternative gains nothing, at the parameters of one order)
    alts = [[m] for m in beyond] + ([beyond] if len(beyond) > 1 else [])
    # a catalog order the sampling folds onto the line (interpolation_error's L, 2 L) is a
    # locked alternative too (issue 44), its gain taken as the line's (over the base orders
    # refitted with it)
    alts += [[mk] for mk in catalog_orders_at(ctx, f_best, w, order_res(ctx) * w / (2 * np.pi))]
    k1 = 2 * rw.shape[1]
    margin = own + k1 * math.log(N)  # no order beyond the base: the base's order alone
    for a in alts:
        margin = min(margin, own - (over_base(_orders_cols(th, a)) - k1 * len(a) * math.log(N)))
    return f_best, float(margin)


def staircase_columns(ctx: Context) -> np.ndarray | None:
    """The quantization staircase's harmonics ``k = 1 … vibration_staircase_harmonics`` at
    the sensor's own reading angle (rebuilt as the quantization term does), each with its own
    phase in every run and direction: ``(n, 4 K segments)``; ``None`` unless one sensor
    against a reference whose readings lie on a value lattice."""
    from ._reference_terms import _need_ref, _quant_lattice, smooth_reading

    K = int(ctx.settings.vibration_staircase_harmonics)
    if K < 1 or _need_ref(ctx):
        return None
    q = _quant_lattice(ctx).lsb_rad
    if q is None:
        return None
    s = smooth_reading(ctx)[3]
    run = np.argmax(np.asarray(ctx.rows["run_onehot"], float), axis=1)
    way = np.sign(np.asarray(ctx.rows["omega"], float))
    cols = []
    for r, d in sorted(set(zip(run.tolist(), way.tolist()))):
        seg = ((run == r) & (way == d)).astype(float)
        for k in range(1, K + 1):
            a = k * (2 * np.pi / float(q)) * s
            cols += [np.cos(a) * seg, np.sin(a) * seg]
    return np.stack(cols, 1)


def staircase_margin(
    ctx: Context, resid: np.ndarray, f_hz: float, stair: np.ndarray | None
) -> float:
    """The whitened chi-square a line at ``f_hz`` (its own amplitude and phase in every run)
    takes beyond the staircase's harmonics ``stair`` (:func:`staircase_columns`), less
    ``k ln N`` for its parameters; :data:`NO_DOUBT` without a staircase."""
    if stair is None:
        return NO_DOUBT
    t = np.asarray(ctx.rows["t"], float)
    oh = np.asarray(ctx.rows["run_onehot"], float)
    rw = _whitened(ctx, resid)
    X = _line_cols(t, oh, f_hz)
    g = _gain(rw, np.concatenate([X, stair], 1)) - _gain(rw, stair)
    return float(g - 2 * oh.shape[1] * rw.shape[1] * math.log(rw.size))
