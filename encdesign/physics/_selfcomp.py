"""Self-compensation with an asymmetric reference head (Cramer, seed 000, sections III-IV).

Convention. Head ``n`` sees the reference head's error function shifted by its offset
``h_n``: ``e_n(theta) = e_0(theta + h_n)``. With encdesign's azimuths (counter-clockwise,
shaft turning ``+theta``, see :mod:`encdesign.physics._kinematics`) a head at azimuth ``alpha_n``
and the reference head at ``alpha_ref`` have ``h_n = alpha_ref - alpha_n``.

Write the reference head's error as ``e_0(theta) = sum_j S_j sin(j theta) + C_j cos(j theta)``
(seed eq. 12/20) and the measured head difference ``d_n = reading_n - reading_0`` as
``sum_j S'_j sin(j theta) + C'_j cos(j theta)`` (seed eq. 27). The *cotangent equations*
(seed eq. 16/35) recover the error function from the differences alone:

    S_j =  (C'_j cot(j h_n / 2) - S'_j) / 2
    C_j = -(S'_j cot(j h_n / 2) + C'_j) / 2

(in complex form ``a_j = a'_j / (exp(i j h_n) - 1)`` with ``a = C - i S``). A mode with
``sin(j h_n / 2) = 0`` is invisible to that pair; near such angles the cotangent blows up
and amplifies measurement noise (seed III.D), which :func:`cotangent_sensitivity`
quantifies.

With several heads each is paired with the reference head; the coefficient sets are
averaged and their spread across pairs is a health diagnostic (seed III.B).
:func:`encoder_map` turns the coefficients into the map ``m(theta)`` of the averaged output
of the symmetric heads (seed eqs. 17-19): ``m(theta) = sum_k w_k e_0(theta + h_k)``, which
for ``N`` equally spaced heads keeps exactly the degenerate modes ``N, 2N, …`` of eq. 17.
:func:`apply_map` subtracts it.
"""

# no ``from __future__ import annotations``: equinox reads the ``AbstractVar`` of
# :class:`AbstractErrorSeries` at class creation and refuses it as a string
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from equinox import AbstractVar
from jaxtyping import Array

from .._array import f64 as _f64
from .._errors import EncdesignInputError
from ._theorem import fourier_coefficients, fourier_series
from ._types import (
    Angles,
    Averaged,
    HeadAngles,
    HeadReadings,
    HeadWeights,
    OrderCoefficients,
    OrderCoefficientsOut,
    OrderValues,
    SampleValues,
    Scalar,
    ScalarOut,
)

__all__ = [
    "AbstractErrorSeries",
    "cotangent_equations",
    "SelfCompensation",
    "self_compensate",
    "EncoderMap",
    "encoder_map",
    "apply_map",
    "cotangent_sensitivity",
]


def cotangent_equations(
    diff_sin_rad: OrderCoefficients,
    diff_cos_rad: OrderCoefficients,
    head_offset_rad: Scalar,
    orders: OrderCoefficients | None = None,
) -> tuple[OrderCoefficientsOut, OrderCoefficientsOut]:
    """Seed eq. 16/35: reference-head error coefficients from one pair's differences.

    Args:
        diff_sin_rad: ``S'_j`` of ``d_n = reading_n - reading_0``, rad, shape ``(M,)``.
        diff_cos_rad: ``C'_j``, rad, shape ``(M,)``.
        head_offset_rad: ``h_n`` with ``e_n(theta) = e_0(theta + h_n)``, rad
            (``alpha_ref - alpha_n`` in encdesign's convention).
        orders: the orders ``j`` of the coefficients (default ``1 … M``).

    Returns:
        ``(S_j, C_j)`` of the reference head's error, rad. Orders with
        ``sin(j h_n / 2) = 0`` are unobservable and come back non-finite; use
        :func:`self_compensate` for masked, averaged results.
    """
    sp, cp = _f64(diff_sin_rad), _f64(diff_cos_rad)
    j = jnp.arange(1, sp.shape[-1] + 1) if orders is None else _f64(orders)
    half = j * _f64(head_offset_rad) / 2
    cot = jnp.cos(half) / jnp.sin(half)
    return 0.5 * (cp * cot - sp), -0.5 * (sp * cot + cp)


class AbstractErrorSeries(eqx.Module):
    """Sine and cosine coefficients ``S_j``, ``C_j`` (rad) of orders ``j = 1 … M`` of an
    error function, and its value: the part :class:`SelfCompensation`,
    :class:`~encdesign.physics.LayoutCompensation` and :class:`EncoderMap` share. Abstract:
    each of them declares the two fields; the methods here are never overridden."""

    sin_rad: AbstractVar[Array]
    cos_rad: AbstractVar[Array]

    @property
    def max_order(self) -> int:
        """Highest order ``M``."""
        return int(self.sin_rad.shape[0])

    def error_function(self, theta_rad: Angles) -> Averaged:
        """The error function at angles ``theta`` (rad, any shape), rad:
        ``sum_j S_j sin(j theta) + C_j cos(j theta)``."""
        return fourier_series(theta_rad, self.sin_rad, self.cos_rad)


class SelfCompensation(AbstractErrorSeries):
    """Result of :func:`self_compensate` (all coefficients in rad, orders ``1 … M``).
    :meth:`error_function` is the reference head's error ``e_0(theta)``.

    Attributes:
        sin_rad, cos_rad: averaged ``S_j``, ``C_j`` of the reference head's error ``(M,)``.
        pair_sin_rad, pair_cos_rad: per-pair estimates ``(P, M)`` (0 where unobservable).
        observable: ``(P, M)`` whether pair ``p`` sees order ``j``
            (``|sin(j h_p / 2)| > min_sin``).
        spread_rad: ``(M,)`` RMS deviation of the pair estimates from their average
            (health diagnostic; 0 with a single observing pair).
        head_offsets_rad: ``(P,)`` offsets ``h_p`` of the paired heads.
        reference_angle_rad: azimuth of the reference head, rad.
        pair_heads: indices of the heads paired with the reference (static).
    """

    sin_rad: Array
    cos_rad: Array
    pair_sin_rad: Array
    pair_cos_rad: Array
    observable: Array
    spread_rad: Array
    head_offsets_rad: Array
    reference_angle_rad: Array
    pair_heads: tuple[int, ...] = eqx.field(static=True)


@functools.partial(jax.jit, static_argnames=("reference_head", "max_order"))
def self_compensate(
    theta_rad: SampleValues,
    readings_rad: HeadReadings,
    head_angles_rad: HeadAngles,
    reference_head: int,
    max_order: int,
    *,
    min_sin: float = 1e-3,
) -> SelfCompensation:
    """Determine the reference head's error function from head differences (seed III.A-B).

    Args:
        theta_rad: abscissa of the samples, rad, ``(n,)``: a reference angle when there
            is one, otherwise the symmetric heads' averaged reading (the difference is
            a second-order effect). Samples should cover whole revolutions.
        readings_rad: head readings, rad, ``(n, H)``; any per-head constant is allowed.
        head_angles_rad: nominal azimuths of all ``H`` heads, rad.
        reference_head: index of the reference head (static).
        max_order: highest order ``M`` to determine (static).
        min_sin: a pair observes order ``j`` when ``|sin(j h / 2)| > min_sin``.

    Returns:
        :class:`SelfCompensation` with the averaged coefficients and the diagnostics.
    """
    y = _f64(readings_rad)
    angles = _f64(head_angles_rad).reshape(-1)
    n_heads = angles.shape[0]
    if y.ndim != 2 or y.shape[1] != n_heads:
        raise EncdesignInputError(f"readings_rad: shape {y.shape}, expected (n, {n_heads})")
    if not 0 <= reference_head < n_heads:
        raise EncdesignInputError(f"reference_head: {reference_head}, expected 0 … {n_heads - 1}")
    pairs = tuple(k for k in range(n_heads) if k != reference_head)
    idx = jnp.asarray(pairs)
    diffs = y[:, idx] - y[:, reference_head : reference_head + 1]  # (n, P)
    _, sp, cp = fourier_coefficients(theta_rad, diffs, max_order)  # (M, P)
    sp, cp = sp.T, cp.T  # (P, M)
    offsets = angles[reference_head] - angles[idx]  # (P,)
    j = jnp.arange(1, max_order + 1, dtype=jnp.float64)
    half = offsets[:, None] * j[None, :] / 2
    sin_h = jnp.sin(half)
    obs = jnp.abs(sin_h) > min_sin
    cot = jnp.cos(half) / jnp.where(obs, sin_h, 1.0)
    ps = jnp.where(obs, 0.5 * (cp * cot - sp), 0.0)
    pc = jnp.where(obs, -0.5 * (sp * cot + cp), 0.0)
    count = jnp.sum(obs, axis=0)
    safe = jnp.maximum(count, 1)
    s_avg = jnp.sum(ps, axis=0) / safe
    c_avg = jnp.sum(pc, axis=0) / safe
    dev2 = jnp.where(obs, (ps - s_avg) ** 2 + (pc - c_avg) ** 2, 0.0)
    spread2 = jnp.sum(dev2, axis=0) / safe
    spread = jnp.sqrt(jnp.where(spread2 > 0, spread2, 1.0)) * (spread2 > 0)
    return SelfCompensation(
        sin_rad=s_avg,
        cos_rad=c_avg,
        pair_sin_rad=ps,
        pair_cos_rad=pc,
        observable=obs,
        spread_rad=spread,
        head_offsets_rad=offsets,
        reference_angle_rad=angles[reference_head],
        pair_heads=pairs,
    )


class EncoderMap(AbstractErrorSeries):
    """The encoder map ``m(theta) = sum_j S_j sin(j theta) + C_j cos(j theta)``, rad.

    ``m`` is the error that remains in an averaged reading; ``corrected = reading - m``.

    Attributes:
        sin_rad, cos_rad: coefficients of orders ``1 … M``, rad.
    """

    sin_rad: Array
    cos_rad: Array

    def __call__(self, theta_rad: Angles) -> Averaged:
        """``m(theta)``, rad, at angles ``theta`` (rad), any shape (:meth:`error_function`)."""
        return self.error_function(theta_rad)

    def table(self, n_points: int) -> tuple[Array, Array]:
        """Seed eq. 19: ``(theta_i, m_i)`` at ``n_points`` equally spaced angles in
        ``[0, 2 pi)``, rad. Choose ``n_points`` well above twice the highest order."""
        th = jnp.arange(n_points) * (2 * jnp.pi / n_points)
        return th, self(th)


def encoder_map(
    result: SelfCompensation,
    head_angles_rad: HeadAngles,
    weights: HeadWeights = None,
) -> EncoderMap:
    """Map of the weighted average of the heads at ``head_angles_rad`` (seed eqs. 17-18).

    ``m(theta) = sum_k w_k e_0(theta + h_k)``, ``h_k = alpha_ref - alpha_k``: each order
    of ``e_0`` is multiplied by ``sum_k w_k exp(i j h_k)``, which is 0 for the modes the
    symmetric average cancels and of modulus 1 for the degenerate ones (eq. 17 up to the
    reference head's phase). Uneven layouts keep their leakage in the map.

    Args:
        result: from :func:`self_compensate`.
        head_angles_rad: nominal azimuths of the averaged heads, rad.
        weights: their weights (equal by default).
    """
    a = _f64(head_angles_rad).reshape(-1)
    w = jnp.full(a.shape, 1.0 / a.shape[0]) if weights is None else _f64(weights)
    w = w / jnp.sum(w)
    h = result.reference_angle_rad - a
    j = jnp.arange(1, result.max_order + 1, dtype=jnp.float64)
    transfer = jnp.exp(1j * j[:, None] * h[None, :]) @ w.astype(jnp.complex128)
    amp = (result.cos_rad - 1j * result.sin_rad) * transfer
    return EncoderMap(sin_rad=-jnp.imag(amp), cos_rad=jnp.real(amp))


def apply_map(emap: EncoderMap, reading_rad: Angles) -> Averaged:
    """Correct averaged readings: ``reading - m(reading)``, rad (the map is evaluated at
    the reading itself, since the true angle is unknown; the error this makes is the
    map's slope times the residual, second order)."""
    r = _f64(reading_rad)
    return r - emap(r)


@functools.partial(jax.jit, static_argnames="max_order")
def cotangent_sensitivity(
    reference_angle_rad: Scalar,
    head_angles_rad: HeadAngles,
    max_order: int,
    weights: HeadWeights = None,
) -> tuple[OrderValues, ScalarOut]:
    """Noise amplification of self-compensation for a reference-head angle (seed III.D).

    Model: every head's reading carries independent white noise, so each Fourier
    coefficient of one head's noise has the same standard deviation ``sigma_c``. Pair
    ``n`` estimates the reference head's complex mode ``a_j`` as
    ``k_nj (eps_n - eps_0)`` with ``k_nj = 1 / (exp(i j h_n) - 1)``,
    ``|k_nj| = 1 / (2 |sin(j h_n / 2)|)`` (the cotangent equations). Averaging over the
    ``P`` pairs, the standard deviation of each recovered coefficient (``S_j`` or ``C_j``)
    is ``A_j sigma_c`` with

        A_j = sqrt( sum_n |k_nj|^2 / P^2 + |sum_n k_nj / P|^2 ).

    The map of the symmetric heads' average carries ``|T_j| A_j``, with
    ``T_j = sum_k w_k exp(i j h_k)``; the aggregate is the RMS of ``A_j`` over orders
    weighted by ``|T_j|^2`` (for ``N`` equally spaced heads: the RMS over the degenerate
    orders ``N, 2N, … <= max_order``, the ones the map must supply).

    Args:
        reference_angle_rad: azimuth of the reference head, rad (differentiable).
        head_angles_rad: azimuths of the symmetric heads, rad (differentiable).
        max_order: highest order ``M`` (static).
        weights: symmetric heads' weights in the average (equal by default).

    Returns:
        ``(A, aggregate)``: per-order amplification ``A_j`` for ``j = 1 … M`` and the
        aggregate scalar (both dimensionless; infinite where a pair is blind to an order).
    """
    a = _f64(head_angles_rad).reshape(-1)
    w = jnp.full(a.shape, 1.0 / a.shape[0]) if weights is None else _f64(weights)
    w = w / jnp.sum(w)
    h = _f64(reference_angle_rad) - a  # (P,)
    j = jnp.arange(1, max_order + 1, dtype=jnp.float64)
    x = j[:, None] * h[None, :]  # (M, P)
    k = 1.0 / (jnp.exp(1j * x) - 1.0)
    p = a.shape[0]
    var = jnp.sum(jnp.abs(k) ** 2, axis=1) / p**2 + jnp.abs(jnp.mean(k, axis=1)) ** 2
    amp = jnp.sqrt(var)
    t2 = jnp.abs(jnp.exp(1j * x) @ w.astype(jnp.complex128)) ** 2
    t2 = jnp.where(t2 > 1e-20, t2, 0.0)  # cancelled orders (|T| ~ 1e-16) carry no weight
    aggregate = jnp.sqrt(jnp.sum(t2 * jnp.where(t2 > 0, var, 0.0)) / jnp.sum(t2))
    return amp, aggregate
