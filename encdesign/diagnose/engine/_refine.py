"""The base fit's checks by its kind: a nuisance the kind holds (``check_base``) and the
kind's refinement of the angle the base is evaluated at (``refine``), each refitted, and
undone where it would diverge (issue 44 A) or, on a record of part of a turn, where the data
do not prefer it (issue 44, session 19)."""

from __future__ import annotations

import numpy as np

from ._fit import FitResult, Fitter
from ._kind import AbstractKind as Kind
from ._prepare import folds_see_each_others_arcs
from ._protocol import FitDivergence, Prepared


def fit_failure(base_info: dict, stage: str, cause: str) -> None:
    """Record a fit stage that would have diverged (``base.fit_failures``; the report
    lists them): the stage, its cause and how the fit recovered."""
    base_info.setdefault("fit_failures", []).append(
        {"stage": stage, "cause": cause, "recovery": "undone; the fit before it is kept"}
    )


def checked_fit(kind: Kind, prep: Prepared, fitter: Fitter, fit: FitResult, info: dict):
    """``fit``, or its refit where the kind held a nuisance it had moved (``check_base``;
    the note in the base info's ``held``)."""
    note = kind.check_base(fit.terms, prep)
    if note is None:
        return fit
    if note not in info.setdefault("held", []):
        info["held"].append(note)
    fitter.clear()
    return fitter.fit(fit.terms)


def refine_base(kind, prep: Prepared, fitter: Fitter, base_fit: FitResult, base_info: dict):
    """The kind's refinement of the angle the base is evaluated at, and the base refit from
    the fitted values (undone, with a fit failure recorded, where it would diverge); run on
    the first base fit and again after the base's orders grow (the refinement evaluates the
    fitted error: without the grown orders its second-order part stays in the residual).

    Where every run covers less than one turn (``Prepared.part_turn_span``) the base's
    orders are not separable, so what the refinement evaluates (e.g. the fitted error's head
    mean) holds parts the data do not determine: the refinement is kept only where the
    refit lowers the whitened chi-square by at least
    ``settings.refine_part_turn_chi2_drop`` (it adds no parameter: the data must prefer
    it); else it is undone and ``base.refine_refused`` says why (not a fit failure: nothing
    diverged). Returns the base fit."""
    state = prep.rows.snapshot()
    try:
        refined = kind.refine(base_fit.terms, prep)
    except FitDivergence as exc:  # the kind's own check: it moved nothing
        prep.rows.restore(state)
        fit_failure(base_info, "refine", str(exc))
        refined = None
    if refined:
        # the kind moved the angle its base model is evaluated at (e.g. the shaft from the
        # heads' mean less the fitted error's mean): refit from the fitted values
        fitter.clear()
        trial = fitter.fit(base_fit.terms)
        rise = prep.settings.refine_chi2_rise_max
        need = prep.settings.refine_part_turn_chi2_drop
        drop = base_fit.chi2 - trial.chi2
        if prep.part_turn_span is not None and np.isfinite(trial.chi2) and drop < need:
            prep.rows.restore(state)
            fitter.clear()
            base_info["refine_refused"] = (
                f"{refined}: every run covers less than one turn, and the refit lowered "
                f"chi-square by {drop:.4g} (at least FinderSettings.refine_part_turn_chi2_drop"
                f" = {need:g} keeps it): undone"
            )
        elif np.isfinite(trial.chi2) and trial.chi2 <= base_fit.chi2 * (1.0 + rise):
            base_info["refined"] = refined
            base_info.pop("refine_refused", None)
            base_fit = trial
        else:  # a divergence never reaches the verdict: undo it, keep the fit before
            prep.rows.restore(state)
            fitter.clear()
            fit_failure(
                base_info,
                "refine",
                f"the refit after the kind's refinement ({refined}) raised chi-square from "
                f"{base_fit.chi2:.6g} to {trial.chi2:.6g} (more than "
                f"FinderSettings.refine_chi2_rise_max = {rise:g} of it)",
            )
    return base_fit


def heldout_decides_orders(prep: Prepared) -> bool:
    """Whether held-out error may decide the base's orders (lower them, or undo their growth
    after a lowering): always on records of a turn or more; on part of a turn
    (``Prepared.part_turn_span``) only where every run's held-out rows lie on angles its
    other folds see (:func:`._prepare.folds_see_each_others_arcs`: a pass forward and back).
    Issue 44 (session 20): one rule for the choice and the growth."""
    if prep.part_turn_span is None:
        return True
    shaft = np.asarray(prep.kd.shaft, float)
    return folds_see_each_others_arcs(shaft, prep.keep, prep.run, prep.fold)
