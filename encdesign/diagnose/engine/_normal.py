"""Issue 43: the accumulated normal equations of a fitter's *static* block.

A block of terms whose free parameters are all linear (the base model with its nonlinear
parameters held, a candidate at held nonlinear values) predicts ``v0 + J p`` with ``v0``
and ``J`` fixed by the held values. Its whitened, projected, scaled residual at scaled
free values ``z`` is ``r(z) = r_ref - S (z - z_ref)`` (``S`` the processed Jacobian,
``r_ref`` the residual at the values ``z_ref`` of the last pass over the rows), so the
per-fold statistics the fitter needs at any ``z`` follow from sums made in that pass,
per fold ``k``: ``G_k = S_k^T S_k`` (the fit's own Gram matrix, summed as the fit sums
it), ``h_k = S_k^T r_ref,k``, ``q_k = |r_ref,k|^2``, and the same unwhitened (each row and
channel divided by ``sqrt(w_c)``, the channel's weight): ``Gu_k``, ``hu_k``, ``qu_k``. With
``dz = z - z_ref``::

    c_k = q_k - 2 dz.h_k + dz^T G_k dz            (whitened chi-square)
    g_k = h_k - G_k dz,  A_k = G_k
    ssr_k = qu_k - 2 dz.hu_k + dz^T Gu_k dz       (unwhitened)

The identities are exact; only their rounding differs from a pass over the rows. The
rounding error of ``c`` is of order ``eps`` times the magnitude of its terms (``q`` and
the two corrections), so :meth:`Accumulated.stats` declines (the fitter then makes the
pass, which sets a new reference) where that magnitude exceeds :data:`CANCEL_MAX` times the
chi-square it would return: ``c`` then carries a relative rounding error of about
``CANCEL_MAX * 2.2e-16`` (``2e-12``) at most, the gradient ``g`` at most that relative to
``|G dz|``. A refit of the same static block on the same observations (the linear step
of a fit, a candidate screened at held values, the backward check, a probe's second
statistics) then costs no pass over the rows.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

CANCEL_MAX = 1e4
"""The accumulated statistics are used only while the magnitude of the terms of the
chi-square (``q + 2 |dz.h| + dz^T G dz``) is at most this many times the chi-square itself
(a rounding error of about ``CANCEL_MAX * eps`` relative); beyond it, a pass over the rows."""


def held_key(terms: Sequence) -> tuple:
    """The held (not free) values of ``terms``, as bytes: the static block's prediction
    ``v0`` depends on them (nonlinear ones and linear ones held at a nonzero value)."""
    return tuple(t.values[q.name][~t.free[q.name]].tobytes() for t in terms for q in t.cand.params)


def free_values(terms: Sequence) -> np.ndarray:
    """The free scalars of ``terms`` in parameter order (parameter units)."""
    return np.concatenate(
        [t.values[q.name][t.free[q.name]].ravel() for t in terms for q in t.cand.params]
        or [np.zeros(0)]
    )


def free_scales(terms: Sequence) -> np.ndarray:
    """The scales of the free scalars of ``terms``, in the order of :func:`free_values`
    (scaled value = value / scale, as :meth:`Fitter.stats` scales its columns)."""
    return np.concatenate(
        [t.scale[q.name][t.free[q.name]].ravel() for t in terms for q in t.cand.params]
        or [np.zeros(0)]
    )


@dataclasses.dataclass
class Accumulated:
    """The normal equations of one static block on one set of observations, per fold and
    channel, at reference values (module doc).

    Attributes:
        y: the observations they were summed from (compared by identity: the engine's probes
            give the prepared record new observations).
        held: :func:`held_key` of the block.
        z_ref: the free values at the reference (parameter units).
        sc: the scales of the free values (scaled = value / sc).
        G: ``(K, p, p)`` per-fold Gram matrices of the processed (whitened) Jacobian.
        Gu: ``(K, p, p)`` the same unwhitened.
        h: ``(K, p)`` its products with the reference residual (whitened).
        q: ``(K,)`` the reference residual's whitened sums of squares.
        hu, qu: ``h`` and ``q`` unwhitened.
    """

    y: np.ndarray
    held: tuple
    z_ref: np.ndarray
    sc: np.ndarray
    G: np.ndarray
    Gu: np.ndarray
    h: np.ndarray
    q: np.ndarray
    hu: np.ndarray
    qu: np.ndarray

    def nbytes(self) -> int:
        """Bytes held (the two Gram matrices)."""
        return int(self.G.nbytes + self.Gu.nbytes)

    def stats(self, y, held: tuple, z: np.ndarray, sc: np.ndarray, w_ch, jac: bool):
        """``(A, g, c, ssr)`` per fold at free values ``z`` (parameter units, scales ``sc``)
        as a pass over the rows would give them, or ``None`` where these sums do not apply
        (other observations, held values or scales) or would round too coarsely
        (:data:`CANCEL_MAX`)."""
        if y is not self.y or held != self.held or not np.array_equal(sc, self.sc):
            return None
        dz = (z - self.z_ref) / np.where(sc != 0, sc, 1.0)
        del w_ch  # (in the unwhitened sums)
        lin = self.h @ dz
        Gdz = self.G @ dz
        quad = Gdz @ dz
        c = self.q - 2.0 * lin + quad
        size = float(np.sum(self.q) + 2.0 * np.sum(np.abs(lin)) + np.sum(np.abs(quad)))
        if not size <= CANCEL_MAX * max(float(c.sum()), 1e-300):
            return None
        ssr = self.qu - 2.0 * (self.hu @ dz) + (self.Gu @ dz) @ dz
        K, p = self.G.shape[0], self.G.shape[2]
        if not jac:
            return np.zeros((K, p, p)), np.zeros((K, p)), c, ssr
        return self.G.copy(), self.h - Gdz, c, ssr
