"""Evidence, not vetoes (issue 22 item 3), for stage 4 (:mod:`._select`): a candidate
far ahead of every other that only its plausibility rule doubts (:func:`dominant`), the
alternatives it is named with (:func:`alternatives`), and pairs the record cannot separate
(:func:`tie`, :func:`partner_entry`, :func:`refused_pair`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ._candidates import Candidate
from ._document import jsonable
from ._fit import FitResult, Fitter, Term
from ._protocol import Prepared
from ._rowshare import summed
from ._settings import FinderSettings


class Trial(NamedTuple):
    """One candidate's full fit in a round of stage 4, against the current model."""

    dbic: float
    """Change of the information criterion (BIC); negative: the candidate is better."""
    cand: Candidate
    fit: FitResult
    """The fit with the candidate's term last."""
    dheldout: float
    """How much it lowers the K-fold held-out chi-square."""
    dchi2: float
    """How much it lowers the chi-square."""
    k_new: int
    """Parameters it determines that the model did not (0: all already taken)."""


class Refused(NamedTuple):
    """A trial refused by a rule (for :func:`refused_pair`)."""

    dbic: float
    cand: Candidate
    fit: FitResult
    rule: str
    """The name of the first rule that refused it."""


class Chosen(NamedTuple):
    """The trial a round names, with what its entry reports."""

    cand: Candidate
    fit: FitResult
    dbic: float
    dheldout: float
    collinearity: float
    """Canonical correlation with the base model."""
    notes: list
    term_rms: float
    explained_rms: float
    ties: list
    """``confounded_with`` entries (trials it cannot be told from)."""
    doubt: dict | None
    """``{rule, reason}`` when a plausibility rule doubted it and it was named as dominant."""


def term_rms(fitter: Fitter, term: Term, prep: Prepared, per_run: bool = False) -> float:
    """RMS of one term's own contribution (projected, whitened by the noise).

    ``per_run``: less its mean per run and channel over the kept rows, the part a constant
    per run and channel of the base model absorbs (e.g. a drift over the whole record seen
    through runs, each with its own zero): not a size the data could see."""
    R, C = prep.ctx.n_runs, prep.n_channels

    def add(sums, a, b, x):  # chunk by chunk (nothing per row is held), rows split (summed)
        v = fitter.eval_term(term, a, b, x, jac=False)[0]
        if prep.kd.project:
            v = v - v.mean(1, keepdims=True)
        k = prep.keep[a:b]
        w = v[k] / prep.sigma[None, :]
        sums[0] += np.sum(w * w)
        if per_run:  # sums per run and channel (bincount: np.add.at is slow per row)
            run = np.asarray(prep.run[a:b])[k]
            sums[2] += np.bincount(run, minlength=R)
            for c in range(C):
                sums[1][:, c] += np.bincount(run, weights=w[:, c], minlength=R)

    tot1, s1, cnt = summed(fitter, [np.zeros(1), np.zeros((R, C)), np.zeros(R)], add)
    tot = float(tot1[0])
    if per_run:
        tot -= float(np.sum(s1 * s1 / np.maximum(cnt, 1.0)[:, None]))
    eff = (C - 1) / C if prep.kd.project else 1.0
    return float(np.sqrt(max(tot, 0.0) / max(prep.keep.sum() * C * eff, 1)))


def tie_gap(
    fitter: Fitter, prep: Prepared, cur_resid: np.ndarray, a: FitResult, b: FitResult
) -> tuple[float, float]:
    """``(chi-square gap, correlation)`` of two alternative fits ``a`` (chosen) and ``b``:
    how much better ``a`` fits, and the correlation of what each takes out of the current
    residual (kept rows, noise-whitened). Near 0 and near 1: the data cannot tell them."""
    keep = prep.keep
    w = 1.0 / prep.sigma[None, :]

    def add(sums, lo, hi, x):  # one pass: both fits on each chunk
        ra = fitter.chunk_residual(a.terms, lo, hi, x)
        rb = fitter.chunk_residual(b.terms, lo, hi, x)
        k = keep[lo:hi]
        ca = ((cur_resid[lo:hi] - ra) * w)[k]
        cb = ((cur_resid[lo:hi] - rb) * w)[k]
        sums[0] += [np.sum(ca * ca), np.sum(cb * cb), np.sum(ca * cb)]

    # the rows split over the processes (_rowshare): the same sums on any number of them
    saa, sbb, sab = (float(v) for v in summed(fitter, [np.zeros(3)], add)[0])
    den = math.sqrt(saa * sbb)
    corr = float(abs(sab) / den) if den > 0 else 0.0
    return float(b.chi2 - a.chi2), corr


def tie_reason(
    chosen: str, gap: float, corr: float, dbic: float, dbic_chosen: float, s: FinderSettings
) -> str:
    """The reason of a ``tie_chi2`` entry beside ``chosen``: ``gap`` is how much worse the
    candidate fits (chi-square; negative: it fits better, and only the criterion's charge
    for its extra parameters put ``chosen`` first, issue 44)."""
    same = f"its fitted error is the same (correlation {corr:.3f})"
    if gap >= 0:
        return (
            f"the data cannot tell it from {chosen}: it fits as well (chi-square {gap:+.1f}, "
            f"needs {s.tie_chi2:.0f} to decide) and {same}"
        )
    return (
        f"the information criterion, not the fit, puts {chosen} first: it fits better "
        f"(chi-square lower by {-gap:.1f}) with more parameters (dBIC {dbic:.1f} against "
        f"{dbic_chosen:.1f}), and {same}"
    )


def refused_pair(prep, fitter, cur_resid, refused: list, rejected: list, confounded: list):
    """Two candidates refused by the same rule that fit alike (within ``tie_chi2``) and take
    out the same error (correlation above ``tie_corr``) are one ``confounded`` entry, not
    two refusals (the two best such of a round; one pass over the rows)."""
    s = prep.settings
    good = sorted((r for r in refused if r.dbic < -s.bic_min), key=lambda r: r.dbic)
    for i in range(len(good) - 1):
        a, b = good[i], good[i + 1]
        if a.rule != b.rule or b.dbic - a.dbic >= s.tie_chi2:
            continue
        gap, corr = tie_gap(fitter, prep, cur_resid, a.fit, b.fit)
        if abs(gap) >= s.tie_chi2 or corr <= s.tie_corr:
            continue
        why = [r for r in rejected if r["name"] in (a.cand.name, b.cand.name)]
        rejected[:] = [r for r in rejected if r["name"] not in (a.cand.name, b.cand.name)]
        confounded.append(
            {
                "pair": [a.cand.name, b.cand.name],
                "correlation": float(corr),
                "delta_bic": float(b.dbic - a.dbic),
                "separate_by": separate_by(a.cand, b.cand, corr),
                "reason": f"the record cannot separate them (chi-square {gap:+.1f}, "
                f"correlation {corr:.3f}); both refused by rule {a.rule}: "
                + "; ".join(f"{r['name']}: {r['reason']}" for r in why[:2]),
                "rule": a.rule,
            }
        )
        return


def find_dominant(st, trials: list[Trial], rules=None) -> tuple[Candidate | None, list]:
    """``(candidate, partners)``: the first trial's candidate when it lowers the criterion
    far more than any other that is not the same fitted error (``dominant_ratio`` times and
    ``dominant_gap`` more than the next such trial, or than nothing), else ``(None, [])``;
    ``partners``: the trials before that one whose fitted error correlates with it above
    ``tie_corr`` (at most two: one residual pass each), as ``(trial, chi2 gap, corr)``.

    Not where a partner fits within ``tie_chi2`` of it and the criterion rules ``rules(trial)``
    (``[(rule, reason), ...]``) refuse that partner for nothing: the record cannot tell the
    two apart, and the doubt against the first is then not outweighed by any evidence, so
    the undoubted one is the reading (session 39: on one sensor of 16 signal periods a disk
    order 16 was named ``bearing_wobble`` at frequency ratio 15.9999, doubted as synchronous,
    over ``interpolation_error``, correlation 1.000 and chi-square +1.5, its lead in the
    criterion only its fewer parameters; training ``finder_variations.py --set high --seed
    6745`` record 6)."""
    prep, fitter = st["prep"], st["fitter"]
    s = prep.settings
    if not trials or trials[0].dbic >= -s.bic_min:
        return None, []
    d0 = trials[0].dbic
    partners = []
    d1 = 0.0
    for tr in trials[1:]:
        if len(partners) < 2 and tr.dbic < -s.bic_min and tr.k_new > 0:
            gap, corr = tie_gap(fitter, prep, st["cur_resid"], trials[0].fit, tr.fit)
            if corr > s.tie_corr:
                partners.append((tr, gap, corr))
                continue
        d1 = min(tr.dbic, 0.0)
        break
    if rules is not None and any(g <= s.tie_chi2 and not rules(tr) for tr, g, _ in partners):
        return None, []
    if -d0 >= s.dominant_ratio * -d1 and d1 - d0 >= s.dominant_gap:
        return trials[0].cand, partners
    return None, []


def rule_args(trial: Trial) -> tuple:
    """``(cand, fit, dbic, dheldout, dchi2)``: the arguments of the criterion rules."""
    return trial.cand, trial.fit, trial.dbic, trial.dheldout, trial.dchi2


def partner_entry(chosen: Candidate, trial: Trial, gap: float, corr: float, dbic0: float) -> dict:
    """A doubted dominant candidate's ``confounded_with`` entry for a trial that takes out
    the same error (correlation above ``tie_corr``) but fits worse by ``gap``."""
    dbic, cand, fr = trial.dbic, trial.cand, trial.fit
    return {
        "name": cand.name,
        "reason": f"takes out the same error as {chosen.name} (correlation {corr:.3f}) and "
        f"fits nearly as well (chi-square {gap:+.1f}): this record cannot tell them apart",
        "rule": "tie_corr",
        "delta_bic": float(dbic),
        "params": {q.name: jsonable(fr.terms[-1].values[q.name]) for q in cand.params},
        "correlation": float(corr),
        "separate_by": separate_by(chosen, cand, corr),
    }


def only_doubts(cand: Candidate, reasons: list) -> bool:
    """Whether every rule that refused ``cand`` is its plausibility rule (a doubt, not a
    failed test of the data)."""
    return cand.doubt_overruled and all(r == f"{cand.name}.plausible" for r, _ in reasons)


def separate_by(a: Candidate, b: Candidate, corr: float | None = None) -> str:
    """What measurement would tell candidate ``a`` from ``b`` (from their signatures)."""
    sa, sb = set(a.signature), set(b.signature)
    both = sa | sb
    pa, pb = {q.name for q in a.params}, {q.name for q in b.params}
    if ("frequency_hz" in pa | pb) and ({"frequency_ratio", "orders"} & (pa | pb)):
        return (
            "runs at a second, clearly different speed: a fractional order follows the "
            "speed, a frequency in Hz does not"
        )
    if ("direction" in sa) != ("direction" in sb):
        return "runs in both directions: a direction-locked effect changes sign with it"
    if ("speed" in sa) != ("speed" in sb):
        return "runs at several speeds: a speed-dependent effect scales with the speed"
    if ({"orders"} & both) and ({"spectrum", "time", "drift"} & both) and sa != sb:
        return (
            "runs at a second, clearly different speed: an effect locked to the angle keeps "
            "its order, one locked to time keeps its frequency (or its time)"
        )
    if {"time", "drift", "order_step", "run_step"} & both:
        return (
            "a longer record, repeated runs or a temperature column: a change in time "
            "recurs at the same time, a function of the angle at the same angle"
        )
    c = "" if corr is None else f" (their fitted errors correlate {corr:.3f} here)"
    return f"a record in which their fitted errors differ{c}: other speeds, directions or turns"


def alternatives_of(chosen: Chosen, trials: list[Trial]) -> list[dict]:
    """The other candidates of a doubted dominant one's round, best first (at most 3):
    name, their criterion, how much worse than the named one, what would tell them apart."""
    out = []
    assert chosen.doubt is not None
    for tr in trials:
        dbic, cand = tr.dbic, tr.cand
        if cand is chosen.cand or len(out) >= 3:
            continue
        out.append(
            {
                "name": cand.name,
                "reason": f"fits, but worse: dBIC {dbic:.1f} vs the named "
                f"{chosen.cand.name}'s {chosen.dbic:.1f}",
                "rule": "dominant_ratio",
                "delta_bic": float(dbic),
                "delta_bic_vs": float(dbic - chosen.dbic),
                "separate_by": separate_by(chosen.cand, cand),
            }
        )
    if not out:
        out.append(
            {
                "name": "out_of_catalog",
                "reason": "no other catalog candidate lowers the criterion here; the doubt "
                f"names what could pose as it: {chosen.doubt['reason']}",
                "rule": chosen.doubt["rule"],
                "delta_bic": None,
                "delta_bic_vs": None,
                "separate_by": "the measurement the doubt asks for (see its reason)",
            }
        )
    return out


def heldout_refused(prep: Prepared, trials, rejected, confounded, rnd: int, best):
    """``best`` or this round's trial of least delta BIC, if lower, that the criterion took
    (below ``-settings.bic_min``) and only held-out error refused (rule ``heldout_min``
    alone: in this round's ``rejected``, or in a ``confounded`` pair): ``(delta BIC, fit)``."""
    names = {
        r["name"]
        for r in rejected
        if r.get("round") == rnd and r.get("rules", [r.get("rule")]) == ["heldout_min"]
    }
    names |= {n for c in confounded if c.get("rule") == "heldout_min" for n in c["pair"]}
    for t in trials:
        if t.cand.name in names and t.dbic < -prep.settings.bic_min:
            if best is None or t.dbic < best[0]:
                best = (float(t.dbic), t.fit)
    return best


def ratio_limit(prep: Prepared) -> float:
    """The ratio of a candidate's own size to what it explains above which rule
    ``plausible_ratio`` refuses it as a cancellation of base terms: ``plausible_ratio``, and
    where every run covers less than one turn (``Prepared.part_turn_span``) the ratio of the
    conditioning limit ``collinear_refuse`` instead, ``1 / sqrt(1 - collinear_refuse^2)``
    (10.0 at 0.995), where that is larger.

    For a term linear in its size the ratio is a property of its shape on the record, not of
    the fit: its own RMS over the RMS it explains is ``1 / sqrt(1 - rho^2)``, ``rho`` the
    correlation of its fitted error with the base model's span (4 is ``rho`` 0.968). Over
    part of a turn seen once, angle and time are one to one and the base's disk orders span
    most of any smooth error in time, so a true effect shows a large ratio at any size; the
    limit there is the one the selection already puts on conditioning (session 39: three true
    eccentricity shifts on 0.34-0.58 turn of the ``short_arcs`` set, their times within
    1.4 ms and two of their sizes within 2 % once named, were refused at 4.3-5.4)."""
    s = prep.settings
    if prep.part_turn_span is None:
        return s.plausible_ratio
    return max(s.plausible_ratio, 1.0 / math.sqrt(max(1.0 - s.collinear_refuse**2, 1e-300)))
