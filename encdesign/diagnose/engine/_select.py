"""Stage 4 of the engine, **select**: forward selection of candidates with nuisance steps,
ties and the backward check."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ._candidates import Candidate
from ._change_rival import rivals_rule
from ._constants import fit_stop_tolerance
from ._dealt_fits import private
from ._document import jsonable
from ._evidence import (
    Chosen,
    Refused,
    Trial,
    alternatives_of,
    find_dominant,
    heldout_refused,
    only_doubts,
    partner_entry,
    ratio_limit,
    refused_pair,
    rule_args,
    separate_by,
    tie_gap,
    tie_reason,
)
from ._evidence import term_rms as _term_rms
from ._fit import FitResult, Fitter, Term, make_term
from ._fit_memo import remembered_fit, remembering
from ._goodness import goodness_of_fit
from ._nuisances import drifts_in_time
from ._protocol import Prepared
from ._spill import band_share, edge_beyond, kept_gain_share, same_place
from ._starts import screened_starts
from ._stats_pass import drive_many
from ._steps import beaten_by_step, free_steps, frozen, place_step_refusals
from ._timing import stage
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
    doubt: dict | None = None
    alternatives: list[dict] = dataclasses.field(default_factory=list)


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


def _unfrozen(terms: list[Term], like: list[Term]) -> list[Term]:
    """``terms`` with the free masks of ``like`` (same order and names)."""
    out = []
    for t, l in zip(terms, like):
        t2 = t.copy()
        t2.free = {k: v.copy() for k, v in l.free.items()}
        out.append(t2)
    return out


def _has_run_constants(terms: Sequence[Term]) -> bool:
    """Whether these (base) terms hold a free linear constant per run and channel."""
    return any(
        q.shape == "runs*channels" and q.linear and bool(t.free[q.name].all())
        for t in terms
        for q in t.cand.params
    )


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


def _trial_fit(st, cand, current, n_base_terms, rejected, held_notes, log, starts):
    """The full fit of one candidate from the best of its (screened) ``starts``, or
    ``None``: a generator of its fits' statistics requests (:func:`._stats_pass.drive_many`
    runs a round's trial fits side by side, one pass over the rows for all)."""
    prep, fitter = st["prep"], st["fitter"]
    N = prep.n_values
    # screen the starts with the nonlinear parameters held (one linear fit each, all side
    # by side: _starts), then run the full fit from the best one
    terms = []
    for s0 in starts[:4]:
        term = make_term(cand, prep, s0)
        frac = prep.settings.max_param_fraction
        if prep.n_values - current.n_params - term.n_free() < 0 or (
            current.n_params + term.n_free() > frac * N
        ):
            reason = f"more parameters than {frac:.0%} of the fitted values"
            rejected.append(_refusal(cand.name, [("max_param_fraction", reason)]))
            break
        terms.append(term)
    screened = [(0.0, term, None) for term in terms]
    if len(starts) > 1 and terms:
        fr0s = yield from screened_starts(fitter, frozen(current.terms), frozen(terms))
        screened = [(fr0.chi2, term, fr0) for term, fr0 in zip(terms, fr0s)]
    if not screened:
        return None
    screened.sort(key=lambda z: z[0])
    term = screened[0][1]
    if screened[0][2] is not None:
        term = _unfrozen(screened[0][2].terms[-1:], [term])[0]
    log(f"trying {cand.name}")
    best = yield from fitter.fit_steps([*frozen(current.terms), term], max_steps=12)
    # columns of the candidate the base model already spans are held at zero (reported),
    # so the rest of it can still be tested
    held = _collinear_columns(best, n_base_terms, prep.settings.collinear_refuse)
    if held.size and held.size < best.terms[-1].n_free():
        t2 = _hold(best.terms[-1], held)
        best = yield from fitter.fit_steps([*frozen(current.terms), t2], max_steps=12)
        held_notes[cand.name] = _local_names(t2, held, best.terms[-1])
    return best


def _trial_fits(st, cands: list, current, n_base_terms: int, log) -> list:
    """``(fit or None, refusals, held notes or None)`` of each candidate's trial fit, side
    by side (:func:`._stats_pass.drive_many`, on a fitter of their own) on every process,
    each pass's rows split over the processes (:mod:`._rowshare`: the base's per-chunk
    Jacobian made once per row, not on every process over every row as when the fits were
    dealt); so are the starts' (the vibration's line search, ``_runout.split_gains``)."""
    prep, resid, findings = st["prep"], st["kept_resid"], st["findings"]
    with stage("candidates"):
        starts = [c.start(prep.ctx, resid(), findings) if c.start else [{}] for c in cands]
        st2 = dict(st, fitter=private(st["fitter"]))
        refused: list[list[dict]] = [[] for _ in cands]
        notes: list[dict[str, list[str]]] = [{} for _ in cands]
        bests = drive_many(
            [
                _trial_fit(st2, c, current, n_base_terms, refused[i], notes[i], log, starts[i])
                for i, c in enumerate(cands)
            ]
        )
    return [(b, refused[i], notes[i].get(c.name)) for i, (c, b) in enumerate(zip(cands, bests))]


def _sort_trials(trials: list, applicable: list) -> None:
    """By dBIC; candidates equal to rounding (the same fitted error, e.g. an offset per
    direction and a delay at one speed), wherever they stand: the catalog's order decides,
    not the last digit."""
    trials.sort(key=lambda x: x.dbic)
    rank = {c.name: i for i, c in enumerate(applicable)}
    g0 = 0
    while g0 < len(trials):
        tol = 1e-7 * max(1.0, abs(trials[g0].dbic))
        g1 = g0 + 1
        while g1 < len(trials) and trials[g1].dbic - trials[g0].dbic <= tol:
            g1 += 1
        trials[g0:g1] = sorted(trials[g0:g1], key=lambda x: rank[x.cand.name])
        g0 = g1


def gain_rules(s, dbic: float, dho: float) -> list[tuple[str, str]]:
    """The rules on a candidate's gain, ``[(rule, reason), ...]``: ``bic_min`` on its
    information criterion change ``dbic`` and ``heldout_min`` on its held-out chi-square
    gain ``dho`` (``s``: the :class:`FinderSettings`); the selection's and the discovered
    model's re-test (:mod:`._discover_rival`) ask the same."""
    out = []
    if dbic > -s.bic_min:
        out.append(("bic_min", f"information criterion not lowered enough (dBIC {dbic:.1f})"))
    if dho < s.heldout_min:
        out.append(
            (
                "heldout_min",
                f"held-out chi-square lowered by {dho:.1f} only (needs {s.heldout_min:.0f})",
            )
        )
    return out


def _criterion_rules(prep, fitter, cand, fr, dbic, dho, dchi, n_base_terms) -> tuple:
    """The rules on the criterion, the held-out gain, plausibility and conditioning:
    ``([(rule, reason), ...], term_rms, explained_rms, collinearity)``."""
    s, N = prep.settings, prep.n_values
    reasons = gain_rules(s, dbic, dho)
    term = fr.terms[-1]
    trms = _term_rms(fitter, term, prep, _has_run_constants(fr.terms[:n_base_terms]))
    erms = math.sqrt(max(dchi, 0.0) / max(N, 1))
    if trms > (lim := ratio_limit(prep)) * max(erms, 1e-300) and trms > s.plausible_rms_min:
        reasons.append(
            (
                "plausible_ratio",
                f"implausible: its own size ({trms:.3g} noise units RMS) is over "
                f"{lim:.3g}x the residual it explains ({erms:.3g})",
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


def _reaches(f, own) -> bool:
    """Whether finding ``f`` lies where the candidate's own fitted error is located (``own``:
    the findings of that error alone): a finding of the same view at the same integer order
    (or both at none), on a head and in a run that one shows."""
    key = _order_key(f)
    for g in own:
        if g.view == f.view and _order_key(g) == key and same_place(f, g):
            return True
    return False


def own_share(findings, after, own, keep=None) -> float | None:
    """The share of the located structure a candidate explains where its own fitted error
    shows: at each place ``g`` its error alone is located (``own``, those ``keep(g)`` admits),
    the share of the excess chi-square located there before its fit (``findings``) that is
    gone after it (``after``, none below nothing), averaged over the places weighted by the
    excess chi-square of its own error there; ``None`` where its error shows at no located
    structure.

    Weighted by its own error, the share is that of its own lines: a fitted error is
    noise-free and shows, through leakage, at many places where other effects' larger
    structure lies (a line at order 84 over one turn leaks into every order near it and into
    the band view); summed over those places unweighted, the others' structure outweighs the
    candidate's own lines and the share moves with whatever else the record holds (twin
    records of one motor got opposite verdicts, issue 44 B)."""
    num = den = 0.0
    for g in own:
        w = g.power - g.dof
        if w <= 0 or (keep is not None and not keep(g)):
            continue
        a = sum(f.power - f.dof for f in findings if _reaches(f, (g,)))
        if a <= 0:
            continue
        b = sum(f.power - f.dof for f in after if _reaches(f, (g,)))
        num += w * max(1.0 - b / a, 0.0)
        den += w
    return num / den if den > 0 else None


def _located_rule(prep, fitter, cand, fr, findings, views, scan_order, current, dchi):
    """The rules on what the candidate leaves of the located structure: ``(rule or None,
    steps it leaves)``; ``current``: the model so far (its free masks), ``dchi``: the
    candidate's chi-square gain in its trial."""
    s = prep.settings
    if sum(f.power - f.dof for f in findings) <= 0:
        return None, []
    resid1 = fitter.residual(fr.terms)
    after = locate(prep, resid1, views, scan_order)
    # steps it leaves (a smooth model fitted to a step moves its change point)
    steps_left = free_steps(prep, after, fit=(fitter, fr.terms))
    # its own fitted error alone, located: where it shows (view, integer order, heads, runs)
    own = locate(prep, fitter.residual(fr.terms[:-1]) - resid1, views, scan_order)
    del resid1
    # and clear the places its own signature located (not a larger structure there that it
    # only dents, e.g. a step fitted by a drift), weighted by its own error there
    # (:func:`own_share`); where its error shows at none of them, all it leaves there counts
    sig = set(cand.signature) or {f.view for f in findings}
    # an integer order it leaves untouched is another effect's (several effects at once
    # share the views), not structure it only dents
    left = _untouched_orders(findings, after, s.untouched_share)
    cleared = own_share(findings, after, own, lambda g: g.view in sig and _order_key(g) not in left)
    if cleared is not None:
        m_left = 1.0 - cleared
    else:
        m0 = sum(f.power - f.dof for f in findings if f.view in sig and _order_key(f) not in left)
        m1 = sum(f.power - f.dof for f in after if f.view in sig and _order_key(f) not in left)
        m_left = m1 / m0 if m0 > 0 else 0.0
    if m_left > s.signature_left_max:
        return (
            "signature_left_max",
            f"leaves {100 * m_left:.0f}% of the structure its signature views "
            f"({', '.join(sorted(sig))}) located where its own fitted error shows in place",
        ), steps_left
    # the share it must explain is of the structure located where its own fitted error shows,
    # weighted by that error, not of everything located: with several effects at once the
    # others' structure is not its to explain (issue 44 B); a larger structure it only dents
    # lies where it shows, and still refuses it
    share = own_share(findings, after, own)
    if share is not None and share < s.located_share_min:
        return (
            "located_share_min",
            f"explains only {100 * share:.0f}% of the structure located where its own fitted "
            f"error shows (weighted by that error; needs {100 * s.located_share_min:.0f}%)",
        ), steps_left
    # nor the one tooth inside its orders of a comb that continues above them
    edge = edge_beyond(cand.orders, own, findings, left, _order_key)
    if edge is not None and edge[2] > dchi:
        return (
            "edge_order",
            f"its fitted error is mostly its top order {edge[0]}, and a larger located "
            f"structure it leaves continues above it (orders {', '.join(map(str, edge[1][:8]))}"
            f", excess chi-square {edge[2]:.0f} against its gain {dchi:.0f}): a piece of it",
        ), steps_left
    # nor, a line fixed in Hz, a slice of a broad band it sits in (a chirp through its
    # frequency); a set of shaft orders is tested against the orders it leaves, not a band
    band = band_share(findings, after, own) if "orders" not in cand.signature else None
    if band is not None and band[1] > dchi and band[0] < s.located_share_min:
        return (
            "located_share_min",
            f"clears only {100 * band[0]:.0f}% of the broad band its own line sits in "
            f"(excess chi-square {band[1]:.0f} against its gain {dchi:.0f}): a slice of a "
            f"broadband structure (needs {100 * s.located_share_min:.0f}%)",
        ), steps_left
    # nor a part of a larger structure it leaves: the integer orders it leaves untouched that
    # located more than its whole gain, fitted with the model, must leave it that share of its
    # gain (an order on one head moves a reference-free shaft angle: the disk error's other
    # orders show a part of it, which a beam tilt fits)
    power: dict = {}
    for f in findings:
        k = _order_key(f)
        if k in left:
            power[k] = power.get(k, 0.0) + max(f.power - f.dof, 0.0)
    larger = {k for k, v in power.items() if v > dchi}
    # and those it dents but leaves with more than its whole gain (a static order of one SDS
    # sensor, which bearing_wobble and sensor_delay_step each took a part of, session 19)
    p_after: dict = {}
    for f in after:
        k = _order_key(f)
        if k is not None:
            p_after[k] = p_after.get(k, 0.0) + max(f.power - f.dof, 0.0)
    larger = sorted(larger | {k for k, v in p_after.items() if v > dchi})
    base = _unfrozen(fr.terms[:-1], current.terms)
    kept = kept_gain_share(prep, fitter, base, fr.terms[-1], larger)
    if kept is not None and kept < s.located_share_min:
        return (
            "located_share_min",
            f"keeps only {100 * max(kept, 0.0):.0f}% of its gain once the larger structure it "
            f"leaves (orders {', '.join(map(str, larger[:8]))}) is fitted too: a part of that "
            f"structure (needs {100 * s.located_share_min:.0f}%)",
        ), steps_left
    return rivals_rule(prep, fitter, cand, findings, base, fr.terms[-1]), steps_left  # rivals


def _tie_entry(prep, fitter, cur_resid, chosen, cand, fr, dbic) -> dict | None:
    """A candidate the data cannot tell from the chosen one (``tie_chi2``, ``tie_corr``):
    its ``confounded_with`` entry, else ``None``."""
    s = prep.settings
    gap, corr = tie_gap(fitter, prep, cur_resid, chosen.fit, fr)
    if not (gap < s.tie_chi2 and corr > s.tie_corr):
        return None
    return {
        "name": cand.name,
        "reason": tie_reason(chosen.cand.name, gap, corr, dbic, chosen.dbic, s),
        "rule": "tie_chi2",
        "delta_bic": float(dbic),
        "params": {q.name: jsonable(fr.terms[-1].values[q.name]) for q in cand.params},
        "correlation": float(corr),
        "separate_by": separate_by(chosen.cand, cand, corr),
    }


def _choose(
    st, trials, current, accepted, n_base_terms, held_notes, rejected, step_refusals, confounded
):
    """Stage 4's decision for one round: the best trial every rule accepts (with the ties
    it cannot be told from), or ``None``; every other trial is a named refusal, except two
    refused by the same rule that the record cannot separate: one ``confounded`` entry."""
    prep, fitter, step_fits = st["prep"], st["fitter"], dict()
    s, dominant, partners = prep.settings, None, []
    if trials and trials[0].k_new > 0 and trials[0].dbic < -s.bic_min:
        r0 = _criterion_rules(prep, fitter, *rule_args(trials[0]), n_base_terms)[0]
        if r0 and only_doubts(trials[0].cand, r0):  # only then is dominance worth a pass
            dominant, partners = find_dominant(
                st, trials, lambda t: _criterion_rules(prep, fitter, *rule_args(t), n_base_terms)[0]
            )
    refused: list[Refused] = []
    chosen: Chosen | None = None
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
        doubt = None
        if reasons and chosen is None and cand is dominant and only_doubts(cand, reasons):
            # evidence, not a veto: far ahead of every other candidate, refused only by a
            # plausibility rule -> named with the doubt and the alternatives
            doubt = {"rule": reasons[0][0], "reason": "; ".join(r for _, r in reasons)}
            reasons = []
        if reasons:
            rejected.append(_refusal(cand.name, reasons, dbic))
            refused.append(Refused(dbic, cand, fr, reasons[0][0]))
            continue
        if chosen is not None:
            tie = _tie_entry(prep, fitter, st["cur_resid"], chosen, cand, fr, dbic)
            if tie is not None:  # not decided by the criterion: reported with the chosen
                chosen.ties.append(tie)
                continue
            reason = (
                f"{chosen.cand.name} lowers the criterion more "
                f"(dBIC {chosen.dbic:.1f} vs {dbic:.1f})"
            )
            rejected.append(_refusal(cand.name, [("better_candidate", reason)], dbic))
            continue
        # it must explain a fair share of everything located, so that a larger structure it
        # cannot explain is not pinned on it through a small part of it
        rule, steps_left = _located_rule(
            prep, fitter, cand, fr, st["findings"], st["views"], st["scan_order"], current, dchi
        )
        if rule is not None:
            rejected.append(_refusal(cand.name, [rule], dbic))
            continue
        # a step located where nothing in the catalog changes (no reversal, no change of
        # speed) is the alternative it must beat: a drift or a scale error only dents it
        steps = st["free_steps"] + steps_left
        if drifts_in_time(prep, cand.name):  # a drift in time makes no step at a reversal
            steps = steps + st["change_steps"]
        why = beaten_by_step(fitter, prep, current, fr, steps, step_fits)
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
        if doubt is not None:
            notes.append(
                f"doubted ({doubt['rule']}): {doubt['reason']}; named because it lowers the "
                "criterion far more than any other candidate (see alternatives)"
            )
        ties = [partner_entry(cand, tr, gap, corr, dbic) for tr, gap, corr in partners]
        chosen = Chosen(cand, fr, dbic, dho, col, notes, trms, erms, ties if doubt else [], doubt)
    if chosen is not None and chosen.doubt is not None:
        rejected[:] = [r for r in rejected if not (r["name"] == chosen.cand.name)]
    refused_pair(prep, fitter, st["cur_resid"], refused, rejected, confounded)
    return chosen


def _backward(prep, fitter, accepted, current, cur_resid, findings, rejected, views, scan):
    """Each named effect must still earn its place on held-out data (the others held at
    their nonlinear values: one linear refit each)."""
    without: dict[str, FitResult] = {}
    if len(accepted) <= 1:
        return current, cur_resid, findings, without
    for s in list(accepted):
        others = frozen([t for t in current.terms if t.cand.name != s.name])
        fr = remembered_fit(fitter, others)
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


@dataclasses.dataclass(frozen=True)
class Selection:
    """What stage 4 hands the document (typed: no string keys).

    Attributes:
        base, final: the base model's and the final model's fits.
        base_resid, final_resid: (n, C) their residuals (unit of y).
        findings0, findings: what the views located in the base and the final residual.
        gof0: the base model's goodness of fit.
        accepted: the named effects (:class:`Step`), in the order named.
        rejected, not_testable: refusals (JSON entries, each with its ``rule``).
        confounded: pairs refused together that the record cannot separate (JSON entries).
        shares: each named effect's share of what all explain together.
        tried: names of the candidates tried.
        heldout_refused: ``(delta BIC, fit)``, :func:`._evidence.heldout_refused`'s, or None.
    """

    base: FitResult
    base_resid: np.ndarray
    findings0: list
    gof0: dict
    final: FitResult
    final_resid: np.ndarray
    findings: list
    accepted: list[Step]
    rejected: list[dict]
    not_testable: list[dict]
    confounded: list[dict]
    shares: dict[str, float]
    tried: list[str]
    heldout_refused: tuple[float, FitResult] | None = None


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
    """Forward selection with refits, then a backward held-out check (stage 4); returns the
    :class:`Selection`. A fit made twice in it is made once (:mod:`._fit_memo`)."""
    with remembering():
        return _select(prep, fitter, base_terms, candidates, views, scan_order, max_effects, log)


def _select(prep, fitter, base_terms, candidates, views, scan_order, max_effects, log):
    """:func:`select`'s work, inside its memo of fits."""
    base = remembered_fit(fitter, base_terms)
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
    confounded: list[dict] = []
    ho_refused: tuple[float, FitResult] | None = None
    for rnd in range(1, max_effects + 1):
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
            free_steps=free_steps(prep, findings, fit=(fitter, current.terms)),
            change_steps=free_steps(prep, findings, at_changes=True, fit=(fitter, current.terms)),
        )
        trials: list[Trial] = []
        todo = []
        for cand in applicable:
            if cand.name in {s.name for s in accepted}:
                continue
            if cand.signature and not (set(cand.signature) & seen):
                continue
            if not cand.signature and gof["passes"]:
                continue
            tried_names.add(cand.name)
            todo.append(cand)
        for cand, (best, refused, notes) in zip(
            todo, _trial_fits(st, todo, current, n_base_terms, log)
        ):
            rejected += refused
            if notes is not None:
                held_notes[cand.name] = notes
            if best is None:
                continue
            dchi = current.chi2 - best.chi2
            k = best.n_determined(len(best.terms) - 1)
            dbic = -(dchi - max(k, 0) * math.log(max(N, 2)))
            dho = current.heldout_chi2 - best.heldout_chi2
            trials.append(Trial(dbic, cand, best, dho, dchi, k))
        _sort_trials(trials, applicable)
        del kept[:]
        chosen = _choose(
            st,
            trials,
            current,
            accepted,
            n_base_terms,
            held_notes,
            rejected,
            step_refusals,
            confounded,
        )
        for r in rejected:  # the selection round that refused it (1-based; earlier: marked)
            r.setdefault("round", rnd)
        ho_refused = heldout_refused(prep, trials, rejected, confounded, rnd, ho_refused)
        if chosen is None:
            break
        cand, fr, dbic, dho, col, notes, trms, erms, ties, doubt = chosen
        alternatives = alternatives_of(chosen, trials) if doubt is not None else []
        if ties:
            notes = [
                *notes,
                "confounded with "
                + ", ".join(c["name"] for c in ties)
                + ": this recording cannot tell them apart; the name is only the one with "
                "the lower information criterion",
            ]
        # (the rules may have made this fit already: _kept_fit's with the candidate)
        full = remembered_fit(fitter, _unfrozen(fr.terms[:-1], current.terms) + fr.terms[-1:])
        # the refit frees the base too, so its optimum is never above the frozen base's: a
        # chi-square above it by less than the fits' stopping tolerance is rounding, and the
        # refit (whose standard errors carry the base's) is kept; not a tie decided by the
        # last bits (issue 43: a factored Jacobian's rounding flipped it at 10^7 rows)
        if full.chi2 <= fr.chi2 + fit_stop_tolerance(fr.chi2):
            fr = full
        # (one residual held at a time: kept_resid's default argument holds this round's
        # residual too, through the next scan; issue 43, peak memory)
        del cur_resid, st, kept_resid
        resid = fitter.residual(fr.terms)
        accepted.append(
            Step(cand.name, fr, dbic, dho, col, notes, trms, erms, ties, doubt, alternatives)
        )
        log(f"named {cand.name}")
        current, cur_resid = fr, resid
        findings = locate(prep, cur_resid, views, scan_order)
    current, cur_resid, findings, without = _backward(
        prep, fitter, accepted, current, cur_resid, findings, rejected, views, scan_order
    )
    findings = place_step_refusals(prep, fitter, current, step_refusals, findings)
    # a named effect's confounded partner is reported with it, never also as a refusal
    partners = {c["name"] for a in accepted for c in a.confounded}
    rejected[:] = [r for r in rejected if r["name"] not in partners]
    # shares: what each effect explains given the others
    shares = {}
    total = base.chi2 - current.chi2
    for s in accepted:
        fr = without.get(s.name)
        if fr is None:
            others = frozen([t for t in current.terms if t.cand.name != s.name])
            fr = remembered_fit(fitter, others) if len(accepted) > 1 else base
        shares[s.name] = float((fr.chi2 - current.chi2) / total) if total > 0 else 0.0
    return Selection(
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
        confounded=confounded,
        shares=shares,
        tried=sorted(tried_names),
        heldout_refused=ho_refused,
    )
