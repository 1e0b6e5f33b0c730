"""Catalog names re-tested beside the discovered model (issue 41, sessions 32-33).

The selection (:mod:`._select`) names catalog effects before discovery (:mod:`._discover`)
models what is left. A catalog effect can then be named on a part of an out-of-catalog
structure: a ``vibration`` at the frequency order 11 makes in one run takes that run's share of
an order-11 line whose amplitude follows the speed, and discovery, fitted beside it, measures
the law on the other runs only (exponent 0.005 against a truth of 1); a ``beam_tilt_axial``
takes the head-specific low orders that a shaft-frame line moves through the reference-free
shaft angle. No rival of the selection's own models that structure: it is outside the
catalog.

Here each catalog effect named in the record is tested again once discovery has modelled the
rest, by the catalog's own acceptance criteria, with the discovered terms
(:func:`._discover_export.discovered_candidate`, the form ``--export-candidates`` writes) in
the model, fitted jointly (their exponents free):

* ``bic_min`` and ``heldout_min`` on its gain beside the other named effects and the
  discovered terms;
* ``located_share_min`` on the share of its gain (beside the other named effects) that it
  keeps once the discovered terms are fitted with it (as :func:`._spill.kept_gain_share` asks
  of the larger located structure a candidate leaves).

A failing effect is refused only where a discovered term holds the larger structure
(session 33; per term since session 34, :func:`_holder`): the term the effect holds a part
of is the one beside which it keeps the least of its gain, and the effect must fail the
catalog's rules beside that term alone (a large discovered line elsewhere, which takes
nothing of the effect, is never compared: session 33 compared the discovered terms as one
set). That term holds the larger structure where its held-out gain beside the effect (what
stays its own once the effect has taken all it can) is at least the effect's whole held-out
gain beside the other named effects. The test is symmetric in the two (each one's gain
beside the other against the other's gain alone). In a false name the effect holds a part of
a larger out-of-catalog line (one run of a line whose amplitude follows the speed; or the
head-specific low orders that a shaft-frame order leaves through the fitted head
placements), and the line keeps far more beside it than the effect has at all. Where the
effect's whole gain is the larger, the discovered term is a remainder beside it, and a term
fitted to that remainder can also absorb much of the effect once fitted without it (two
heads over part of a turn without a reference: an ``order 2, disk`` term took 95 % of a true
``eccentricity_shift``'s gain, and kept a held-out gain of 305 beside it against the
shift's 1934, training seed 7740 record 7 of ``tests/test_order_step_zeros.py``); the effect
keeps its name, as discovery must never take structure a catalog effect explains. Held-out
gains (the catalog's ``heldout_min`` measure) are compared, not the chi-square: a term that
only fits the noise of the rows it was fitted on is no larger for it.

The one exception is a term in the effect's own place (:func:`_place`: a line at a fixed
frequency, the catalog's ``vibration``, and a discovered term in the frame of a fixed
frequency) that keeps a gain beside the effect past the catalog's gain rules (``bic_min``,
``heldout_min``): the structure at that frequency is then more than the catalog effect, of
which the effect holds a part, whatever their sizes. A mode rung at the start of each run
and decaying with its own Q is the case (session 34): the steady ``vibration``, fitted
first, takes the mean of each run's ring-down (its whole held-out gain 2,195-27,305 on the
traced training cases) and the discovered ``ringing`` term keeps the decay beside it
(1,399-86,318, past the gain rules), while the vibration keeps 0-13 % of its gain beside
the term. A true steady ``vibration`` leaves no such term at its frequency. Since session 36
the place is the frequency: a discovered line at the effect's frequency in one of its runs,
within ``peak_match_bins`` of that run's frequency bin (the views' rule of one line), a
fixed-frequency line or a shaft order ``m`` at ``m`` times the run's revolutions per second
(a ``vibration`` at order 14 of the slowest run took 88 % of an order 14 whose amplitude falls
with the speed, and kept 0.2 % of its gain beside the discovered law). And a discovered
fixed-frequency line's frequency is fitted here (it is discovery's located bin: 0.15-0.35 Hz
from a ring-down the ``vibration`` fits to 0.01 Hz, beside which the vibration kept 21-52 %
of its gain; at the fitted frequency 8-9 %); a frequency that leaves its line
(``peak_match_bins`` of its runs' widest bin) makes the term no rival, as an exponent out of
range does.

An effect that fails is refused (``rejected``, the rule and the reason; no ``round``: after
the selection, as the backward check), the catalog model is refitted without it and discovery
runs again on what is left; then the remaining named effects are tested beside the new
discovered model, until none fails. A catalog effect that is really there keeps its gain
beside the discovered terms (they were fitted beside it, orthogonal to what it explains), so
it keeps its name: discovery never takes structure a catalog effect explains. A discovered
speed law whose exponent, fitted beside the model without the effect, leaves the range
discovery searches (``discover_beta_max``) is no rival: it refuses nothing (as a rival whose
``plausible`` hook refuses its values in :func:`._spill.rival_rule`). Its size is free: it
takes the part of its structure the effect had taken (the ``plausible`` hook of an exported
candidate, which asks for the discovered size, does not apply).

Since session 39 a named effect the selection named despite its own ``plausible`` doubt (only
for its lead over every other catalog candidate) is also tested beside the model discovery
builds without it (:func:`_without_rival`), even where nothing is left unexplained beside it
(the effect can take all of an out-of-catalog line, and discovery then never runs). Where the
effect and the discovered term each fail the catalog's rules beside the other (a mutual tie
the record cannot break by them), the information criterion decides (:func:`_holder`): the
term, fitting the same structure with fewer parameters, is the reading. An ``order 5`` of
the platform angle near the noise on 12 positions was named ``beam_tilt_axial`` doubted ("the
common structure peaks at order 5"); discovery without it found ``order 5, platform,
static``, beside which it kept 1 % of its gain, and the term kept a held-out gain of 11 beside
it (2 parameters against its 6; training seeds 6741 record 30 and 6763 record 29 of
``studies/conceal_benchmark.py --kinds sds``). A doubted effect that is there keeps its gain
beside the term (the term fits one line of its structure), so it keeps its name.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np

from ._discover_export import candidate_name, discovered_candidate, nonlinear_start
from ._fit import Fitter, make_term
from ._fit_memo import remembered_fit, remembered_steps
from ._select import Selection, _refusal, gain_rules
from ._stats_pass import drive_many
from ._timing import stage
from ._views import locate, run_spans
from ._views_time import findings_listed

RULE_PREFIX = "beside the discovered model"
"""How a refusal of this test begins (its reason names the discovered terms)."""


def _specs(models: Sequence[dict | None]) -> list[dict]:
    """The discovered terms of a record, once each (a term sits in every finding at its
    line)."""
    out: dict[str, dict] = {}
    for m in models:
        for t in (m or {}).get("terms", ()):
            out.setdefault(candidate_name(t), t)
    return list(out.values())


ROW_MODULATIONS = ("static", "direction", "forward", "reverse")
"""The modulations a discovered term's line can be given again from the rows alone (each two
coefficients per line and frame: the same size), among which a tie of discovery's held-out
gains is decided by the joint fit (:func:`_ties`, :func:`_untie`)."""


def _ties(prep, models: Sequence[dict | None]) -> dict[str, list[dict]]:
    """Per discovered term (by its candidate name): the terms of its line and frame with
    another of :data:`ROW_MODULATIONS` that discovery lists as alternatives (``model``'s
    ``alternatives``: held-out gain alone) within ``tie_chi2`` of the term's own held-out
    gain: discovery's criterion does not decide between them (the catalog's rule of two
    candidates that are one confounded pair)."""
    s = prep.settings
    out: dict[str, list[dict]] = {}
    for m in models:
        for t in (m or {}).get("terms", ()):
            if t["modulation"] not in ROW_MODULATIONS or t["line_kind"] == "hz":
                continue
            for a in (m or {}).get("alternatives", ()):
                frame, _, mod = str(a["term"]).partition(" / ")
                if frame != t["frame"] or mod == t["modulation"] or mod not in ROW_MODULATIONS:
                    continue
                if not float(a["heldout_gain_chi2"]) >= float(t["heldout_gain_chi2"]) - s.tie_chi2:
                    continue
                out.setdefault(candidate_name(t), []).append({**t, "modulation": mod})
    return out


def _untie(prep, fitter: Fitter, base: list, disc: list, specs: list[dict], ties) -> tuple:
    """``(disc, specs)`` with each discovered term that discovery's held-out gains tie with
    another modulation of its line (:func:`_ties`) replaced by the one of the tie whose joint
    fit beside ``base`` (the catalog model without the effect tested) leaves the least
    chi-square (session 39).

    Discovery fits its terms orthogonal to the catalog model's Jacobian, linear about the
    catalog fit; the catalog model can hold part of a line through its nonlinear
    parameters, which that linear model cannot give back. A 20x shaft-frame order 9 in the
    forward runs only, on four heads with a reference: the fitted head placements moved to
    take its static half into the disk error at order 9, and discovery's ``direction``,
    ``forward`` and ``reverse`` at order 9 tied (held-out gains 437,310, 437,303, 437,266):
    it kept ``direction``, beside which a ``beam_tilt_axial`` named on the head-specific low
    orders that the moved placements left kept all its gain (101 %); beside ``forward``,
    fitted jointly, the placements return and it kept 0.15 % (training seed 20261532,
    multihead ``one_direction`` 20x)."""
    if not ties:
        return disc, specs
    disc, specs = list(disc), list(specs)
    for j, sp in enumerate(list(specs)):
        alts = ties.get(candidate_name(sp), [])
        if not alts:
            continue
        tries = [(disc[j], sp), *((t, a) for a, t in zip(alts, _terms(prep, alts)))]
        fits = [[*base, *disc[:j], t, *disc[j + 1 :]] for t, _ in tries]
        done = drive_many([remembered_steps(fitter, f) for f in fits])
        k = min(range(len(tries)), key=lambda i: done[i].chi2)
        disc[j], specs[j] = tries[k]
    return disc, specs


def _terms(prep, specs: list[dict]) -> list:
    """The discovered terms, their exponents and fixed frequencies free (session 36: a
    line at a fixed frequency was fitted at the frequency discovery located, its bin's,
    0.15-0.35 Hz from a mode the catalog's ``vibration`` fits to 0.01 Hz)."""
    out = []
    for s in specs:
        start = nonlinear_start(s)
        if s["line_kind"] == "hz":
            start["frequency_hz"] = float(s["params"].get("frequency_hz", s["value"]))
        out.append(make_term(discovered_candidate(s, free_frequency=True), prep, start))
    return out


def _run_lines(prep) -> dict[int, tuple[float, float]]:
    """Each run's ``(revolutions per second, frequency bin in Hz)`` by its id, over its
    kept rows, as the spectrum view reads them (:func:`._views.view_spectrum`: the median
    ``|omega| / 2 pi`` and the transform's bin ``1 / (rows x dt)``; no ``omega``: 0)."""
    out = {}
    has_omega = "omega" in prep.rows
    for r, (a, b) in run_spans(prep.run):
        kr = np.asarray(prep.keep[a:b], bool)
        if b - a <= 1 or not kr.any():  # no span to read a bin from
            continue
        t = np.asarray(prep.rows.column("t", a, b), float)
        dt = float(np.median(np.diff(t)))
        frev = 0.0
        if has_omega:
            om = np.asarray(prep.rows.column("omega", a, b), float)[kr]
            frev = float(np.median(np.abs(om))) / (2 * math.pi)
        rid = int(prep.run_ids[r]) if r < len(prep.run_ids) else r
        out[rid] = (frev, 1.0 / ((b - a) * dt) if dt > 0 else math.inf)
    return out


def _line_hz(spec: dict, fitted, lines: dict[int, tuple[float, float]]) -> list[tuple]:
    """``[(frequency Hz, bin Hz), ...]``: the discovered term's line in each of its runs
    (``fitted``: its fitted term; a fixed-frequency line at its fitted frequency, a shaft
    order ``m`` at ``m`` x the run's revolutions per second; none for an offset)."""
    v = float(spec["value"])
    if spec["line_kind"] == "hz":
        v = float(np.asarray(fitted.values.get("frequency_hz", v)))
    elif v == 0.0:
        return []
    runs = [r for r in spec["runs"] if r in lines]
    return [(v if spec["line_kind"] == "hz" else v * lines[r][0], lines[r][1]) for r in runs]


def _moved(prep, spec: dict, fitted, lines: dict[int, tuple[float, float]]) -> bool:
    """Whether a fixed-frequency term's fitted frequency left its line: more than
    ``peak_match_bins`` of its runs' widest bin from the discovered one (the views' rule of
    one line, :func:`._views.view_spectrum`)."""
    if "frequency_hz" not in fitted.values:
        return False
    bins = [lines[r][1] for r in spec["runs"] if r in lines]
    f = float(np.asarray(fitted.values["frequency_hz"]))
    width = prep.settings.peak_match_bins * (max(bins) if bins else math.inf)
    return not abs(f - float(spec["value"])) <= width


def _test(
    prep,
    fitter: Fitter,
    final_terms: list,
    name: str,
    disc: list,
    specs: list[dict],
    doubted: bool = False,
    how: str = "",
    ties: dict[str, list[dict]] | None = None,
):
    """``(kept share, [(rule, reason), ...])`` of the named effect ``name`` beside the
    discovered terms ``disc``; no rule: it keeps its name. ``doubted``: the selection named
    it despite its own plausibility doubt (:func:`_holder`). ``how``: words after the terms'
    names in the reason (how the model was discovered). ``ties``: the modulations discovery
    did not decide between (:func:`_ties`), decided here by the joint fit (:func:`_untie`)."""
    s = prep.settings
    idx = next(i for i, t in enumerate(final_terms) if t.cand.name == name)
    base = [t for i, t in enumerate(final_terms) if i != idx]
    term = final_terms[idx]
    disc, specs = _untie(prep, fitter, base, disc, specs, ties)
    fits = [base, [*base, term], [*base, *disc], [*base, *disc, term]]
    f0, f1, fo, f2 = drive_many([remembered_steps(fitter, f) for f in fits])
    bmax = s.discover_beta_max
    lines = _run_lines(prep)
    for d, sp in zip(fo.terms[len(base) :], specs):  # a rival only with an exponent in the
        if "beta" in d.values and not abs(float(d.values["beta"])) <= bmax:  # range searched
            return None, []
        if _moved(prep, sp, d, lines):  # ... and a fixed frequency on its line
            return None, []
    g0, g1 = f0.chi2 - f1.chi2, fo.chi2 - f2.chi2
    if g0 <= 0:
        return None, []
    k = f2.n_determined(len(f2.terms) - 1)
    dbic = _dbic(prep, g1, k)
    dho = fo.heldout_chi2 - f2.heldout_chi2
    kept = g1 / g0
    what = f"{RULE_PREFIX} ({', '.join(candidate_name(t) for t in specs[:4])}){how}:"
    rules = gain_rules(s, dbic, dho)
    if kept < s.located_share_min:
        rules.append(
            (
                "located_share_min",
                f"keeps only {100 * max(kept, 0.0):.0f}% of its gain once the "
                f"discovered terms are fitted with it: a part of that structure, outside the "
                f"catalog (needs {100 * s.located_share_min:.0f}%)",
            )
        )
    # the larger structure, per discovered term (session 34): the term the effect holds a
    # part of is the one beside which it keeps least, and it must fail the rules beside that
    # term alone (an unrelated discovered line elsewhere takes nothing of it); that term
    # refuses it where its held-out gain beside the effect is at least the effect's whole
    # held-out gain, or where it sits in the effect's own place and keeps a gain beside it
    # that the catalog's gain rules accept (the structure there is more than the effect)
    whole = f0.heldout_chi2 - f1.heldout_chi2
    if not rules:
        return kept, []
    holder = _holder(prep, fitter, base, term, disc, specs, f1, g0, whole, lines, doubted)
    if holder is None:
        return kept, []
    name_j, own, place = holder
    r, why = rules[-1]
    rules[-1] = (
        r,
        f"{why}; the discovered term {name_j} keeps a held-out gain of {own:.0f} beside "
        f"it (its whole: {whole:.0f}){place}: it holds a part of that structure",
    )
    rules = [(r, f"{what} {why}" if i == 0 else why) for i, (r, why) in enumerate(rules)]
    return kept, [(r, why, dbic) for r, why in rules]


def _dbic(prep, gain: float, k: int) -> float:
    """The information criterion change of a chi-square ``gain`` bought with ``k``
    determined scalars, over the record's kept values (rows kept: N > 2)."""
    return -(gain - max(k, 0) * math.log(prep.n_values))


def _place(prep, term, spec: dict, fitted, lines: dict[int, tuple[float, float]]) -> bool:
    """Whether the discovered term ``spec`` (``fitted``: its fitted term) sits in the place
    of the fitted catalog effect ``term``: a line at a fixed frequency (a fitted
    ``frequency_hz``, the catalog's ``vibration``) and a discovered line at that frequency
    in one of its runs, within ``peak_match_bins`` of the run's frequency bin (the views'
    rule of one line): a line in the frame of a fixed frequency (``hz``), or a shaft order
    ``m`` where ``m`` x the run's revolutions per second is that frequency (session 36: a
    ``vibration`` at order 14 of the slowest run, of an order 14 whose amplitude falls with
    the speed)."""
    if "frequency_hz" not in term.values:
        return False
    f = float(np.asarray(term.values["frequency_hz"]))
    width = prep.settings.peak_match_bins
    return any(abs(fl - f) <= width * b for fl, b in _line_hz(spec, fitted, lines))


def _holder(
    prep,
    fitter: Fitter,
    base: list,
    term,
    disc: list,
    specs: list[dict],
    f1,
    g0,
    whole,
    lines,
    doubted: bool = False,
):
    """The discovered term of ``disc`` the fitted effect ``term`` holds a part of:
    ``(name, its held-out gain beside the effect, words)``, or ``None``. ``f1``: the fit of
    ``base`` and the effect.

    Each discovered term is fitted beside ``base`` with and without the effect (the four
    fits of :func:`._spill._kept_fit`, one term at a time). The term the effect holds a part
    of is the one beside which it keeps the least of its gain ``g0``; it must fail the
    catalog's rules beside that term alone (``bic_min``, ``heldout_min``,
    ``located_share_min``: the term takes it). Then the term holds the larger structure where
    its held-out gain beside the effect is at least the effect's whole held-out gain
    ``whole`` (session 33's test, per term: a large discovered line elsewhere, which takes
    nothing of the effect, is never compared), or where it sits in the effect's place
    (:func:`_place`) and its own gain beside the effect passes the catalog's gain rules: the
    structure at that frequency is more than the catalog effect (a mode's ring-down, of
    which a steady ``vibration`` takes the mean of each run). Or, for an effect the
    selection named despite its own ``plausible`` doubt (``doubted``: named only because it
    was far ahead of every other catalog candidate, :func:`._select._choose`), where the
    term's gain beside the effect passes the catalog's gain rules: the lead that outweighed
    the doubt is taken by a model the doubt does not touch (session 38: a 20x step of one SDS
    sensor at order 7, named ``beam_tilt_axial`` with the doubt "the common structure peaks
    at order 7, not at the beam-tilt orders", kept 1 % of its gain beside the discovered
    step, and the step kept 1,622 of held-out gain beside it against the effect's whole
    1,624: a tie of the two sizes, where the size test alone cannot decide). Or where the
    effect keeps no held-out gain beside the term (what it predicts on rows it was not fitted
    on, the term predicts) and the term's gain beside it passes the catalog's gain rules: the
    effect is then a part of the term's structure, whatever their sizes (session 38: a
    ``beam_tilt_axial``, not doubted, kept 0.05 % of its gain and a held-out gain of -0.7
    beside a discovered 20x step at platform order 7, which kept 2,522 beside it against the
    effect's whole 8,520; training seed 20261523). There the joint model is no better than
    the term alone, and the term's held-out gain beside the effect is read against the
    better of the two fits: the fold fits of a pair collinear within the other folds can
    leave the held-out rows far worse (4.8e11 of held-out chi-square beside a discovered
    speed law, against the law alone, that kept a ``beam_tilt_axial`` and an
    ``eccentricity_shift`` named; training seed 20261522). Since session 39 an effect that
    fails all three of the catalog's rules beside the term keeps no gain of its own beside
    it either: a held-out gain under ``heldout_min`` is no evidence by the catalog's own
    measure (a ``beam_tilt_axial`` kept 0.18 % of its gain, a held-out gain of 1.8 and a
    criterion change of +29.8 beside a discovered 20x platform step at order 7, which kept
    1,453 beside it against the effect's whole 4,820; training seed 20261532, SDS
    ``platform_step`` 20x). And (session 39) for a doubted effect, where the term fails the
    catalog's gain rules beside the effect too (a mutual tie: each keeps too little beside
    the other), where the information criterion prefers the term: its criterion change
    beside the effect is at most the effect's beside it, the criterion of the term alone
    against the effect alone (the same fit for fewer parameters; an ``order 5, platform,
    static`` term, 2 parameters, against a doubted ``beam_tilt_axial``, 6, training seed
    6741 record 30 of the SDS catalog set)."""
    s = prep.settings
    fits = [f for d in disc for f in ([*base, d], [*base, d, term])]
    done = drive_many([remembered_steps(fitter, f) for f in fits])
    best = None
    for j in range(len(specs)):
        fd, fb = done[2 * j], done[2 * j + 1]
        kept = (fd.chi2 - fb.chi2) / g0
        if best is None or kept < best[0]:
            best = (kept, j, fd, fb)
    if best is None:
        return None
    kept, j, fd, fb = best
    k_eff = fb.n_determined(len(fb.terms) - 1)
    fails = gain_rules(
        s,
        _dbic(prep, fd.chi2 - fb.chi2, k_eff),
        fd.heldout_chi2 - fb.heldout_chi2,
    )
    if not fails and kept >= s.located_share_min:
        return None  # the effect keeps its gain beside each term alone: none holds it
    # the effect keeps no held-out gain beside the term (what it predicts on held-out rows the
    # term predicts): the joint model is then no better than the term alone, whose held-out
    # chi-square is the joint one's (a fold fit of the two together can also leave the rows
    # it did not see far worse, where the pair is collinear within the other folds)
    # (session 39) or where it fails every one of the catalog's rules beside the term
    # (``bic_min``, ``heldout_min``, ``located_share_min``): a held-out gain under
    # ``heldout_min`` is no evidence of its own by the catalog's own measure
    nested = fd.heldout_chi2 - fb.heldout_chi2 <= 0.0 or (
        {r for r, _ in fails} == {"bic_min", "heldout_min"} and kept < s.located_share_min
    )
    own = f1.heldout_chi2 - min(fb.heldout_chi2, fd.heldout_chi2)
    name = candidate_name(specs[j])
    if own >= whole:
        return name, own, ", at least the effect's whole: the larger structure"
    k = fb.n_determined(len(base))  # the discovered term's determined scalars
    dbic = _dbic(prep, f1.chi2 - fb.chi2, k)
    if _place(prep, term, specs[j], fb.terms[len(base)], lines) and not gain_rules(s, dbic, own):
        return name, own, ", in its place (at its frequency), past the catalog's gain rules"
    if doubted and not gain_rules(s, dbic, own):
        return (
            name,
            own,
            ", past the catalog's gain rules, and the effect was named despite its own "
            "plausibility doubt only for its lead over every other catalog candidate, "
            "which this term takes",
        )
    if nested and not gain_rules(s, dbic, own):
        return (
            name,
            own,
            ", past the catalog's gain rules, while the effect keeps no held-out gain beside "
            "the term: what it predicts, the term predicts",
        )
    # (session 39) a mutual tie of a doubted effect: each fails the catalog's rules beside
    # the other, and the information criterion decides (the term's change beside the effect
    # against the effect's beside the term: the criterion of the term alone against that of
    # the effect alone, the same fit for fewer parameters)
    if doubted and dbic <= _dbic(prep, fd.chi2 - fb.chi2, k_eff):
        return (
            name,
            own,
            f", and the effect keeps as little beside the term (a tie the record cannot "
            f"break by the catalog's rules), while the term fits what the effect fits with "
            f"{k} parameters against its {k_eff} (the information criterion prefers the "
            f"term), and the effect was named despite its own plausibility doubt",
        )
    return None


def _without(
    prep, fitter: Fitter, sel: Selection, name: str, entry: dict, views, scan
) -> Selection:
    """The selection with the named effect ``name`` refused: the catalog model refitted
    without it, its residual located again, the others' shares recomputed."""
    terms = [t for t in sel.final.terms if t.cand.name != name]
    final = remembered_fit(fitter, terms)
    resid = fitter.residual(final.terms)
    accepted = [s for s in sel.accepted if s.name != name]
    shares = {}
    total = sel.base.chi2 - final.chi2
    for s in accepted:
        others = [t for t in final.terms if t.cand.name != s.name]
        fr = remembered_fit(fitter, others) if len(accepted) > 1 else sel.base
        shares[s.name] = float((fr.chi2 - final.chi2) / total) if total > 0 else 0.0
    return dataclasses.replace(
        sel,
        final=final,
        final_resid=resid,
        findings=locate(prep, resid, views, scan),
        accepted=accepted,
        rejected=[*sel.rejected, entry],
        shares=shares,
    )


def _uncovered(prep, sel: Selection, specs: list[dict]) -> list[str]:
    """The named effects at a fixed frequency (a fitted ``frequency_hz``, the catalog's
    ``vibration``) in the place of a discovered shaft order in a run its term does not cover:
    ``m`` x that run's revolutions per second within ``peak_match_bins`` of the run's
    frequency bin of the effect's frequency (the views' rule of one line, as
    :func:`_place`), where ``m`` is the order of a discovered line (not an offset)."""
    lines = _run_lines(prep)
    width = prep.settings.peak_match_bins
    out = []
    for t in sel.final.terms:
        if t.cand.name not in {s.name for s in sel.accepted} or "frequency_hz" not in t.values:
            continue
        f = float(np.asarray(t.values["frequency_hz"]))
        for sp in specs:
            m = float(sp["value"])
            if sp["line_kind"] == "hz" or m == 0.0:
                continue
            if any(
                r not in sp["runs"] and abs(m * frev - f) <= width * b
                for r, (frev, b) in lines.items()
            ):
                out.append(t.cand.name)
                break
    return out


def _without_rival(
    prep,
    fitter: Fitter,
    sel: Selection,
    specs: list[dict],
    rediscover: Callable[[Selection], list[dict | None]],
    views: tuple[str, ...],
    scan: int,
) -> tuple[Selection, list[dict | None]] | None:
    """Session 38: a named effect at a fixed frequency tested beside the model discovery
    builds without it (:func:`_uncovered` names the ones to test).

    Within one steady run a shaft order ``m`` is a line at one frequency, ``m`` x the run's
    revolutions per second, which the catalog's ``vibration`` (each run its own amplitude
    and phase) fits exactly: named first, it takes that run's part of an order line (or,
    where two runs share a speed, both runs' parts), and discovery, fitted beside it, models
    what is left. The model it then keeps is shaped by the effect's take: where the base
    holds the static order, the runs left can be one run's remnant, so that of the terms the
    record then cannot tell apart (``direction``, ``forward``, ``reverse``, ``cell <i>``, at
    equal gain) rounding picks one that covers none of the effect's runs (training seeds
    20261519 sensor ``direction_lag`` 20x, read ``cell 1`` beside a ``vibration`` at order 13
    of the two faster runs; 20261514 sensor ``intermittent`` 20x, read ``cell 1`` beside a
    ``vibration`` at order 9 of the slowest run). Such a term takes nothing of the effect,
    and the test beside it (:func:`_test`) keeps the name.

    The rival of the effect is then the model discovery builds on the record without it:
    the catalog model refitted without the effect, discovery run again on its residual, and
    the effect tested beside its shaft-order terms (a fixed-frequency line discovered there
    is the effect's own structure: a true steady ``vibration``, fitted again as an ``hz``
    line, is no rival of itself) by the same rules (:func:`_test`: the catalog's
    gain rules and ``located_share_min``, and a discovered term holding the larger structure
    or in its place). A true fixed-frequency line in runs at other speeds is at other orders
    there, which no order term fits, so it keeps its gain beside them; a line the
    rediscovered order term fits in the effect's runs leaves it a remnant. Since session 39
    each effect named despite its own ``plausible`` doubt is tested the same way, beside all
    the terms discovered without it (where its removal leaves findings to discover): the
    selection named it only for its lead over every other catalog candidate, which a term
    discovery finds in its place can take (:func:`_holder`). ``(selection, models)`` with the
    first effect that fails refused, else ``None``."""
    worst = None
    fixed = _uncovered(prep, sel, specs)
    doubted_names = [a.name for a in sel.accepted if a.doubt is not None and a.name not in fixed]
    for name in [*fixed, *doubted_names]:
        alt = _without(prep, fitter, sel, name, {}, views, scan)
        if name not in fixed and not findings_listed(alt.findings, 12):
            continue  # nothing is left without the doubted effect to discover
        models = rediscover(alt)
        # its rivals are the shaft orders discovered without it: a fixed-frequency line
        # discovered there is the effect's own structure, which it keeps (discovery never
        # takes a catalog effect's structure); a doubted effect's rivals are all the terms
        specs2 = [
            sp
            for sp in _specs(models)
            if name not in fixed or (sp["line_kind"] != "hz" and sp["value"] != 0)
        ]
        if not specs2:
            continue
        disc = _terms(prep, specs2)
        how = ", discovered without it"
        doubted = any(a.doubt is not None for a in sel.accepted if a.name == name)
        kept, rules = _test(
            prep,
            fitter,
            list(sel.final.terms),
            name,
            disc,
            specs2,
            doubted,
            how,
            _ties(prep, models),
        )
        if rules and kept is not None and (worst is None or kept < worst[0]):
            worst = (kept, name, rules, alt, models)
    if worst is None:
        return None
    _, name, rules, alt, models = worst
    entry = _refusal(name, [(r, why) for r, why, _ in rules], rules[0][2])
    return dataclasses.replace(alt, rejected=[*sel.rejected, entry]), models


def rival_names(
    prep,
    fitter: Fitter,
    sel: Selection,
    models: list[dict | None],
    rediscover: Callable[[Selection], list[dict | None]],
    views: tuple[str, ...],
    scan: int,
) -> tuple[Selection, list[dict | None]]:
    """Each catalog effect named in ``sel`` re-tested beside the discovered terms of
    ``models`` (module doc); ``(selection, models)`` after the refusals (unchanged where none
    fails). ``rediscover(selection)``: discovery on a selection's final model and residual."""
    while sel.accepted:
        specs = _specs(models)
        disc = _terms(prep, specs)
        ties = _ties(prep, models)
        worst: tuple[float, str, list] | None = None
        for s in sel.accepted if specs else ():
            kept, rules = _test(
                prep,
                fitter,
                list(sel.final.terms),
                s.name,
                disc,
                specs,
                s.doubt is not None,
                ties=ties,
            )
            if rules and kept is not None and (worst is None or kept < worst[0]):
                worst = (kept, s.name, rules)
        if worst is None:
            alt = _without_rival(prep, fitter, sel, specs, rediscover, views, scan)
            if alt is None:
                break
            sel, models = alt
            continue
        _, name, rules = worst
        entry = _refusal(name, [(r, why) for r, why, _ in rules], rules[0][2])
        sel = _without(prep, fitter, sel, name, entry, views, scan)
        models = rediscover(sel)
    return sel, models


def discovered(prep, fitter: Fitter, sel: Selection, views, scan: int, discover: Callable):
    """Discovery after the catalog (``discover``: :func:`._discover.discover`, on the final
    catalog model, its residual and the first 12 findings) and the named effects re-tested
    beside its model (:func:`rival_names`): ``(selection, models or None)``; ``None`` where
    nothing is left unexplained."""

    def run(s: Selection) -> list[dict | None]:
        return discover(prep, fitter, s.final.terms, s.final_resid, s.findings[:12])

    listed = findings_listed(sel.findings, 12)
    if not listed and not any(a.doubt is not None for a in sel.accepted):
        return sel, None
    with stage("discovery"):
        # (session 39) a doubted named effect is tested beside the model discovery builds
        # without it even where nothing is left beside it (:func:`_without_rival`)
        sel, models = rival_names(prep, fitter, sel, run(sel) if listed else [], run, views, scan)
    return sel, models if findings_listed(sel.findings, 12) else None


__all__ = ["RULE_PREFIX", "discovered", "rival_names"]
