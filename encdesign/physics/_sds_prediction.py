"""The seed's analysis of speed error against mark errors (seed ``001_…``, eqs. 46–53).

:func:`predict_speed_mark_error` evaluates how the motor's speed ripple and the marks'
errors interact in the shifted-delta-sum, independently of the edge-time simulation of
:mod:`encdesign.physics._sds`. All angles in rad.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from .._array import f64 as _f
from .._array import wrap_rad as _wrap
from ._sds import SDSDesign, mark_angles

__all__ = ["SpeedMarkPrediction", "predict_speed_mark_error"]


# ------------------------------------------------------------------ eqs. 46–53


class SpeedMarkPrediction(eqx.Module):
    """Result of :func:`predict_speed_mark_error`.

    Attributes:
        phi_error_rad: predicted error of φ, rad, shape ``phi.shape`` (pair average).
        order_error_rad: contribution of each DFT order ``n = 0 … N/2`` of the mark
            differences f and the speed factor g (eq. 53 in the Fourier basis), rad,
            shape ``phi.shape + (N//2 + 1,)``; sums to ``phi_error_rad``.
    """

    phi_error_rad: Array
    order_error_rad: Array


def predict_speed_mark_error(design: SDSDesign, phi_rad: ArrayLike) -> SpeedMarkPrediction:
    """Seed eqs. 46–53: error of φ from speed error × mark errors, without edge times.

    For each fixed × moving sensor pair and platform angle φ:

    * ``A_i`` = disk angle at which mark i of disk A passes the fixed sensor,
      ``B_i + φ`` the same for disk B and the moving sensor; the shift k pairs each A_i
      with the nearest B mark; ``f(i) = B_{i−k} + φ − A_i`` (eq. 51);
    * ``g(i) = e(t(ψ_i)) t'(ψ_i)`` (eq. 52) with ψ_i the midpoint of [A_i, B_{i−k}+φ]
      (mean-value point of eq. 49), ``t(ψ)`` the inverse of θ(t) from ``t ≈ ψ/Ω`` (eq. 50)
      refined by three fixed-point steps, and ``t' = 1/(Ω + e)``;
    * ``E(φ) = −Σ_i f(i) g(i)`` (eq. 53), the error of the shifted delta sum; the error of
      φ is ``E/N``, averaged over the pairs.

    The Fourier form ``Σ f g = (1/N) Σ_n F_n conj(G_n)`` gives the contribution of each
    order (only orders present in both the mark errors and the speed error contribute).
    Only ripple and mark errors enter (no tilt, runout or timing noise).

    Args:
        design: an :class:`~encdesign.SDSDesign`.
        phi_rad: platform angles, rad (any shape).

    Returns:
        :class:`SpeedMarkPrediction`.
    """
    return _predict(design, mark_angles(design.disk_a), mark_angles(design.disk_b), _f(phi_rad))


@jax.jit
def _predict(design: SDSDesign, mu_a: Array, mu_b: Array, phi: Array) -> SpeedMarkPrediction:
    """Body of :func:`predict_speed_mark_error`: one XLA program per design structure
    (marks, sensor counts) and φ shape instead of op-by-op dispatch (CI time). The mark
    angles ``mu_a``, ``mu_b`` (rad) come from outside, as before, so the result is
    bit-equal to the op-by-op evaluation (checked on 20 design/φ cases)."""
    n_marks = design.marks_per_rev
    motor = design.motor
    om = motor.speed_rad_s

    def one(phi1, sf, sm):
        d = sm + phi1 - sf
        k = jnp.round(d * n_marks / (2 * jnp.pi)).astype(jnp.int32)
        idx = jnp.mod(jnp.arange(n_marks) - k, n_marks)
        a = sf + mu_a
        f = _wrap(d + jnp.take(mu_b, idx) - mu_a)
        psi = a + 0.5 * f
        # t(ψ): inverse of θ(t) by fixed-point iteration t = (ψ − ripple(t))/Ω (eq. 50 refined)
        # (three steps in one loop body: one copy of θ(t)'s harmonic scan to compile)
        t = jax.lax.fori_loop(0, 3, lambda _, t: t + (psi - motor.theta(t)) / om, psi / om)
        e = motor.speed_error(t)
        g = e / (om + e)
        ff = jnp.fft.rfft(f)
        gg = jnp.fft.rfft(g)
        w = jnp.full(n_marks // 2 + 1, 2.0).at[0].set(1.0)
        if n_marks % 2 == 0:
            w = w.at[-1].set(1.0)
        per_order = -w * jnp.real(ff * jnp.conj(gg)) / n_marks / n_marks
        return -jnp.sum(f * g) / n_marks, per_order

    sf = design.fixed_azimuths_rad
    sm = design.moving_azimuths_rad

    def at_phi(phi1):
        tot, orders = jax.vmap(lambda a: jax.vmap(lambda b: one(phi1, a, b))(sm))(sf)
        return jnp.mean(tot), jnp.mean(orders, axis=(0, 1))

    flat = phi.reshape(-1)
    tot, orders = jax.lax.map(at_phi, flat)
    return SpeedMarkPrediction(
        phi_error_rad=tot.reshape(phi.shape),
        order_error_rad=orders.reshape(phi.shape + (n_marks // 2 + 1,)),
    )
