"""The moving sensors' common component at its own, unbiased level in the run-mean level
without a test's columns (issue 41, session 28).

:class:`._sds_level_out.LevelOut` reads a test of columns ``X`` against
``s' c(nu - r) sqrt(1 + kappa (g^2 - 1))`` (session 27): ``s'`` the saturated fit's level
without ``X`` (the moving sensors' differences: the saturating columns leave the common
component nearly no degrees of freedom), ``kappa`` the columns' share in the common
component (:func:`._sds_level_out.common_share`) and ``g`` the whitening level's common
factor, the indirect excess (revolution contrasts, fixed sensors) capped at the **upper
confidence limit** of the base residual's own common component
(:func:`._sds_noise._direct_common_factor`) and floored at 1. Both the cap and the floor
lean high: on the discovery benchmark's 2x misses the finder's level was 1.13-1.42x the
truth's for one-sensor tests and 1.78-2.44x for a common step (session 27's audit), while
the true common level was 0.5-1.1x the differences'.

Here the common part enters at its own unbiased estimate instead, as session 25's level
per component did, but on :class:`LevelOut`'s own differences level (the same ``s'``, the
same F-test's denominator) and with the share of session 27:

    ``sigma_X^2 = c(nu_X)^2 v``,  ``v = s'^2 + kappa (sc'^2 - s'^2)``,

``sc'^2 = (|z|^2 - g_c) / (dof - r_c)`` the variance of the base residual's common
component ``z`` (off the base's common columns, :func:`._sds_noise.common_base_columns`:
``dof = R - k``) **without** ``X``'s common part (``g_c`` the power it takes from ``z``,
``r_c`` its rank), unbiased and not floored at ``s'^2``. Under noise of variance ``sd^2``
on every difference and ``sc^2`` on the common component, a test of ``X`` sees
``sd^2 + kappa (sc^2 - sd^2)`` (exactly for one sensor's columns, where ``P_X Sigma P_X =
sigma_X^2 P_X``), and ``v`` estimates it without bias from two independent chi-squares
(``z`` off the base and ``e`` off the saturating columns use disjoint components). The
widening ``c`` (:func:`._sds_noise.dof_widening`) is taken at the mix's degrees of freedom
(Welch-Satterthwaite, rounded down): ``nu_X = v^2 / ((1 - kappa)^2 s'^4 / (nu - r) +
kappa^2 sc'^4 / (dof - r_c))``, so a common pattern (``kappa = 1``) pays the widening of the
common component's own few degrees of freedom (1.5 at 12), a one-sensor test little more
than the differences'. Where the common component has fewer than 3 degrees of freedom left,
or the run means are projected on the differences (no ``phi_ref``), the level is
session 27's. Behind ``FinderSettings.sds_level_common_direct`` (with the share on).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np


class CommonPart:
    """The base residual's common component over the moving sensors and its powers.

    ``means`` (R, M): the base residual's run means (rows in the level's order); ``base``
    (R, k): the base's common columns. ``z`` (R,): the common component
    (``sum_m means / sqrt(M)``) off ``base``; ``dof = R - rank(base)``."""

    def __init__(self, means: np.ndarray, base: np.ndarray):
        means, base = np.asarray(means, float), np.asarray(base, float)
        R, M = means.shape
        self.M = int(M)
        U, s, _ = np.linalg.svd(base, full_matrices=False)
        self.A = U[:, s > 1e-10 * max(float(s.max(initial=0.0)), 1e-300)]
        z0 = means.sum(1) / math.sqrt(M)
        self.z = z0 - self.A @ (self.A.T @ z0)
        self.zz = float(self.z @ self.z)
        self.dof = int(R - self.A.shape[1])

    def _common(self, X: np.ndarray) -> np.ndarray:
        """``X`` (R, M, ...)'s common components (R, -1), off the base's common columns."""
        Xc = np.asarray(X, float).sum(1) / math.sqrt(self.M)
        Xc = Xc.reshape(Xc.shape[0], -1)
        return Xc - self.A @ (self.A.T @ Xc)

    def power(self, X: np.ndarray) -> tuple[float, int]:
        """``(g_c, r_c)``: the power columns ``X`` (R, M, q) take from ``z`` by their common
        parts off the base, and the rank of those parts (directions below ``1e-6`` of the
        columns' norm are none, as :class:`._sds_level_out.LevelOut` cuts its own)."""
        Xc = self._common(X)
        n = math.sqrt(float(np.max(np.sum(np.asarray(X, float) ** 2, (0, 1)), initial=0.0)))
        U, s, _ = np.linalg.svd(Xc, full_matrices=False)
        U = U[:, s > 1e-6 * max(n, 1e-300)]
        return float(np.sum((U.T @ self.z) ** 2)), int(U.shape[1])

    def pair_powers(self, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(g_c, r_c)`` (G,) of each pair of columns of ``A`` (R, M, G, 2), from the
        pairs' 2x2 Gram matrices (eigenvalues below ``1e-12`` of the pair's largest squared
        column norm are no direction, as :meth:`._sds_level_out.LevelOut.pairs` cuts)."""
        A = np.asarray(A, float)
        G = A.shape[2]
        P = self._common(A).reshape(-1, G, 2)
        n2 = np.sum(A**2, (0, 1)).max(1)  # (G,)
        gram = np.einsum("ngi,ngj->gij", P, P)
        ev, V = np.linalg.eigh(gram)
        big = ev > 1e-12 * np.maximum(n2, 1e-300)[:, None]
        proj = np.einsum("gi,gij->gj", np.einsum("n,ngi->gi", self.z, P), V)
        g = np.sum(np.where(big, proj**2 / np.where(big, ev, 1.0), 0.0), 1)
        return g, big.sum(1)

    def levels(
        self,
        widening: Callable[[np.ndarray], np.ndarray],
        s2: np.ndarray,
        n: np.ndarray,
        kappa: np.ndarray,
        gc: np.ndarray,
        rc: np.ndarray,
        floor: np.ndarray | None = None,
    ) -> np.ndarray:
        """The level (rad) ``c(nu_X) sqrt(v)`` (module doc) of tests whose differences level
        without their columns is ``s2`` (rad^2) on ``n`` degrees of freedom, common share
        ``kappa``, taking power ``gc`` of rank ``rc`` from the common component (arrays of
        one shape); ``nan`` where the common component has fewer than 3 degrees of freedom
        left (the caller keeps session 27's level there). ``widening``: the level's
        widening on an array of degrees of freedom. ``floor`` (rad^2, same shape; ``None``:
        none): ``nu_X`` is also taken at the common component's variance ``max(sc'^2,
        floor)`` and the smaller of the two is kept (``v`` itself is not changed:
        :mod:`._sds_level_component`)."""
        s2, n = np.asarray(s2, float), np.asarray(n, float)
        kappa = np.clip(np.asarray(kappa, float), 0.0, 1.0)
        nc = self.dof - np.asarray(rc, int)
        ok = (nc >= 3) & (self.zz - np.asarray(gc, float) > 0)
        ncs = np.where(ok, nc, 3).astype(float)
        sc2 = np.where(ok, self.zz - np.asarray(gc, float), 1.0) / ncs
        v = s2 + kappa * (sc2 - s2)

        def dof(c2: np.ndarray) -> np.ndarray:  # Welch-Satterthwaite at common variance c2
            var = (1.0 - kappa) ** 2 * s2**2 / n + kappa**2 * c2**2 / ncs
            return (s2 + kappa * (c2 - s2)) ** 2 / np.maximum(var, 1e-300)

        nu = np.floor(dof(sc2))
        if floor is not None:  # a hair up: where kappa = 1 both are nc, and floor() keeps it
            nu2 = dof(np.maximum(sc2, np.asarray(floor, float))) * (1.0 + 1e-12)
            nu = np.minimum(nu, np.floor(nu2))
        c = widening(np.maximum(nu, 1.0))
        return np.where(ok, c * np.sqrt(np.maximum(v, 0.0)), np.nan)
