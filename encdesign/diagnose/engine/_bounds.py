"""Detection bounds of a clean verdict (issue 44 F): per catalog effect and per head or
sensor, the smallest size this record would have revealed at the finder's own thresholds.

A candidate offers :class:`~._candidates.Probe` s (``Candidate.probes``): a unit-size
effect, its linear parameters at one unit where it acts and its nonlinear ones held at a
stated value. The effect is added, free of noise, to the base model's prediction and the
base model refitted (its nonlinear parameters held, as the selection's trial fits hold
them); what the base leaves, ``P v``, carries the noncentrality
``lambda(a) = a^2 ||P v / sigma||^2`` of the effect at size ``a`` (the chi-square an effect
of that size adds to the base residual on average, beyond the noise). The finder names an
effect when all of these hold, and the bound is the smallest size where each is met at its
median (about 50 % power, :data:`CONVENTION`):

1. **a view locates it** (the candidate is tried only when a view of its signature finds
   something): noise-free, the signature views are run on ``a P v`` and ``a`` bisected to
   where they start to fire, at ``FinderSettings.alpha`` with their own Bonferroni counts.
   A noisy statistic of that noncentrality exceeds its threshold about half of the time
   (slightly more: the noise adds its degrees of freedom);
2. **the information criterion** (``bic_min``): the candidate's chi-square gain is
   noncentral chi-square with ``k`` degrees of freedom (its determined parameters, the
   nonlinear ones counted) and noncentrality ``lambda``; its median reaches
   ``bic_min + k ln N``;
3. **the held-out gain** (``heldout_min``): ``lambda >= heldout_min + k K / (K - 1)``, the
   held-out cost of ``k`` fitted parameters over ``K`` folds.

Only reported; nothing here changes a fit, a finding or the verdict (the noise-free record
is a copy of the prepared one, fitted by a fitter of its own).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import numpy as np
from scipy import optimize, stats

from ._candidates import Candidate, Probe
from ._fit import Fitter, Term, make_term
from ._protocol import Prepared
from ._steps import frozen
from ._views import locate

CONVENTION = (
    "the size detected with about 50 % probability: its noncentrality (the chi-square it "
    "adds to the base residual beyond the noise, after the base model takes its share) "
    "reaches the median of every test the finder asks of it (a view of its signature at "
    "alpha with the view's Bonferroni count, found noise-free; the information criterion "
    "bic_min + k ln N; the held-out gain heldout_min); 1.5x the bound is found almost "
    "always, half of it almost never"
)
"""What a reported bound means, in full (``docs/diagnose.md``, the report)."""

CONVENTION_SHORT = "50 % power at the finder's thresholds"
"""Each bound's ``convention`` in the JSON."""

VIEW_DOUBLINGS = 12
"""Doublings of the size beyond the criterion's before a view is called blind to it."""

VIEW_BISECTIONS = 5
"""Bisections of the size between the last size a view missed and the first it found
(a factor 2 to 2^(1/32), 2 %)."""

PROBE_NORM = 10.0
"""The whitened norm of the effect added to the base prediction (the fits are linear in
it; any size well inside the base model's linear range does)."""


def median_noncentrality(k: int, target: float) -> float:
    """The noncentrality ``lambda`` at which the noncentral chi-square with ``k`` degrees of
    freedom has its median at ``target`` (0 when the central one reaches it already)."""
    k = max(int(k), 1)
    if stats.chi2.median(k) >= target:
        return 0.0

    def f(lam: float) -> float:
        return float(stats.ncx2.median(k, lam)) - target

    hi = max(target, 1.0)
    while f(hi) < 0:
        hi *= 2.0
    return float(optimize.brentq(f, 1e-9, hi, xtol=1e-6))


SEEN_GRID = np.geomspace(1.0, 1e4, 801)
"""Multiples of a needed noncentrality searched for the smallest one a probe's ``seen``
reaches it at (0.5 % apart)."""


def _unseen(probe: Probe, lam: float) -> float | None:
    """The smallest noncentrality at the record's noise whose part the finder sees
    (``probe.seen``) reaches ``lam``; ``None`` when none within :data:`SEEN_GRID` does."""
    if probe.seen is None or lam <= 0:
        return lam
    for x in lam * SEEN_GRID:
        if probe.seen(float(x)) >= lam:
            return float(x)
    return None


def _values(fitter: Fitter, terms: Sequence[Term]) -> np.ndarray:
    """The sum of ``terms`` (n, C), chunk by chunk."""
    out = np.zeros_like(fitter.prep.y)
    for a, b, x in fitter.chunks():
        for t in terms:
            out[a:b] += fitter.eval_term(t, a, b, x, jac=False)[0]
    return out


def _n_nonlinear(cand: Candidate, prep: Prepared) -> int:
    """Fitted nonlinear scalars of ``cand`` (counted in its ``k``, held in the probe)."""
    C, R = prep.n_channels, prep.ctx.n_runs
    return int(
        sum(
            int(np.prod(q.resolved_shape(C, R), dtype=int))
            for q in cand.params
            if q.fit and not q.linear
        )
    )


class _Bench:
    """A noise-free copy of the prepared record: its ``y`` is the base model's prediction
    plus one probe; a fitter of its own (the base Jacobians cached across probes)."""

    def __init__(self, prep: Prepared, fitter: Fitter, base_terms: Sequence[Term]):
        self.prep = copy.copy(prep)
        self.fitter = Fitter(self.prep)
        self.fitter.w_ch = fitter.w_ch
        self.base_terms = [t.copy() for t in base_terms]
        self.pred = _values(fitter, base_terms)

    def probe(self, cand: Candidate, probe: Probe):
        """``(lam, k, residual)``: the noncentrality of the unit effect after the base
        model's refit (per unit size squared; the candidate's fit at the probe's nonlinear
        values takes all of it: the probe lies in its span), the candidate's determined
        parameters (the rank of its whitened columns on the kept rows, the nonlinear ones
        counted; a column the base also spans still counts: conservative) and the base
        residual of the unit effect (n, C); ``None`` when the effect vanishes on the kept
        rows."""
        prep, fitter = self.prep, self.fitter
        term = make_term(cand, prep, dict(probe.values))
        for q in cand.params:  # held: value and Jacobian of the linear part in one pass
            if not q.linear:
                term.free[q.name][...] = False
        v = np.zeros_like(self.pred)
        p = term.n_free()
        gram = np.zeros((p, p))
        sw = 1.0 / prep.sigma
        for a, b, x in fitter.chunks():
            va, J = fitter.eval_term(term, a, b, x, jac=True)
            v[a:b] = va
            k = prep.keep[a:b]
            if p and k.any():
                Jk = J[k]
                if prep.kd.project:
                    Jk = Jk - Jk.mean(1, keepdims=True)
                Jw = (Jk * sw[None, :, None]).reshape(-1, p)
                gram += Jw.T @ Jw
        if prep.kd.project:
            v = v - v.mean(1, keepdims=True)
        keep = prep.keep
        norm = math.sqrt(float(np.sum((v[keep] * sw[None, :]) ** 2)))
        if not (norm > 0 and math.isfinite(norm)):
            return None
        d = np.sqrt(np.maximum(np.diag(gram), 0.0))
        ok = d > 0
        ev = np.linalg.eigvalsh(gram[np.ix_(ok, ok)] / np.outer(d[ok], d[ok])) if ok.any() else []
        k_lin = int(np.sum(np.asarray(ev) > 1e-10 * max(float(np.max(ev, initial=0.0)), 1e-300)))
        c = PROBE_NORM / norm
        prep.y = self.pred + c * v
        # the base's nonlinear parameters held, as the selection's trial fits hold them: a
        # linear refit whose Jacobians are cached across probes
        base = fitter.fit(frozen(self.base_terms))
        resid = fitter.residual(base.terms)
        return base.chi2 / c**2, k_lin + _n_nonlinear(cand, prep), resid / c


def _view_size(prep, resid, views, signature, scan, a0: float) -> float | None:
    """The smallest size (multiple of the unit residual ``resid``) at which ``views``
    locate something in a view of ``signature``, from ``a0`` up (``a0`` when they do there
    already); ``None`` when none does within :data:`VIEW_DOUBLINGS` doublings."""

    def fires(a: float) -> bool:
        return any(f.view in signature for f in locate(prep, resid * a, views, scan))

    if fires(a0):
        return a0
    lo, hi = a0, 2.0 * a0
    for _ in range(VIEW_DOUBLINGS):
        if fires(hi):
            break
        lo, hi = hi, 2.0 * hi
    else:
        return None
    for _ in range(VIEW_BISECTIONS):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if fires(mid) else (mid, hi)
    return hi


def _failed_entry(cand: Candidate, probe: Probe, note: str) -> dict:
    """An entry without a bound, with the reason."""
    return {
        "effect": cand.name,
        "parameter": probe.parameter,
        "unit": probe.unit,
        "where": probe.where,
        "at": probe.at,
        "bound": None,
        "set_by": None,
        "noncentrality": None,
        "n_params": None,
        "note": note,
    }


def _bound_entry(prep, bench: _Bench, cand, probe: Probe, views, scan) -> dict:
    """One ``detection_bounds`` entry: the largest bound over the probe and its ``worst_of``
    (``bound`` ``None`` with a ``note`` when the record cannot show the effect at one of them
    at any size); reported with the probe's own ``where`` and ``at``."""
    worst: dict | None = None
    for pr in (probe, *probe.worst_of):
        e = _one_bound(prep, bench, cand, pr, views, scan)
        if e["bound"] is None:
            return e
        if worst is None or e["bound"] > worst["bound"]:
            worst = e
    assert worst is not None
    return {**worst, "where": probe.where, "at": probe.at}


def _one_bound(prep, bench: _Bench, cand, probe: Probe, views, scan) -> dict:
    """The bound of one parameter set of a probe."""
    s = prep.settings
    entry = _failed_entry(cand, probe, "")
    del entry["note"]
    got = bench.probe(cand, probe)
    if got is None or got[0] <= 0:
        return {**entry, "note": "the effect vanishes on the kept rows"}
    lam_base, k, resid = got
    if k == 0 or lam_base <= 1e-12 * PROBE_NORM**2:
        return {**entry, "note": "the base model takes all of it (not identifiable here)"}
    N = max(prep.n_values, 2.0)
    K = s.n_folds
    need = {
        "bic_min": median_noncentrality(k, s.bic_min + k * math.log(N)),
        "heldout_min": s.heldout_min + k * K / max(K - 1, 1),
    }
    rule = max(need, key=lambda r: need[r])
    lam_need = _unseen(probe, need[rule])
    if lam_need is None:
        return {**entry, "n_params": int(k), "note": "the noise estimate takes it at any size"}
    a_crit = math.sqrt(lam_need / lam_base)
    # the engine's views by name where the signature names them; a kind's own views where the
    # names they report (``KindView.names``) meet it (all of them when they do not say)
    sig = set(cand.signature)
    run = tuple(
        v
        for v in views
        if (v in sig if isinstance(v, str) else set(getattr(v, "names", sig)) & sig)
    )
    a = a_crit
    if cand.signature:
        # noise-free from the criterion's size at the record's noise: a view that fires there
        # asks less than the criterion, at that noise and (``seen`` is monotone) at any
        a0 = math.sqrt(need[rule] / lam_base)
        a_view = _view_size(bench.prep, resid, run, sig, scan, a0)
        if a_view is None:
            return {
                **entry,
                "n_params": int(k),
                "note": "no view of its signature locates it at any size tried",
            }
        if a_view > a0:
            lam_view = _unseen(probe, a_view * a_view * lam_base)
            if lam_view is None:
                return {
                    **entry,
                    "n_params": int(k),
                    "note": "the noise estimate takes it at any size",
                }
            a_view = math.sqrt(lam_view / lam_base)
            if a_view > a_crit:
                a, rule = a_view, "view"
    return {
        **entry,
        "bound": float(a * probe.size),
        "set_by": rule,
        "noncentrality": float(a * a * lam_base),
        "n_params": int(k),
    }


def detection_bounds(
    prep: Prepared,
    fitter: Fitter,
    base_terms: Sequence[Term],
    candidates: Sequence[Candidate],
    views: tuple,
    scan_order: int,
) -> list[dict]:
    """The ``detection_bounds`` of a record: one entry per probe of every candidate that
    applies and offers probes (``Candidate.probes``), in catalog order (module doc)."""
    out: list[dict] = []
    bench = None
    for cand in candidates:
        if cand.probes is None or (cand.applies is not None and cand.applies(prep.ctx)):
            continue
        probes = cand.probes(prep.ctx)
        if not probes:
            continue
        if bench is None:
            bench = _Bench(prep, fitter, base_terms)
        for probe in probes:
            try:
                entry = _bound_entry(prep, bench, cand, probe, views, scan_order)
            except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
                # reporting only: a probe that fails numerically never fails the diagnosis
                entry = _failed_entry(cand, probe, f"not computed: {exc}")
            out.append({**entry, "convention": CONVENTION_SHORT})
    return out


def not_covered(candidates: Sequence[Candidate], prep: Prepared) -> list[str]:
    """Names of the candidates that apply to this record and offer no probe (the report
    says their sizes are not bounded)."""
    return [
        c.name
        for c in candidates
        if c.probes is None and not (c.applies is not None and c.applies(prep.ctx))
    ]


__all__ = [
    "CONVENTION",
    "CONVENTION_SHORT",
    "Probe",
    "detection_bounds",
    "median_noncentrality",
    "not_covered",
]
