"""The fitter's passes over the rows (:meth:`._fit.Fitter.stats`), several fits in one
(issue 43).

A selection round fits each candidate on top of the same frozen base model: every pass of
every trial fit evaluates the base's Jacobian (the static block, linear in its free
parameters) on every chunk, and processes it (fold order, projection, scaling) before the
candidate's own columns join it; on a long record the fitter's caches hold only the first
chunks of it. :func:`drive_many` runs the trial fits side by side instead, each a generator
of its fit's statistics requests (:meth:`._fit.Fitter.fit_steps`), and answers the requests
of one round in one pass (:func:`run_passes`): each chunk's row columns are built once, and
the static block's Jacobian and processed Jacobian, the same numbers for every fit of the
round (they depend only on the block's held values, its free masks and the scales), are
computed once per chunk (:class:`ChunkMemo`) and read by the others. Each request's sums
are its own and made in the same order as alone, so every fit gets the numbers it would get
alone.
"""

from __future__ import annotations

import math
from collections.abc import Generator, Sequence
from typing import Any

import numpy as np

from ._features import feature_parts
from ._normal import (
    Accumulated,
    factors_of,
    free_scales,
    free_values,
    held_key,
    linear_only,
    static_key,
)
from ._rowshare import my_groups, reduce_groups, row_groups, unflatten

FEATURE_GRAM = True
"""Sum a request's free nonlinear Gram matrix from a factored term's features
(:meth:`StatsPass._gram_f`) where it has no static block; ``False``: from the whole
processed Jacobian (the same sums to rounding; tests compare the two)."""

StatsRequest = tuple[Any, Sequence[Any], bool]
"""``(fitter, terms, jac)``: what :meth:`._fit.Fitter.stats` is asked."""


class ChunkMemo:
    """Within one pass for several requests: the results of pure per-chunk computations of
    the static blocks (keys say what they depend on, the chunk's first row included), kept
    for the current chunk only."""

    def __init__(self) -> None:
        self._a: int | None = None
        self._kept: dict = {}

    def at(self, a: int) -> None:
        """The pass moved to the chunk from row ``a`` (the previous chunk's entries go)."""
        if a != self._a:
            self._kept.clear()
            self._a = a

    def get(self, key: tuple):
        """The kept result for ``key`` or ``None``."""
        return self._kept.get(key)

    def put(self, key: tuple, value) -> None:
        """Keep ``value`` for ``key`` until the pass moves on."""
        self._kept[key] = value


def term_key(term) -> tuple:
    """Everything a term's value and Jacobian on a chunk depend on besides the chunk: its
    values and free masks, as bytes (a term with free nonlinear parameters is read from the
    :class:`ChunkMemo` by it: two fits of one round at the same values, e.g. the model's
    first pass beside the model with a rival, evaluate it once per chunk)."""
    return tuple(
        (term.values[q.name].tobytes(), term.free[q.name].tobytes()) for q in term.cand.params
    )


class StatsPass:
    """One request of :meth:`._fit.Fitter.stats`: per-fold ``(A_f, g_f, c_f, ssr_f)`` over
    the kept rows, parameters in scaled units (see there). :attr:`done` holds the answer
    once known: at once where the kept normal equations give it, else after a pass
    (:meth:`open_group`, :meth:`chunk` per chunk, :meth:`close_group` per row group,
    :meth:`finish`)."""

    def __init__(self, fitter, terms: Sequence[Any], jac: bool = True) -> None:
        self.fitter = fitter
        self.jac = jac
        prep = fitter.prep
        self.K = prep.settings.n_folds
        self.terms = terms = list(terms)
        self.static = static = [t for t in terms if linear_only(t)]
        self.dyn = dyn = [t for t in terms if not linear_only(t)]
        self.p_s = sum(t.n_free() for t in static)
        self.p = sum(t.n_free() for t in terms)
        self.sc_s, self.sc_d = free_scales(static), free_scales(dyn)
        self.skey = static_key(static)
        # the free nonlinear terms' identity (a pass for several fits shares their
        # processed Jacobian and its per-fold Gram products where two fits hold them alike)
        self.dkey = tuple((id(t.cand), term_key(t)) for t in dyn) + (self.sc_d.tobytes(),)
        self.held, self.z_s = held_key(static), free_values(static)
        self.done: tuple | None = None
        acc = fitter.blocks.accumulated(self.skey)
        if not dyn and acc is not None:
            got = acc.stats(prep.y, self.held, self.z_s, self.sc_s, jac)
            if got is not None:
                self.done = fitter._caller_order(terms, static, dyn, *got, self.sc_s, self.sc_d)
                return
        self.gram = fitter.blocks.gram(self.skey)
        # the longest leading block with kept Gram matrices: only the other columns' products
        self.lead: StatsPass | None = None
        self._plan(fitter.blocks.longest_prefix(static))
        self.kept_gram: tuple | None = None
        self.parts: list[np.ndarray] = []
        self.sums: list = []

    def _plan(self, k0: int) -> None:
        """The sums' shapes where the leading ``k0`` terms' Gram matrices are known (kept, or
        summed by a lead in the same pass, :meth:`join`): only the other columns' products."""
        K, p, p_s, gram = self.K, self.p, self.p_s, self.gram
        self.k0 = k0
        self.p0 = p0 = sum(t.n_free() for t in self.static[:k0]) if gram is None else p_s
        self.p_t = p_t = p_s - p0
        shapes = [(K, p, p), (K, p), (K,), (K,)]
        if self.jac:  # the static block's own normal equations, whitened and not (for ssr)
            shapes += [(K, p_s), (K,), (K, p_s), (K,)]
            shapes += [(K, p_s, p_t), (K, p_s, p_t)] if gram is None else []
        self.shapes = shapes

    def join(self, k0: int, lead: StatsPass) -> None:
        """Sum beside ``lead`` (a request of the same pass, before this one, that sums and
        keeps the Gram matrices of this block's leading ``k0`` terms) only the other columns'
        products, as this request would after ``lead``'s pass: the same sums, one pass less
        (issue 43: a candidate's fit beside the fit of its leading block)."""
        self.lead = lead
        self._plan(k0)

    def open_group(self) -> None:
        """Start the sums of one row group."""
        self.sums = [np.zeros(s) for s in self.shapes] + [None] * (10 - len(self.shapes))

    def close_group(self) -> None:
        """End the row group's sums."""
        self.parts.append(np.concatenate([v.ravel() for v in self.sums[: len(self.shapes)]]))

    def chunk(self, a: int, b: int, x: dict) -> None:
        """Add the chunk of rows ``a:b`` (row columns ``x``) to the group's sums; a request
        that joined a lead's pass keeps nothing in the fitter's caches (alone, after the
        lead's pass, it found them full on a long record: a cached Jacobian and the compiled
        value differ in rounding, so the caches' contents must be those of the passes one
        after another)."""
        if self.lead is None:
            self._chunk(a, b, x)
            return
        self.fitter.keeps = False
        try:
            self._chunk(a, b, x)
        finally:
            self.fitter.keeps = True

    def _chunk(self, a: int, b: int, x: dict) -> None:
        fitter, prep, jac, K = self.fitter, self.fitter.prep, self.jac, self.K
        static, dyn, p, p_s = self.static, self.dyn, self.p, self.p_s
        A, g, c, ssr, h, q, hu, qu, new_gram, new_gu = self.sums
        w = fitter.w_ch
        sw = np.sqrt(w)
        # the static prediction from current linear values (v0 + J p), with the processed
        # Jacobian where it is needed
        if jac:
            pred, Js_, order, edges = fitter._split_processed(static, self.k0, a, b, x, self.sc_s)
        else:
            pred, Js_ = fitter._values(static, a, b, x), None
            order, edges = fitter._fold_order(a, b)
        rs = None
        if jac and dyn:  # the static block's own residual (whitened, fold-sorted)
            rs = prep.y[a:b] - pred
            if prep.kd.project:
                rs = rs - rs.mean(1, keepdims=True)
            rs = (rs * sw)[order]
        parts = None
        if dyn and jac and FEATURE_GRAM:
            if sum(factors_of(t.cand) is not None for t in dyn) == 1:
                parts = feature_parts(fitter, dyn, a, b, x, self.sc_d, self.dkey)
        if dyn:
            if parts is not None:  # (the factored columns' Gram from their features)
                pd, Jd = parts[0], None
            elif jac:
                pd, Jd, _, _ = fitter._processed(dyn, a, b, x, self.sc_d, self.dkey)
            else:
                pd = sum(fitter.eval_term(tm, a, b, x, jac=False)[0] for tm in dyn)
                Jd = None
            pred = pred + pd
        else:
            Jd = None
        r = prep.y[a:b] - pred
        if prep.kd.project:
            r = r - r.mean(1, keepdims=True)
        rw = (r * sw)[order]
        rr = r[order]
        for k in range(K):
            lo, hi = edges[k], edges[k + 1]
            if hi <= lo:
                continue
            c[k] += float(np.sum(rw[lo:hi] ** 2))
            ssr[k] += float(np.sum(rr[lo:hi] ** 2))
            if not jac:
                continue
            rk = rw[lo:hi].ravel()
            Sk = Js_[lo:hi].reshape(rk.size, p_s)
            g[k, :p_s] += Sk.T @ rk
            # alone, the block's residual is the whole one (h = g, q = c, qu = ssr)
            rsk = rk if rs is None else rs[lo:hi].ravel()
            hu[k] += Sk.T @ (rsk.reshape(-1, prep.n_channels) / w[None, :]).ravel()
            if rs is not None:
                h[k] += Sk.T @ rsk
                q[k] += float(rsk @ rsk)
                qu[k] += float(rsk @ (rs[lo:hi] / w[None, :]).ravel())
            if new_gram is not None:
                gk, guk = self._gram_s(a, k, Sk, Js_[lo:hi])
                new_gram[k] += gk
                new_gu[k] += guk
            if parts is not None:
                A[k, p_s:, p_s:] += self._gram_f(a, k, parts, lo, hi)
                g[k, p_s:] += self._grad_f(parts, lo, hi, rw[lo:hi], p - p_s)
                if p_s:
                    A[k, :p_s, p_s:] += self._cross_f(parts, lo, hi, Js_[lo:hi], p - p_s)
            if Jd is not None and Jd.shape[2]:
                Dk = Jd[lo:hi].reshape(rk.size, p - p_s)
                A[k, :p_s, p_s:] += Sk.T @ Dk
                A[k, p_s:, p_s:] += self._gram_d(a, k, Dk)
                g[k, p_s:] += Dk.T @ rk

    def _gram_s(self, a: int, k: int, Sk: np.ndarray, Jk: np.ndarray) -> tuple:
        """The static block's Gram products on fold ``k`` of the chunk from row ``a``
        (``Sk``: its processed Jacobian there as a matrix, ``Jk`` by row and channel),
        whitened and not: the whole block's, or its new columns' beside the kept leading
        block's; from the memo of a pass for several fits where another fit's request sums
        the same (the frozen model's first pass beside each candidate)."""
        memo = self.fitter.memo
        key = ("gram_s", self.skey, self.p0, self.sc_s.tobytes(), a, k)
        got = memo.get(key) if memo is not None else None
        if got is not None:
            return got
        w, p0 = self.fitter.w_ch, self.p0
        if p0 == 0:  # the whole block's
            Su = (Jk / np.sqrt(w)[None, :, None]).reshape(Sk.shape)
            got = (Sk.T @ Sk, Su.T @ Su)
        else:  # the new columns' products only
            Tk = Jk[:, :, p0:]
            got = (
                Sk.T @ Tk.reshape(Sk.shape[0], self.p_t),
                Sk.T @ (Tk / w[None, :, None]).reshape(Sk.shape[0], self.p_t),
            )
        if memo is not None:
            memo.put(key, got)
        return got

    def _gram_f(self, a: int, k: int, parts: tuple, lo: int, hi: int) -> np.ndarray:
        """The free nonlinear terms' Gram matrix on fold ``k`` (rows ``lo:hi`` of the sorted
        chunk from row ``a``) from :func:`._features.feature_parts`: the factored columns'
        ``sum_c Wp_c^T (X^T X) Wp_c``, their products with the other columns ``sum_c Wp_c^T
        (X^T O_c)``, the other columns' own ``O^T O`` (the same sums as ``D^T D`` of the
        whole Jacobian ``D``, in another order: equal to rounding); from the memo of a pass
        for several fits where another fit's request holds the same free nonlinear terms."""
        memo = self.fitter.memo
        got = memo.get(("gram_f", self.dkey, a, k)) if memo is not None else None
        if got is not None:
            return got
        _, Xo, Wp, fc, O, oc, _, _ = parts
        F, C, kw = Wp.shape
        q = O.shape[2]
        Xk = Xo[lo:hi]
        W2 = Wp.reshape(F * C, kw)
        T = ((Xk.T @ Xk) @ Wp.reshape(F, C * kw)).reshape(F * C, kw)
        Gff = W2.T @ T
        got = np.empty((kw + q, kw + q))
        got[np.ix_(fc, fc)] = 0.5 * (Gff + Gff.T)
        if q:
            Ok = O[lo:hi]
            XtO = (Xk.T @ Ok.reshape(hi - lo, C * q)).reshape(F * C, q)
            Gfo = W2.T @ XtO
            O2 = Ok.reshape(-1, q)
            got[np.ix_(fc, oc)] = Gfo
            got[np.ix_(oc, fc)] = Gfo.T
            got[np.ix_(oc, oc)] = O2.T @ O2
        if memo is not None:
            memo.put(("gram_f", self.dkey, a, k), got)
        return got

    @staticmethod
    def _grad_f(parts: tuple, lo: int, hi: int, rwk: np.ndarray, p_d: int) -> np.ndarray:
        """``D^T r`` on fold rows ``lo:hi`` (whitened residual ``rwk`` (rows, C)) from
        :func:`._features.feature_parts`: ``sum_c Wp_c^T (X^T r_c)`` for the factored
        columns, ``O^T r`` for the others."""
        _, Xo, Wp, fc, O, oc, _, _ = parts
        F, C, kw = Wp.shape
        out = np.empty(p_d)
        out[fc] = Wp.reshape(F * C, kw).T @ (Xo[lo:hi].T @ rwk).ravel()
        if oc.size:
            out[oc] = O[lo:hi].reshape(-1, oc.size).T @ rwk.ravel()
        return out

    @staticmethod
    def _cross_f(parts: tuple, lo: int, hi: int, Sk: np.ndarray, p_d: int) -> np.ndarray:
        """``S^T D`` on fold rows ``lo:hi`` (``Sk`` the static block's processed Jacobian
        there, (rows, C, p_s)) from :func:`._features.feature_parts`: ``sum_c (S_c^T X)
        Wp_c`` for the factored columns, ``S^T O`` for the others."""
        _, Xo, Wp, fc, O, oc, _, _ = parts
        Xk = Xo[lo:hi]
        out = np.empty((Sk.shape[2], p_d))
        out[:, fc] = sum((Sk[:, c, :].T @ Xk) @ Wp[:, c, :] for c in range(Wp.shape[1]))
        if oc.size:
            out[:, oc] = Sk.reshape(-1, Sk.shape[2]).T @ O[lo:hi].reshape(-1, oc.size)
        return out

    def _gram_d(self, a: int, k: int, Dk: np.ndarray) -> np.ndarray:
        """``Dk^T Dk``, fold ``k`` of the chunk from row ``a``: from the memo of a pass for
        several fits where another fit's request holds the same free nonlinear terms."""
        memo = self.fitter.memo
        got = memo.get(("gram_d", self.dkey, a, k)) if memo is not None else None
        if got is None:
            got = Dk.T @ Dk
            if memo is not None:
                memo.put(("gram_d", self.dkey, a, k), got)
        return got

    def finish(self, n_groups: int) -> None:
        """Gather the groups' sums (over the processes) and set :attr:`done`."""
        fitter, static, dyn, p_s, shapes = self.fitter, self.static, self.dyn, self.p_s, self.shapes
        n_out = len(shapes)
        total = reduce_groups(self.parts, n_groups, sum(math.prod(s) for s in shapes))
        A, g, c, ssr, h, q, hu, qu, new_gram, new_gu = unflatten(total, shapes) + [None] * (
            10 - n_out
        )
        if self.jac:
            if not dyn:
                h, q, qu = g[:, :p_s].copy(), c.copy(), ssr.copy()
            gram = self.gram
            if gram is None:
                lead = fitter.gram(static[: self.k0])
                if lead is None and self.lead is not None and self.lead.kept_gram is not None:
                    lead = tuple(G[:, : self.p0, : self.p0] for G in self.lead.kept_gram)
                gram = fitter._assemble(static, self.p0, new_gram, new_gu, lead)
            self.kept_gram = gram
            A[:, :p_s, :p_s] = gram[0]
            A[:, p_s:, :p_s] = np.transpose(A[:, :p_s, p_s:], (0, 2, 1))
            acc = Accumulated(fitter.prep.y, self.held, self.z_s, self.sc_s, *gram, h, q, hu, qu)
            fitter.blocks.keep_accumulated(self.skey, acc)
        self.done = fitter._caller_order(
            self.terms, static, dyn, A, g, c, ssr, self.sc_s, self.sc_d
        )


def run_passes(passes: Sequence[StatsPass]) -> list[tuple]:
    """The answers of ``passes`` (requests of fitters on one prepared record), those that
    need the rows in one pass over them; with more than one, the static blocks' per-chunk
    Jacobians are computed once (:class:`ChunkMemo`)."""
    live = [s for s in passes if s.done is None]
    if live:
        f0 = live[0].fitter
        fitters = list({id(s.fitter): s.fitter for s in live}.values())
        memo = ChunkMemo() if len(live) > 1 else None
        for f in fitters:
            if f.prep is not f0.prep or f.chunk != f0.chunk:
                raise ValueError("run_passes: the requests' fitters must share their record")
            f.memo = memo
        try:
            groups = row_groups(f0.n_chunks())
            # the chunks in fixed groups; this process sums its share group by group and the
            # groups' sums are gathered (_rowshare): the same sums for any number of processes
            for grp in my_groups(len(groups)):
                for s in live:
                    s.open_group()
                for a, b, x in f0.chunks(*groups[grp]):
                    if memo is not None:
                        memo.at(a)
                    for s in live:
                        s.chunk(a, b, x)
                for s in live:
                    s.close_group()
        finally:
            for f in fitters:
                f.memo = None
        for s in live:
            s.finish(len(groups))
    return [s.done for s in passes]  # type: ignore[misc]


FitSteps = Generator[StatsRequest, tuple, Any]
"""A fit as a generator: it yields its statistics requests and receives their answers."""


def drive(steps: FitSteps):
    """Run one fit's requests one by one; its result (:func:`drive_many` of one fit)."""
    return drive_many([steps])[0]


def _waits(sp: StatsPass, kept: set) -> bool:
    """Whether the request of ``sp`` would start from a longer leading block's kept Gram
    matrices (``kept``: those the round's earlier passes will keep) than it found: it then
    waits one round, so that it sums what it would sum after those passes, alone (unless it
    :func:`_joins` them)."""
    return any(static_key(sp.static[:k]) in kept for k in range(sp.k0 + 1, len(sp.static)))


def _joins(sp: StatsPass, kept: set, leads: dict) -> bool:
    """Where ``sp`` :func:`_waits`: join the round instead (:meth:`StatsPass.join`) when what
    it would find kept after the round is known now: the longest of its leading blocks that
    a request of the round with the Jacobian sums and keeps (``leads``: static key -> that
    request; a values-only request keeps nothing), and its own whole block is no request's
    (then it would be answered from the kept normal equations). Whether it joined."""
    if static_key(sp.static) in kept:
        return False
    k = next(
        (k for k in range(len(sp.static) - 1, sp.k0, -1) if static_key(sp.static[:k]) in leads), 0
    )
    if k:
        sp.join(k, leads[static_key(sp.static[:k])])
    return True


class Many(tuple):
    """Several statistics requests of one fit generator (:func:`._starts.side_by_side`),
    answered in the same round as everybody's: :func:`drive_many` sends it back a list of
    the answers in order, ``None`` for a request that waits for the next round."""


def drive_many(all_steps: Sequence[FitSteps]) -> list:
    """Run several fits side by side: each round, the next request of every fit not done
    (every request of a :class:`Many`), answered in one pass (:func:`run_passes`); their
    results, in order. A request that would sum a block's Gram matrices an earlier request
    of the round keeps (the frozen base of a candidate's first pass, before the base's own
    first pass) waits for the next round: one after another, it would have found them kept
    and summed the new columns only (the same numbers as one fit after another, not the
    whole block's rounding); where what it would find is known now (:func:`_joins`), it
    sums those new columns beside that request in the same pass instead (issue 43: the
    candidates' screened starts beside the first pass that sums the frozen base's Gram
    matrices, a fit beside the fit of its leading block), one pass less."""
    out: list = [None] * len(all_steps)
    reqs: dict[int, StatsRequest | Many] = {}

    def advance(i: int, ans) -> None:
        try:
            reqs[i] = next(all_steps[i]) if ans is None else all_steps[i].send(ans)
        except StopIteration as stop:
            out[i] = stop.value
            reqs.pop(i, None)

    for i in range(len(all_steps)):
        advance(i, None)
    while reqs:
        idx, passes, kept, leads = [], [], set(), {}
        for i, req in reqs.items():
            for j, one in enumerate(req if isinstance(req, Many) else [req]):
                sp = StatsPass(*one)
                if sp.done is None and _waits(sp, kept) and not _joins(sp, kept, leads):
                    continue  # (next round, as it would run after that pass alone)
                idx.append((i, j))
                passes.append(sp)
                if sp.done is None and sp.gram is None:  # the leading blocks' Gram it keeps
                    keys = [static_key(sp.static[:k]) for k in range(1, len(sp.static) + 1)]
                    kept |= set(keys)
                    if sp.jac:
                        for key in keys:
                            leads.setdefault(key, sp)
        got: dict[int, dict[int, tuple]] = {}
        for (i, j), ans in zip(idx, run_passes(passes)):
            got.setdefault(i, {})[j] = ans
        for i, ans in got.items():
            req = reqs[i]
            advance(i, [ans.get(j) for j in range(len(req))] if isinstance(req, Many) else ans[0])
    return out


__all__ = ["ChunkMemo", "Many", "StatsPass", "drive", "drive_many", "run_passes", "term_key"]
