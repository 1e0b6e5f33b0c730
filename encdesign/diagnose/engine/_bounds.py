"""Detection bounds of a verdict (issue 44 F): per catalog effect not named and per head
or sensor, the smallest size this record would have revealed at the finder's own thresholds,
against the final model (below).

A candidate offers :class:`~._candidates.Probe` s (``Candidate.probes``): a unit-size
effect, its linear parameters at one unit where it acts and its nonlinear ones held at a
stated value. The effect is added, free of noise, to the reference model's prediction and
that model refitted (its nonlinear parameters held, as the selection's trial fits hold
them); what it leaves, ``P v``, carries the noncentrality
``lambda(a) = a^2 ||P v / sigma||^2`` of the effect at size ``a`` (the chi-square an effect
of that size adds to the model's residual on average, beyond the noise). The finder names an
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
   held-out cost of ``k`` fitted parameters over ``K`` folds;

and it is not refused by **its own size** (``plausible_ratio``): the effect's own RMS (noise
units, net of run means where the base has run constants) against the RMS it explains,
``sqrt(lambda / N)``, is a ratio the size does not change; above ``plausible_ratio`` the
finder refuses it wherever its own RMS exceeds ``plausible_rms_min``, so the bound is null
(with the note) when that holds at the bound, and the note states the size above which it
is refused otherwise.

**Against which model.** A candidate is tried against the model of its selection round, the
base plus the effects named before it, their nonlinear parameters held and their linear ones
refitted with it (``_select``'s trial fits). The bounds of a record are therefore computed
against the *final* model (:class:`Reference`): on a ``consistent`` verdict the base model,
on any other verdict the base plus the named effects (and their confounded partners: named as
a pair), each unnamed catalog effect's unit probe added to that model's prediction and the
model refitted as the trial fits refit it. A named effect is not bounded (its size is
measured). Where the selection already named ``max_effects``, no further effect would be
named at any size (``bound`` null, with the note). Where structure is left unexplained, the
final residual's findings are what a later round's candidate meets, and two more rules then
ask for a size (``set_by`` names them):

4. **its share of what is located** (``located_share_min``): at each place its own error is
   located (noise-free, the views run on ``a P v``), weighted by its power there, the share
   of the structure there that is its own (its power over its power and the final findings'
   excess at that place) must reach ``s``: structure at other places does not count (stage
   4 measures the share where the candidate's own error shows, issue 44 B);
5. **what its signature views keep** (``signature_left_max``): in its own signature views,
   weighted alike, the share of the structure at its places that is the final findings'
   must stay under ``m`` (a place where they keep ``untouched_share`` or more is another
   effect's, which the rule sets aside).

6. **the held-out gain beside that structure** (``heldout_min``): unexplained structure can
   cost a candidate its held-out gain (a fold that misses part of the structure leaves the
   candidate's columns bent to it: phase sectors of a capture, a strong order beside the
   candidate's). The trial fit of a later round is then run on the record itself with the
   effect added at the size so far (the final model held as in the trial fits, the probe's
   nonlinear values held): the size is raised (doubling, then bisection) until its held-out
   gain reaches ``heldout_min``. This one uses the record's own noise: it is the literal
   "this record would have revealed it".

And the view condition (1) is met at any size when a finding of the final residual is in
one of the candidate's signature views already (the candidate is then tried anyway).

Only reported; nothing here changes a fit, a finding or the verdict (the noise-free record
is a copy of the prepared one, fitted by a fitter of its own).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
from scipy import optimize, stats

from ._bounds_shares import VIEW_DOUBLINGS, _share_size
from ._bounds_sums import _add_gram, _channel_products, _rank
from ._candidates import Candidate, Probe
from ._evidence import ratio_limit
from ._fit import Fitter, Term, make_term
from ._normal import Accumulated, free_scales, free_values, held_key
from ._protocol import Prepared
from ._rowshare import summed
from ._select import _has_run_constants, _order_key
from ._stats_pass import ChunkMemo
from ._steps import frozen
from ._views import locate
from ._views_sums import sums_of
from ._workshare import deal

CONVENTION = (
    "the size detected with about 50 % probability: its noncentrality (the chi-square it "
    "adds to the residual beyond the noise, after the final model, the base and the named "
    "effects, takes its share) "
    "reaches the median of every test the finder asks of it (a view of its signature at "
    "alpha with the view's Bonferroni count, found noise-free; the information criterion "
    "bic_min + k ln N; the held-out gain heldout_min); 1.5x the bound is found almost "
    "always, half of it almost never"
)
"""What a reported bound means, in full (``docs/diagnose.md``, the report)."""

CONVENTION_SHORT = "50 % power at the finder's thresholds"
"""Each bound's ``convention`` in the JSON."""

VIEW_BISECTIONS = 5
"""Bisections of the size between the last size a view missed and the first it found
(a factor 2 to 2^(1/32), 2 %)."""

PROBE_NORM = 10.0
"""The whitened norm of the effect added to the base prediction (the fits are linear in
it; any size well inside the base model's linear range does)."""


@dataclasses.dataclass(frozen=True)
class Reference:
    """The model the bounds are computed against (module doc): its terms (the base's
    ``n_base`` first, then the named effects), the names not bounded (named, or named as a
    pair), whether the selection had room for another effect, and the findings the final
    residual leaves."""

    terms: Sequence[Term]
    n_base: int
    named: frozenset[str] = frozenset()
    room: bool = True
    findings: Sequence = ()
    n_params: int | None = None  # the fitted model's parameters (its free columns kept)

    def excess(self, views: set[str] | None = None) -> float:
        """The excess chi-square (power less degrees of freedom) of the final findings, in
        ``views`` and off integer orders (what ``signature_left_max`` counts) when given."""
        out = 0.0
        for f in self.findings:
            if views is not None and (f.view not in views or _order_key(f) is not None):
                continue
            out += max(float(f.power) - float(f.dof), 0.0)
        return out

    def to_json(self, description: str) -> dict:
        """``detection_bounds_reference`` (``diagnosis.schema.json``)."""
        base = [t.cand.name for t in self.terms if t.cand.name not in self.named]
        return {
            "model": "base" if not self.named else "base and named effects",
            "terms": [t.cand.name for t in self.terms],
            "base_terms": base,
            "named": sorted(self.named),
            "room_for_another_effect": bool(self.room),
            "located_excess_chi2": self.excess(),
            "description": description,
        }


REFERENCE_DESCRIPTION = (
    "the final model: the base plus every named effect (none on a consistent verdict), "
    "their nonlinear parameters held and their linear ones refitted with the probe, as the "
    "selection's trial fits of a later round; on a record with unexplained structure also "
    "the rules located_share_min and signature_left_max against the excess the final "
    "residual's findings carry"
)
"""What ``detection_bounds_reference.description`` says."""


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
    (``probe.seen``) reaches ``lam`` (to :data:`SEEN_RTOL`); ``None`` when none within
    :data:`SEEN_GRID` does."""
    if probe.seen is None or lam <= 0:
        return lam
    for x in lam * SEEN_GRID:
        if probe.seen(float(x)) >= lam - SEEN_RTOL * lam:
            return float(x)
    return None


SEEN_RTOL = 1e-12
"""Relative rounding accepted when a probe's ``seen`` is compared with the noncentrality it
must reach: where the effect leaves the noise estimate as it is, ``seen(lam)`` is ``lam``
up to rounding, and rounding alone (the order of a sum) would otherwise decide between two
points of :data:`SEEN_GRID` (a 1.2 % step in the noncentrality)."""


def _values(fitter: Fitter, terms: Sequence[Term], compiled: bool = False) -> np.ndarray:
    """The sum of ``terms`` (n, C), chunk by chunk. With ``compiled``, each term's compiled
    value (a factored term's ``v0 + X (W p)``, :func:`._normal.register_factors`), never
    ``v0 + J p`` from a Jacobian the fitter happens to cache: the same numbers whatever the
    caches hold (the two differ in the last bit)."""
    out = np.zeros_like(fitter.prep.y)
    for a, b, x in fitter.chunks():
        for t in terms:
            out[a:b] += fitter.eval_term(t, a, b, x, jac=False, compiled=compiled)[0]
    return out


def _n_nonlinear(cand: Candidate, prep: Prepared, held: tuple[str, ...] = ()) -> int:
    """Fitted nonlinear scalars of ``cand`` (counted in its ``k``, held in the probe), less
    those the finder holds where the probe's effect is (``Probe.held``)."""
    C, R = prep.n_channels, prep.ctx.n_runs
    return int(
        sum(
            int(np.prod(q.resolved_shape(C, R), dtype=int))
            for q in cand.params
            if q.fit and not q.linear and q.name not in held
        )
    )


def _held_term(cand: Candidate, prep: Prepared, probe: Probe) -> Term:
    """The probe's term, its nonlinear parameters held at the probe's values."""
    term = make_term(cand, prep, dict(probe.values))
    for q in cand.params:
        if not q.linear:
            term.free[q.name][...] = False
    return term


def _columns_key(term: Term) -> tuple:
    """What a linear-only term's Jacobian on a chunk depends on besides the chunk (the key
    of :meth:`._fit.Fitter.eval_term`'s Jacobian cache): its candidate, its nonlinear
    values and its free masks."""
    held = tuple(term.values[q.name].tobytes() for q in term.cand.params if not q.linear)
    return id(term.cand), held, tuple(term.free[q.name].tobytes() for q in term.cand.params)


class _Bench:
    """A noise-free copy of the prepared record: its ``y`` is the reference model's
    prediction plus one probe; a fitter of its own (the model's Jacobians cached across
    probes)."""

    def __init__(self, prep: Prepared, fitter: Fitter, ref: Reference):
        self.prep = copy.copy(prep)
        self.fitter = Fitter(self.prep)
        self.fitter.w_ch = fitter.w_ch
        self.engine_fitter = fitter  # (its kept Gram matrices: the same rows and weights)
        self.base_terms = [t.copy() for t in ref.terms]
        self.pred = _values(fitter, ref.terms)
        self.y0 = prep.y  # the record itself (read only): the held-out check beside structure
        # the base holds a constant per run and channel: an effect's own size is then net of
        # its run means (``_select._term_rms``)
        self.per_run = _has_run_constants(ref.terms[: ref.n_base])
        self._pre: dict[int, tuple] = {}  # id(probe) -> its sums from the shared pass

    def prepare(self, probes: Sequence[tuple[Candidate, Probe]]) -> None:
        """One pass over the rows for all ``probes`` (issue 43): each one's own Jacobian (its
        rank) and, per fold, the sums of the base's processed (whitened, projected, scaled)
        Jacobian ``S`` with the probe's processed unit effect ``u``: ``S^T u``, ``|u|^2``
        and the same unwhitened, and ``S^T S``. A probe's observations are the base
        prediction plus ``c v``, whose residual at the base's values is ``c u``: its refit's
        normal equations are these sums scaled (:mod:`._normal`), so it needs no pass over
        the rows of its own (each probe used to recompute ``S`` where the cache does not
        hold it: the largest cost of the bounds on long records). The products are summed
        channel by channel (:func:`_channel_products`: the whitened and unwhitened sums from
        one product each, issue 43), with each probe's whitened unit effect's sums per run
        and channel on the kept rows: its norm and own RMS (:meth:`own_rms`) without a copy
        of the record. :meth:`probe` uses them and falls back to its own pass for a probe
        not prepared."""
        prep, fitter = self.prep, self.fitter
        K = prep.settings.n_folds
        static = frozen(self.base_terms)
        sc = free_scales(static)
        p = sc.size
        terms = [_held_term(c, prep, pr) for c, pr in probes]
        # probes whose held terms have the same columns (a candidate's probes at the same
        # nonlinear values: one per head or sensor) share one Gram matrix (their rank) and,
        # through the chunk's memo, one Jacobian per chunk (issue 43: the same numbers)
        same = [_columns_key(t) for t in terms]
        owner: dict[tuple, int] = {}
        gi = [owner.setdefault(key, len(owner)) for key in same]
        firsts = [same.index(key) for key in owner]
        grams = [np.zeros((terms[i].n_free(), terms[i].n_free())) for i in firsts]
        m = len(terms)
        # the base's Gram matrices where a fit kept them (this fitter's or the record's: the
        # same rows, folds and weights), else summed here as Fitter.stats sums them
        kept = fitter.gram(static) or self.engine_fitter.gram(static)
        G, Gu = (np.zeros((K, p, p)), np.zeros((K, p, p))) if kept is None else kept
        hv, huv, qv, quv = (
            np.zeros((m, K, p)),
            np.zeros((m, K, p)),
            np.zeros((m, K)),
            np.zeros((m, K)),
        )
        C, R = prep.n_channels, prep.ctx.n_runs
        s1 = np.zeros((R, C, m))  # each probe's whitened unit effect summed per run, channel
        w = fitter.w_ch
        sw = np.sqrt(w)
        memo = ChunkMemo()  # (the fitter's during the pass)

        def add(sums: list, a: int, b: int, x) -> None:  # the rows split over processes
            G, Gu, hv, huv, qv, quv, s1, *grams = sums
            got = fitter.processed_block(static, a, b, x, sc, pred=False, keep=False)
            _, S, order, edges = got
            rows = [(k, edges[k], edges[k + 1]) for k in range(K) if edges[k + 1] > edges[k]]
            for k, lo, hi in rows if kept is None else ():
                _channel_products(S[lo:hi], S[lo:hi], w, G[k], Gu[k])
            if not m:
                return
            U = np.empty((b - a, C, m))
            memo.at(a)
            for i, t in enumerate(terms):
                va, J = fitter.eval_term(t, a, b, x, jac=True)
                if firsts[gi[i]] == i:
                    _add_gram(prep, grams[gi[i]], J, a, b, 1.0 / prep.sigma)
                if prep.kd.project:
                    va = va - va.mean(1, keepdims=True)
                U[:, :, i] = va * sw
            U = U[order]
            run = np.asarray(prep.run[a:b])[order]
            for k, lo, hi in rows:  # every probe at once (a matrix product per fold, channel)
                _channel_products(S[lo:hi], U[lo:hi], w, hv[:, k].T, huv[:, k].T)
                _channel_products(U[lo:hi], U[lo:hi], w, qv[:, k], quv[:, k], diagonal=True)
            kept_rows = slice(rows[0][1], rows[-1][2]) if rows else slice(0, 0)
            for r in np.unique(run[kept_rows]):  # (the kept rows: those of a fold)
                s1[r] += U[kept_rows][run[kept_rows] == r].sum(0)

        fitter.memo = memo
        try:
            got = summed(fitter, [G, Gu, hv, huv, qv, quv, s1, *grams], add)
        finally:
            fitter.memo = None
        G, Gu, hv, huv, qv, quv, s1, *grams = got
        if kept is not None:  # (not summed in the pass: zeros there)
            G, Gu = kept
        ranks = [_rank(g) for g in grams]
        for i, (_, pr) in enumerate(probes):
            unit = (float(np.sum(qv[i])), s1[:, :, i])  # its norm squared, its run sums
            self._pre[id(pr)] = (ranks[gi[i]], (G, Gu, hv[i], huv[i], qv[i], quv[i]), unit)

    def release(self) -> None:
        """Drop what the last probe's observations hold (issue 43, peak memory): the
        prepared copy's ``y`` goes back to the reference prediction and the fitter's
        normal equations summed from the old one are dropped, their Gram matrices kept
        (:meth:`._normal.BlockCache.release_observations`: no later fit matches them, each
        probe's observations are a new array), so the old observations are freed before the
        next ones are made."""
        self.prep.y = self.pred
        self.fitter.blocks.release_observations()

    def _own_from_sums(self, tot: float, s1: np.ndarray) -> float:
        """The own RMS from a whitened unit effect's sums on the kept rows: ``tot`` its sum of
        squares, ``s1`` (R, C) its sums per run and channel (read where the run means are
        fitted): from the prepared pass (:meth:`prepare`) or from the effect itself
        (:meth:`own_rms`)."""
        prep = self.prep
        keep = prep.keep
        if self.per_run:
            cnt = np.bincount(np.asarray(prep.run)[keep], minlength=prep.ctx.n_runs)
            for c in range(s1.shape[1]):
                tot -= float(np.sum(s1[:, c] * s1[:, c] / np.maximum(cnt, 1)))
        C = prep.n_channels
        eff = (C - 1) / C if prep.kd.project else 1.0
        return math.sqrt(max(tot, 0.0) / max(float(keep.sum()) * C * eff, 1.0))

    def own_rms(self, v: np.ndarray) -> float:
        """The own RMS of the unit effect ``v`` in noise units, as the rule
        ``plausible_ratio`` measures a fitted term's (``_select._term_rms``): one copy of the
        kept rows, whitened and squared in place (the same numbers as whitening and
        squaring into new arrays)."""
        prep = self.prep
        keep = prep.keep
        w = v[keep]
        w /= prep.sigma[None, :]
        R = prep.ctx.n_runs
        s1 = np.zeros((R, w.shape[1]))  # its sums per run and channel (the run means' share)
        if self.per_run:
            run = np.asarray(prep.run)[keep]
            for c in range(w.shape[1]):
                s1[:, c] = np.bincount(run, weights=w[:, c], minlength=R)
        return self._own_from_sums(float(np.sum(np.square(w, out=w))), s1)

    def probe(self, cand: Candidate, probe: Probe):
        """``(lam, k, residual, own)``: the noncentrality of the unit effect after the reference
        model's refit (per unit size squared; the candidate's fit at the probe's nonlinear
        values takes all of it: the probe lies in its span), the candidate's determined
        parameters (the rank of its whitened columns on the kept rows, the nonlinear ones
        counted; a column the model also spans still counts: conservative) and the model's
        residual of the unit effect (n, C) and its own RMS (:meth:`own_rms`); ``None`` when
        the effect vanishes on the kept rows."""
        prep, fitter = self.prep, self.fitter
        # the last probe's observations and the views' sums of its residual (a reused scan
        # matches its own residual only) are freed before this one's are made (issue 43)
        self.release()
        sums_of(prep).forget()
        term = _held_term(cand, prep, probe)
        pre = self._pre.pop(id(probe), None)
        sw = 1.0 / prep.sigma
        if pre is None:  # its own pass: value and Jacobian of the linear part
            v = np.zeros_like(self.pred)
            gram = np.zeros((term.n_free(), term.n_free()))
            for a, b, x in fitter.chunks():
                va, J = fitter.eval_term(term, a, b, x, jac=True)
                v[a:b] = va
                _add_gram(prep, gram, J, a, b, sw)
            k_lin = _rank(gram)
        else:  # the Jacobian's rank, its norm, own RMS and the base's sums: the shared pass
            k_lin = pre[0]
            norm = math.sqrt(pre[2][0])
            if not (norm > 0 and math.isfinite(norm)):
                return None
            own = self._own_from_sums(*pre[2])
            # its compiled value: the prepared pass cached its Jacobian where the budget
            # allowed, and v0 + J p rounds otherwise (the caches must not change a bound)
            v = _values(fitter, [term], compiled=True)
        if prep.kd.project:
            v -= v.mean(1, keepdims=True)
        if pre is None:
            keep = prep.keep
            vw = v[keep]  # one copy of the kept rows, whitened and squared in place
            vw *= sw[None, :]
            norm = math.sqrt(float(np.sum(np.square(vw, out=vw))))
            del vw
            if not (norm > 0 and math.isfinite(norm)):
                return None
            own = self.own_rms(v)
        c = PROBE_NORM / norm
        # the observations ``pred + c v`` made in v's own array (issue 43: one whole-record
        # array fewer; the same numbers)
        v *= c
        prep.y = np.add(self.pred, v, out=v)
        # the base's nonlinear parameters held, as the selection's trial fits hold them: a
        # linear refit whose Jacobians are cached across probes
        static = frozen(self.base_terms)
        if pre is not None:  # its normal equations at the base's values: no pass over the rows
            G, Gu, hv, huv, qv, quv = pre[1]
            sc = free_scales(static)
            h, q, hu, qu = c * hv, c * c * qv, c * huv, c * c * quv
            acc = Accumulated(
                prep.y, held_key(static), free_values(static), sc, G, Gu, h, q, hu, qu
            )
            fitter.keep_accumulated(static, acc)
        base = fitter.fit(static)
        resid = fitter.residual(base.terms)
        self.release()  # its observations are not needed past its residual (issue 43)
        resid /= c
        k = k_lin + _n_nonlinear(cand, prep, probe.held)
        return base.chi2 / c**2, k, resid, own

    def heldout_gain(self, cand: Candidate, probe: Probe, a: float) -> float:
        """The held-out gain of ``cand`` (its probe's nonlinear values held, its linear
        parameters fitted) on the record itself with the effect added at size ``a``: the
        trial fit of a later round, with the record's own noise and unexplained structure
        (which can cost a candidate its held-out gain: a fold misses part of the structure
        the candidate then bends to)."""
        prep, fitter = self.prep, self.fitter
        term = _held_term(cand, prep, probe)
        v = _values(fitter, [term])
        v *= a
        prep.y = np.add(self.y0, v, out=v)  # ``y0 + a v`` in v's own array (issue 43)
        del v
        try:
            r0 = fitter.fit(frozen(self.base_terms))
            r1 = fitter.fit([*frozen(self.base_terms), term])
        finally:
            self.release()
        return float(r0.heldout_chi2 - r1.heldout_chi2)


def _first_size(ok: Callable[[float], bool], a0: float) -> float | None:
    """The smallest size from ``a0`` up where ``ok`` holds (assumed monotone in the size):
    ``a0`` when it holds there, else doublings up to :data:`VIEW_DOUBLINGS`, then
    :data:`VIEW_BISECTIONS` geometric bisections; ``None`` when no doubling reaches it."""
    if ok(a0):
        return a0
    lo, hi = a0, 2.0 * a0
    for _ in range(VIEW_DOUBLINGS):
        if ok(hi):
            break
        lo, hi = hi, 2.0 * hi
    else:
        return None
    for _ in range(VIEW_BISECTIONS):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return hi


def _heldout_size(bench: _Bench, cand, probe: Probe, a0: float, need: float) -> float | None:
    """The smallest size from ``a0`` up whose held-out gain on the record itself
    (:meth:`_Bench.heldout_gain`) reaches ``need`` (:func:`_first_size`)."""
    return _first_size(lambda a: bench.heldout_gain(cand, probe, a) >= need, a0)


def _view_size(prep, resid, views, signature, scan, a0: float) -> float | None:
    """The smallest size (multiple of the unit residual ``resid``) at which ``views``
    locate something in a view of ``signature``, from ``a0`` up (:func:`_first_size`)."""
    return _first_size(
        lambda a: any(
            f.view in signature for f in locate(prep, resid, views, scan, scale=a, reuse=True)
        ),
        a0,
    )


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


def _bound_entry(
    prep, bench: _Bench, cand, probe: Probe, views, scan, ref: Reference, got=None
) -> dict:
    """One ``detection_bounds`` entry: the largest bound over the probe and its ``worst_of``
    (``bound`` ``None`` with a ``note`` when the record cannot show the effect at one of them
    at any size); reported with the probe's own ``where`` and ``at``, and, where there are
    several, each one's own bound (``each``: ``label``, ``bound``, ``set_by``): the worst is
    what the record guarantees for any of them, and an effect whose shape is one of them
    (an order, an azimuth) is revealed from its own, which can be well below the worst.
    ``got``: each one's :func:`_one_bound` computed already (dealt over processes), in
    order; an exception there is raised where it would have been."""
    worst: dict | None = None
    each = []
    for j, pr in enumerate((probe, *probe.worst_of)):
        e = _one_bound(prep, bench, cand, pr, views, scan, ref) if got is None else got[j]
        if isinstance(e, Exception):
            raise e
        if e["bound"] is None:
            return e
        each.append({"label": pr.label or pr.at, "bound": e["bound"], "set_by": e["set_by"]})
        if worst is None or e["bound"] > worst["bound"]:
            worst = e
    assert worst is not None
    return {**worst, "where": probe.where, "at": probe.at} | (
        {"each": each} if probe.worst_of else {}
    )


def _over_budget(prep, cand, probe: Probe, ref: Reference) -> str | None:
    """The selection's parameter budget (``max_param_fraction``, ``_select``): an effect
    whose parameters beside the reference model's exceed it is refused at any size, so it
    has no bound (an sds ``beam_tilt_axial``, 6 parameters, beside a 5-parameter base on
    8 runs x 3 sensors with 4 complete revolutions, 96 values: a bound was reported and the
    effect was never named, ``max_param_fraction``)."""
    n_ref = ref.n_params if ref.n_params is not None else sum(t.n_free() for t in ref.terms)
    n_cand = make_term(cand, prep, dict(probe.values)).n_free()
    N = prep.n_values
    frac = prep.settings.max_param_fraction
    if N - n_ref - n_cand < 0 or n_ref + n_cand > frac * N:
        return (
            f"more parameters ({n_ref} + {n_cand}) than {frac:.0%} of the {N:.0f} fitted "
            "values (max_param_fraction): not named at any size"
        )
    return None


def _one_bound(prep, bench: _Bench, cand, probe: Probe, views, scan, ref: Reference) -> dict:
    """The bound of one parameter set of a probe."""
    s = prep.settings
    entry = _failed_entry(cand, probe, "")
    del entry["note"]
    if not ref.room:
        return {
            **entry,
            "note": "the selection names at most max_effects effects, and this record has "
            "that many: no further effect is named at any size",
        }
    over = _over_budget(prep, cand, probe, ref)
    if over:
        return {**entry, "note": over}
    got = bench.probe(cand, probe)
    if got is None or got[0] <= 0:
        return {**entry, "note": "the effect vanishes on the kept rows"}
    lam_base, k, resid, own = got
    if probe.seen_of is not None:
        probe = dataclasses.replace(probe, seen=probe.seen_of(resid[prep.keep], lam_base))
    if k == 0 or lam_base <= 1e-12 * PROBE_NORM**2:
        return {**entry, "note": "the final model takes all of it (not identifiable here)"}
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
    # a final finding in its signature views: the candidate is tried at any size
    tried = bool(sig & {f.view for f in ref.findings})
    if cand.signature and not tried:
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
    # structure left unexplained: the share rules against what the final residual carries
    if ref.excess() > 0:
        a_share, i = _share_size(bench.prep, resid, views, scan, a, sig, ref.findings)
        if a_share is None:
            return {**entry, "n_params": int(k), "note": "no view locates it at any size tried"}
        if a_share > a:
            a, rule = a_share, ("located_share_min", "signature_left_max")[i]
        # and the held-out gain on the record itself, beside the structure it leaves (the
        # views' sums of its residual are not needed past its scans: issue 43)
        sums_of(bench.prep).forget()
        a_ho = _heldout_size(bench, cand, probe, a, s.heldout_min)
        if a_ho is None:
            return {**entry, "n_params": int(k), "note": "no held-out gain at any size tried"}
        if a_ho > a:
            a, rule = a_ho, "heldout_min"
    out = {
        **entry,
        "bound": float(a * probe.size),
        "set_by": rule,
        "noncentrality": float(a * a * lam_base),
        "n_params": int(k),
    }
    # rule plausible_ratio: its own size against what it explains (sqrt(lambda / N)), the
    # same ratio at any size; it refuses only above plausible_rms_min noise units (its
    # limit: ``_evidence.ratio_limit``, the conditioning limit's on part of a turn)
    ratio = own / math.sqrt(lam_base / N)
    if ratio > ratio_limit(prep):
        a_max = s.plausible_rms_min / own
        why = (
            f"its own size is {ratio:.3g}x the residual it explains (the model takes most of "
            f"it): plausible_ratio refuses it above {a_max * probe.size:.3g} {probe.unit}"
        )
        if a > a_max:
            return {**entry, "n_params": int(k), "note": f"not named at any size: {why}"}
        out["note"] = why
    return out


def detection_bounds(
    prep: Prepared,
    fitter: Fitter,
    ref: Reference,
    candidates: Sequence[Candidate],
    views: tuple,
    scan_order: int,
) -> list[dict]:
    """The ``detection_bounds`` of a record against the reference model ``ref``: one entry
    per probe of every candidate that applies, offers probes (``Candidate.probes``) and is
    not named, in catalog order (module doc)."""
    out: list[dict] = []
    work = [
        (c, c.probes(prep.ctx)) for c in _bounded(candidates, prep, ref) if c.probes is not None
    ]
    work = [(c, probes) for c, probes in work if probes]
    if not work:
        return out
    bench = _Bench(prep, fitter, ref)
    # the selection's fits are done: the engine fitter's per-chunk caches (the candidates'
    # Jacobians, its static blocks') are freed for the bench's own (issue 43, peak memory)
    fitter.release_chunks()
    if ref.room:  # one pass over the rows for every probe's refit (_Bench.prepare)
        items = [(c, q) for c, probes in work for pr in probes for q in (pr, *pr.worst_of)]
        try:
            bench.prepare(items)
        except (np.linalg.LinAlgError, FloatingPointError, ValueError):
            bench._pre.clear()  # each probe then makes its own pass

    def bounds_of(mine: list) -> list:  # this process's parameter sets (_workshare.deal)
        got = []
        for cand, pr in mine:
            try:
                got.append(_one_bound(prep, bench, cand, pr, views, scan_order, ref))
            except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
                got.append(type(exc)(*exc.args))  # raised by _bound_entry, in its order
        return got

    # every parameter set of every probe (a probe and its worst_of) is one work item
    sets = [(c, q) for c, probes in work for pr in probes for q in (pr, *pr.worst_of)]
    try:
        done = iter(deal(sets, bounds_of))
    finally:
        sums_of(prep).forget()  # the last probe's residual and its views' sums
    for cand, probes in work:
        for probe in probes:
            got = [next(done) for _ in range(1 + len(probe.worst_of))]
            try:
                entry = _bound_entry(prep, bench, cand, probe, views, scan_order, ref, got)
            except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
                # reporting only: a probe that fails numerically never fails the diagnosis
                entry = _failed_entry(cand, probe, f"not computed: {exc}")
            out.append({**entry, "convention": CONVENTION_SHORT})
    return out


def _bounded(candidates: Sequence[Candidate], prep: Prepared, ref: Reference) -> list:
    """The candidates a record's bounds are about: those that apply and are not named."""
    return [
        c
        for c in candidates
        if c.name not in ref.named and not (c.applies is not None and c.applies(prep.ctx))
    ]


def not_covered(candidates: Sequence[Candidate], prep: Prepared, ref: Reference) -> list[str]:
    """Names of the candidates that apply to this record, are not named and offer no probe
    (the report says their sizes are not bounded)."""
    return [c.name for c in _bounded(candidates, prep, ref) if c.probes is None]


__all__ = [
    "CONVENTION",
    "CONVENTION_SHORT",
    "REFERENCE_DESCRIPTION",
    "Probe",
    "Reference",
    "detection_bounds",
    "median_noncentrality",
    "not_covered",
]
