"""Stage 2 of the engine, **fit**: terms, the chunked Gauss-Newton fitter (the goodness of fit:
:mod:`._goodness`)."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence

import jax
import numpy as np
import scipy.linalg as sla

from ._candidates import Candidate
from ._constants import CACHE_BYTES, CHUNK_ROWS, FIT_STOP_CHI2, FIT_STOP_REL
from ._features import Factored, scaled_columns
from ._normal import (
    Accumulated,
    BlockCache,
    compiled_valjac,
    factors_of,
    free_scales,
    linear_only,
    linear_valjac,
    solve_determined,
    solve_determined_many,
    static_key,
)
from ._protocol import Prepared
from ._rowshare import my_groups, reduce_groups, row_groups, unflatten
from ._stats_pass import ChunkMemo, FitSteps, StatsPass, drive, run_passes, term_key
from ._timing import stage

# ----------------------------------------------------------------------------- fitting


@functools.lru_cache(maxsize=256)
def valjac_fn(cand: Candidate):
    # one jacfwd over all parameters (splitting it into linear and nonlinear tangents was
    # ~5x faster on the base term, but jax 0.10.2's CPU jit returned a Jacobian with zero
    # rows for the nonlinear half: checked against finite differences, not used)
    def vj(p, x):
        v = cand.fn(p, x)
        J = jax.jacfwd(cand.fn)(p, x)
        return v, J

    return jax.jit(vj) if cand.valjac is None else compiled_valjac(cand.valjac)


@functools.lru_cache(maxsize=256)
def _val_fn(cand: Candidate):
    return jax.jit(cand.fn if cand.value is None else cand.value)


@dataclasses.dataclass
class Term:
    """A candidate with its current parameter values and which scalars are free."""

    cand: Candidate
    values: dict[str, np.ndarray]
    free: dict[str, np.ndarray]  # bool masks, same shapes
    scale: dict[str, np.ndarray]

    def flat(self) -> np.ndarray:
        """Values of the free scalars, in parameter order."""
        return np.concatenate(
            [self.values[p.name][self.free[p.name]].ravel() for p in self.cand.params]
            or [np.zeros(0)]
        )

    def n_free(self) -> int:
        """Free scalars."""
        return int(sum(int(self.free[p.name].sum()) for p in self.cand.params))

    def copy(self) -> Term:
        """A deep copy."""
        return Term(
            self.cand,
            {k: v.copy() for k, v in self.values.items()},
            {k: v.copy() for k, v in self.free.items()},
            {k: v.copy() for k, v in self.scale.items()},
        )


def make_term(cand: Candidate, prep: Prepared, start: dict | None = None) -> Term:
    """A :class:`Term` at ``start`` (others zero), free where the parameter is fitted."""
    C, R = prep.n_channels, prep.ctx.n_runs
    vals, free, scale = {}, {}, {}
    for p in cand.params:
        shp = p.resolved_shape(C, R)
        v = np.zeros(shp)
        if start and p.name in start:
            v = np.broadcast_to(np.asarray(start[p.name], float), shp).copy()
        vals[p.name] = v
        free[p.name] = np.full(shp, bool(p.fit))
        scale[p.name] = np.full(shp, p.scale if p.scale else 1.0)
    return Term(cand, vals, free, scale)


@dataclasses.dataclass
class FitResult:
    """Sufficient statistics of a fitted model and what follows from them."""

    terms: list[Term]
    chi2: float  # whitened residual sum of squares (kept rows)
    n_params: int
    cov: np.ndarray  # covariance of the free scalars (parameter units)
    heldout_chi2: float
    heldout_ssr: float  # unwhitened, for an RMS
    ssr: float
    n_rows: int
    converged: bool
    A: np.ndarray  # whitened normal matrix in parameter units (free scalars)
    unidentifiable: list[str]
    slices: list[tuple[int, int]]  # per term, range in the free vector
    determined: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, int))

    def n_determined(self, index: int) -> int:
        """Determined (fitted) scalars of term ``index``."""
        s0, s1 = self.slices[index]
        return int(np.sum((self.determined >= s0) & (self.determined < s1)))

    def rms(self, prep: Prepared) -> float:
        """Fitted residual RMS (unit of y)."""
        return math.sqrt(self.ssr / max(prep.n_values, 1))

    def heldout_rms(self, prep: Prepared) -> float:
        """K-fold held-out residual RMS (unit of y)."""
        return math.sqrt(self.heldout_ssr / max(prep.n_values, 1))


class Fitter:
    """Chunked evaluation of a sum of terms, its Jacobian and the per-fold statistics."""

    def __init__(self, prep: Prepared, progress: Callable[[int, int, int], None] | None = None):
        self.prep = prep
        self.w_ch = 1.0 / prep.sigma**2
        n = prep.n
        self.chunk = int(min(CHUNK_ROWS, 1 << max(5, int(math.ceil(math.log2(max(n, 2)))))))
        self.progress = progress
        self._jcache: dict = {}
        self._jbytes = 0
        self.blocks = BlockCache()  # static blocks: processed Jacobians, Gram matrices
        self.memo: ChunkMemo | None = None  # during a pass for several fits (_stats_pass)
        # while a request that joined a lead's pass sums (_stats_pass.StatsPass.join): keep
        # nothing in the caches, as after the lead's pass alone (its caches already full)
        self.keeps = True

    def n_chunks(self) -> int:
        """Chunks of a pass over all rows."""
        return -(-self.prep.n // self.chunk)

    def chunks(self, first: int = 0, last: int | None = None):
        """``(a, b, row columns of rows a:b)`` for chunks ``first … last - 1`` (all)."""
        prep = self.prep
        n = prep.n
        c = self.chunk
        stop = n if last is None else min(n, last * c)
        for a in range(first * c, stop, c):
            b = min(n, a + c)
            pad = c - (b - a)
            x = {}
            for k in prep.rows.names():
                s = prep.rows.column(k, a, b)
                if pad:
                    s = np.concatenate([s, np.repeat(s[-1:], pad, axis=0)], axis=0)
                x[k] = s
            x.update({k: v for k, v in prep.consts.items() if isinstance(v, np.ndarray)})
            yield a, b, x
            if self.progress is not None:
                self.progress(a, b, n)

    def clear(self) -> None:
        """Drop the cached Jacobians (after a row column changed)."""
        self._jcache.clear()
        self.blocks.clear()
        self._jbytes = 0

    def release_chunks(self) -> None:
        """Drop what is cached per chunk (the linear terms' Jacobians, the static blocks'
        processed Jacobians: up to :data:`CACHE_BYTES` each), keeping the per-block Gram
        matrices and normal equations: once the fits it served are done (the detection
        bounds fit with a fitter of their own: issue 43, peak memory). Later evaluations
        compute what is no longer cached (a linear term's value directly, not as
        ``v0 + J p``: the same up to rounding)."""
        self._jcache.clear()
        self._jbytes = 0
        self.blocks.release_processed()

    def keep_accumulated(self, static: Sequence[Term], acc: Accumulated) -> None:
        """Use ``acc`` as the normal equations of the static block ``static`` (a refit of
        the block on ``acc.y`` then makes no pass over the rows)."""
        self.blocks.keep_accumulated(static_key(static), acc)

    def gram(self, static: Sequence[Term]):
        """The kept ``(G, Gu)`` of the static block ``static`` (:mod:`._normal`) or ``None``."""
        return self.blocks.gram(static_key(static))

    def eval_term(
        self,
        term: Term,
        a: int,
        b: int,
        x: dict,
        jac: bool,
        whole: bool = True,
        compiled: bool = False,
    ):
        """Value (rows, C) and Jacobian (rows, C, free) of one term on one chunk.

        A term whose free parameters are all linear is ``v0 + J p_lin`` with ``v0`` and ``J``
        depending only on the held (nonlinear) parameters: those are cached (within a
        memory budget), so refits with other terms cost one matrix product. A term with a
        factored Jacobian (:func:`._normal.register_factors`) keeps ``J = X W`` as its
        factors: without ``whole``, the Jacobian is returned as :class:`Factored`. With
        ``compiled`` (a value only, ``jac`` false), the term's compiled value, never ``v0 +
        J p`` from a Jacobian the caches happen to hold (the two differ in the last bit): the
        same numbers whatever the caches hold (a factored term's value is ``v0 + X (W p)``
        either way)."""

        def params() -> dict:  # NumPy values: the compiled function transfers them itself
            return dict(term.values)  # (a jnp.asarray each was ~10% of a long diagnosis)

        if linear_only(term):
            held = tuple(term.values[q.name].tobytes() for q in term.cand.params if not q.linear)
            fmask = tuple(term.free[q.name].tobytes() for q in term.cand.params)
            key = (id(term.cand), a, held, fmask)
            hit = self._jcache.get(key)
            factors = factors_of(term.cand)
            if (hit is None or compiled) and not jac and factors is None:  # a value only
                return np.asarray(_val_fn(term.cand)(params(), x))[: b - a], None
            # (a factored term's value is v0 + X (W p) whether its factors were kept or not:
            # the same numbers whatever the caches hold, on one process or several)
            if hit is None:
                memo = self.memo  # during a pass for several fits: another fit's, this chunk
                hit = memo.get(("jac", *key)) if memo is not None else None
                if hit is None:
                    p = params()
                    p0 = {
                        q.name: (np.zeros_like(p[q.name]) if q.linear else p[q.name])
                        for q in term.cand.params
                    }
                    if factors is not None:  # J = X W: per-row features, not (rows, C, k)
                        v0, X, W, _ = factors(p0, x, term.free, b - a)
                        hit = (v0, Factored(X, W))
                    else:
                        v0, J = linear_valjac(term.cand)(p0, x)  # linear tangents only
                        v0 = np.asarray(v0)[: b - a]
                        hit = (v0, self._gather(term, J, b - a, v0.shape[1]))
                    if memo is not None:
                        memo.put(("jac", *key), hit)
                v0, Jt = hit
                nbytes = Jt.nbytes + v0.nbytes
                if jac and self.keeps and self._jbytes + nbytes < CACHE_BYTES:
                    self._jcache[key] = hit
                    self._jbytes += nbytes
            v0, Jt = hit
            lin = np.concatenate(
                [term.values[q.name][term.free[q.name]].ravel() for q in term.cand.params]
                or [np.zeros(0)]
            )
            # held linear parameters (fit=False) enter through v0 only when zero: add them
            if not lin.size:
                v = v0.copy()
            elif isinstance(Jt, Factored):
                v = v0 + Jt.X @ (Jt.W.reshape(-1, lin.size) @ lin).reshape(Jt.X.shape[1], -1)
            else:
                v = v0 + (Jt.reshape(-1, lin.size) @ lin).reshape(v0.shape)
            held_lin = [
                q
                for q in term.cand.params
                if q.linear
                and (~term.free[q.name]).any()
                and np.any(term.values[q.name][~term.free[q.name]] != 0)
            ]
            if held_lin:
                v = np.asarray(_val_fn(term.cand)(params(), x))[: b - a]
            if isinstance(Jt, Factored) and whole:  # (a value only: never made whole)
                Jt = Jt.whole() if jac else None
            return v, Jt
        memo = self.memo  # during a pass for several fits: this term at these values, this chunk
        mkey = ("term", id(term.cand), a, jac, term_key(term)) if memo is not None else ()
        got = memo.get(mkey) if memo is not None else None
        if got is not None:
            return got
        factors = factors_of(term.cand) if jac else None
        if factors is not None:  # J = [X W, E]: kept factored (made whole where asked); the
            # value the compiled one (a hand valjac's value is it: the same prediction, and so
            # chi-square, as without the factors)
            _, X, W, E = factors(params(), x, term.free, b - a, full=True)
            got = (np.asarray(_val_fn(term.cand)(params(), x))[: b - a], Factored(X, W, E))
        elif jac:
            v, J = valjac_fn(term.cand)(params(), x)
            v = np.asarray(v)[: b - a]
            got = (v, self._gather(term, J, b - a, v.shape[1]))
        else:
            got = (np.asarray(_val_fn(term.cand)(params(), x))[: b - a], None)
        if memo is not None:
            memo.put(mkey, got)
        if whole and isinstance(got[1], Factored):
            return got[0], got[1].whole()
        return got

    @staticmethod
    def _gather(term: Term, J: dict, rows: int, C: int) -> np.ndarray:
        cols = []
        for par in term.cand.params:
            free = term.free[par.name].ravel()
            if par.name not in J and not free.any():  # (linear_valjac: held, no tangent)
                continue
            Jp = np.asarray(J[par.name])[:rows].reshape(rows, C, -1)
            cols.append(Jp if free.all() else Jp[:, :, free])  # no copy when all are free
        return np.concatenate(cols, axis=2) if cols else np.zeros((rows, C, 0))

    def chunk_residual(self, terms: Sequence[Term], a: int, b: int, x: dict) -> np.ndarray:
        """Residual of rows ``a:b`` (projected when the kind says so), from the chunk's row
        columns ``x`` (as :meth:`chunks` yields them)."""
        prep = self.prep
        pred = np.zeros((b - a, prep.n_channels))
        for tm in terms:
            pred += self.eval_term(tm, a, b, x, jac=False)[0]
        r = prep.y[a:b] - pred
        if prep.kd.project:
            r = r - r.mean(1, keepdims=True)
        return r

    def iter_residual(self, terms: Sequence[Term]):
        """``(a, b, residual of rows a:b)`` chunk by chunk: statistics of a residual without
        holding it whole."""
        for a, b, x in self.chunks():
            yield a, b, self.chunk_residual(terms, a, b, x)

    def residual(self, terms: Sequence[Term]) -> np.ndarray:
        """Residual ``(n, C)`` (projected when the kind says so), all rows."""
        out = np.empty_like(self.prep.y)
        for a, b, r in self.iter_residual(terms):
            out[a:b] = r
        return out

    def jacobian(
        self, terms: Sequence[Term], a: int, b: int, x: dict, order: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Prediction (rows, C) and Jacobian (rows, C, p) of ``terms`` on rows ``a:b`` (the
        chunk's row columns ``x``, as :meth:`chunks` yields them), the Jacobian projected like
        the data (where the kind projects), neither scaled nor whitened, its rows in
        ``order`` (a permutation of the chunk's rows) where given. A new array: the terms'
        cached Jacobians are not touched. The one place the fit's Jacobian is assembled
        (:meth:`_processed`, ``_views_modulated.base_jacobian``)."""
        prep = self.prep
        pred = np.zeros((b - a, prep.n_channels))
        Js = []
        for tm in terms:
            v, J = self.eval_term(tm, a, b, x, jac=True)
            pred += v
            Js.append(J)
        if len(Js) == 1:  # the term's own (maybe cached): the row order or a copy
            J = Js[0][order] if order is not None else Js[0].copy()
        elif order is not None:  # each term's columns sorted into place: one copy (sorting
            # the joined block is a second one, and slower on wide blocks; the same numbers)
            J = np.empty((b - a, prep.n_channels, sum(j.shape[2] for j in Js)))
            at = 0
            for Jt in Js:
                J[:, :, at : at + Jt.shape[2]] = Jt[order]
                at += Jt.shape[2]
        else:
            J = np.concatenate(Js, axis=2) if Js else np.zeros((b - a, prep.n_channels, 0))
        # sorted first (the copy), then projected in place (one pass): (J - mean)
        if prep.kd.project:
            J -= J.mean(1, keepdims=True)
        return pred, J

    def _processed(
        self, terms: Sequence[Term], a: int, b: int, x: dict, sc: np.ndarray, key: tuple = ()
    ):
        """Projected, scaled, whitened, fold-sorted Jacobian and prediction of ``terms`` on
        one chunk: ``(pred (rows, C), J (rows, C, p) sorted by fold, order, edges)``; with
        ``key`` (terms with free nonlinear parameters: everything they depend on,
        :func:`._stats_pass.term_key` and the scales), from or into the memo of a pass for
        several fits."""
        if key and self.memo is not None:
            got = self.memo.get(("processed_dyn", key, a))
            if got is None:
                got = self._processed(terms, a, b, x, sc)
                self.memo.put(("processed_dyn", key, a), got)
            return got
        memo = self.memo if all(linear_only(t) for t in terms) else None
        mkey = ("processed", static_key(terms), a, sc.tobytes()) if memo is not None else ()
        if memo is not None:  # a static block's: another fit's of this pass, this chunk
            got = memo.get(mkey)
            if got is not None:
                pred = np.zeros((b - a, self.prep.n_channels))
                for tm in terms:
                    pred += self.eval_term(tm, a, b, x, jac=True, whole=False)[0]
                return (pred, *got)
        order, edges = self._fold_order(a, b)
        pred, J = self._scaled_jacobian(terms, a, b, x, order, sc)
        if memo is not None:
            memo.put(mkey, (J, order, edges))
        return pred, J, order, edges

    def _scaled_jacobian(self, terms: Sequence[Term], a: int, b: int, x: dict, order, sc):
        """:meth:`jacobian` with rows in ``order``, projected, whitened and scaled by ``sc``:
        ``(J - mean) sqrt(w) sc``. A term with a factored Jacobian (:class:`Factored`) gets
        its ``X W`` columns as one matrix product of its fold-sorted features with its weights
        projected, whitened and scaled (``P (X W) = X (P W)``: the same numbers to rounding,
        without the term's ``(rows, C, k)`` Jacobian, its sort or its passes; issue 43); the
        other terms' columns are the numbers :meth:`jacobian` gives, scaled."""
        if not any(factors_of(t.cand) is not None for t in terms):
            pred, J = self.jacobian(terms, a, b, x, order)
            J *= np.sqrt(self.w_ch)[:, None] * sc[None, :]  # (J - mean) (sc sqrt(w)), in place
            return pred, J
        got = [self.eval_term(t, a, b, x, jac=True, whole=False) for t in terms]
        return scaled_columns(self, got, order, sc)[:2]

    def _fold_order(self, a: int, b: int):
        f = self.prep.fold[a:b]
        order = np.argsort(f, kind="stable")
        edges = np.searchsorted(f[order], np.arange(self.prep.settings.n_folds + 1) - 0.5)
        return order, edges

    def processed_block(
        self,
        static: Sequence[Term],
        a: int,
        b: int,
        x: dict,
        sc: np.ndarray,
        pred: bool = True,
        keep: bool = True,
    ):
        """:meth:`_processed` of the static block ``static`` on one chunk, from the cache
        where it is kept (and, with ``keep``, kept where the budget allows): ``(pred, S,
        order, edges)``, the prediction at the block's current values (``None`` unless
        ``pred``)."""
        skey = static_key(static)
        hit = self.blocks.processed(skey, a)
        if hit is None:
            hit = self._processed(static, a, b, x, sc)
            if keep and self.keeps:
                self.blocks.keep_processed(skey, a, (None, *hit[1:]))
            return hit
        return (self._values(static, a, b, x) if pred else None, *hit[1:])

    def _values(self, terms: Sequence[Term], a: int, b: int, x: dict) -> np.ndarray:
        out = np.zeros((b - a, self.prep.n_channels))
        for tm in terms:
            out += self.eval_term(tm, a, b, x, jac=False)[0]
        return out

    def _split_processed(self, static, k0: int, a: int, b: int, x: dict, sc: np.ndarray):
        """:meth:`processed_block` of the static block, from its leading ``k0`` terms' (kept)
        beside the rest's, made now, where the whole block's is not kept (processing is
        column by column: the same numbers as the whole block's)."""
        if not 0 < k0 < len(static) or self.blocks.processed(static_key(static), a):
            return self.processed_block(static, a, b, x, sc)
        p0 = sum(t.n_free() for t in static[:k0])
        pred, S0, _, _ = self.processed_block(static[:k0], a, b, x, sc[:p0])
        pt, St, order, edges = self._processed(static[k0:], a, b, x, sc[p0:])
        assert pred is not None  # (asked for)
        return pred + pt, np.concatenate([S0, St], axis=2), order, edges

    def stats(self, terms: Sequence[Term], jac: bool = True):
        """Per-fold ``(A_f, g_f, c_f, ssr_f)`` over kept rows; parameters in scaled units.

        Terms whose free parameters are all linear form a *static* block: its processed
        Jacobian and per-fold Gram matrix are cached (:class:`._normal.BlockCache`), so a
        trial fit of one more candidate costs the products with the candidate's columns
        only, and a block that starts with a kept one (the model and a candidate start)
        sums only its new columns' Gram products. Each pass with the Jacobian also sums the
        block's normal equations per fold (:mod:`._normal`): a static block alone on the
        same observations then needs no pass at all."""
        return run_passes([StatsPass(self, terms, jac)])[0]

    def _assemble(self, static, p0: int, cross, cross_u, lead) -> tuple:
        """The block's ``(G, Gu)`` from its leading block's kept ones ``lead`` (its first
        ``p0`` columns) and the new columns' products ``cross`` (``S^T S_new``); each
        leading block's own kept."""
        if p0 and lead is not None:
            G0, Gu0 = lead
            out = []
            for M0, X in ((G0, cross), (Gu0, cross_u)):
                M = np.concatenate(
                    [np.concatenate([M0, X[:, :p0]], 2), np.transpose(X, (0, 2, 1))], 1
                )
                tail = M[:, p0:, p0:]
                M[:, p0:, p0:] = 0.5 * (tail + np.transpose(tail, (0, 2, 1)))
                out.append(M)
            G, Gu = out
        else:
            G, Gu = cross, cross_u
        s = 0
        for k, t in enumerate(static[:-1], start=1):  # leading squares: leading blocks' own
            s += t.n_free()
            self.blocks.keep_gram(static_key(static[:k]), G[:, :s, :s].copy(), Gu[:, :s, :s].copy())
        return G, Gu

    @staticmethod
    def _caller_order(terms, static, dyn, A, g, c, ssr, sc_s, sc_d):
        """``(A, g, c, ssr, sc)`` with the parameters back in the caller's term order (the
        static block first in the sums)."""
        idx = []
        pos = {}
        s0 = 0
        for t in static + dyn:
            pos[id(t)] = (s0, s0 + t.n_free())
            s0 += t.n_free()
        for t in terms:
            lo, hi = pos[id(t)]
            idx += list(range(lo, hi))
        idx = np.asarray(idx, dtype=int)
        A = A[:, idx][:, :, idx]
        g = g[:, idx]
        sc = np.concatenate([sc_s, sc_d])[idx]
        return A, g, c, ssr, sc

    def column_chi2(self, held: Sequence[Term], extra: Sequence[Term]) -> np.ndarray:
        """``fit([*held, e]).chi2`` for each term ``e`` of ``extra``, without the fits.

        ``held`` must be linear in its free parameters and each ``e`` have free (linear)
        scalars only: the fit is then linear least squares, and adding one column ``j`` to
        the columns ``B`` of ``held`` lowers chi-square by ``(j.r - j.B u)^2 / (j.j - j.B
        w)`` (``u = A^+ B.r``, ``w = A^+ B.j``, ``A = B.B`` on the columns the data
        determine), ``r`` the residual of ``held`` at its values; a term of ``k`` free
        scalars (columns ``J``) by ``n^T G^+ n``, ``n = J.r - J.B u``, ``G = J.J - J.B W``
        (issue 44 C, session 22: a located time's profile with the term's own sizes refitted
        jointly at each time). The Gram matrix of ``held`` is the cached one; each extra
        column costs one product with ``B``. A column the others span (relative ``j.P.j``
        under ``1e-10``, as the fit's pivoted Cholesky) lowers nothing."""
        prep = self.prep
        held = list(held)
        if not all(linear_only(t) for t in held) or any(
            e.n_free() < 1 or not linear_only(e) for e in extra
        ):
            raise ValueError("column_chi2: held terms linear, free linear scalars in each extra")
        K = prep.settings.n_folds
        A, gb, c, _, _ = self.stats(held)  # caches the held Gram and processed Jacobians
        At, gt = A.sum(0), gb.sum(0)
        sc = free_scales(held)
        sw = np.sqrt(self.w_ch)
        ks = [e.n_free() for e in extra]
        at = np.concatenate([[0], np.cumsum(ks)]).astype(int)
        E = int(at[-1])
        p = At.shape[0]
        shapes = [(p, E), (E, E), (E,)]
        groups = row_groups(self.n_chunks())  # split over processes as in stats
        parts = []
        for grp in my_groups(len(groups)):
            Bj, jj, jr = (np.zeros(s) for s in shapes)
            for a, b, x in self.chunks(*groups[grp]):
                pred, Js_, order, edges = self.processed_block(held, a, b, x, sc)
                r = prep.y[a:b] - pred
                if prep.kd.project:
                    r = r - r.mean(1, keepdims=True)
                lo, hi = int(edges[0]), int(edges[K])
                rw = (r * sw)[order][lo:hi].ravel()
                S = Js_[lo:hi].reshape(rw.size, p)
                cols = np.empty((rw.size, E))
                for i, e in enumerate(extra):
                    pv = e.values
                    p0 = {
                        q.name: (np.zeros_like(pv[q.name]) if q.linear else pv[q.name])
                        for q in e.cand.params
                    }
                    _, J = valjac_fn(e.cand)(p0, x)
                    Je = self._gather(e, J, b - a, prep.n_channels)
                    if prep.kd.project:
                        Je = Je - Je.mean(1, keepdims=True)
                    Jw = (Je * sw[None, :, None])[order][lo:hi]
                    cols[:, at[i] : at[i + 1]] = Jw.reshape(rw.size, ks[i])
                Bj += S.T @ cols
                for i in range(len(extra)):  # each term's own block (no cross terms needed)
                    sl = slice(at[i], at[i + 1])
                    jj[sl, sl] += cols[:, sl].T @ cols[:, sl]
                jr += cols.T @ rw
            parts.append(np.concatenate([Bj.ravel(), jj.ravel(), jr]))
        total = reduce_groups(parts, len(groups), p * E + E * E + E)
        Bj, jj, jr = unflatten(total, shapes)
        uw = solve_determined_many(At, np.column_stack([gt, Bj]))
        u, w = uw[:, 0], uw[:, 1:]
        dj = np.diag(jj).copy()
        jpj = dj - np.einsum("pe,pe->e", Bj, w)
        num = jr - Bj.T @ u
        ok = jpj > 1e-10 * np.maximum(dj, 1e-300)
        gain = np.where(ok, num * num / np.where(ok, jpj, 1.0), 0.0)[at[:-1]]
        for i in np.flatnonzero(np.asarray(ks) > 1):  # several columns: n^T G^+ n
            sl = slice(at[i], at[i + 1])
            G = jj[sl, sl] - Bj[:, sl].T @ w[:, sl]
            ev, V = np.linalg.eigh(0.5 * (G + G.T))
            good = ev > 1e-10 * max(float(np.max(np.diag(jj[sl, sl]))), 1e-300)
            z = V[:, good].T @ num[sl]
            gain[i] = float(np.sum(z * z / ev[good]))
        return float(c.sum()) - float(gt @ u) - gain

    def fit(self, terms: list[Term], max_steps: int = 30) -> FitResult:
        """Levenberg-Marquardt on the chunked normal equations; exact in one step for linear
        terms. Parameters that the data cannot determine (pivoted Cholesky of the scaled
        normal matrix) are held and listed."""
        return drive(self.fit_steps(terms, max_steps))

    def fit_steps(self, terms: list[Term], max_steps: int = 30) -> FitSteps:
        """:meth:`fit` as a generator of its :meth:`stats` requests (``(fitter, terms,
        jac)``, sent their answers; :func:`._stats_pass.drive_many` runs several side by
        side); it returns the :class:`FitResult`."""
        terms = [t.copy() for t in terms]
        nonlinear = any(
            (not q.linear) and t.free[q.name].any() for t in terms for q in t.cand.params
        )
        lam = 1e-6
        converged = True
        A, g, c, ssr, sc = yield (self, terms, True)
        unident: list[str] = []
        for it in range(max_steps):
            At, gt, ct = A.sum(0), g.sum(0), c.sum()
            dz, keep_idx = solve_determined(At, gt, lam if nonlinear else 0.0)
            if it == 0:
                unident = _names_of(terms, np.setdiff1d(np.arange(At.shape[0]), keep_idx))
                if nonlinear:
                    # converged already (e.g. a refit from the optimum): the Gauss-Newton
                    # step's predicted decrease of chi-square is negligible
                    dz0, _ = solve_determined(At, gt, 0.0)
                    if float(dz0 @ gt) < min(1e-2, 1e-7 * max(ct, 1e-300)):
                        break
            new = _apply(terms, dz * sc)
            if not nonlinear:
                terms = new
                A, g, c, ssr, sc = yield (self, terms, True)
                break
            # the trial point's chi-square first (values only); the Jacobian only where the
            # step is taken
            _, _, c2, _, _ = yield (self, new, False)
            if c2.sum() <= ct:
                rel = (ct - c2.sum()) / max(ct, 1e-300)
                terms = new
                A, g, c, ssr, sc = yield (self, new, True)
                lam = max(lam / 10, 1e-9)
                if rel < FIT_STOP_REL or (ct - c2.sum()) < FIT_STOP_CHI2:
                    break
                # the next Gauss-Newton step would lower chi-square negligibly: converged
                dz1, _ = solve_determined(A.sum(0), g.sum(0), 0.0)
                if float(dz1 @ g.sum(0)) < min(1e-2, 1e-7 * max(c.sum(), 1e-300)):
                    break
            else:
                lam *= 10
                if lam > 1e8:
                    break
        else:
            converged = False
        return self._result(terms, A, g, c, ssr, sc, converged, unident)

    def _result(self, terms, A, g, c, ssr, sc, converged, unident) -> FitResult:
        with stage("heldout"):
            return self._result_timed(terms, A, g, c, ssr, sc, converged, unident)

    def _result_timed(self, terms, A, g, c, ssr, sc, converged, unident) -> FitResult:
        K = A.shape[0]
        At, gt = A.sum(0), g.sum(0)
        ho_c, ho_ssr = 0.0, 0.0
        # one held-out step per fold from the full solution (exact for linear terms):
        # delta_f = (A - A_f)^+ (g - g_f); held-out chi2 = c_f - 2 delta.g_f + delta A_f delta
        _, kidx = solve_determined(At, gt, 0.0)
        for k in range(K):
            Ak = (At - A[k])[np.ix_(kidx, kidx)]
            gk = (gt - g[k])[kidx]
            try:
                d = sla.solve(
                    Ak + 1e-12 * np.trace(Ak) / max(len(kidx), 1) * np.eye(len(kidx)),
                    gk,
                    assume_a="pos",
                )
            except (np.linalg.LinAlgError, ValueError):
                d = np.linalg.lstsq(Ak, gk, rcond=None)[0]
            Af = A[k][np.ix_(kidx, kidx)]
            gf = g[k][kidx]
            hc = c[k] - 2 * d @ gf + d @ Af @ d
            ho_c += hc
            # unwhitened: scale by the mean channel variance ratio of this fold
            ho_ssr += ssr[k] * (hc / c[k] if c[k] > 0 else 1.0)
        p = At.shape[0]
        cov = np.full((p, p), np.nan)
        if kidx.size:
            sub = At[np.ix_(kidx, kidx)]
            try:
                inv = np.linalg.inv(sub)
            except np.linalg.LinAlgError:
                inv = np.linalg.pinv(sub)
            full = np.full((p, p), np.nan)
            full[np.ix_(kidx, kidx)] = inv
            cov = full * np.outer(sc, sc)
        slices, s = [], 0
        for t in terms:
            slices.append((s, s + t.n_free()))
            s += t.n_free()
        Apar = At / np.outer(sc, sc) if p else At
        return FitResult(
            terms=terms,
            chi2=float(c.sum()),
            n_params=int(kidx.size),
            cov=cov,
            heldout_chi2=float(ho_c),
            heldout_ssr=float(ho_ssr),
            ssr=float(ssr.sum()),
            n_rows=int(self.prep.keep.sum()),
            converged=converged,
            A=Apar,
            unidentifiable=unident,
            slices=slices,
            determined=kidx,
        )


def _apply(terms: list[Term], dz: np.ndarray) -> list[Term]:
    out = []
    s = 0
    for t in terms:
        t2 = t.copy()
        for q in t.cand.params:
            m = t.free[q.name]
            k = int(m.sum())
            v = t2.values[q.name]
            v[m] = v[m] + dz[s : s + k]
            s += k
        out.append(t2)
    return out


def _names_of(terms: list[Term], idx: np.ndarray) -> list[str]:
    names = []
    s = 0
    idx = set(int(i) for i in idx)
    for t in terms:
        for q in t.cand.params:
            m = t.free[q.name]
            pos = np.argwhere(m)
            for j, ij in enumerate(pos):
                if s + j in idx:
                    ij_s = [int(v) for v in ij]
                    names.append(f"{t.cand.name}.{q.name}{ij_s if ij_s else ''}")
            s += int(m.sum())
    return names
