"""A term's factored Jacobian kept as features and weights through a pass (issue 43):
``fitter``'s processed Jacobian of the free nonlinear terms with one term's ``X W`` columns
left factored (:func:`feature_parts`), so :mod:`._stats_pass` sums their Gram matrices from
``X^T X`` (``StatsPass._gram_f``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np


@dataclasses.dataclass
class Factored:
    """A term's Jacobian on a chunk as ``J[n, c, j] = sum_f X[n, f] W[f, c, j]`` followed by
    the columns ``E`` (:func:`._normal.register_factors`): ``X`` (rows, F), ``W`` (F, C, k),
    ``E`` (rows, C, e) or ``None``."""

    X: np.ndarray
    W: np.ndarray
    E: np.ndarray | None = None

    @property
    def nbytes(self) -> int:
        """Bytes held."""
        return int(self.X.nbytes + self.W.nbytes + (0 if self.E is None else self.E.nbytes))

    @property
    def width(self) -> int:
        """Columns of ``J``."""
        return int(self.W.shape[2] + (0 if self.E is None else self.E.shape[2]))

    def whole(self, order: np.ndarray | None = None) -> np.ndarray:
        """``J`` (rows, C, k + e), its rows in ``order`` where given."""
        X = self.X if order is None else self.X[order]
        out = np.empty((X.shape[0], self.W.shape[1], self.width))
        self.into(out, X)
        if self.E is not None:
            out[:, :, self.W.shape[2] :] = self.E if order is None else self.E[order]
        return out

    def into(self, out: np.ndarray, X: np.ndarray, W: np.ndarray | None = None) -> None:
        """``out[:, :, :k] = X W`` (weights ``W``, default the term's own): one product."""
        W = self.W if W is None else W
        k = W.shape[2]
        out[:, :, :k] = (X @ W.reshape(W.shape[0], -1)).reshape(X.shape[0], *W.shape[1:])


def scaled_columns(fitter, got: Sequence, order: np.ndarray, sc, features: bool = False):
    """The columns of one chunk's Jacobian, its rows in ``order`` (the fold order),
    projected (where the kind projects), whitened and scaled by ``sc``: ``(J - mean) sqrt(w)
    sc``, from ``got`` (each term's ``(value, J)`` from ``Fitter.eval_term(..., jac=True,
    whole=False)``, ``J`` (rows, C, k) or :class:`Factored`). A factored term's ``X W``
    columns are one matrix product of its fold-sorted features with its weights projected,
    whitened and scaled (``P (X W) = X (P W)``); its ``E`` columns and the other terms' are
    copied, projected and scaled like an unfactored Jacobian's. Returns ``(pred (rows, C),
    out (rows, C, q), Xo, Wp, fcols, ocols)``: with ``features``, one factored term's ``X W``
    columns are left out of ``out`` and kept as ``Xo = X[order]`` (rows, F) and ``Wp = P W
    sqrt(w) sc`` (F, C, kw) (``None`` without ``features`` or a factored term), ``fcols`` /
    ``ocols`` the places of the kept and of ``out``'s columns in the terms' order.
    (``Fitter._scaled_jacobian`` and :func:`feature_parts`.)"""
    project = fitter.prep.kd.project
    sw = np.sqrt(fitter.w_ch)
    rows, C = len(order), sw.shape[0]
    ks = [J.width if isinstance(J, Factored) else J.shape[2] for _, J in got]
    kept = sum(J.W.shape[2] for _, J in got if isinstance(J, Factored)) if features else 0
    out = np.empty((rows, C, sum(ks) - kept))
    pred = np.zeros((rows, C))
    fcols, ocols = [], []
    at = oat = 0  # the next column in the terms' order, in ``out``
    Xo = Wp = None
    for (v, J), k in zip(got, ks):
        pred += v
        s = sw[:, None] * sc[None, at : at + k]
        first = at  # the first of the term's columns copied into ``out``
        if isinstance(J, Factored):
            kw = J.W.shape[2]
            W = J.W - J.W.mean(1, keepdims=True) if project else J.W
            if features:
                if Xo is not None:
                    raise ValueError("features: one factored term at most")
                Xo, Wp = J.X[order], W * s[:, :kw]
                fcols += range(at, at + kw)
            else:
                J.into(out[:, :, oat : oat + kw], J.X[order], W * s[:, :kw])
                ocols += range(at, at + kw)
                oat += kw
            if J.E is None:
                at += k
                continue
            first, s, J = at + kw, s[:, kw:], J.E
        cols = out[:, :, oat : oat + at + k - first]
        cols[...] = J[order]
        if project:
            cols -= cols.mean(1, keepdims=True)
        cols *= s
        ocols += range(first, at + k)
        oat += at + k - first
        at += k
    return pred, out, Xo, Wp, np.asarray(fcols, int), np.asarray(ocols, int)


def feature_parts(fitter, terms: Sequence, a: int, b: int, x: dict, sc, key: tuple = ()):
    """The projected, whitened, scaled, fold-sorted Jacobian of ``terms`` on one chunk
    with one term's factored columns (:class:`Factored`) left as features and weights,
    or ``None`` where no term (or more than one) has them: ``(pred, Xo (rows, F) sorted,
    Wp (F, C, kw) = P W sqrt(w) sc, fcols, O (rows, C, q) the other columns as
    ``Fitter._scaled_jacobian`` makes them, ocols, order, edges)``, ``fcols`` / ``ocols``
    the columns' places in the terms' order (:func:`scaled_columns`). A pass's per-fold
    Gram matrix of the factored columns is then ``sum_c Wp_c^T (Xo^T Xo) Wp_c`` (``F^2``
    products a row instead of ``C kw^2``; issue 43: the base fit with its placements and
    run zeros free); with ``key``, from or into the memo of a pass for several fits."""
    memo = fitter.memo if key else None
    if memo is not None:
        got = memo.get(("parts_dyn", key, a))
        if got is not None:
            return got
    got = [fitter.eval_term(t, a, b, x, jac=True, whole=False) for t in terms]
    if sum(isinstance(J, Factored) for _, J in got) != 1:
        return None
    order, edges = fitter._fold_order(a, b)
    pred, out, Xo, Wp, fcols, ocols = scaled_columns(fitter, got, order, sc, features=True)
    parts = (pred, Xo, Wp, fcols, out, ocols, order, edges)
    if memo is not None:
        memo.put(("parts_dyn", key, a), parts)
    return parts


__all__ = ["Factored", "feature_parts", "scaled_columns"]
