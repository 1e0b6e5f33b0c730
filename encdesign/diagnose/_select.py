"""Stage 4 of the engine, **select**: forward selection of candidates with nuisance steps,
ties and the backward check."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import jax.numpy as jnp
import numpy as np

from ._candidates import Candidate, Param
from ._document import _jsonable
from ._fit import FitResult, Fitter, Term, goodness_of_fit, make_term
from ._nuisances import drifts_in_time
from ._protocol import Prepared
from ._views import locate

# ----------------------------------------------------------------------------- selection


@dataclasses.dataclass
class Step:
    """One accepted (or tried) candidate."""

    name: str
    fit: FitResult
    delta_bic: float
    delta_heldout: float
    collinearity: float
    notes: list[str]
    term_rms: float
    explained_rms: float
    confounded: list[dict] = dataclasses.field(default_factory=list)


def _tie(
    fitter: Fitter, prep: Prepared, cur_resid: np.ndarray, a: FitResult, b: FitResult
) -> tuple[float, float]:
    """``(chi-square gap, correlation)`` of two alternative fits ``a`` (chosen) and ``b``:
    how much better ``a`` fits, and the correlation of what each takes out of the current
    residual (kept rows, noise-whitened). Near 0 and near 1: the data cannot tell them."""
    keep = prep.keep
    w = 1.0 / prep.sigma[None, :]
    saa = sbb = sab = 0.0
    for lo, hi, x in fitter._chunks():  # one pass: both fits on each chunk
        ra = fitter.chunk_residual(a.terms, lo, hi, x)
        rb = fitter.chunk_residual(b.terms, lo, hi, x)
        k = keep[lo:hi]
        ca = ((cur_resid[lo:hi] - ra) * w)[k]
        cb = ((cur_resid[lo:hi] - rb) * w)[k]
        saa += float(np.sum(ca * ca))
        sbb += float(np.sum(cb * cb))
        sab += float(np.sum(ca * cb))
    den = math.sqrt(saa * sbb)
    corr = float(abs(sab) / den) if den > 0 else 0.0
    return float(b.chi2 - a.chi2), corr


def _collinearity(fit: FitResult, n_base_terms: int) -> float:
    """Largest canonical correlation between the last term's columns and the base's."""
    s0, s1 = fit.slices[-1]
    base_n = fit.slices[n_base_terms - 1][1] if n_base_terms else 0
    A = fit.A
    p = A.shape[0]
    if s1 <= s0 or base_n == 0:
        return 0.0
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d)
    b = np.arange(base_n)
    e = np.arange(s0, s1)
    Abb, Aee, Abe = An[np.ix_(b, b)], An[np.ix_(e, e)], An[np.ix_(b, e)]
    try:
        Lb = np.linalg.pinv(Abb, rcond=1e-10, hermitian=True)
        Le = np.linalg.pinv(Aee, rcond=1e-10, hermitian=True)
    except np.linalg.LinAlgError:
        return float("nan")
    M = Le @ Abe.T @ Lb @ Abe
    ev = np.linalg.eigvals(M).real
    del p
    return float(math.sqrt(min(max(ev.max(initial=0.0), 0.0), 1.0)))


def _collinear_columns(fit: FitResult, n_base_terms: int, refuse: float) -> np.ndarray:
    """Local indices (in the last term's free vector) to hold so that the rest of the term
    has a canonical correlation with the base model's columns of at most
    ``settings.collinear_refuse``: greedily, the column best explained by the base and the columns
    kept so far first."""
    s0, s1 = fit.slices[-1]
    base_n = fit.slices[n_base_terms - 1][1] if n_base_terms else 0
    if s1 <= s0 or base_n == 0:
        return np.zeros(0, int)
    A = fit.A
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    An = A / np.outer(d, d)
    b = np.arange(base_n)
    Lb = np.linalg.pinv(An[np.ix_(b, b)], rcond=1e-10, hermitian=True)
    keep = list(range(s0, s1))
    held: list[int] = []
    for _ in range(s1 - s0):
        e = np.asarray(keep)
        Aee, Abe = An[np.ix_(e, e)], An[np.ix_(b, e)]
        Le = np.linalg.pinv(Aee, rcond=1e-10, hermitian=True)
        ev = np.linalg.eigvals(Le @ Abe.T @ Lb @ Abe).real
        if ev.size == 0 or ev.max() <= refuse**2:
            break
        r2 = np.einsum("bj,bc,cj->j", Abe, Lb, Abe)
        j = int(np.argmax(r2))
        held.append(keep.pop(j) - s0)
        if not keep:
            break
    return np.asarray(sorted(held), int)


def _hold(term: Term, local: np.ndarray) -> Term:
    """``term`` with the free scalars at ``local`` (free-vector indices) held at zero."""
    t2 = term.copy()
    pos = 0
    local = set(int(i) for i in local)
    for q in t2.cand.params:
        m = t2.free[q.name]
        flat = m.ravel()
        v = t2.values[q.name].ravel()
        for j in np.flatnonzero(flat):
            if pos in local:
                flat[j] = False
                v[j] = 0.0
            pos += 1
        t2.free[q.name] = flat.reshape(m.shape)
        t2.values[q.name] = v.reshape(m.shape)
    return t2


def _local_names(held_term: Term, local: np.ndarray, fitted: Term) -> list[str]:
    del fitted
    names = []
    for q in held_term.cand.params:
        m = held_term.free[q.name]
        for ij in np.argwhere(~m):
            names.append(f"{q.name}{[int(v) for v in ij] if ij.size else ''}")
    del local
    return names


def _frozen(terms: list[Term]) -> list[Term]:
    """Copies with the nonlinear parameters held (trial fits: one matrix product each)."""
    out = []
    for t in terms:
        t2 = t.copy()
        for q in t.cand.params:
            if not q.linear:
                t2.free[q.name][...] = False
        out.append(t2)
    return out


def _unfrozen(terms: list[Term], like: list[Term]) -> list[Term]:
    """``terms`` with the free masks of ``like`` (same order and names)."""
    out = []
    for t, l in zip(terms, like):
        t2 = t.copy()
        t2.free = {k: v.copy() for k, v in l.free.items()}
        out.append(t2)
    return out


def _term_rms(fitter: Fitter, term: Term, prep: Prepared) -> float:
    """RMS of one term's own contribution (projected, whitened by the noise)."""
    tot = 0.0
    for a, b, x in fitter._chunks():  # chunk by chunk: nothing per row is held
        v = fitter._eval_term(term, a, b, x, jac=False)[0]
        if prep.kd.project:
            v = v - v.mean(1, keepdims=True)
        tot += float(np.sum((v[prep.keep[a:b]] / prep.sigma[None, :]) ** 2))
    C = prep.n_channels
    eff = (C - 1) / C if prep.kd.project else 1.0
    return float(np.sqrt(tot / max(prep.keep.sum() * C * eff, 1)))


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


def _free_steps(prep: Prepared, findings: list, at_changes: bool = False) -> list[dict]:
    """Steps the time view located at a time where nothing the catalog knows changes.

    A direction offset (backlash, hysteresis) is a step at a reversal and a reading delay a
    step where the speed changes: a located step within ``settings.step_change_rows`` kept rows (or
    half a time-view block, 1/64 of the run) of a kept row where the direction or the
    steady speed changes is left to those terms. The others are steps no smooth term (a
    drift, a scale error, an order) can make; each is returned with its time, run and
    channels. ``at_changes``: only the steps at such a change instead (``at_change`` set),
    the alternative a drift in time must beat as well (:func:`._nuisances.drifts_in_time`)."""
    out = []
    keep = prep.keep
    for f in findings:
        if f.view != "time" or not (
            f.detail.get("shape") == "step" or f.detail.get("step_significant")
        ):
            continue
        if len(out) >= 2:
            break
        r = int(np.flatnonzero(prep.run_ids == f.where["runs"][0])[0])
        rows = np.flatnonzero((prep.run == r) & keep)
        tau0 = float(f.detail["global_step_time_s"])
        i = int(np.searchsorted(prep.rows.take("tau", rows), tau0))
        if i <= 0 or i >= rows.size:
            continue
        # kept rows where the direction or the steady speed changes (a reversal or a speed
        # change, with the non-steady rows between them left out)
        d = np.asarray(prep.rows.take("direction", rows), float)
        w = np.asarray(prep.rows.take("omega", rows), float)
        ch_rows = (
            np.flatnonzero(
                (d[1:] != d[:-1])
                | (np.abs(w[1:] - w[:-1]) > 0.05 * np.maximum(np.abs(w[1:]), np.abs(w[:-1])))
            )
            + 1
        )
        near = max(prep.settings.step_change_rows, rows.size // 64)
        if bool(ch_rows.size and np.min(np.abs(ch_rows - i)) <= near) != at_changes:
            continue
        ch = np.zeros(prep.n_channels)
        ch[list(f.where["heads"])] = 1.0
        sel = np.zeros(prep.ctx.n_runs)
        sel[r] = 1.0
        out.append(dict(tau_s=tau0, run=r, channels=ch, run_sel=sel, finding=f))
        out[-1]["at_change"] = at_changes
    return out


_NO_STEP = (
    "it cannot make a step there (no reversal, no change of speed at that time)",
    "a slow drift in time cannot make the step at that reversal or change of speed",
)


def _step_term(prep: Prepared, step: dict) -> Term:
    tm = make_term(
        STEP_NUISANCE,
        prep,
        {"tau_s": step["tau_s"], "run_sel": step["run_sel"], "channel_sel": step["channels"]},
    )
    tm.scale["size"][...] = float(np.mean(prep.sigma))
    return tm


def _beaten_by_step(
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
    base_terms = _frozen(current.terms)
    cand = _frozen(fr.terms[-1:])
    for st in steps:
        key = (st["tau_s"], st["run"], tuple(st["channels"]))
        if key not in cache:
            cache[key] = fitter.fit([*base_terms, _step_term(prep, st)])
        f = st["finding"]
        for attempt in range(2):
            fs = cache[key]
            both = fitter.fit([*base_terms, _step_term(prep, st), *cand])
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
                _refine_step(fitter, prep, current.terms, g)
                st2 = dict(st, tau_s=g.detail["global_step_time_s"], finding=g)
                cache[rkey] = st2
            st2 = cache[rkey]
            if st2["tau_s"] == st["tau_s"]:
                break
            st, f = st2, st2["finding"]
            key = (st["tau_s"], st["run"], tuple(st["channels"]))
            if key not in cache:
                cache[key] = fitter.fit([*base_terms, _step_term(prep, st)])
    return None


def _refine_step(fitter: Fitter, prep: Prepared, terms: list[Term], f) -> None:
    """Move a located step's time (``f``, a ``time`` finding) to the row where the model
    ``terms`` plus a step fits best: the time view's change point is read off a residual
    from which the base model has taken part of the step (and moved its change point). A
    scan of 32 rows over 4 time-view blocks (1/8 of the run) either side, then of the rows
    between the best one's neighbours (at most 48)."""
    r = int(np.flatnonzero(prep.run_ids == f.where["runs"][0])[0])
    rows = np.flatnonzero((prep.run == r) & prep.keep)
    tau = prep.rows.take("tau", rows)
    ch = np.zeros(prep.n_channels)
    ch[list(f.where["heads"])] = 1.0
    sel = np.zeros(prep.ctx.n_runs)
    sel[r] = 1.0
    held = _frozen(terms)

    def chi2(i: int) -> float:
        st = dict(tau_s=float(tau[i]), channels=ch, run_sel=sel)
        return fitter.fit([*held, _step_term(prep, st)]).chi2

    # within 4 time-view blocks of the located row: a step and its mirror image about a
    # reversal differ by a function of the angle, which the base model takes (the two
    # times cannot be told apart over a turn back and forth); the located one is kept
    i0 = int(np.searchsorted(tau, f.detail["global_step_time_s"]))
    width = max(int(4 * rows.size / 32), 4)
    lo, hi = max(i0 - width, 1), min(i0 + width, rows.size - 1)
    grid = np.unique(np.linspace(lo, hi, 32).astype(int))
    best = min(grid, key=chi2)
    k = int(np.searchsorted(grid, best))
    a = int(grid[max(k - 1, 0)])
    b = int(grid[min(k + 1, grid.size - 1)])
    fine = np.arange(a, b + 1)
    if fine.size > 48:
        fine = np.unique(np.linspace(a, b, 48).astype(int))
    best = int(min(fine, key=chi2))
    t = prep.rows["t"]
    f.detail["step_time_s"] = float(t[rows[best]])
    f.detail["global_step_time_s"] = float(tau[best])
    f.detail["step_times_s"] = [float(t[rows[best - 1]]), float(t[rows[best]])]


def _order_key(f) -> int | None:
    """The integer order a finding is at (the ``orders`` view, or a spectrum line at an
    integer order), else None."""
    integer = f.view == "orders" or (f.view == "spectrum" and f.detail.get("integer_order"))
    ints = {round(o) for o in f.where.get("orders", []) if math.isfinite(o)}
    return ints.pop() if integer and len(ints) == 1 else None


def _untouched_orders(before, after, share: float) -> set:
    """Integer orders located before a candidate's fit that keep at least
    ``settings.untouched_share`` of their excess power after it."""
    p0: dict = {}
    p1: dict = {}
    for fs, acc in ((before, p0), (after, p1)):
        for f in fs:
            k = _order_key(f)
            if k is not None:
                acc[k] = acc.get(k, 0.0) + max(f.power - f.dof, 0.0)
    return {k for k, v in p0.items() if v > 0 and p1.get(k, 0.0) >= share * v}


def _refusal(name: str, rules: list[tuple[str, str]], dbic: float | None = None) -> dict:
    """A refused candidate's JSON entry: the reasons, and the name of every acceptance rule
    (a :class:`~encdesign.diagnose.FinderSettings` field or a named rule) that refused it."""
    out = {"name": name, "reason": "; ".join(r for _, r in rules), "rule": rules[0][0]}
    out["rules"] = [k for k, _ in rules]
    if dbic is not None:
        out["delta_bic"] = float(dbic)
    return out


def _applicable(prep: Prepared, candidates: Sequence[Candidate], not_testable: list) -> list:
    out = []
    for c in candidates:
        why = c.applies(prep.ctx) if c.applies else None
        if why:
            not_testable.append({"name": c.name, "reason": why, "rule": "applies"})
        else:
            out.append(c)
    return out


def _trial_fit(st, cand, current, n_base_terms, rejected, held_notes, log):
    """The full fit of one candidate from the best of its (screened) starts, or ``None``."""
    prep, fitter = st["prep"], st["fitter"]
    N = prep.n_values
    starts = cand.start(prep.ctx, st["kept_resid"](), st["findings"]) if cand.start else [{}]
    # screen the starts with the nonlinear parameters held (one linear pass each), then run
    # the full fit from the best one
    screened = []
    for s0 in starts[:4]:
        term = make_term(cand, prep, s0)
        frac = prep.settings.max_param_fraction
        if prep.n_values - current.n_params - term.n_free() < 0 or (
            current.n_params + term.n_free() > frac * N
        ):
            reason = f"more parameters than {frac:.0%} of the fitted values"
            rejected.append(_refusal(cand.name, [("max_param_fraction", reason)]))
            break
        if len(starts) > 1:
            held = _frozen([term])[0]
            fr0 = fitter.fit([*_frozen(current.terms), held])
            screened.append((fr0.chi2, term, fr0))
        else:
            screened.append((0.0, term, None))
    if not screened:
        return None
    screened.sort(key=lambda z: z[0])
    term = screened[0][1]
    if screened[0][2] is not None:
        term = _unfrozen(screened[0][2].terms[-1:], [term])[0]
    log(f"trying {cand.name}")
    best = fitter.fit([*_frozen(current.terms), term], max_steps=12)
    # columns of the candidate the base model already spans are held at zero (reported),
    # so the rest of it can still be tested
    held = _collinear_columns(best, n_base_terms, prep.settings.collinear_refuse)
    if held.size and held.size < best.terms[-1].n_free():
        t2 = _hold(best.terms[-1], held)
        best = fitter.fit([*_frozen(current.terms), t2], max_steps=12)
        held_notes[cand.name] = _local_names(t2, held, best.terms[-1])
    return best


def _sort_trials(trials: list, applicable: list) -> None:
    """By dBIC; candidates equal to rounding (the same fitted error, e.g. an offset per
    direction and a delay at one speed), wherever they stand: the catalog's order decides,
    not the last digit."""
    trials.sort(key=lambda x: x[0])
    rank = {c.name: i for i, c in enumerate(applicable)}
    g0 = 0
    while g0 < len(trials):
        tol = 1e-7 * max(1.0, abs(trials[g0][0]))
        g1 = g0 + 1
        while g1 < len(trials) and trials[g1][0] - trials[g0][0] <= tol:
            g1 += 1
        trials[g0:g1] = sorted(trials[g0:g1], key=lambda x: rank[x[1].name])
        g0 = g1


def _criterion_rules(prep, fitter, cand, fr, dbic, dho, dchi, n_base_terms) -> tuple:
    """The rules on the criterion, the held-out gain, plausibility and conditioning:
    ``([(rule, reason), ...], term_rms, explained_rms, collinearity)``."""
    s = prep.settings
    N = prep.n_values
    reasons = []
    if dbic > -s.bic_min:
        reasons.append(("bic_min", f"information criterion not lowered enough (dBIC {dbic:.1f})"))
    if dho < s.heldout_min:
        reasons.append(
            (
                "heldout_min",
                f"held-out chi-square lowered by {dho:.1f} only (needs {s.heldout_min:.0f})",
            )
        )
    term = fr.terms[-1]
    trms = _term_rms(fitter, term, prep)
    erms = math.sqrt(max(dchi, 0.0) / max(N, 1))
    if trms > s.plausible_ratio * max(erms, 1e-300) and trms > 1.0:
        reasons.append(
            (
                "plausible_ratio",
                f"implausible: its own size ({trms:.3g} noise units RMS) is over "
                f"{s.plausible_ratio:.0f}x the residual it explains ({erms:.3g})",
            )
        )
    col = _collinearity(fr, n_base_terms)
    if np.isfinite(col) and col > s.collinear_refuse:
        reasons.append(
            (
                "collinear_refuse",
                f"ill-conditioned against the base model (canonical correlation {col:.4f})",
            )
        )
    if cand.plausible is not None:
        why = cand.plausible(prep.ctx, term.values)
        if why:
            reasons.append((f"{cand.name}.plausible", f"implausible: {why}"))
    return reasons, trms, erms, col


def _located_rule(prep, fitter, cand, fr, findings, views, scan_order):
    """The rules on what the candidate leaves of the located structure: ``(rule or None,
    steps it leaves)``."""
    s = prep.settings
    p0 = sum(f.power - f.dof for f in findings)
    if p0 <= 0:
        return None, []
    after = locate(prep, fitter.residual(fr.terms), views, scan_order)
    # steps it leaves (a smooth model fitted to a step moves its change point)
    steps_left = _free_steps(prep, after)
    p1 = sum(f.power - f.dof for f in after)
    # and clear the places its own signature located (not a larger structure there that it
    # only dents, e.g. a step fitted by a drift)
    sig = set(cand.signature) or {f.view for f in findings}
    # an integer order it leaves untouched is another effect's (several effects at once
    # share the views), not structure it only dents
    left = _untouched_orders(findings, after, s.untouched_share)
    m0 = sum(f.power - f.dof for f in findings if f.view in sig and _order_key(f) not in left)
    m1 = sum(f.power - f.dof for f in after if f.view in sig and _order_key(f) not in left)
    if m0 > 0 and m1 > s.signature_left_max * m0:
        return (
            "signature_left_max",
            f"leaves {100 * m1 / m0:.0f}% of the structure its signature views "
            f"({', '.join(sorted(sig))}) located in place",
        ), steps_left
    if p1 > (1.0 - s.located_share_min) * p0:
        return (
            "located_share_min",
            f"explains only {100 * (1 - p1 / p0):.0f}% of the located structure (needs "
            f"{100 * s.located_share_min:.0f}%)",
        ), steps_left
    return None, steps_left


def _tie_entry(prep, fitter, cur_resid, chosen, cand, fr, dbic) -> dict | None:
    """A candidate the data cannot tell from the chosen one (``tie_chi2``, ``tie_corr``):
    its ``confounded_with`` entry, else ``None``."""
    s = prep.settings
    gap, corr = _tie(fitter, prep, cur_resid, chosen[1], fr)
    if not (gap < s.tie_chi2 and corr > s.tie_corr):
        return None
    return {
        "name": cand.name,
        "reason": f"the data cannot tell it from {chosen[0].name}: it fits as well "
        f"(chi-square {gap:+.1f}, needs {s.tie_chi2:.0f} to decide) and its fitted error is "
        f"the same (correlation {corr:.3f})",
        "rule": "tie_chi2",
        "delta_bic": float(dbic),
        "params": {q.name: _jsonable(fr.terms[-1].values[q.name]) for q in cand.params},
    }


def _choose(st, trials, current, accepted, n_base_terms, held_notes, rejected, step_refusals):
    """Stage 4's decision for one round: the best trial every rule accepts (with the ties
    it cannot be told from), or ``None``; every other trial is a named refusal."""
    prep, fitter = st["prep"], st["fitter"]
    s = prep.settings
    chosen = None
    step_fits: dict = {}
    for dbic, cand, fr, dho, dchi, k_new in trials:
        if k_new == 0:
            reason = (
                "confounded: all its parameters are already taken by the base model or by "
                f"{', '.join(a.name for a in accepted) or 'nothing else'} (shared orders go "
                "to the effect accepted first)"
            )
            rejected.append(_refusal(cand.name, [("identifiable", reason)]))
            continue
        reasons, trms, erms, col = _criterion_rules(
            prep, fitter, cand, fr, dbic, dho, dchi, n_base_terms
        )
        if reasons:
            rejected.append(_refusal(cand.name, reasons, dbic))
            continue
        if chosen is not None:
            tie = _tie_entry(prep, fitter, st["cur_resid"], chosen, cand, fr, dbic)
            if tie is not None:  # not decided by the criterion: reported with the chosen
                chosen[8].append(tie)
                continue
            reason = (
                f"{chosen[0].name} lowers the criterion more (dBIC {chosen[2]:.1f} vs {dbic:.1f})"
            )
            rejected.append(_refusal(cand.name, [("better_candidate", reason)], dbic))
            continue
        # it must explain a fair share of everything located, so that a larger structure it
        # cannot explain is not pinned on it through a small part of it
        rule, steps_left = _located_rule(
            prep, fitter, cand, fr, st["findings"], st["views"], st["scan_order"]
        )
        if rule is not None:
            rejected.append(_refusal(cand.name, [rule], dbic))
            continue
        # a step located where nothing in the catalog changes (no reversal, no change of
        # speed) is the alternative it must beat: a drift or a scale error only dents it
        steps = st["free_steps"] + steps_left
        if drifts_in_time(prep, cand.name):  # a drift in time makes no step at a reversal
            steps = steps + st["change_steps"]
        why = _beaten_by_step(fitter, prep, current, fr, steps, step_fits)
        if why:
            rejected.append(_refusal(cand.name, [("step_change_rows", why[0])], dbic))
            step_refusals.append((cand.name, why[1]))
            continue
        notes = []
        if held_notes.get(cand.name):
            notes.append(
                "held at zero, already spanned by the base model (canonical correlation "
                f"> {s.collinear_refuse}): {', '.join(held_notes[cand.name][:12])}"
            )
        if col > s.collinear_note:
            notes.append(
                f"nearly collinear with the base model (canonical correlation {col:.3f}): "
                "part of it could be absorbed by base parameters"
            )
        chosen = (cand, fr, dbic, dho, col, notes, trms, erms, [])
    return chosen


def _backward(prep, fitter, accepted, current, cur_resid, findings, rejected, views, scan):
    """Each named effect must still earn its place on held-out data (the others held at
    their nonlinear values: one linear refit each)."""
    without: dict[str, FitResult] = {}
    if len(accepted) <= 1:
        return current, cur_resid, findings, without
    for s in list(accepted):
        others = _frozen([t for t in current.terms if t.cand.name != s.name])
        fr = fitter.fit(others)
        without[s.name] = fr
        if fr.heldout_chi2 - current.heldout_chi2 < prep.settings.heldout_min:
            accepted.remove(s)
            reason = (
                "backward check: with the other named effects it no longer lowers the "
                "held-out residual"
            )
            rejected.append(_refusal(s.name, [("heldout_min", reason)]))
            current = fitter.fit(
                _unfrozen(fr.terms, [t for t in current.terms if t.cand.name != s.name])
            )
            cur_resid = fitter.residual(current.terms)
            findings = locate(prep, cur_resid, views, scan)
            without = {}
    return current, cur_resid, findings, without


def _place_step_refusals(prep, fitter, current, step_refusals, findings) -> list:
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
            and min(g.where["times_s"]) - 4 * g.detail["block_s"]
            <= ts
            <= max(g.where["times_s"]) + 4 * g.detail["block_s"]
        ]
        if seen:  # the final residual's own step: refined with the final model
            _refine_step(fitter, prep, current.terms, seen[0])
            seen[0].where["times_s"] = list(seen[0].detail["step_times_s"])
            continue
        _refine_step(fitter, prep, current.terms, f)
        f.where["times_s"] = list(f.detail["step_times_s"])
        f.detail["shape"] = "step"
        if not any(h is f for h in findings):  # else a finding of the final residual
            f.detail["located_with"] = f"located in the residual of the model with {name}"
            findings = sorted([*findings, f], key=lambda g: g.log10_p)
    return findings


def select(
    prep: Prepared,
    fitter: Fitter,
    base_terms: list[Term],
    candidates: Sequence[Candidate],
    views: tuple[str, ...],
    scan_order: int,
    max_effects: int = 3,
    log: Callable[[str], None] = lambda s: None,
):
    """Forward selection with refits, then a backward held-out check (stage 4)."""
    base = fitter.fit(base_terms)
    cur_resid = fitter.residual(base.terms)
    findings0 = locate(prep, cur_resid, views, scan_order)
    N = prep.n_values
    current, findings = base, findings0
    accepted: list[Step] = []
    rejected: list[dict] = []
    not_testable: list[dict] = []
    n_base_terms = len(base.terms)
    tried_names: set[str] = set()
    applicable = _applicable(prep, candidates, not_testable)
    gof0 = goodness_of_fit(prep, cur_resid, current.n_params)
    held_notes: dict[str, list[str]] = {}
    step_refusals: list[tuple[str, Any]] = []
    for _ in range(max_effects):
        seen = {f.view for f in findings}
        gof = goodness_of_fit(prep, cur_resid, current.n_params)
        if not findings and gof["passes"]:
            break
        kept: list = []  # the current residual over the kept rows, made once per round

        def kept_resid(kept=kept, r=cur_resid):
            if not kept:
                kept.append(r if prep.keep.all() else r[prep.keep])
            return kept[0]

        st = dict(
            prep=prep,
            fitter=fitter,
            findings=findings,
            kept_resid=kept_resid,
            cur_resid=cur_resid,
            views=views,
            scan_order=scan_order,
            free_steps=_free_steps(prep, findings),
            change_steps=_free_steps(prep, findings, at_changes=True),
        )
        trials = []
        for cand in applicable:
            if cand.name in {s.name for s in accepted}:
                continue
            if cand.signature and not (set(cand.signature) & seen):
                continue
            if not cand.signature and gof["passes"]:
                continue
            tried_names.add(cand.name)
            best = _trial_fit(st, cand, current, n_base_terms, rejected, held_notes, log)
            if best is None:
                continue
            dchi = current.chi2 - best.chi2
            k = best.n_determined(len(best.terms) - 1)
            dbic = -(dchi - max(k, 0) * math.log(max(N, 2)))
            dho = current.heldout_chi2 - best.heldout_chi2
            trials.append((dbic, cand, best, dho, dchi, k))
        _sort_trials(trials, applicable)
        del kept[:]
        chosen = _choose(
            st, trials, current, accepted, n_base_terms, held_notes, rejected, step_refusals
        )
        if chosen is None:
            break
        cand, fr, dbic, dho, col, notes, trms, erms, confounded = chosen
        if confounded:
            notes = [
                *notes,
                "confounded with "
                + ", ".join(c["name"] for c in confounded)
                + ": this recording cannot tell them apart; the name is only the one with "
                "the lower information criterion",
            ]
        full = fitter.fit(_unfrozen(fr.terms[:-1], current.terms) + fr.terms[-1:])
        if full.chi2 <= fr.chi2:
            fr = full
        del cur_resid, st  # (one residual held at a time)
        resid = fitter.residual(fr.terms)
        accepted.append(Step(cand.name, fr, dbic, dho, col, notes, trms, erms, confounded))
        log(f"named {cand.name}")
        current, cur_resid = fr, resid
        findings = locate(prep, cur_resid, views, scan_order)
    current, cur_resid, findings, without = _backward(
        prep, fitter, accepted, current, cur_resid, findings, rejected, views, scan_order
    )
    findings = _place_step_refusals(prep, fitter, current, step_refusals, findings)
    # shares: what each effect explains given the others
    shares = {}
    total = base.chi2 - current.chi2
    for s in accepted:
        fr = without.get(s.name)
        if fr is None:
            others = _frozen([t for t in current.terms if t.cand.name != s.name])
            fr = fitter.fit(others) if len(accepted) > 1 else base
        shares[s.name] = float((fr.chi2 - current.chi2) / total) if total > 0 else 0.0
    return dict(
        base=base,
        # the base residual again (one pass): not held through the selection
        base_resid=cur_resid if current is base else fitter.residual(base.terms),
        findings0=findings0,
        gof0=gof0,
        final=current,
        final_resid=cur_resid,
        findings=findings,
        accepted=accepted,
        rejected=rejected,
        not_testable=not_testable,
        shares=shares,
        tried=sorted(tried_names),
    )
