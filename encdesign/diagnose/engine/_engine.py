"""The discrepancy finder's engine: every stage written once, for every recording kind.

Stages (``docs/diagnose.md``):

1. **prepare** (:func:`prepare`): the kind turns the recording into observations ``y`` (n, C)
   and row columns; the engine finds the bench's nuisances: gaps in ``t``, segments where the
   shaft does not turn steadily (start-up, return moves, reversals, dwells, speed far from the
   segment's steady speed), single-sample glitches and count jumps; it estimates the noise per
   channel from second differences (structure smooth on the sampling scale cannot inflate it)
   and lays out K blocked, randomly assigned held-out folds.
2. **base fit**: the kind's base terms (one constant per channel and run, run angle offsets,
   the kind's error function up to the orders the record resolves) by Gauss-Newton /
   Levenberg-Marquardt on sufficient statistics accumulated chunk by chunk (bounded memory).
3. **locate** (:mod:`encdesign.diagnose.engine._views`): views of the residual, each finding with
   where it sits and a p-value.
4. **select**: forward selection of candidates whose signature matches a finding, each refit
   with everything accepted so far; accepted on information criterion, K-fold held-out gain,
   plausibility and conditioning; then a backward check on held-out data.
5. **held-out proof**: the K-fold held-out residual of each model, from the per-fold
   sufficient statistics (exact for parameters the model is linear in).
6. **verdict** and report: ``consistent`` only when the goodness-of-fit test (variance ratio
   of the residual to the difference-based noise, globally and per time block) passes and no
   view finds anything.

The wall time of each stage goes to the document's ``timings_s`` (:mod:`._timing`; exclusive:
they add up to the diagnosis, less the report's text): ``reduce`` (issue 43: a record over
``FinderSettings.reduce_min_rows`` rows to block means, :mod:`._reduce`; ``reduced`` in the
document says whether, ``B`` and the bound), ``data`` (the kind's observations
from the recording's columns), ``prepare`` (segments, glitches, noise, folds), ``base_fit``
(with the base's order growth and noise), ``views`` (every scan of a residual, wherever it
runs), ``candidates`` (each candidate's starts and trial fits), ``heldout`` (the K-fold
held-out solutions of every fit), ``select`` (the rest of stage 4: choosing, the backward
check, residuals) and ``report`` (the document, the kind's additions, the verdict, the
named effects' contributions).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..._errors import input_error
from ._aside import SetAside
from ._base_order import (
    choose_base_order,
    choose_order_again,
    least_heldout_order,
    order_beside_refused,
    order_row,
    set_order,
    terms_at_order,
)
from ._bounds import REFERENCE_DESCRIPTION, Reference, detection_bounds, not_covered
from ._candidates import Candidate
from ._discover import discover
from ._discover_rival import discovered
from ._document import (
    global_times_in_own_clock,
    lattice_effect,
    order_spectrum,
    report_text,
    scan_order_of,
    se_dict,
    significant_channels,
    term_params,
)
from ._fit import FitResult, Fitter, make_term
from ._goodness import goodness_of_fit
from ._growth_line import growth_beside_line
from ._growth_start import grown_base
from ._kind import AbstractKind as Kind
from ._located import value_in_interval
from ._noise import noise_method, noise_spectral_dof
from ._nuisances import excluded_share, step_context
from ._protocol import Prepared
from ._reduce_restart import check_growth, orders_checked, run_reduced, state_reduction
from ._refine import checked_fit, refine_base
from ._results import PlotData
from ._select import Selection, select
from ._settings import DEFAULT_SETTINGS, SETTINGS_FIELDS, FinderSettings
from ._steps import run_param_interval, time_param_interval
from ._timing import stage, timing
from ._views import locate
from ._views_modulated import base_jacobian
from ._views_time import findings_listed


def _phase_at_orders(findings: list, L: int) -> float:
    """The excess of the ``line_phase`` view that the ``orders`` view locates too, at the
    integer orders ``L`` and ``2 L``: where the signal phase is ``L`` times the shaft angle
    (one sensor against its reference) the line at the signal period is those shaft orders,
    rotation locked, the disk's own error there as much as ``interpolation_error``'s (a disk
    error whose orders run past ``2 L``): the same structure, not an aliased line that only
    poses as integer orders."""
    lp = sum(max(f.power - f.dof, 0.0) for f in findings if f.view == "line_phase")
    at = sum(
        max(f.power - f.dof, 0.0)
        for f in findings
        if L > 0 and f.view == "orders" and {round(o) for o in f.where["orders"]} & {L, 2 * L}
    )
    return min(lp, at)


def _grow_base_order(
    kind: Kind,
    prep: Prepared,
    fitter: Fitter,
    fit: FitResult,
    order: int,
    limits: tuple[int, int],
    base_info: dict,
):
    """The base's order growth (:func:`_grow_to`) within ``limits = (budget limit, growth
    limit)``: past the budget (``max_param_fraction``) up to the kind's growth limit
    (``growth_param_fraction``) first, where the record's budget binds; else, as before it,
    within the budget. Returns ``(order, fit)``, grown and refitted, or ``None``."""
    limit, glimit = limits
    if glimit > limit:
        grown = _grow_to(kind, prep, fitter, fit, order, glimit, base_info, past=limit)
        if grown is not None:
            return grown
    return _grow_to(kind, prep, fitter, fit, order, limit, base_info)


def _grow_to(
    kind: Kind,
    prep: Prepared,
    fitter: Fitter,
    fit: FitResult,
    order: int,
    limit: int,
    base_info: dict,
    past: int | None = None,
):
    """Integer orders above ``order`` that the base residual shows significantly (the
    ``orders`` view, up to ``min(limit, max(2 order, 24))``) join the base model: a disk's
    error function has every order, and one left out would be reported as structure no
    effect explains. Not when the residual also shows a line at the signal period (aliased,
    it can pose as integer orders) holding at least ``settings.growth_veto_share`` of what
    every view located and staying significant beside the orders the growth would add (or
    they not beside it: :func:`._growth_line.growth_beside_line`), nor when the grown base
    leaves that share in structure tied to the direction, the speed or the angle's trend
    (the candidates' to explain; judged after the growth, since on part of a turn the
    missing orders leak into it, issue 44); and the grown base must leave at most
    ``settings.growth_left_max`` of what every view located (a line in Hz, a step or a drift
    that only leaks into high orders stays the candidates'; a strong order's leakage into
    lines off the integers goes with it; before it is undone, the grown base from the kind's
    own start at the grown order: :func:`._growth_start.grown_base`).
    Orders ``L`` and ``2 L`` of the signal period (``interpolation_error``'s) stay out. Where
    held-out error lowered the base order (:func:`choose_base_order`), growth is also undone
    when it raises the held-out chi-square; on part of a turn (``Prepared.part_turn_span``:
    the orders are not separable there; the kind's base says so) held-out error decides
    neither (it never lowers the order there). ``past``: the budget's order
    (``max_param_fraction``); the growth is then tried only to an order above it, and kept
    only where it lowers the held-out chi-square by ``settings.heldout_min`` (the orders past
    the budget earn their parameters on held-out rows). Returns ``(order, fit)``, grown and
    refitted, or ``None``."""
    hi = scan_order_of(limit, order, prep.settings)
    if hi <= order:
        return None
    L = int(getattr(prep.ctx, "signal_periods", 0) or 0)
    findings = locate(prep, fitter.residual(fit.terms), kind.views(prep), hi)
    p0 = sum(max(f.power - f.dof, 0.0) for f in findings)
    veto = prep.settings.growth_veto_share * p0
    pv = sum(max(f.power - f.dof, 0.0) for f in findings if f.view == "line_phase")
    line = pv - min(_phase_at_orders(findings, L), pv) > max(veto, 0.0)
    found = [
        round(f.where["orders"][0])
        for f in findings
        if f.view == "orders" and f.where["orders"] and round(f.where["orders"][0]) > order
    ]
    found = [m for m in found if not (L > 0 and m in (L, 2 * L))]
    if not found:
        return None
    M = int(max(found))
    if past is not None and M <= past:
        return None
    check_growth(prep, limit, M)  # issue 43: not past the orders a reduced record keeps
    if line and not growth_beside_line(prep, fitter.residual(fit.terms), order, M, L, base_info):
        return None
    lowered = (base_info.get("order_choice") or {}).get("lowered", False)
    # (an order the held-out choice lowered, or one past the budget, grows only where
    # held-out error allows; the two held-out chi-squares in the same noise weights)
    ho0 = fitter.fit(fit.terms).heldout_chi2 if lowered or past is not None else math.inf
    judged = (p0, veto, ho0, past)
    grown, refused = _grown_at(kind, prep, fitter, fit, (order, M, limit), judged, base_info)
    lower, located = sorted({m for m in found if order < m < M}), sorted(set(found))
    if grown is None and refused and lowered and past is None and lower:
        # session 36: held-out error refused the highest located order; the located order
        # it favours (the same rule as the base order's choice), once
        M2 = least_heldout_order(kind, prep, fitter, fit, order, lower, ho0)
        if M2 is not None:
            grown, _ = _grown_at(kind, prep, fitter, fit, (order, M2, limit), judged, base_info)
            M, found = M2, [m for m in found if m <= M2]
    if grown is None:  # the orders the residual showed, left out (the vibration's doubt)
        left = set(prep.ctx.orders_left_out) | set(located)
        prep.ctx = dataclasses.replace(prep.ctx, orders_left_out=tuple(sorted(left)))
        return None
    base_info["grown_orders"] = sorted(set(base_info.get("grown_orders", [])) | set(found))
    return M, grown


def _grown_at(kind, prep: Prepared, fitter: Fitter, fit: FitResult, orders, judged, base_info):
    """:func:`_grow_to`'s growth from ``order`` to ``M`` (``orders = (order, M, limit)``)
    and its checks (``judged = (p0, veto, ho0, past)``). Returns ``(grown fit or None,
    whether held-out error alone refused it)``."""
    order, M, limit = orders
    p0, veto, ho0, past = judged
    terms, info = terms_at_order(kind, prep, fit, M)
    set_order(prep, M)
    left = prep.settings.growth_left_max
    fitter.clear()
    hi1, fresh = scan_order_of(limit, M, prep.settings), lambda: _base_terms(kind, prep, M)[0]
    grown, after, p1, restart = grown_base(  # (restarted from the kind's own start: session 23)
        fitter, terms, fresh, lambda r: locate(prep, r, kind.views(prep), hi1), left * p0
    )
    tv = ("direction", "speed", "angle_trend")  # tied: judged after the growth
    tied = sum(max(f.power - f.dof, 0.0) for f in after if f.view in tv)
    held = grown.heldout_chi2 > ho0
    worse = held or tied > max(veto, 0.0)
    drop = ho0 - grown.heldout_chi2
    if past is not None and not drop >= prep.settings.heldout_min:
        worse = True
    if p1 > left * p0 or worse:
        set_order(prep, order)
        fitter.clear()
        return None, held and p1 <= left * p0 and not tied > max(veto, 0.0)
    base_info.update(info)
    if past is not None:  # the orders past the parameter budget, and what they earned
        base_info["grown_past_budget"] = {"budget_order": past, "heldout_chi2_drop": drop}
    base_info.update({"grown_from_start": True} if restart else {})
    return grown, False


class _Progress:
    """The two tqdm bars of a diagnosis (stages, rows of each chunked pass); quiet unless
    ``verbose`` on a terminal."""

    def __init__(self, verbose: bool):
        from ..._progress import progress_bar

        self.verbose = verbose
        self.bar = progress_bar("diagnose", 6, enabled=verbose, unit="stage")
        self.rows = None
        self.bar.set_postfix_str("preparing")

    def stage(self, name: str) -> None:
        self.bar.set_postfix_str(name)
        self.bar.update(1)

    def log(self, msg: str) -> None:
        if self.verbose:
            self.bar.set_postfix_str(msg)

    def chunk_done(self, a: int, b: int, n: int) -> None:
        if self.rows is None:
            from ..._progress import progress_bar

            self.rows = progress_bar("  pass", n, enabled=self.verbose, unit="row")
        if a == 0:
            self.rows.reset(total=n)
        self.rows.update(b - a)

    def close(self) -> None:
        if self.rows is not None:
            self.rows.close()
        self.bar.close()


def _order_of(kd, prep: Prepared, kind: Kind, max_order: int | None) -> tuple[int, int]:
    """``(order, limit)``: the base order to start from and the highest the record
    resolves. Raises EncdesignInputError for a ``max_order`` beyond the limit."""
    limit = int(kind.max_order_limit(prep))
    if max_order is not None and max_order > limit:
        raise input_error(
            f"{kd.where}: --max-order",
            f"got {max_order}; this record resolves orders up to {limit} "
            "(half the samples per revolution of its slowest-sampled run, and at most "
            f"{prep.settings.max_param_fraction:.0%} of the fitted values as parameters)",
            f"a max order <= {limit}",
        )
    order = min(limit, kind.default_max_order) if max_order is None else max_order
    return order, limit


def _base_terms(kind: Kind, prep: Prepared, order: int) -> tuple[list, dict]:
    """The kind's base terms at ``order`` (scales from the noise) and its base info."""
    set_order(prep, order)
    base_spec, base_info = kind.base(prep, order)
    base_terms = [make_term(c, prep, st) for c, st in base_spec]
    for tm in base_terms:
        for q in tm.cand.params:
            if q.scale is None:
                tm.scale[q.name][...] = float(np.mean(prep.sigma))
    return base_terms, base_info


def _align(kind: Kind, prep: Prepared, fitter: Fitter, fit: FitResult) -> None:
    """Rotation-locked candidates see the aligned angle (the kind's ``align``)."""
    aligned = kind.align(fit.terms, prep)
    if aligned is None:
        return
    if callable(aligned):  # a lazy column fn(lo, hi)
        prep.rows.set_lazy("theta", aligned)
    else:
        prep.rows["theta"] = aligned
    fitter.clear()


def _estimate_noise(kind: Kind, prep: Prepared, fitter: Fitter, fit: FitResult) -> None:
    """The noise from the base residual's periodogram (structure cannot inflate it), or the
    kind's own estimate; the fitter's weights follow."""
    r_base = fitter.residual(fit.terms)
    est = kind.noise(prep, r_base)
    if est is not None and est.info is not None:  # the kind's findings, for its candidates
        prep.ctx = dataclasses.replace(prep.ctx, noise_info=est.info)
    own = None if est is None else est.sigma
    if own is not None and kind.noise_replaces:
        sig, dof = np.asarray(own, float), None
    else:  # the kind's second estimate, where it has one: the smaller of the two
        sig, dof = noise_spectral_dof(prep, r_base, fit.n_params, own)
    del r_base
    if np.all(np.isfinite(sig)) and np.all(sig > 0):
        prep.sigma, prep.noise_dof = sig, dof
        prep.ctx.noise[...] = sig
        fitter.w_ch = 1.0 / sig**2
        fitter.clear()


def _fit_base(kind, prep, fitter, base_terms, base_info, order, limit, grow: bool):
    """Base fit, the kind's refinement, alignment, noise and (``grow``) the base's order
    growth. Returns ``(base_fit, order, limit)``: the limit is the kind's growth limit
    (``growth_param_fraction``) where the base grew past ``limit``."""
    base_fit = checked_fit(kind, prep, fitter, fitter.fit(base_terms), base_info)
    base_fit = refine_base(kind, prep, fitter, base_fit, base_info)
    _align(kind, prep, fitter, base_fit)
    _estimate_noise(kind, prep, fitter, base_fit)
    if grow:  # issue 44 E: an ill-conditioned base's order is chosen by held-out error
        chosen = choose_base_order(kind, prep, fitter, base_fit, order, base_info)
        if chosen is not None:
            order, base_fit = chosen[0], checked_fit(kind, prep, fitter, chosen[1], base_info)
            _align(kind, prep, fitter, base_fit)
            _estimate_noise(kind, prep, fitter, base_fit)
    limits = (limit, max(limit, int(kind.growth_order_limit(prep)))) if grow else (limit, limit)
    for _ in range(2 if grow else 0):
        grown = _grow_base_order(kind, prep, fitter, base_fit, order, limits, base_info)
        if grown is None:
            break
        order, base_fit = grown[0], checked_fit(kind, prep, fitter, grown[1], base_info)
        # the refinement evaluated the fitted error before the orders grown: again with them
        base_fit = refine_base(kind, prep, fitter, base_fit, base_info)
        _align(kind, prep, fitter, base_fit)  # the refit moved the run offsets a little
        _estimate_noise(kind, prep, fitter, base_fit)  # the orders it left out were there
    return base_fit, order, (limits[1] if order > limit else limit)


def _effect_json(prep: Prepared, sel: Selection, s, fitter: Fitter | None = None) -> dict:
    """One named effect of the selection as its JSON entry (with ``fitter``, each parameter
    that is a time gains its interval: :func:`._steps.time_param_interval`)."""
    final = sel.final
    idx = next(i for i, t in enumerate(final.terms) if t.cand.name == s.name)
    term = final.terms[idx]
    derived = {}
    if term.cand.derived is not None:
        derived = term.cand.derived(prep.ctx, term.values, se_dict(term, final, idx))
    chans = significant_channels(term, final, idx, prep.n_channels, prep.ctx.n_runs, prep.settings)
    names = prep.kd.channel_names
    params = global_times_in_own_clock(prep, term, term_params(term, final, idx))
    for q in term.cand.params:  # issue 44 C: a located time's interval
        if fitter is None or q.name not in params or not (q.global_time or q.first_run):
            continue
        if q.global_time:
            lt = time_param_interval(fitter, prep, final.terms, idx, q.name)
            keys = ("interval_s", "interval_runs", "level", "convention")
        else:
            lt = run_param_interval(fitter, prep, final.terms, idx, q.name)
            keys = ("t_s", "run", "interval_s", "interval_runs", "level", "clock", "convention")
        params[q.name].update({k: lt[k] for k in keys})
        if q.global_time:  # the value inside its own interval
            params[q.name] = value_in_interval(params[q.name], lt)
    out = {
        "name": s.name,
        "params": params,
        "derived": derived,
        "channels": [names[k] for k in chans] if chans is not None else None,
        "rms_after": s.fit.rms(prep),
        "heldout_rms_after": s.fit.heldout_rms(prep),
        "delta_bic": float(s.delta_bic),
        "delta_heldout_chi2": float(s.delta_heldout),
        "collinearity": float(s.collinearity) if np.isfinite(s.collinearity) else None,
        "share": float(sel.shares.get(s.name, 0.0)),
        "size_rms": float(s.term_rms * float(np.mean(prep.sigma))),
        "notes": s.notes,
        "explanation": term.cand.explanation,
        "confounded_with": s.confounded,
    }
    if s.doubt is not None:  # named although a plausibility rule doubts it (issue 22 item 3)
        out["doubt"] = s.doubt
        out["alternatives"] = s.alternatives
    return out


def confounded_pairs(effects: list[dict], refused_pairs: list[dict]) -> list[dict]:
    """The ``confounded`` entries: each named effect with each candidate it cannot be told
    from (its ``confounded_with`` ties), and pairs refused together by one rule."""
    out = []
    for e in effects:
        for c in e.get("confounded_with") or []:
            if c.get("correlation") is None:
                continue
            db = c.get("delta_bic")
            out.append(
                {
                    "pair": [e["name"], c["name"]],
                    "correlation": float(min(c["correlation"], 1.0)),
                    "delta_bic": None
                    if db is None or e["delta_bic"] is None
                    else float(db - e["delta_bic"]),
                    "separate_by": c.get("separate_by", ""),
                    "reason": c["reason"] + f"; {e['name']} is named",
                    "rule": c.get("rule") or "tie_corr",
                }
            )
    return out + list(refused_pairs)


def effect_contributions(prep: Prepared, fitter: Fitter, sel: Selection) -> dict[str, np.ndarray]:
    """``{name: (n, C)}``: each named effect's own contribution in the final model (its
    term evaluated alone, chunk by chunk; projected like the residual where the kind
    projects), unit of y."""
    out = {}
    names = {s.name for s in sel.accepted}
    for term in sel.final.terms:
        if term.cand.name not in names:
            continue
        parts = []
        for a, b, x in fitter.chunks():
            v = np.asarray(fitter.eval_term(term, a, b, x, jac=False)[0], float)
            if prep.kd.project:
                v = v - v.mean(1, keepdims=True)
            parts.append(v.reshape(b - a, -1))
        out[term.cand.name] = np.concatenate(parts) if parts else np.zeros((0, prep.n_channels))
    return out


def bounds_reference(doc: dict, sel: Selection, max_effects: int) -> Reference:
    """The model the detection bounds are computed against (:mod:`._bounds`): the final one,
    the base plus the named effects (and the partners each is named with), the findings the
    final residual leaves (none on a consistent verdict)."""
    named = {e["name"] for e in doc["effects"]}
    named |= {c["name"] for e in doc["effects"] for c in e.get("confounded_with") or []}
    return Reference(
        terms=sel.final.terms,
        n_base=len(sel.base.terms),
        named=frozenset(named),
        room=len(doc["effects"]) < max_effects,
        findings=tuple(sel.findings) if doc["verdict"] != "consistent" else (),
        n_params=int(sel.final.n_params),
    )


def decide_verdict(doc: dict) -> str:
    """The verdict, decided once from the finished document: ``missing_physics`` when an
    effect is named, ``unexplained`` when structure is located that none explains or the
    goodness-of-fit test fails, else ``consistent``."""
    if doc["effects"]:
        return "missing_physics"
    if doc["unexplained"] or not (doc.get("goodness_of_fit") or {}).get("passes", True):
        return "unexplained"
    return "consistent"


def _nearest_catalog(rejected: list[dict]) -> list[dict]:
    """The catalog candidates fitted and refused in this diagnosis (best criterion first, one
    entry per name): the nearest catalog effects a discovered model reports, and why each
    was not enough."""
    seen: dict[str, dict] = {}
    for r in rejected:
        if r.get("delta_bic") is None or r["name"] in seen:
            continue
        seen[r["name"]] = {"name": r["name"], "reason": r["reason"], "delta_bic": r["delta_bic"]}
    return sorted(seen.values(), key=lambda r: r["delta_bic"])[:3]


def _document(kind, rec, prep, sel, base_info, order, limit, scan, fitter=None) -> tuple:
    """``(document, selection)``: the document before the kind's additions, the verdict and
    the report. With ``fitter`` and ``settings.discover`` on, each ``unexplained`` finding
    gains a ``model``: what discovery (:mod:`._discover`) models of it outside the catalog,
    fitted jointly with the final catalog model (the verdict stays ``unexplained``); the
    named effects are re-tested beside it (:mod:`._discover_rival`: the selection less those
    it refuses)."""
    kd = prep.kd
    models = None
    if fitter is not None and prep.settings.discover:
        sel, models = discovered(prep, fitter, sel, kind.views(prep), scan, discover)
    base, final = sel.base, sel.final
    sig_mean = float(np.mean(prep.sigma))
    effects = [_effect_json(prep, sel, s, fitter) for s in sel.accepted]
    unexplained = [
        {**f.to_json(sig_mean), "note": "significant structure no named effect explains"}
        for f in findings_listed(sel.findings, 12)
    ]
    for u in unexplained:  # a located step: where it lies in the motion (issue 22 item 4)
        if (ctx := step_context(prep, u)) is not None:
            u["step_at"] = ctx
    if models is not None:
        near = _nearest_catalog(sel.rejected)
        for u, m in zip(unexplained, models):
            if m is not None:
                u["model"] = {**m, "nearest_catalog": near} if m["terms"] else m
    if kind.reading_lattice and not any(e["name"] == "quantization" for e in effects):
        q_eff = lattice_effect(prep, final.rms(prep), final.heldout_rms(prep))
        if q_eff is not None:
            effects.append(q_eff)
    nuis_notes = []
    if prep.excluded:
        nuis_notes.append(
            f"{len(prep.excluded)} non-steady segment(s) left out of every fit "
            f"({sum(e['n_rows'] for e in prep.excluded)} rows)"
        )
    base_params = {t.cand.name: term_params(t, base, i) for i, t in enumerate(base.terms)}
    # the base terms as refitted with the named effects (kinds report e.g. their ellipse)
    final_base = {
        t.cand.name: term_params(t, final, i)
        for i, t in enumerate(final.terms)
        if t.cand.name in base_params
    }
    doc = {
        "format": "encdesign-diagnosis/2",
        "kind": rec.kind,
        "recording": str(rec.path) if rec.path is not None else None,
        "verdict": None,  # decided once, after the kind's additions (decide_verdict)
        "unit": kd.unit,
        "rms_before": base.rms(prep),
        "heldout_rms_before": base.heldout_rms(prep),
        "rms_final": final.rms(prep),
        "heldout_rms_final": final.heldout_rms(prep),
        "noise": {
            "per_channel": [float(s) for s in prep.sigma],
            "channels": kd.channel_names,
            "method": noise_method(prep),
        },
        "goodness_of_fit": goodness_of_fit(prep, sel.final_resid, final.n_params),
        "goodness_of_fit_base": sel.gof0,
        "heldout": prep.fold_design,
        "excluded_segments": prep.excluded,
        "glitches": prep.glitches,
        "count_jumps": [
            {k: v for k, v in j.items() if k not in ("index", "channel_index")}
            for j in prep.count_jumps
        ],
        "gaps": prep.gaps,
        "angle_steps": [
            {
                **{k: v for k, v in s.items() if k != "channel_index"},
                "channel": kd.channel_names[s["channel_index"]],
            }
            for s in prep.angle_steps
        ],
        "effects": effects,
        "unexplained": unexplained,
        "rejected": sel.rejected,
        "confounded": confounded_pairs(effects, sel.confounded),
        "not_testable": sel.not_testable,
        "findings_before": [f.to_json(sig_mean) for f in findings_listed(sel.findings0, 12)],
        "base": {
            "terms": base_params,
            "max_order": order,
            "max_order_limit": limit,
            "max_param_fraction": prep.settings.max_param_fraction,
            "n_params": base.n_params,
            "unidentifiable": base.unidentifiable + base_info.get("unidentifiable", []),
            "has_theta_ref": prep.ctx.has_ref,
            "terms_with_effects": final_base,
            **{k: v for k, v in base_info.items() if k not in ("unidentifiable", "order_choice")},
        },
        "notes": nuis_notes,
        "status": "ok"
        if (base.converged and final.converged)
        else "a least-squares fit stopped before converging",
        "settings": {f: getattr(prep.settings, f) for f in SETTINGS_FIELDS},
    }
    if base_info.get("order_choice") is not None:  # issue 44 E: the order held-out error chose
        doc["base_order"] = base_info["order_choice"]
    doc["spectrum"] = order_spectrum(prep, sel.base_resid, sel.final_resid, scan)
    # issue 22 item 4: a record mostly excluded is said so, with the reasons
    doc["excluded_share"] = excluded_share(
        prep.n, int(prep.keep.sum()), prep.excluded, prep.settings
    )
    doc.update(kind.summary(prep, base_params))
    return doc, sel


def _base_done(prep: Prepared, fitter: Fitter, base_fit: FitResult, order: int, limit: int):
    """The base's Jacobian and terms for the views and candidates; returns the scan order."""
    prep.base_jacobian = base_jacobian(prep, fitter, base_fit.terms)
    prep.base_terms = tuple(base_fit.terms)
    return scan_order_of(limit, order, prep.settings)


def _refit_at(kind, prep: Prepared, fitter: Fitter, base_fit: FitResult, M: int, base_info):
    """The base refitted at order ``M`` (:func:`._base_order.choose_order_again`'s), aligned,
    its noise estimated again, as after the first held-out choice. Returns ``(M, fit)``."""
    terms, info = terms_at_order(kind, prep, base_fit, M)
    set_order(prep, M)
    fitter.clear()
    base_info.update(info)
    choice = base_info["order_choice"]
    choice.update(chosen=int(M), lowered=M < choice["start"])
    choice["reason"] += "; " + choice["again"]["reason"]
    fit = checked_fit(kind, prep, fitter, fitter.fit(terms), base_info)
    if M not in {r["order"] for r in choice["tried"]}:  # (order_beside_refused: not tried)
        tried = [*choice["tried"], order_row(prep, M, fit)]
        choice["tried"] = sorted(tried, key=lambda r: r["order"])
    _align(kind, prep, fitter, fit)
    _estimate_noise(kind, prep, fitter, fit)
    return M, fit


def run_engine(
    kind: Kind,
    rec,
    *,
    max_order: int | None = None,
    max_effects: int = 3,
    extra_candidates: Sequence[Candidate] = (),
    verbose: bool = False,
    settings: FinderSettings | None = None,
    reduced: dict | None = None,
) -> tuple[dict[str, Any], PlotData]:
    """Diagnose ``rec`` with ``kind``; returns ``(document, plot data)``: the diagnosis JSON
    document (a dict, ``diagnosis.schema.json``) and what the figures need
    (:class:`~encdesign.diagnose.engine._results.PlotData`).

    ``reduced``: the ``reduced`` entry of a record already reduced to block means as it was
    read (:func:`._reduce_stream.stream_reduce`); else a long record is reduced here.

    The kind's ``finish`` additions (floors named from a lattice, clipping, ...) come
    before the verdict, which :func:`decide_verdict` decides once, and before the report,
    built once from the finished document.

    Raises:
        EncdesignInputError: a recording the kind cannot diagnose, or ``max_order`` beyond
            what the record resolves.
    """
    settings = DEFAULT_SETTINGS if settings is None else settings
    t0 = time.perf_counter()
    pg = _Progress(verbose)
    own = max_order is None
    order0, grows = (kind.default_max_order if own else max_order), kind.grows_orders and own
    try:
        with timing() as timer:  # issue 43: a long record on block means (_reduce_restart)

            def once(r, red: dict):
                return _diagnose(
                    kind, r, red, max_order, max_effects, extra_candidates, pg, settings
                )

            doc, plot = run_reduced(once, rec, reduced, order0, grows, settings)
        doc["time_s"] = time.perf_counter() - t0
        doc["timings_s"] = dict(timer.totals)
        doc["timings_cpu_s"] = dict(timer.cpu_totals)
        doc["report"] = report_text(doc) + kind.report_lines(doc)
    finally:
        pg.close()
    return doc, plot


def _diagnose(kind, rec, reduced: dict, max_order, max_effects, extra_candidates, pg, settings):
    """:func:`run_engine`'s diagnosis of ``rec``, reduced as ``reduced`` says (or not):
    ``(document without its times and report, plot data)``."""
    with stage("data"):
        kd = kind.data(rec, settings)
    meta = dict(rec.meta)
    meta.setdefault("kind", rec.kind)
    with stage("prepare"):
        prep = kind.prepare(kd, meta, settings)
    prep.orders_kept = orders_checked(reduced)  # issue 43: a growth past it restarts
    pg.stage("prepared")
    with stage("base_fit"):
        order, limit = _order_of(kd, prep, kind, max_order)
        base_terms, base_info = _base_terms(kind, prep, order)
        fitter = Fitter(prep, progress=pg.chunk_done)
        seen: dict[str, Candidate] = {}
        for c in [*kind.candidates(prep.ctx), *extra_candidates]:
            seen[c.name] = c  # later ones (reference, user terms) override by name
        grow = kind.grows_orders and max_order is None
        base_fit, order, limit = _fit_base(
            kind, prep, fitter, base_terms, base_info, order, limit, grow
        )
        scan = _base_done(prep, fitter, base_fit, order, limit)
    pg.stage("base fitted")
    cands = list(seen.values())
    with stage("select"):
        sel = select(
            prep, fitter, base_fit.terms, cands, kind.views(prep), scan, max_effects, pg.log
        )
        nb = len(sel.base.terms)
        again = choose_order_again(kind, prep, fitter, sel.final, nb, order, base_info)
        if again is None and grow:  # session 38: the same beside an effect held-out refused
            again = order_beside_refused(
                kind, prep, fitter, sel.heldout_refused, nb, order, base_info
            )
    if again is not None:  # session 36: the held-out choice made again beside the effects
        with stage("base_fit"):
            order, base_fit = _refit_at(kind, prep, fitter, base_fit, again, base_info)
            scan = _base_done(prep, fitter, base_fit, order, limit)
        with stage("select"):
            sel = select(
                prep, fitter, base_fit.terms, cands, kind.views(prep), scan, max_effects, pg.log
            )
    pg.stage("selected")
    pg.stage("held-out + goodness of fit")
    with stage("report"):
        doc, sel = _document(kind, rec, prep, sel, base_info, order, limit, scan, fitter)
        pg.stage("report")
        doc = kind.finish(prep, doc, settings)
        state_reduction(doc, reduced)
        doc["verdict"] = decide_verdict(doc)
    with stage("bounds"):  # issue 44 F: what the record could have shown
        # the selection's two residuals are not read by the bounds (the stage with the
        # highest peak on a long record): in a temporary file meanwhile (issue 43, _aside)
        aside = SetAside([sel.base_resid, sel.final_resid])
        sel = dataclasses.replace(sel, base_resid=None, final_resid=None)
        ref = bounds_reference(doc, sel, max_effects)
        doc["detection_bounds"] = detection_bounds(prep, fitter, ref, cands, kind.views(prep), scan)
        doc["detection_bounds_not_covered"] = not_covered(cands, prep, ref)
        doc["detection_bounds_reference"] = ref.to_json(REFERENCE_DESCRIPTION)
        base_resid, final_resid = aside.restore()
        sel = dataclasses.replace(sel, base_resid=base_resid, final_resid=final_resid)
        del base_resid, final_resid
    with stage("report"):
        contributions = effect_contributions(prep, fitter, sel)
    plot = PlotData(
        prep=prep,
        base_resid=sel.base_resid,
        final_resid=sel.final_resid,
        effect_contributions=contributions,
    )
    return doc, plot
