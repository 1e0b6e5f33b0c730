"""The angular encoder theorem: symmetry averaging of read heads (Cramer, seed 000, section II).

If every head sees the same error function delayed by its azimuth,
``e_k(theta) = e(theta - alpha_k)``, a Fourier mode ``a_m exp(i m theta)`` of ``e`` reaches
the (weighted) head average multiplied by the *transfer*

    T_m = sum_k w_k exp(-i m alpha_k),     sum_k w_k = 1.

For ``N`` equally spaced heads with equal weights ``T_m = 1`` when ``N`` divides ``m`` (the
degenerate modes ``N, 2N, …`` survive untouched, seed eq. 3) and ``T_m = 0`` otherwise
(seed eqs. 5-11). Heads that are not where the design puts them give ``0 < |T_m| < 1``
for the modes that should cancel: *modal leakage*. :func:`surviving_orders` evaluates
``|T_m|`` in closed form; :func:`model_mode_transfer` measures the same quantity by running
the kinematic model with one pure grating mode at a time and Fourier-analysing the
averaged error, so it also includes whatever the closed form leaves out.

Fourier conventions (used across encdesign): ``f(theta) = c0 + sum_m S_m sin(m theta) +
C_m cos(m theta)``; the amplitude of order ``m`` is ``sqrt(S_m**2 + C_m**2)``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from .._errors import EncdesignInputError
from ._kinematics import EncoderModel, head_errors
from ._types import (
    Angles,
    ArrayInput,
    Averaged,
    HeadAngles,
    HeadErrors,
    HeadWeights,
    OrderCoefficients,
    OrderTransfer,
    OrderValues,
    Signals,
)

__all__ = [
    "averaged_error",
    "mode_transfer",
    "surviving_orders",
    "model_mode_transfer",
    "fourier_coefficients",
    "fourier_series",
    "mode_amplitudes",
]


def _weights(n_heads: int, weights: ArrayInput | None) -> Array:
    if weights is None:
        return jnp.full((n_heads,), 1.0 / n_heads)
    w = jnp.asarray(weights, dtype=jnp.float64).reshape(-1)
    if w.shape[0] != n_heads:
        raise EncdesignInputError(f"weights: {w.shape[0]} values for {n_heads} heads")
    return w / jnp.sum(w)


def averaged_error(errors: HeadErrors, weights: HeadWeights = None) -> Averaged:
    """Symmetry average of head errors (or readings) over the last axis, rad.

    Args:
        errors: per-head errors ``(..., H)``, rad.
        weights: optional per-head weights ``(H,)`` (normalised to sum 1); equal by default
            (seed eq. 1).
    """
    errors = jnp.asarray(errors)
    return errors @ _weights(errors.shape[-1], weights)


def mode_transfer(
    head_angles_rad: HeadAngles, max_order: int, weights: HeadWeights = None
) -> OrderTransfer:
    """Complex transfer ``T_m = sum_k w_k exp(-i m alpha_k)`` for ``m = 1 … max_order``.

    Args:
        head_angles_rad: actual head azimuths ``alpha_k``, rad (nominal plus placement error).
        max_order: highest order ``M``.
        weights: head weights (equal by default).

    Returns:
        ``(M,)`` complex128: the averaged error's mode ``m`` is ``T_m`` times a single
        head-at-azimuth-0's mode ``m`` (complex amplitude ``C_m - i S_m``).
    """
    a = jnp.asarray(head_angles_rad, dtype=jnp.float64).reshape(-1)
    w = _weights(a.shape[0], weights)
    m = jnp.arange(1, max_order + 1, dtype=jnp.float64)
    return jnp.exp(-1j * m[:, None] * a[None, :]) @ w.astype(jnp.complex128)


def surviving_orders(
    head_angles_rad: HeadAngles, max_order: int, weights: HeadWeights = None
) -> OrderValues:
    """Magnitude ``|T_m|`` of each order ``m = 1 … max_order`` after the head average.

    1 for a degenerate mode (survives untouched), 0 for an exactly cancelled mode, in
    between for modal leakage when the spacing is unequal.
    """
    return jnp.abs(mode_transfer(head_angles_rad, max_order, weights))


@functools.partial(jax.jit, static_argnames="max_order")
def fourier_coefficients(
    theta_rad: Angles, values: Signals, max_order: int
) -> tuple[Array, Array, Array]:
    """Least-squares Fourier fit of ``values`` against ``theta`` over orders ``1 … M``.

    Works for any sampling that resolves the orders (several revolutions, uneven steps);
    on ``n`` equally spaced samples over one revolution it equals the DFT. Differentiable.

    Args:
        theta_rad: abscissa, rad, ``(n,)``.
        values: samples ``(n,)`` or ``(n, k)`` (``k`` independent signals), any unit.
        max_order: highest order ``M`` (``2 M + 1 <= n``).

    Returns:
        ``(c0, S, C)``: constant ``(...)``, sine and cosine coefficients ``(M, ...)``, in
        the unit of ``values``.
    """
    theta = jnp.asarray(theta_rad, dtype=jnp.float64).reshape(-1)
    y = jnp.asarray(values, dtype=jnp.float64)
    if 2 * max_order + 1 > theta.shape[0]:
        raise EncdesignInputError(
            f"fourier_coefficients: {theta.shape[0]} samples cannot resolve order {max_order}"
        )
    m = jnp.arange(1, max_order + 1, dtype=jnp.float64)
    arg = theta[:, None] * m
    a = jnp.concatenate([jnp.ones((theta.shape[0], 1)), jnp.sin(arg), jnp.cos(arg)], axis=1)
    scale = jnp.sqrt(jnp.sum(a * a, axis=0))
    an = a / scale
    coef = jnp.linalg.solve(an.T @ an, an.T @ y.reshape(theta.shape[0], -1))
    coef = (coef / scale[:, None]).reshape((2 * max_order + 1, *y.shape[1:]))
    return coef[0], coef[1 : max_order + 1], coef[max_order + 1 :]


def fourier_series(
    theta_rad: Angles, sin_rad: OrderCoefficients, cos_rad: OrderCoefficients
) -> Averaged:
    """``sum_j S_j sin(j theta) + C_j cos(j theta)`` over orders ``j = 1 … M`` at angles
    ``theta`` (rad, any shape): the series :func:`fourier_coefficients` fits, without its
    constant. The result has the shape of ``theta`` and the unit of the coefficients
    (``(M,)`` each). Differentiable."""
    th = jnp.asarray(theta_rad, dtype=jnp.float64)
    s = jnp.asarray(sin_rad, dtype=jnp.float64)
    j = jnp.arange(1, s.shape[-1] + 1)
    arg = th[..., None] * j
    return jnp.sin(arg) @ s + jnp.cos(arg) @ jnp.asarray(cos_rad, dtype=jnp.float64)


@functools.partial(jax.jit, static_argnames="max_order")
def mode_amplitudes(theta_rad: Angles, values: Signals, max_order: int) -> Array:
    """Amplitude ``sqrt(S_m**2 + C_m**2)`` of orders ``1 … M`` (unit of ``values``)."""
    _, s, c = fourier_coefficients(theta_rad, values, max_order)
    return jnp.sqrt(s * s + c * c)


@functools.partial(jax.jit, static_argnames=("max_order", "n_angles"))
def model_mode_transfer(
    model: EncoderModel,
    max_order: int,
    *,
    weights: ArrayLike | None = None,
    n_angles: int = 256,
    probe_rad: float = 1e-6,
) -> Array:
    """``|T_m|`` measured on the kinematic model, ``m = 1 … max_order``.

    For each order the model's geometry errors are switched off (eccentricity, tilt,
    motion), its grating is replaced by a pure mode ``probe_rad * sin(m psi)``, and the
    amplitude of order ``m`` of the weighted head average is divided by ``probe_rad``.
    Placement errors, beam tilts and head layout are those of ``model``.

    Args:
        model: the encoder (its heads define the layout).
        max_order: highest order.
        weights: head weights (equal by default).
        n_angles: samples per revolution (``> 2 max_order``).
        probe_rad: amplitude of the probe mode, rad.
    """
    theta = jnp.arange(n_angles) * (2 * jnp.pi / n_angles)
    zeros_m = jnp.zeros(max_order)
    disk = model.disk
    base = EncoderModel(
        disk=type(disk)(disk.optical_radius_m, jnp.zeros(2), jnp.zeros(2), zeros_m, zeros_m),
        heads=model.heads,
        motion=type(model.motion).still(model.motion.axial_cos_m.shape[0]),
    )

    def one(m_index: Array) -> Array:
        gs = zeros_m.at[m_index].set(probe_rad)
        mdl = EncoderModel(
            disk=type(disk)(disk.optical_radius_m, jnp.zeros(2), jnp.zeros(2), gs, zeros_m),
            heads=base.heads,
            motion=base.motion,
        )
        avg = averaged_error(head_errors(mdl, theta), weights)
        amps = mode_amplitudes(theta, avg, max_order)
        return amps[m_index] / probe_rad

    return jax.vmap(one)(jnp.arange(max_order))
