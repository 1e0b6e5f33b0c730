"""Located steps as rivals, for stage 4 (:mod:`._select`): a step located where nothing in
the catalog changes (no reversal, no change of speed) is the alternative a candidate must
beat (:func:`beaten_by_step`); its time is refined on the model (:func:`refine_step`) and
reported where it was located (:func:`place_step_refusals`)."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np

from ._candidates import Candidate, Param
from ._fit import FitResult, Fitter, Term, make_term
from ._located import change_chi2, interval_of, located_time, profile_scan
from ._protocol import Prepared
from ._stats_pass import drive, drive_many
from ._steps_near import off_change
from ._tangent import tangent_terms


def frozen(terms: list[Term]) -> list[Term]:
    """Copies with the nonlinear parameters held (trial fits: one matrix product each)."""
    out = []
    for t in terms:
        t2 = t.copy()
        for q in t.cand.params:
            if not q.linear:
                t2.free[q.name][...] = False
        out.append(t2)
    return out


def _step_fn(p: dict, x: dict):
    on = jnp.where(x["tau"] >= p["tau_s"], 1.0, 0.0) * (x["run_onehot"] @ p["run_sel"])
    return p["size"] * on[:, None] * p["channel_sel"][None, :]


STEP_NUISANCE = Candidate(
    name="located_step",
    fn=_step_fn,
    params=(
        Param("size", "unit of y", scale=None, description="size of the step"),
        Param("tau_s", "s", linear=False, fit=False, description="global time of the step"),
        Param("run_sel", "1", shape="runs", linear=False, fit=False),
        Param("channel_sel", "1", shape="channels", linear=False, fit=False),
    ),
    explanation="a step located in time (no catalog effect: the alternative a candidate "
    "must beat where the time view located a step)",
)
"""A step of one size on the channels of a located step, from its row on within its run."""


def at_change(
    prep: Prepared, r: int, tau0: float, fit=None, channels: np.ndarray | None = None
) -> bool | None:
    """Whether a step at ``tau0`` (end-to-end time, s) in run index ``r`` lies within
    ``settings.step_change_rows`` kept rows (or 1/64 of the run) of a kept row where the
    direction or the steady speed changes (a reversal or a speed change; the non-steady
    rows between them, e.g. an excluded dwell, left out: a reversal inside it counts);
    ``None`` when it is not inside the run's kept rows. ``fit`` (``(fitter, terms)``, with
    the step's ``channels``): a step more than ``step_change_rows`` from the change but
    within 1/64 of the run is settled on that model (:func:`._steps_near.off_change`: a
    step off the change that fits better is not at it; issue 44, session 24)."""
    rows = np.flatnonzero((prep.run == r) & prep.keep)
    i = int(np.searchsorted(prep.rows.take("tau", rows), tau0))
    if i <= 0 or i >= rows.size:
        return None
    d = np.asarray(prep.rows.take("direction", rows), float)
    w = np.asarray(prep.rows.take("omega", rows), float)
    ch_rows = (
        np.flatnonzero(
            (d[1:] != d[:-1])
            | (
                np.abs(w[1:] - w[:-1])
                > prep.settings.speed_change_min * np.maximum(np.abs(w[1:]), np.abs(w[:-1]))
            )
        )
        + 1
    )
    near = max(prep.settings.step_change_rows, rows.size // 64)
    if not (ch_rows.size and np.min(np.abs(ch_rows - i)) <= near):
        return False
    if (
        fit is None
        or channels is None
        or np.min(np.abs(ch_rows - i)) <= prep.settings.step_change_rows
    ):
        return True
    chi2_of = step_chi2_at(fit[0], prep, fit[1], r, rows, channels)
    return not off_change(chi2_of, prep.settings, rows.size, i, ch_rows, near)


def step_chi2_at(
    fitter: Fitter, prep: Prepared, terms: list[Term], r: int, rows: np.ndarray, channels
) -> Callable[[np.ndarray], np.ndarray]:
    """``chi2_of(idx)``: the chi-square of the model ``terms`` (held) plus a step on
    ``channels`` of run index ``r`` from each of its kept rows ``rows[idx]`` on, one
    linear column each (:meth:`._fit.Fitter.column_chi2`)."""
    held = frozen(terms)
    tau = prep.rows.take("tau", rows)
    sel = np.zeros(prep.ctx.n_runs)
    sel[r] = 1.0

    def chi2_of(idx: np.ndarray) -> np.ndarray:
        steps = [
            step_term(prep, dict(tau_s=float(tau[j]), channels=channels, run_sel=sel)) for j in idx
        ]
        return fitter.column_chi2(held, steps)

    return chi2_of


def free_steps(prep: Prepared, findings: list, at_changes: bool = False, fit=None) -> list[dict]:
    """Steps the time view located at a time where nothing the catalog knows changes.

    A direction offset (backlash, hysteresis) is a step at a reversal and a reading delay a
    step where the speed changes: a located step within ``settings.step_change_rows`` kept rows (or
    half a time-view block, 1/64 of the run) of a kept row where the direction or the
    steady speed changes is left to those terms. The others are steps no smooth term (a
    drift, a scale error, an order) can make; each is returned with its time, run and
    channels. ``at_changes``: only the steps at such a change instead (``at_change`` set),
    the alternative a drift in time must beat as well (``s9-nuis``:
    ``_nuisances.drifts_in_time``). ``fit``: ``(fitter, terms)``, the model so far, which
    settles a step near a change (:func:`at_change`)."""
    out = []
    for f in findings:
        if f.view != "time" or not (
            f.detail.get("shape") == "step" or f.detail.get("step_significant")
        ):
            continue
        if len(out) >= 2:
            break
        r = int(np.flatnonzero(prep.run_ids == f.where["runs"][0])[0])
        tau0 = float(f.detail["global_step_time_s"])
        ch = np.zeros(prep.n_channels)
        ch[list(f.where["heads"])] = 1.0
        near = at_change(prep, r, tau0, fit, ch)
        if near is None or near != at_changes:
            continue
        sel = np.zeros(prep.ctx.n_runs)
        sel[r] = 1.0
        out.append(dict(tau_s=tau0, run=r, channels=ch, run_sel=sel, finding=f))
        out[-1]["at_change"] = at_changes
    return out


_NO_STEP = (
    "it cannot make a step there (no reversal, no change of speed at that time)",
    "a slow drift in time cannot make the step at that reversal or change of speed",
)


def step_term(prep: Prepared, step: dict) -> Term:
    tm = make_term(
        STEP_NUISANCE,
        prep,
        {"tau_s": step["tau_s"], "run_sel": step["run_sel"], "channel_sel": step["channels"]},
    )
    tm.scale["size"][...] = float(np.mean(prep.sigma))
    return tm


def beaten_by_step(
    fitter: Fitter,
    prep: Prepared,
    current: FitResult,
    fr: FitResult,
    steps: list[dict],
    cache: dict,
) -> tuple[str, Any] | None:
    """``(why, the step's finding)`` when a candidate ``fr`` (current model plus the
    candidate) is refused for a located step it cannot make, or ``None``: fitted together
    with the step, the step still earns its place and the candidate no longer does
    (information criterion or held-out)."""
    if not steps:
        return None
    N = prep.n_values
    logn = math.log(max(N, 2))
    k = max(fr.n_determined(len(fr.terms) - 1), 0)
    base_terms = frozen(current.terms)
    cand = frozen(fr.terms[-1:])
    first = _first_fits(fitter, prep, base_terms, cand, steps, cache)
    for st in steps:
        key = _step_key(st)
        f = st["finding"]
        for attempt in range(2):
            if attempt == 0:
                both = first[key]
            else:
                with_cand = fitter.fit_steps([*base_terms, step_term(prep, st), *cand])
                if key not in cache:  # the step alone and with the candidate side by side:
                    # the second sums its own columns beside the first's pass (drive_many)
                    alone = fitter.fit_steps([*base_terms, step_term(prep, st)])
                    cache[key], both = drive_many([alone, with_cand])
                else:
                    both = drive(with_cand)
            fs = cache[key]
            if fr.chi2 - both.chi2 < prep.settings.bic_min + logn:
                break  # with the candidate there is no step left: it makes it
            dchi = fs.chi2 - both.chi2
            dbic = -(dchi - k * logn)
            dho = fs.heldout_chi2 - both.heldout_chi2
            if dbic > -prep.settings.bic_min or dho < prep.settings.heldout_min:
                heads = [prep.kd.channel_names[h] for h in f.where["heads"]]
                return (
                    f"a step located at t = {f.detail['step_time_s']:.6g} s (run "
                    f"{f.where['runs'][0]}, {', '.join(heads)}) explains what it explains: "
                    f"fitted with that step it lowers chi-square by {dchi:.1f} only (dBIC "
                    f"{dbic:.1f}, held-out {dho:.1f}); " + _NO_STEP[bool(st.get("at_change"))],
                    f,
                )
            if attempt:
                break
            # the step still leaves it something: a step placed a few rows off leaves a box
            # a smooth term takes part of; the step's row from base + step fits, once
            rkey = ("refined", key)
            if rkey not in cache:
                g = dataclasses.replace(f, where=dict(f.where), detail=dict(f.detail))
                refine_step(fitter, prep, current.terms, g)
                st2 = dict(st, tau_s=g.detail["global_step_time_s"], finding=g)
                cache[rkey] = st2
            st2 = cache[rkey]
            if st2["tau_s"] == st["tau_s"]:
                break
            if at_change(
                prep, st["run"], st2["tau_s"], (fitter, current.terms), st["channels"]
            ) != bool(st.get("at_change")):
                # placed on the model, the step moved to (or off) a reversal or change of
                # speed: it is no longer the step this rule is about (issue 44 E)
                return None
            st, f = st2, st2["finding"]
            key = _step_key(st)
    return None


def _step_key(st: dict) -> tuple:
    """A located step's identity in :func:`beaten_by_step`'s cache: its time, run, channels."""
    return (st["tau_s"], st["run"], tuple(st["channels"]))


def _first_fits(fitter, prep, base_terms, cand, steps: list[dict], cache: dict) -> dict:
    """The first attempt's fits of every step of :func:`beaten_by_step` side by side, one
    pass over the rows for all (issue 43; one after another, a pass per step): per step key
    the fit of the frozen model with the step and the candidate ``cand`` (frozen), and into
    ``cache`` the fit with the step alone where it is not there yet. The fits are linear
    (one pass each); each sums what it would sum alone after the others' passes
    (:func:`._stats_pass.drive_many`: a step's fit beside the first's, whose leading block,
    the frozen model, it shares, sums only its own columns; the same numbers). A step past
    one that refuses the candidate is fitted too: in the same pass, it costs its own
    columns' sums, not a pass."""
    fits, where = [], []
    for st in steps:
        key = _step_key(st)
        if any(w == ("both", key) for w in where):
            continue  # (the same step twice)
        if key not in cache and ("alone", key) not in where:
            fits.append(fitter.fit_steps([*base_terms, step_term(prep, st)]))
            where.append(("alone", key))
        fits.append(fitter.fit_steps([*base_terms, step_term(prep, st), *cand]))
        where.append(("both", key))
    first = {}
    for (what, key), got in zip(where, drive_many(fits)):
        if what == "alone":
            cache[key] = got
        else:
            first[key] = got
    return first


REFINE_STEP_SHIFTS = 3
"""Times :func:`refine_step` moves its window on when the best row is at the window's
edge (each move one window width; not a threshold: a bound on the work)."""


def refine_step(
    fitter: Fitter, prep: Prepared, terms: list[Term], f, interval: bool = False
) -> None:
    """Move a located step's time (``f``, a ``time`` finding) to the row where the model
    ``terms`` plus a step fits best: the time view's change point is read off a residual
    from which the base model has taken part of the step (and moved its change point). A
    scan of 32 rows over 4 time-view blocks (1/8 of the run) either side, then of the rows
    between the best one's neighbours (at most 48). ``interval``: then the profile of the
    model's chi-square over the step's row around it (:func:`._located.profile_scan`),
    the finding's ``located_time`` (issue 44 C)."""
    r = int(np.flatnonzero(prep.run_ids == f.where["runs"][0])[0])
    rows = np.flatnonzero((prep.run == r) & prep.keep)
    tau = prep.rows.take("tau", rows)
    ch = np.zeros(prep.n_channels)
    ch[list(f.where["heads"])] = 1.0
    # fit(terms + step at row i).chi2 for every row at once (one linear column each)
    chi2_of = step_chi2_at(fitter, prep, terms, r, rows, ch)

    def best_of(idx: np.ndarray) -> int:
        return int(idx[int(np.argmin(chi2_of(idx)))])

    # within 4 time-view blocks of the located row: a step and its mirror image about a
    # reversal differ by a function of the angle, which the base model takes (the two
    # times cannot be told apart over a turn back and forth); the located one is kept
    i0 = int(np.searchsorted(tau, f.detail["global_step_time_s"]))
    width = max(int(4 * rows.size / 32), 4)
    for _ in range(REFINE_STEP_SHIFTS + 1):
        lo, hi = max(i0 - width, 1), min(i0 + width, rows.size - 1)
        grid = np.unique(np.linspace(lo, hi, 32).astype(int))
        best = best_of(grid)
        # issue 44 C: the best row at an edge of the window that is not the run's edge: the
        # step lies beyond it (the view's change point was blocks off); move the window
        if not ((best == grid[0] and lo > 1) or (best == grid[-1] and hi < rows.size - 1)):
            break
        i0 = best
    k = int(np.searchsorted(grid, best))
    a = int(grid[max(k - 1, 0)])
    b = int(grid[min(k + 1, grid.size - 1)])
    fine = np.arange(a, b + 1)
    if fine.size > 48:
        fine = np.unique(np.linspace(a, b, 48).astype(int))
    best = best_of(fine)
    if interval:
        c = change_chi2(prep.settings.change_time_level)
        best, lo, hi = profile_scan(chi2_of, best, 1, rows.size - 1, c)
        f.located_time = located_time(prep, rows, best, lo, hi)
    t = prep.rows["t"]
    f.detail["step_time_s"] = float(t[rows[best]])
    f.detail["global_step_time_s"] = float(tau[best])
    f.detail["step_times_s"] = [float(t[rows[best - 1]]), float(t[rows[best]])]
    f.detail["placed"] = True


def place_step_refusals(prep, fitter, current, step_refusals, findings) -> list:
    """A step that refused a candidate is reported where it was located (a smooth base or
    effect fitted to it moves the change point the final residual's time view sees)."""
    done: set = set()
    for name, f in step_refusals:
        key = (tuple(f.where["runs"]), tuple(f.where["heads"]))
        if key in done:  # one refined step per run and heads: the first refusal's
            continue
        done.add(key)
        ts = f.detail["step_time_s"]
        seen = [
            g
            for g in findings
            if g.view == "time"
            and g.detail.get("shape") == "step"
            and g.where["runs"] == f.where["runs"]
            and min(g.where["times_s"]) - prep.settings.step_match_blocks * g.detail["block_s"]
            <= ts
            <= max(g.where["times_s"]) + prep.settings.step_match_blocks * g.detail["block_s"]
        ]
        if seen:  # the final residual's own step: refined with the final model
            refine_step(fitter, prep, current.terms, seen[0], interval=True)
            seen[0].where["times_s"] = list(seen[0].detail["step_times_s"])
            continue
        refine_step(fitter, prep, current.terms, f, interval=True)
        f.where["times_s"] = list(f.detail["step_times_s"])
        f.detail["shape"] = "step"
        if not any(h is f for h in findings):  # else a finding of the final residual
            f.detail["located_with"] = f"located in the residual of the model with {name}"
            findings = sorted([*findings, f], key=lambda g: g.log10_p)
    # issue 44 C: every step the final residual's time view locates is placed on the final
    # model too (the view's change point is read off a residual from which smooth terms
    # took part of the step, and may lie blocks away from it); not a step the residual's
    # order change explains better (session 26, ``_views_time.time_steps_beside_order_change``:
    # its located time is the ``order_step`` finding's)
    for g in findings:
        if (
            g.view == "time"
            and g.detail.get("shape") == "step"
            and not g.detail.get("order_change_explains")
            and (not g.detail.get("placed") or g.located_time is None)
        ):
            refine_step(fitter, prep, current.terms, g, interval=True)
            g.where["times_s"] = list(g.detail["step_times_s"])
    return findings


@functools.lru_cache(maxsize=32)
def _scaled(cand: Candidate) -> Candidate:
    """``cand`` with every parameter held and one free scale ``size``: its column at the
    held values (a profile over a held time, the rest of its shape at its fitted values)."""

    def fn(p: dict, x: dict):
        return p["size"] * cand.fn({q.name: p[q.name] for q in cand.params}, x)

    held = tuple(
        Param(q.name, q.unit, q.shape, linear=False, fit=False, scale=q.scale) for q in cand.params
    )
    return Candidate(
        name=f"{cand.name}.time_profile",
        fn=fn,
        params=(Param("size", "1", description="scale of the fitted term"), *held),
        explanation=f"{cand.name} at its fitted shape, its time moved (a profile)",
    )


@functools.lru_cache(maxsize=32)
def _sharp(cand: Candidate) -> Candidate:
    """``cand`` with its steps in time sharp: the width ``step_width_s`` (half a row's
    spacing, which the fit's gradient in the time needs) the smallest positive number, so
    a change between two rows puts every row before it before the change and every row
    after it after (issue 44 C, session 23: the smooth step put 27 % of a shift on each
    row beside the change; at a run's start that spill falls on the earlier run's last
    row, and a shift in the pause between runs was profiled a row into the later run,
    11.6 chi-square above the row after it: training ``shift_record(7623)``)."""

    def sharp(x: dict) -> dict:
        if "step_width_s" not in x:
            return x
        w = jnp.asarray(x["step_width_s"])
        return {**x, "step_width_s": jnp.zeros_like(w) + jnp.finfo(w.dtype).tiny}

    def fn(p: dict, x: dict):
        return cand.fn(p, sharp(x))

    hand, val = cand.valjac, cand.value
    return dataclasses.replace(
        cand,
        fn=fn,
        valjac=None if hand is None else (lambda p, x: hand(p, sharp(x))),
        value=None if val is None else (lambda p, x: val(p, sharp(x))),
    )


def time_param_interval(
    fitter: Fitter, prep: Prepared, terms: list[Term], idx: int, name: str
) -> dict:
    """The ``located_time`` of a parameter ``name`` of ``terms[idx]`` that is a time on the
    end-to-end axis (``Param.global_time``): the profile of chi-square over that time, at
    the midpoints between kept rows, the other terms' linear parameters refitted and the
    term's own linear parameters refitted jointly at each time (its other nonlinear ones
    held at the fitted values: :meth:`Fitter.column_chi2`; issue 44 C, session 22: with the
    shape held at the fitted time, a profile of a shift on part of a turn missed a change
    in the pause between runs), and the other terms' fitted nonlinear parameters moved to
    first order (their tangents, :mod:`._tangent`; session 23: a run's angle zero held at
    the fitted time put a shift in the pause some rows into the later run); a term with no
    free linear parameter is scaled (its shape at the fitted values, one free column). The
    interval at
    ``FinderSettings.change_time_level`` (:mod:`._located`). Where the candidate has its own
    profile (``Candidate.time_profile``) and it applies, that one."""
    term = terms[idx]
    if term.cand.time_profile is not None:
        own_lt = term.cand.time_profile(fitter, prep, terms, idx, name)
        if own_lt is not None:
            return own_lt
    rows = np.flatnonzero(prep.keep)
    tau = np.asarray(prep.rows.take("tau", rows), float)
    mid = np.concatenate([[tau[0]], 0.5 * (tau[1:] + tau[:-1])])  # change before row i
    others = [t for i, t in enumerate(terms) if i != idx]
    held = frozen(others) + tangent_terms(prep, others)
    own = [q for q in term.cand.params if q.linear and term.free[q.name].any()]
    sc = _scaled(_sharp(term.cand))
    vals = {k: np.asarray(v, float) for k, v in term.values.items()}

    def at_time(t: float):
        if not own:  # scaled
            tm = make_term(sc, prep, {**vals, name: t, "size": 1.0})
            tm.values["size"][...] = 0.0
            return tm
        tm = make_term(_sharp(term.cand), prep, {**vals, name: t})
        for q in term.cand.params:  # its own sizes free, the rest held
            tm.free[q.name] = term.free[q.name].copy() if q in own else tm.free[q.name] & False
            if q in own:
                tm.values[q.name][...] = 0.0
        return tm

    def chi2_of(ix: np.ndarray) -> np.ndarray:
        return fitter.column_chi2(held, [at_time(mid[i]) for i in ix])

    best = int(np.clip(np.searchsorted(tau, float(np.ravel(vals[name])[0])), 1, rows.size - 1))
    c = change_chi2(prep.settings.change_time_level)
    best, lo, hi = profile_scan(chi2_of, best, 1, rows.size - 1, c)
    return located_time(prep, rows, best, lo, hi)


def run_param_interval(
    fitter: Fitter, prep: Prepared, terms: list[Term], idx: int, name: str
) -> dict:
    """The ``located_time`` of a held parameter ``name`` of ``terms[idx]`` that is the index
    of the first run of a change (``Param.first_run``): the profile of chi-square over runs
    ``0 .. R - 1`` as :func:`time_param_interval` (the term at its fitted shape, scaled),
    the located time the first row of that run on the recording's own ``t``."""
    term = terms[idx]
    R = int(prep.ctx.n_runs)
    firsts = np.concatenate([[0], np.flatnonzero(np.diff(prep.run) != 0) + 1])
    held = frozen([t for i, t in enumerate(terms) if i != idx])
    sc = _scaled(term.cand)
    vals = {k: np.asarray(v, float) for k, v in term.values.items()}
    ks = np.arange(R)  # 0: the term on every run (a change before the record)
    cols = []
    for k in ks:
        tm = make_term(sc, prep, {**vals, name: float(k), "size": 1.0})
        tm.values["size"][...] = 0.0
        cols.append(tm)
    chi = fitter.column_chi2(held, cols)
    best = int(np.clip(round(float(np.ravel(vals[name])[0])), 0, R - 1))
    c = change_chi2(prep.settings.change_time_level)
    best, lo, hi = interval_of(ks, chi, c, best=best)
    return located_time(prep, firsts, best, lo, hi)
