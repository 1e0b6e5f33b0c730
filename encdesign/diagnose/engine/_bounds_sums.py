"""The sums of the detection bounds' one pass over the rows (:meth:`._bounds._Bench.prepare`,
issue 43): the probes' Gram matrices (their rank) and the products of the base's processed
Jacobian with the probes' unit effects, whitened and unwhitened, channel by channel."""

from __future__ import annotations

import numpy as np

from ._protocol import Prepared


def _add_gram(prep: Prepared, gram: np.ndarray, J, a: int, b: int, sw: np.ndarray) -> None:
    """Add the whitened Gram matrix of the Jacobian ``J`` of rows ``a:b`` (kept rows,
    projected where the kind projects) to ``gram``: channel by channel, each channel's
    Gram matrix weighted by its ``sw^2`` (no whitened copy of the rows; only its rank is
    used, :func:`_rank`)."""
    p = gram.shape[0]
    k = prep.keep[a:b]
    if p and k.any():
        Jk = J[k]  # (a copy: projected in place)
        if prep.kd.project:
            Jk -= Jk.mean(1, keepdims=True)
        for c in range(Jk.shape[1]):
            col = Jk[:, c, :]
            gram += (col.T @ col) * (sw[c] * sw[c])


def _channel_products(
    A: np.ndarray, B: np.ndarray, w: np.ndarray, out: np.ndarray, out_u: np.ndarray, diagonal=False
) -> None:
    """Add ``A^T B`` summed over rows and channels (``A`` (rows, C, p), ``B`` (rows, C, q):
    whitened columns) to ``out`` (p, q) and the same unwhitened, ``sum_c A_c^T B_c / w_c``
    (``w`` the channels' weights), to ``out_u``: one product per channel serves both (the
    same sums as the products of the whole ``(rows C, p)`` matrices, summed in another
    order: rounding apart, issue 43). With ``diagonal``, ``A`` and ``B`` have the same
    columns and only the column-wise products are added (``out``, ``out_u`` (q,))."""
    for c in range(A.shape[1]):
        a, b = A[:, c, :], B[:, c, :]
        x = np.einsum("ij,ij->j", a, b) if diagonal else a.T @ b
        out += x
        out_u += x / w[c]


def _rank(gram: np.ndarray) -> int:
    """The numerical rank of a Gram matrix (columns normalized; relative 1e-10)."""
    d = np.sqrt(np.maximum(np.diag(gram), 0.0))
    ok = d > 0
    ev = np.linalg.eigvalsh(gram[np.ix_(ok, ok)] / np.outer(d[ok], d[ok])) if ok.any() else []
    return int(np.sum(np.asarray(ev) > 1e-10 * max(float(np.max(ev, initial=0.0)), 1e-300)))
