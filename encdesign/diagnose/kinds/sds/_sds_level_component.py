"""The SDS run-mean level per component: the moving sensors' common component and their
differences each at its own level, never above session 27's (issue 41, session 38).

:class:`._sds_level_out.LevelOut` reads a test of columns ``X`` (an order of one moving
sensor, a step, a discovered term) against the run-mean level without ``X``. Session 27's
level (``FinderSettings.sds_level_common_share``) is
``sigma_27 = c(nu - r) sqrt(s'^2 + kappa (s'^2 g(s')^2 - s'^2))``: ``s'`` the differences'
level without ``X`` (the saturated fit's residual, which leaves the common component nearly no
degrees of freedom), ``kappa`` the columns' share in the common component
(:func:`._sds_level_out.common_share`: 1 for a platform pattern, ``1 / M`` for one sensor's)
and ``g`` the whitening level's common factor, **floored at 1**: the common component is never
taken quieter than the differences. On the discovery benchmark's SDS 2x misses the true
common component was 0.4-0.9 times the differences' (the level mix 1.09-1.29 of
``benchmarks/discovery_acceptance.py``), so a one-sensor pattern (a third of it in the common
component with three moving sensors) or a platform pattern was tested against more noise than
it has.

Here the test's variance is the per-component mix with the common component at its own,
unbiased level, as session 28's :class:`._sds_level_common.CommonPart` estimates it:

    ``v = (1 - kappa) s'^2 + kappa sc'^2``,  ``sigma_own = c(nu_X) sqrt(v)``,

``sc'^2`` the variance of the base residual's common component off the base's common columns
and **without** ``X``'s common part (``dof - r_c`` degrees of freedom), ``c`` the widening
(:func:`._sds_noise.dof_widening`) at the mix's Welch-Satterthwaite degrees of freedom
``nu_X`` (each component pays for its own degrees of freedom: a platform pattern the common
component's few, a one-sensor pattern little more than the differences'). ``v`` is the
variance of the test's least-squares chi-square per unit of its columns exactly for one
sensor's columns (``P_X Sigma P_X = v P_X`` with covariance ``s^2`` on the differences and
``sc^2`` on the common component) and for common ones; the generalised least-squares sum of
the two parts, each whitened apart, would be more powerful for one sensor's columns but is
not what the views compute (their chi-square is whitened with one level and multiplied by
``(sigma / sigma_X)^2``, :meth:`._sds_level_out.LevelOut._factor`).

**The degrees of freedom at the less favourable common variance** (session 41). The
Welch-Satterthwaite ``nu_X`` needs the components' true variances; at the estimate ``sc'^2``
(5-20 degrees of freedom, and less the test's own common part) it is overstated exactly where
``sc'^2`` comes out low: the common component then weighs little in the mix and ``nu_X``
approaches the differences' (a one-sensor test's widening 1.37 at 16 dof instead of 2.6 at 6).
On the SDS catalog set 6742 (``--sds-unlocked-clock``, training) record 23, clean, an unlocked
clock's common component ``sqrt(31)`` times the differences' over 7 degrees of freedom, 96 % of
it along the common part of a one-sensor order-2 decay: ``sc'`` fell to 1.26 ``s'``, the dof
to 16, and the decay read chi-square 52 against 24.5 (session 27's level: under 24.5). So
``nu_X`` is also computed at the common variance ``max(sc'^2, s'^2 g(s')^2)`` (session 27's
common variance at the test's ``s'``, from what no structure in the platform angle reaches)
and the smaller of the two is kept (``v`` itself stays the estimate). As ``nu_X`` is not
monotone in the common variance (the mix has the most degrees of freedom where the two parts
weigh alike), the minimum of the two, not the dof at the larger variance, is what never
overstates it; a common test (``kappa = 1``: ``nu_X`` = the common component's own) is
unchanged. Under noise of that record's shape the one-sensor decay's false-alarm rate at 2e-3
was 2.3x (5-11 of 1500 draws, 3 expected) and is 0-1x (0-3)
(``tests/test_sds_level_component.py``).

**The guard against session 28's failure.** Session 28 used ``sigma_own`` alone
(``FinderSettings.sds_level_common_direct``): the base residual's common component also holds
any common structure the test's columns do not span (a platform step's part off the tested
columns, a common line at another order), which raised every other test's level and made a
test of columns that take part of that structure win over the structure's own (training
20261430, a 2x ``platform_step`` modelled at the wrong order; two catalog-set drops). Here the
level is ``min(sigma_own, sigma_27)``: session 27's common factor is estimated from what no
structure in the platform angle reaches (the revolution contrasts and the fixed sensors' run
means, :func:`._sds_noise._common_excess`, capped by the direct upper confidence limit), so
common structure in the base residual can never raise a test's level above today's, and
where the common component is louder than the differences the level is session 27's. It is
lowered only where the common component is quieter than session 27 takes it, which is the
case the level was built for. Under noise alone the minimum of two valid levels is somewhat
liberal; ``tests/test_sds_level_component.py`` measures the false-alarm rate of a one-sensor
and a common test with a quiet, an equal and a loud common component.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ._sds_level_common import CommonPart


class ComponentLevel(CommonPart):
    """The base residual's common component (:class:`._sds_level_common.CommonPart`: ``means``
    (R, M) the base residual's run means, ``base`` (R, k) the base's common columns) read as
    the per-component level of the module doc: :meth:`capped`."""

    def capped(
        self,
        widening: Callable[[np.ndarray], np.ndarray],
        s2: np.ndarray,
        n: np.ndarray,
        kappa: np.ndarray,
        gc: np.ndarray,
        rc: np.ndarray,
        ceiling: np.ndarray,
        common: np.ndarray | None = None,
    ) -> np.ndarray:
        """The level (rad) ``min(sigma_own, sigma_27)`` (module doc) of tests whose
        differences' level without their columns is ``s2`` (rad^2) on ``n`` degrees of
        freedom, common share ``kappa``, taking power ``gc`` (rad^2) of rank ``rc`` from the
        common component; ``ceiling`` (rad): session 27's level of the same tests (arrays
        of one shape). Where the common component has fewer than 3 degrees of freedom left
        the level is ``ceiling``. ``widening``: the level's widening on an array of degrees
        of freedom. ``common`` (rad^2, same shape; ``None``: none): session 27's common
        variance ``s'^2 g(s')^2``, at which the degrees of freedom are also taken (module
        doc)."""
        own = self.levels(widening, s2, n, kappa, gc, rc, common)
        ceiling = np.asarray(ceiling, float)
        return np.where(np.isfinite(own), np.minimum(own, ceiling), ceiling)
