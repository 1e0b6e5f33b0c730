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
3. **locate** (:mod:`encdesign.diagnose._views`): views of the residual, each finding with
   where it sits and a p-value.
4. **select**: forward selection of candidates whose signature matches a finding, each refit
   with everything accepted so far; accepted on information criterion, K-fold held-out gain,
   plausibility and conditioning; then a backward check on held-out data.
5. **held-out proof**: the K-fold held-out residual of each model, from the per-fold
   sufficient statistics (exact for parameters the model is linear in).
6. **verdict** and report: ``consistent`` only when the goodness-of-fit test (variance ratio
   of the residual to the difference-based noise, globally and per time block) passes and no
   view finds anything.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._errors import input_error
from ._candidates import Candidate
from ._document import (
    _scan_order,
    _se_dict,
    _significant_channels,
    lattice_effect,
    order_spectrum,
    report_text,
    term_params,
)
from ._fit import FitResult, Fitter, goodness_of_fit, make_term
from ._prepare import noise_spectral, prepare
from ._protocol import Kind, Prepared
from ._select import select
from ._settings import MAX_PARAM_FRACTION
from ._views import locate

GROWTH_LEFT_MAX = 0.2
"""The grown base must leave at most this share of the structure the views located (excess
chi-square over their degrees of freedom) in the base residual, or the growth is undone."""


def _grow_base_order(
    kind: Kind,
    prep: Prepared,
    fitter: Fitter,
    fit: FitResult,
    order: int,
    limit: int,
    base_info: dict,
):
    """Integer orders above ``order`` that the base residual shows significantly (the
    ``orders`` view, up to ``min(limit, max(2 order, 24))``) join the base model: a disk's
    error function has every order, and one left out would be reported as structure no
    effect explains. Not when the residual also shows a line at the signal period (aliased,
    it can pose as integer orders) or structure tied to the direction or speed (the
    candidates' to explain); and the grown base must leave at most ``GROWTH_LEFT_MAX`` of
    what every view located (a line in Hz, a step or a drift that only leaks into high orders
    stays the candidates'; a strong order's leakage into lines off the integers goes with it).
    Orders ``L`` and ``2 L`` of the signal period
    (``interpolation_error``'s) stay out. Returns ``(order, fit)``, grown and refitted from
    the fitted values, or ``None`` (nothing changed)."""
    hi = _scan_order(limit, order)
    if hi <= order:
        return None
    L = int(getattr(prep.ctx, "signal_periods", 0) or 0)
    findings = locate(prep, fitter.residual(fit.terms), kind.views, hi)
    if any(f.view in ("line_phase", "direction", "speed", "angle_trend") for f in findings):
        return None
    found = [
        round(f.where["orders"][0])
        for f in findings
        if f.view == "orders" and f.where["orders"] and round(f.where["orders"][0]) > order
    ]
    found = [m for m in found if not (L > 0 and m in (L, 2 * L))]
    if not found:
        return None
    M = int(max(found))
    spec, info = kind.base(prep, M)
    old = {t.cand.name: t for t in fit.terms}
    terms = []
    for cand, start in spec:
        prev = old.get(cand.name)
        st = dict(start)
        if prev is not None:
            for q in cand.params:
                v = prev.values.get(q.name)
                if v is None:
                    continue
                shp = q.resolved_shape(prep.n_channels, prep.ctx.n_runs)
                if v.shape == shp:
                    st[q.name] = v
                elif v.ndim == 1 and len(shp) == 1 and v.size < shp[0]:
                    st[q.name] = np.concatenate([v, np.zeros(shp[0] - v.size)])
        tm = make_term(cand, prep, st)
        for q in cand.params:
            if q.scale is None:
                tm.scale[q.name][...] = float(np.mean(prep.sigma))
        terms.append(tm)
    prep.consts["max_order"] = M  # type: ignore[index]
    fitter.clear()
    grown = fitter.fit(terms)
    p0 = sum(max(f.power - f.dof, 0.0) for f in findings)
    after = locate(prep, fitter.residual(grown.terms), kind.views, _scan_order(limit, M))
    p1 = sum(max(f.power - f.dof, 0.0) for f in after)
    if p1 > GROWTH_LEFT_MAX * p0:
        prep.consts["max_order"] = order  # type: ignore[index]
        fitter.clear()
        return None
    base_info.update({k: v for k, v in info.items() if k not in ("refine",)})
    base_info["grown_orders"] = sorted(set(base_info.get("grown_orders", [])) | set(found))
    return M, grown


def run_engine(
    kind: Kind,
    rec,
    *,
    max_order: int | None = None,
    max_effects: int = 3,
    extra_candidates: Sequence[Candidate] = (),
    verbose: bool = False,
) -> dict[str, Any]:
    """Diagnose ``rec`` with ``kind``; returns the diagnosis JSON document (a dict).

    Raises:
        EncdesignInputError: a recording the kind cannot diagnose, or ``max_order`` beyond
            what the record resolves.
    """
    from .._progress import progress_bar

    t0 = time.perf_counter()
    # a tqdm bar on a terminal only (quiet in pipes, logs and tests), through every stage
    bar = progress_bar("diagnose", 6, enabled=verbose, unit="stage")

    def stage(name: str) -> None:
        bar.set_postfix_str(name)
        bar.update(1)

    bar.set_postfix_str("preparing")
    kd = kind.data(rec)
    meta = dict(rec.meta)
    meta.setdefault("kind", rec.kind)
    prep = (kind.prepare or prepare)(kd, meta)
    stage("prepared")
    limit = int(kind.max_order_limit(prep))
    if max_order is not None and max_order > limit:
        raise input_error(
            f"{kd.where}: --max-order",
            f"got {max_order}; this record resolves orders up to {limit} "
            "(half the samples per revolution of its slowest-sampled run, and at most "
            f"{MAX_PARAM_FRACTION:.0%} of the fitted values as parameters)",
            f"a max order <= {limit}",
        )
    order = min(limit, kind.default_max_order) if max_order is None else max_order
    prep.consts["max_order"] = order  # type: ignore[index]
    base_spec, base_info = kind.base(prep, order)
    base_terms = [make_term(c, prep, st) for c, st in base_spec]
    for tm in base_terms:
        for q in tm.cand.params:
            if q.scale is None:
                tm.scale[q.name][...] = float(np.mean(prep.sigma))
    # a second bar moves through every chunked pass over the rows (fits, residuals)
    rows_bar = progress_bar("  pass", prep.n, enabled=verbose, unit="row")

    def chunk_done(a: int, b: int, n: int) -> None:
        if a == 0:
            rows_bar.reset(total=n)
        rows_bar.update(b - a)

    fitter = Fitter(prep, progress=chunk_done)
    cands = list(kind.candidates(prep.ctx)) + list(extra_candidates)
    seen: dict[str, Candidate] = {}
    for c in cands:
        seen[c.name] = c  # later ones (reference terms, user terms) override by name
    cands = list(seen.values())
    scan = _scan_order(limit, order)

    def log(msg: str) -> None:
        if verbose:
            bar.set_postfix_str(msg)

    # alignment: after the base fit, rotation-locked candidates see the aligned angle
    base_fit = fitter.fit(base_terms)
    refined = base_info["refine"](base_fit.terms, prep) if "refine" in base_info else None
    if refined:
        # the kind moved the angle its base model is evaluated at (e.g. the shaft from the
        # heads' mean less the fitted error's mean): refit from the fitted values
        base_info["refined"] = refined
        fitter.clear()
        base_fit = fitter.fit(base_fit.terms)

    def align(fit: FitResult) -> None:
        if "align" in base_info:
            aligned = base_info["align"](fit.terms, prep)
            if callable(aligned):  # a lazy column fn(lo, hi)
                prep.rows.set_lazy("theta", aligned)
            else:
                prep.rows["theta"] = aligned
            fitter.clear()

    align(base_fit)

    def estimate_noise(fit: FitResult) -> None:
        # the noise from the base residual's periodogram (structure cannot inflate it);
        # refit the weights with it
        r_base = fitter.residual(fit.terms)
        if kind.noise is not None and kind.noise_replaces:
            sig = np.asarray(kind.noise(prep, r_base), float)
        else:
            sig = noise_spectral(prep, r_base)
            if kind.noise is not None:  # the kind's second estimate: the smaller of the two
                sig = np.fmin(sig, np.asarray(kind.noise(prep, r_base), float))
        del r_base
        if np.all(np.isfinite(sig)) and np.all(sig > 0):
            prep.sigma = sig
            prep.ctx.noise[...] = sig
            fitter.w_ch = 1.0 / sig**2
            fitter.clear()

    estimate_noise(base_fit)
    for _ in range(2 if kind.grows_orders and max_order is None else 0):
        grown = _grow_base_order(kind, prep, fitter, base_fit, order, limit, base_info)
        if grown is None:
            break
        order, base_fit = grown
        scan = _scan_order(limit, order)
        align(base_fit)  # the refit moved the run offsets a little
        estimate_noise(base_fit)  # the orders it left out were in the residual
    stage("base fitted")
    sel = select(prep, fitter, base_fit.terms, cands, kind.views, scan, max_effects, log)
    stage("selected")
    base, final = sel["base"], sel["final"]
    C = prep.n_channels
    sig_mean = float(np.mean(prep.sigma))
    gof = goodness_of_fit(prep, sel["final_resid"], final.n_params)
    gof_base = sel["gof0"]
    stage("held-out + goodness of fit")
    effects = []
    for s in sel["accepted"]:
        idx = next(i for i, t in enumerate(final.terms) if t.cand.name == s.name)
        term = final.terms[idx]
        params = term_params(term, final, idx)
        derived = {}
        if term.cand.derived is not None:
            derived = term.cand.derived(prep.ctx, term.values, _se_dict(term, final, idx))
        chans = _significant_channels(term, final, idx, C, prep.ctx.n_runs)
        expl = term.cand.explanation
        effects.append(
            {
                "name": s.name,
                "params": params,
                "derived": derived,
                "channels": [kd.channel_names[k] for k in chans] if chans is not None else None,
                "rms_after": s.fit.rms(prep),
                "heldout_rms_after": s.fit.heldout_rms(prep),
                "delta_bic": float(s.delta_bic),
                "delta_heldout_chi2": float(s.delta_heldout),
                "collinearity": float(s.collinearity) if np.isfinite(s.collinearity) else None,
                "share": float(sel["shares"].get(s.name, 0.0)),
                "size_rms": float(s.term_rms * sig_mean),
                "notes": s.notes,
                "explanation": expl,
                "confounded_with": s.confounded,
            }
        )
    unexplained = [
        {**f.to_json(sig_mean), "note": "significant structure no named effect explains"}
        for f in sel["findings"][:12]
    ]
    if kind.reading_lattice and not any(e["name"] == "quantization" for e in effects):
        q_eff = lattice_effect(prep, final.rms(prep), final.heldout_rms(prep))
        if q_eff is not None:
            effects.append(q_eff)
    if effects:
        verdict = "missing_physics"
    elif unexplained or not gof["passes"]:
        verdict = "unexplained"
    else:
        verdict = "consistent"
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
    stage("report")
    doc = {
        "format": "encdesign-diagnosis/2",
        "kind": rec.kind,
        "recording": str(rec.path) if rec.path is not None else None,
        "verdict": verdict,
        "unit": kd.unit,
        "rms_before": base.rms(prep),
        "heldout_rms_before": base.heldout_rms(prep),
        "rms_final": final.rms(prep),
        "heldout_rms_final": final.heldout_rms(prep),
        "noise": {
            "per_channel": [float(s) for s in prep.sigma],
            "channels": kd.channel_names,
            "method": "median of the base residual's periodogram per channel (white noise: "
            "ln 2 sigma^2; structure in fewer than half the bins cannot inflate it); second "
            "differences for the first weights and the glitch scan",
        },
        "goodness_of_fit": gof,
        "goodness_of_fit_base": gof_base,
        "heldout": prep.fold_design,
        "excluded_segments": prep.excluded,
        "glitches": prep.glitches,
        "count_jumps": [
            {k: v for k, v in j.items() if k not in ("index", "channel_index")}
            for j in prep.count_jumps
        ],
        "gaps": prep.gaps,
        "effects": effects,
        "unexplained": unexplained,
        "rejected": sel["rejected"],
        "not_testable": sel["not_testable"],
        "findings_before": [f.to_json(sig_mean) for f in sel["findings0"][:12]],
        "base": {
            "terms": base_params,
            "max_order": order,
            "max_order_limit": limit,
            "max_param_fraction": MAX_PARAM_FRACTION,
            "n_params": base.n_params,
            "unidentifiable": base.unidentifiable + base_info.get("unidentifiable", []),
            "has_theta_ref": prep.ctx.has_ref,
            "terms_with_effects": final_base,
            **{
                k: v for k, v in base_info.items() if k not in ("align", "refine", "unidentifiable")
            },
        },
        "notes": nuis_notes,
        "status": "ok"
        if (base.converged and final.converged)
        else "a least-squares fit stopped before converging",
        "time_s": time.perf_counter() - t0,
    }
    doc["spectrum"] = order_spectrum(prep, sel["base_resid"], sel["final_resid"], scan)
    if kind.summary is not None:
        doc.update(kind.summary(prep, base_params))
    doc["report"] = report_text(doc)
    rows_bar.close()
    bar.close()
    doc["_plot"] = dict(prep=prep, base_resid=sel["base_resid"], final_resid=sel["final_resid"])
    return doc
