"""Discovery's ``ringdown`` modulation (issue 41, session 37): a fixed-frequency (``hz``)
line rung at the start of every run, each cell its own amplitude and phase, times
``exp(-t_in_run / T)`` with one decay time ``T`` (s) shared by the runs.

The term is linear given ``T`` (its ``ringdown`` block of the sums, :func:`ring_factor`);
``T`` itself is fitted once per line before the sums (:func:`locate_ringdowns`), as the speed
law fits its exponent: the chi-square drop of the term, jointly with the catalog model
(Frisch-Waugh, the same projection as the sums; on records longer than
``STEP_EXACT_ROWS`` rows on the residual alone, as the step scan), maximised over ``log T``
by a grid and a bounded 1-D search (scipy), and a standard error from the profile's
curvature inflated like the exponent's. The decay time counts as one more parameter in the
term's multiple-testing threshold (:attr:`Term.n_params`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from scipy import optimize

from ._discover_law import Sums, Term, _gain_in
from ._discover_lines import Line, hmap, phase_basis, tau_of

RING_RUNS_MAX = 10.0
"""Longest decay time searched, in units of the record's longest run (s per s): beyond it a
ring-down is a steady line over every run (the ``per_cell`` modulation)."""

RING_PERIODS_MIN = 1.0
"""Shortest decay time searched, in periods of the line (s per period, ``Q >= pi``): a mode
that dies within one cycle is no line."""

RING_GRID = 17
"""Decay times on the log grid the bounded 1-D search starts from (a factor of about 1.5
apart on a 2 s run of a 30 Hz line)."""


XATOL_LOG_T = 0.01
"""Tolerance of the decay time's search, in ``log T`` (1 %: well under its standard error)."""

XATOL_F = 0.002
"""Tolerance of the frequency's search, in bins (1 / the longest run)."""


def run_starts(prep) -> np.ndarray:
    """Each run's start on the end-to-end time ``tau`` (s): its first row's (kept or not)."""
    run = np.asarray(prep.run)
    tau = tau_of(prep)
    out = np.full(int(prep.ctx.n_runs), np.inf)
    np.minimum.at(out, run, tau)
    return np.where(np.isfinite(out), out, 0.0)


def ring_columns(B, th, t, tau, run, starts, ring: dict | None) -> np.ndarray:
    """The ``ringdown`` block's columns of one line (rows, n_basis): cos/sin at the
    ring-down's own frequency times ``exp(-(tau - the run's start) / T)`` (zeros: no
    ring-down at this line; ``B``: the line's own basis, for its shape)."""
    if ring is None:
        return np.zeros_like(B)
    decay = np.exp(-np.maximum(tau - starts[run], 0.0) / float(ring["tau_s"]))
    return phase_basis(Line("hz", float(ring["f_hz"])), th, t) * decay[:, None]


def _longest_run(prep) -> float:
    """The longest run's span on ``tau`` over its kept rows (s)."""
    run = np.asarray(prep.run)[prep.keep]
    tau = tau_of(prep)[prep.keep] - run_starts(prep)[run]
    out = np.zeros(int(run.max()) + 1 if run.size else 1)
    np.maximum.at(out, run, tau)
    return float(out.max())


def _search(fn: Callable[[float], float], grid: np.ndarray, xatol: float, vals=None) -> float:
    """The argument of ``fn``'s largest value: the best of ``grid`` (``vals``: ``fn`` there,
    where already known), refined by a bounded 1-D search (scipy) between its neighbours to
    ``xatol``."""
    vals = [fn(float(u)) for u in grid] if vals is None else vals
    i = int(np.argmax(vals))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    res = optimize.minimize_scalar(
        lambda u: -fn(u), bounds=(a, b), method="bounded", options={"xatol": xatol}
    )
    return float(res.x) if -float(res.fun) >= vals[i] else float(grid[i])


def locate_ringdowns(
    prep,
    lines: Sequence[Line],
    S: int,
    maps: Callable[[Line], dict[str, np.ndarray]],
    sums_at: Callable[[int, dict], Sums],
) -> list[dict | None]:
    """Per line its ring-down (``None``: not an ``hz`` line, or no run long enough):
    ``{"tau_s", "tau_se_s", "f_hz", "frame"}``. ``maps``: the line's frame maps
    (:func:`frame_maps`); ``sums_at(li, ring)``: the sums of line ``li`` alone with its
    ring-down block at ``ring``'s decay time and frequency.

    The decay time is searched over ``log T`` at the located frequency (the frame whose
    ring-down takes the most on that grid is kept for the rest); the frequency, within one
    bin (1 / the longest run) of the located one (a located bin's frequency can sit a third
    of a bin from the mode's, and over a run a line that far off beats against the
    catalog's own steady ``vibration`` where it should decay); then ``T`` again at that
    frequency, and its standard error from the profile's curvature in ``log T`` at that
    frequency, inflated by the square root of the residual's chi-square per value when above
    1 (as the speed exponent's)."""
    span = _longest_run(prep)
    out: list[dict | None] = []
    for li, ln in enumerate(lines):
        lo, hi = RING_PERIODS_MIN / max(ln.value, 1e-12), RING_RUNS_MAX * span
        if ln.kind != "hz" or not 0 < lo < hi:
            out.append(None)
            continue
        frames = maps(ln)

        def drop_at(u: float, f: float, frame: str | None, li=li, frames=frames):
            """The ring-down's best chi-square drop over the frames (or in ``frame``) at
            ``T = exp(u)`` and ``f`` Hz, that frame, and the residual's chi-square."""
            sums = sums_at(li, {"tau_s": math.exp(u), "f_hz": f})
            bl = sums.blocks.index("ringdown")
            At, bt, Rt = sums.A.sum(0), sums.b.sum(0), sums.raw.sum(0)
            best, best_fr = -np.inf, ""
            for fr, M in frames.items():
                if frame is not None and fr != frame:
                    continue
                H = hmap(sums.layout[0], bl, M, np.eye(S))
                g = _gain_in(H, At, bt, Rt)
                if g > best:
                    best, best_fr = g, fr
            return best, best_fr, float(sums.rr.sum())

        def drop(u: float, f: float, frame: str | None, drop_at=drop_at) -> float:
            return drop_at(u, f, frame)[0]

        grid = np.linspace(math.log(lo), math.log(hi), RING_GRID)
        f0 = float(ln.value)
        at_grid = [drop_at(float(u), f0, None) for u in grid]
        vals = [a[0] for a in at_grid]
        i = int(np.argmax(vals))
        fr, rr0 = at_grid[i][1], at_grid[0][2]
        u0 = _search(lambda u, fr=fr, f0=f0: drop(u, f0, fr), grid, XATOL_LOG_T, vals)
        fb = 1.0 / span if span > 0 else 0.0
        fg = f0 + fb * np.linspace(-1, 1, 9)
        f1 = _search(lambda f, u0=u0, fr=fr: drop(u0, f, fr), fg, XATOL_F * fb)
        du = grid[1] - grid[0]  # T again at that frequency, near where it was
        ug = u0 + du * np.linspace(-1, 1, 3)
        u1 = _search(lambda u, f1=f1, fr=fr: drop(u, f1, fr), ug, XATOL_LOG_T)
        h = 0.01
        g0 = drop(u1, f1, fr)
        curv = -(drop(u1 + h, f1, fr) - 2 * g0 + drop(u1 - h, f1, fr)) / h**2
        tau = math.exp(u1)
        infl = rr0 / max(prep.n_values, 1.0)
        se = tau * math.sqrt(2.0 / curv) * math.sqrt(max(infl, 1.0)) if curv > 0 else None
        out.append({"tau_s": tau, "tau_se_s": se, "f_hz": f1, "frame": fr})
    return out


def ring_json(prep, tm: Term) -> tuple[dict, dict]:
    """``(params, export)`` entries of a ``ringdown`` term: its decay time and ``Q = pi f T``
    with their standard errors, and its own frequency (fitted within a bin of the located
    line's); the decay time and the runs' starts (on ``tau``) its
    exported candidate uses (``{}``, ``{}`` for another term)."""
    if tm.decay is None:
        return {}, {}
    tau, se = float(tm.decay["tau_s"]), tm.decay["tau_se_s"]
    qf = math.pi * float(tm.decay["f_hz"])
    params = {
        "decay_time_s": tau,
        "decay_time_se_s": None if se is None else float(se),
        "q_factor": qf * tau,
        "q_factor_se": None if se is None else qf * float(se),
    }
    params["frequency_hz"] = float(tm.decay["f_hz"])
    export = {"decay_time_s": tau, "run_start_tau_s": [float(v) for v in run_starts(prep)]}
    return params, export


def ring_words(decay: dict) -> str:
    """The modulation's words: its decay time and Q with their standard errors."""
    tau, se = float(decay["tau_s"]), decay["tau_se_s"]
    qf = math.pi * float(decay["f_hz"])
    pm = "" if se is None else f" +- {se:.2g}"
    qpm = "" if se is None else f" +- {qf * se:.2g}"
    return (
        f"a mode at {float(decay['f_hz']):.4g} Hz rung at the start of every run (its own "
        f"amplitude and phase in each), decaying in "
        f"{tau:.3g}{pm} s (Q {qf * tau:.3g}{qpm}): a structural resonance (a mode) excited "
        "by the run's start"
    )
