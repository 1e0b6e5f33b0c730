"""The SDS run-mean level's search for an order of the platform angle on one moving sensor
(there throughout, growing or switching on): pairs of columns tested as F(2, dof) against
what the saturating columns leave (:func:`._sds_noise._level_sigma`; issue 41, sessions 18
and 19)."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats


def _order_groups(phi: np.ndarray, R: int, M: int, proj: bool) -> np.ndarray:
    """``(R*M, G, 2)``: pairs of columns of the run means (rows in time order), each the
    cos / sin of an order ``1 .. R*M/2 - 1`` of the platform angle ``phi`` on one moving
    sensor times a shape over the runs: 1 (there throughout), a linear growth from the first
    run to the last, or switching on at run ``j`` (2 runs at least either side); projected on
    the moving-sensor differences where the run means are (``proj``)."""
    i = np.arange(R, dtype=float)
    shapes = [np.ones(R), i / max(R - 1, 1)] + [(i >= j).astype(float) for j in range(2, R - 1)]
    W = np.stack(shapes, 1)  # (R, S)
    m = np.arange(1, max(R * M // 2 - 1, 1) + 1)
    cs = np.stack([np.cos(np.outer(phi, m)), np.sin(np.outer(phi, m))], -1)  # (R, L, 2)
    per = W[:, :, None, None] * cs[:, None]  # (R, S, L, 2)
    A = np.zeros((R, M, M) + per.shape[1:])
    for k in range(M):
        A[:, k, k] = per
    if proj:
        A = A - A.mean(1, keepdims=True)
    return A.reshape(R * M, -1, 2)


def _projected_pairs(A: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(Ap, norm2)``: the pairs of columns ``A`` (R*M, G, 2; :func:`_order_groups`) less
    their part in the span of the orthonormal basis ``Q`` (R*M, q), as a matrix (R*M, 2 G),
    and each pair's squared norm before (G,). Made once per basis of the saturating columns
    (the probes re-run the level many times on the same columns)."""
    n = A.shape[0]
    A2 = A.reshape(n, -1)
    return A2 - Q @ (Q.T @ A2), np.sum(A2**2, 0).reshape(-1, 2).sum(1)


def _best_pair(
    e: np.ndarray, dof: int, Qa: np.ndarray, pairs: tuple[np.ndarray, np.ndarray]
) -> tuple[float, np.ndarray] | None:
    """The pair of columns of :func:`_order_groups` (``pairs``: :func:`_projected_pairs` off
    the saturating columns) that takes the most of the residual ``e`` of the current basis
    (the saturating columns and ``Qa``, orthonormal columns orthogonal to them): ``(log p,
    columns)``, ``p`` its ``F(2, dof)`` tail probability times the number of pairs
    (Bonferroni); ``None`` where none is left. An order of one sensor that grows or
    switches on is in no saturating column: left in, it raised the run-mean level 1.8-1.95
    times on 5x records of the discovery benchmark (issue 41, session 18), and the
    structure fell below every threshold with it."""
    ssr0 = float(e @ e)
    if dof < 3 or ssr0 <= 0:
        return None
    Ap, norm2 = pairs
    if Qa.shape[1]:
        Ap = Ap - Qa @ (Qa.T @ Ap)
    P = Ap.reshape(Ap.shape[0], -1, 2)
    g00, g11 = np.sum(P[..., 0] ** 2, 0), np.sum(P[..., 1] ** 2, 0)
    g01 = np.sum(P[..., 0] * P[..., 1], 0)
    b = (e @ Ap).reshape(-1, 2)
    det = g00 * g11 - g01**2
    ok = det > 1e-10 * norm2**2
    q = b[:, 0] ** 2 * g11 - 2 * b[:, 0] * b[:, 1] * g01 + b[:, 1] ** 2 * g00
    q = np.where(ok, q / np.where(ok, det, 1.0), 0.0)
    j = int(np.argmax(q))
    if not ok[j]:
        return None
    f = (q[j] / 2) / ((ssr0 - q[j]) / dof) if ssr0 > q[j] else np.inf
    return float(stats.f.logsf(f, 2, dof)) + math.log(norm2.size), P[:, j]
