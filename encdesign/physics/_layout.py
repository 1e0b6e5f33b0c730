"""Self-compensation for heads at arbitrary azimuths: least squares per order.

Model (the convention of :mod:`encdesign.physics._selfcomp` and
:func:`encdesign.physics.mode_transfer`): every head sees the disk's error function ``e``
delayed by its azimuth, ``e_k(theta) = e(theta - alpha_k)``; ``e`` is the error a head at
azimuth 0 would see. In complex form an order ``j`` of ``e`` with amplitude
``a_j = C_j - i S_j`` reaches head ``k`` as ``a_j u_kj``, ``u_kj = exp(-i j alpha_k)``.

The true shaft angle is unknown, so only head *differences* carry information. For order
``j`` head ``k``'s reading has the Fourier coefficient

    Y_kj = a_j u_kj + b_j + noise,

with an unknown common term ``b_j`` (the abscissa's own error). Least squares in
``(a_j, b_j)`` over the ``H`` heads gives the centred regression

    a_j = sum_k conj(u_kj - ubar_j) Y_kj / G_j,    G_j = sum_k |u_kj - ubar_j|^2
        = H (1 - |ubar_j|^2),    ubar_j = mean_k u_kj,

which uses only differences (``sum_k conj(u_kj - ubar_j) = 0``). Order ``j`` is
*unobservable* when every head has the same phase ``j alpha_k`` (``G_j = 0``): then the
differences of that order vanish whatever ``a_j``. With white read noise of standard deviation
``sigma_c`` on each real Fourier coefficient of each head, each recovered real coefficient
has standard deviation ``A_j sigma_c`` with the *noise amplification*

    A_j = 1 / sqrt(G_j).

Cramer's ``N + 1`` layout (``N`` equally spaced heads plus a reference head, seed 000) is a
special case: for the orders ``j`` the symmetric average keeps (multiples of ``N``) all
symmetric heads have ``u_kj = 1``, the regression reduces to the cotangent equation of the
reference head against the symmetric heads' mean, and ``A_j^2 = |k_j|^2 (1 + 1/N)``,
``|k_j| = 1 / (2 |sin(j h / 2)|)``: exactly :func:`encdesign.physics.cotangent_sensitivity`
(``tests/test_selfcomp.py`` checks both).

The output of the encoder is the weighted head average (weights ``w``, all heads equal by
default) whose order ``j`` is ``T_j a_j`` with ``T_j = sum_k w_k u_kj``; the calibration map
carries ``T_j â_j`` (:func:`layout_map`) and its noise ``|T_j| A_j sigma_c`` per order.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._array import f64 as _f64
from .._errors import EncdesignInputError
from ._selfcomp import AbstractErrorSeries, EncoderMap
from ._theorem import fourier_coefficients
from ._types import (
    HeadAngles,
    HeadReadings,
    HeadWeights,
    LayoutPhases,
    OrderValues,
    SampleValues,
    ScalarOut,
)

__all__ = [
    "LayoutCompensation",
    "layout_phases",
    "layout_gain",
    "layout_noise_amplification",
    "unobservable_orders",
    "least_squares_compensate",
    "layout_map",
    "check_layout",
]

MIN_GAIN = 1e-9
"""``1 - |ubar_j|^2`` below which order ``j`` counts as unobservable."""


def _weights(n: int, weights: HeadWeights) -> Array:
    w = jnp.full((n,), 1.0 / n) if weights is None else _f64(weights).reshape(-1)
    return w / jnp.sum(w)


def layout_phases(head_angles_rad: HeadAngles, max_order: int) -> LayoutPhases:
    """``u_kj = exp(-i j alpha_k)``: ``(M, H)`` complex128 for orders ``1 … M``."""
    a = _f64(head_angles_rad).reshape(-1)
    j = jnp.arange(1, max_order + 1, dtype=jnp.float64)
    return jnp.exp(-1j * j[:, None] * a[None, :])


def layout_gain(head_angles_rad: HeadAngles, max_order: int) -> OrderValues:
    """``G_j = H (1 - |mean_k u_kj|^2)`` for orders ``1 … M`` (dimensionless, ``(M,)``):
    the information the head differences carry about order ``j`` (0: unobservable)."""
    u = layout_phases(head_angles_rad, max_order)
    h = u.shape[1]
    return h * (1.0 - jnp.abs(jnp.mean(u, axis=1)) ** 2)


def _safe_inv_sqrt(g: Array) -> tuple[Array, Array]:
    """``1/sqrt(g)`` where observable, ``inf`` elsewhere, with finite gradients (double
    ``where``)."""
    obs = g > MIN_GAIN
    safe = jnp.where(obs, g, 1.0)
    return jnp.where(obs, 1.0 / jnp.sqrt(safe), jnp.inf), obs


def layout_noise_amplification(
    head_angles_rad: HeadAngles, max_order: int, weights: HeadWeights = None
) -> tuple[OrderValues, OrderValues, ScalarOut]:
    """Noise amplification of least-squares self-compensation (module docstring).

    Args:
        head_angles_rad: nominal azimuths of all ``H`` heads, rad (differentiable).
        max_order: highest order ``M`` (static).
        weights: weights of the heads in the encoder's output (equal by default).

    Returns:
        ``(A, map_gain, aggregate)``: per-order amplification ``A_j = 1/sqrt(G_j)``
        (``inf`` where unobservable), the map's per-order noise gain ``|T_j| A_j`` (0 for an
        unobservable order: the map cannot supply it, the mode passes uncorrected) and the
        aggregate ``sqrt(sum_j |T_j|^2 A_j^2 / sum_j |T_j|^2)`` (the RMS of ``A_j`` over the
        orders the output carries, weighted by ``|T_j|^2``; for Cramer's ``N + 1`` layout
        with only the symmetric heads averaged it equals
        :func:`encdesign.physics.cotangent_sensitivity`; ``inf`` when the output carries
        an unobservable order). All dimensionless.
    """
    u = layout_phases(head_angles_rad, max_order)
    h = u.shape[1]
    g = h * (1.0 - jnp.abs(jnp.mean(u, axis=1)) ** 2)
    amp, obs = _safe_inv_sqrt(g)
    w = _weights(h, weights)
    t2 = jnp.abs(u @ w.astype(jnp.complex128)) ** 2
    t2 = jnp.where(t2 > 1e-20, t2, 0.0)  # cancelled orders carry no weight
    var = jnp.where(obs, 1.0 / jnp.where(obs, g, 1.0), jnp.inf)
    carried = t2 > 0
    num = jnp.sum(jnp.where(carried, t2 * var, 0.0))
    aggregate = jnp.sqrt(num / jnp.sum(t2))
    # an unobservable order is not in the map (it passes uncorrected), so carries no noise
    map_gain = jnp.where(carried & obs, jnp.sqrt(t2) * jnp.where(obs, amp, 0.0), 0.0)
    return amp, map_gain, aggregate


def unobservable_orders(
    head_angles_rad: HeadAngles, max_order: int, *, min_gain: float = 1e-6
) -> list[int]:
    """Orders ``j <= max_order`` the layout cannot observe: ``1 - |mean_k u_kj|^2 <=
    min_gain`` (every head at the same phase ``j alpha_k`` modulo ``2 pi``). Concrete
    azimuths only (returns a Python list)."""
    a = np.asarray(head_angles_rad, dtype=np.float64).reshape(-1)
    j = np.arange(1, max_order + 1)
    ubar = np.mean(np.exp(-1j * j[:, None] * a[None, :]), axis=1)
    return [int(k) for k in j[1.0 - np.abs(ubar) ** 2 <= min_gain]]


def check_layout(
    head_angles_rad: HeadAngles, *, min_separation_rad: float = 1e-6, where: str = "head_angles"
) -> None:
    """Raise :class:`~encdesign.EncdesignInputError` when the layout has fewer than two heads,
    a non-finite azimuth, or two heads closer than ``min_separation_rad`` (modulo ``2 pi``),
    naming the offending heads. Concrete azimuths only."""
    from .._errors import input_error

    a = np.asarray(head_angles_rad, dtype=np.float64).reshape(-1)
    if a.size < 2:
        raise input_error(where, f"{a.size} head(s)", "at least two head azimuths")
    if not np.all(np.isfinite(a)):
        raise input_error(where, f"non-finite azimuth in {a.tolist()}", "finite azimuths")
    for p in range(a.size):
        for q in range(p + 1, a.size):
            d = abs((a[p] - a[q] + np.pi) % (2 * np.pi) - np.pi)
            if d < min_separation_rad:
                raise input_error(
                    where,
                    f"heads {p} and {q} coincide ({np.degrees(a[p]):.6g} and "
                    f"{np.degrees(a[q]):.6g} deg, {d:.3g} rad apart modulo 360 deg)",
                    f"distinct azimuths at least {min_separation_rad:g} rad apart",
                )


class LayoutCompensation(AbstractErrorSeries):
    """Result of :func:`least_squares_compensate` (orders ``1 … M``).
    :meth:`error_function` is ``e(theta)`` of a head at azimuth 0 (unobservable orders left
    out).

    Attributes:
        sin_rad, cos_rad: ``S_j``, ``C_j`` of the error function ``e`` of a head at azimuth 0,
            rad ``(M,)`` (0 where unobservable).
        observable: ``(M,)`` whether the layout observes order ``j``.
        gain: ``G_j`` ``(M,)`` (dimensionless).
        noise_amplification: ``A_j = 1/sqrt(G_j)`` ``(M,)`` (``inf`` where unobservable).
        fit_residual_rad: ``(M,)`` RMS over heads of the regression residual of order ``j``
            (rad; 0 for noise-free readings that follow the model, a health diagnostic like
            the pair spread of :class:`~encdesign.physics.SelfCompensation`).
        head_angles_rad: the nominal azimuths used, rad ``(H,)``.
    """

    sin_rad: Array
    cos_rad: Array
    observable: Array
    gain: Array
    noise_amplification: Array
    fit_residual_rad: Array
    head_angles_rad: Array


@functools.partial(jax.jit, static_argnames="max_order")
def least_squares_compensate(
    theta_rad: SampleValues,
    readings_rad: HeadReadings,
    head_angles_rad: HeadAngles,
    max_order: int,
) -> LayoutCompensation:
    """Recover the disk's error function from head differences for any head layout.

    Args:
        theta_rad: abscissa of the samples, rad ``(n,)`` (the true angle in simulation, or
            the averaged reading; any error of the abscissa is common to all heads and drops
            out). Samples should cover whole revolutions.
        readings_rad: readings (or errors) of the ``H`` heads, rad ``(n, H)``; per-head
            constants are allowed.
        head_angles_rad: nominal azimuths, rad ``(H,)`` (differentiable).
        max_order: highest order ``M`` (static).

    Returns:
        :class:`LayoutCompensation`.
    """
    y = _f64(readings_rad)
    a = _f64(head_angles_rad).reshape(-1)
    h = a.shape[0]
    if y.ndim != 2 or y.shape[1] != h:
        raise EncdesignInputError(f"readings_rad: shape {y.shape}, expected (n, {h})")
    if h < 2:
        raise EncdesignInputError("least_squares_compensate: at least two heads")
    d = y - jnp.mean(y, axis=1, keepdims=True)  # the common abscissa term drops out
    _, s, c = fourier_coefficients(theta_rad, d, max_order)  # (M, H)
    yc = c - 1j * s
    u = layout_phases(a, max_order)
    v = u - jnp.mean(u, axis=1, keepdims=True)
    g = jnp.sum(jnp.abs(v) ** 2, axis=1)
    obs = g > MIN_GAIN
    gs = jnp.where(obs, g, 1.0)
    ahat = jnp.where(obs, jnp.sum(jnp.conj(v) * yc, axis=1) / gs, 0.0)
    fit = yc - ahat[:, None] * v
    fit_rms = jnp.sqrt(jnp.mean(jnp.abs(fit) ** 2, axis=1))
    amp = jnp.where(obs, 1.0 / jnp.sqrt(gs), jnp.inf)
    return LayoutCompensation(
        sin_rad=-jnp.imag(ahat),
        cos_rad=jnp.real(ahat),
        observable=obs,
        gain=g,
        noise_amplification=amp,
        fit_residual_rad=fit_rms,
        head_angles_rad=a,
    )


def layout_map(
    result: LayoutCompensation,
    weights: HeadWeights = None,
    head_angles_rad: HeadAngles | None = None,
) -> EncoderMap:
    """Map of the weighted head average: order ``j`` is ``T_j â_j``, ``T_j = sum_k w_k
    u_kj`` over the compensation's heads (or ``head_angles_rad`` when given: a subset or
    another set of heads reading the same disk), rad. ``corrected = average - map``."""
    a = result.head_angles_rad if head_angles_rad is None else _f64(head_angles_rad).reshape(-1)
    u = layout_phases(a, result.max_order)
    w = _weights(a.shape[0], weights)
    t = u @ w.astype(jnp.complex128)
    amp = (result.cos_rad - 1j * result.sin_rad) * t
    return EncoderMap(sin_rad=-jnp.imag(amp), cos_rad=jnp.real(amp))
