"""Reading-space effects of one sensor read against a reference (``docs/effects.md``).

Setting: a ``multihead`` recording with one head ``h0`` (the sensor's reading, rad) and a
``theta_ref`` column (the reference angle, rad). The sensor's error is::

    e = h0 - theta_ref = f(theta) + c_r + sum(terms) + noise

with ``f`` the sensor's error function of the shaft angle (the base model: Fourier orders of
``theta_ref``), ``c_r`` one constant per run (each run re-zeroes) and the candidate terms
below (the finder registers each as a ``Candidate`` in
``encdesign.diagnose.kinds.multihead._reference_terms``;
the concealed benches of ``encdesign.simulate`` add them to generated records). Every term is
a differentiable JAX function of data arrays (``theta_ref``, the reference velocity
``omega``, the modelled reading) and of its parameters; it returns the additive error in rad
per sample, shape ``(n,)``. No Python control flow on traced values;
discrete choices (the number of signal periods per turn, the smoothing width) are plain
Python numbers that the caller keeps static.

Physics and closed forms (tests check each against finite differences and the closed form):

* ``direction_hysteresis`` (backlash of the coupling or the drive, magnetic hysteresis of the
  sensor): the error profile moves by a constant ``h`` (rad) when the direction of rotation
  reverses. Written ``+h/2`` while turning forward and ``-h/2`` backward, so ``h`` is the
  forward-minus-backward offset; the sign of the velocity is smoothed as
  ``tanh(omega / omega_w)`` with ``omega_w`` a small fraction of the steady speed, which keeps
  the term differentiable in ``h`` and in ``omega``. A backlash ``b`` between a drive that
  leads and a sensor that follows gives ``h = -b``.
* ``reading_delay``: the sensor reports the angle of ``tau`` seconds ago (filtering,
  latency): ``theta(t - tau) - theta(t) = -omega tau`` to first order, so the error grows with
  speed and flips sign with the direction. At one steady speed in both directions it is
  indistinguishable from ``direction_hysteresis`` (``h = -2 |omega| tau``); two speeds
  separate them.
* ``scale_error``: the sensor advances ``(1 + s)`` turns per reference turn (gear ratio,
  counts per turn, steps of a stepper): error ``s * theta_ref``, a ramp that is not periodic
  in the turn (after ``N`` turns it is ``2 pi N s``). The per-run constants absorb
  ``s * theta_ref(0)``.
* ``quantization``: a reading of finite resolution ``q`` (one LSB, rad) on a lattice
  ``c + q k``; the error of the staircase is ``Q(x) - x = -q saw((x - c) / q)`` with
  ``saw(u) = u - round(u) = sum_k (-1)^(k+1) sin(2 pi k u) / (pi k)``, uniform in
  ``[-q/2, q/2)`` with RMS ``q / sqrt(12)``. Noise ``sigma`` ahead of the quantizer blurs it:
  ``E[Q(x + n) - x]`` has the harmonics damped by ``exp(-2 pi^2 k^2 sigma^2 / q^2)``
  (dither), which is also what keeps the term differentiable. ``q`` itself is found from the
  value lattice of the readings (:func:`detect_lsb`), not fitted: the staircase is then
  fixed by the data; it needs the *unquantized* modelled reading ``x`` (on the measured
  reading itself ``Q(r) - r = 0``).
* ``interpolation_error`` at ``P = signal_periods_per_rev``: a sensor whose signal has ``P``
  periods per turn (a magnet of ``P`` pole pairs, a resolver of speed ``P``, a grating of ``P``
  lines) interpolates ``psi = P theta`` from ``S_A = b_a + rho sin(psi + Phi_1)`` and
  ``S_B = b_b + cos psi`` (seed 002 eq. 1, as in ``encdesign.physics._quadrature``). The
  shaft-angle error is ``d_psi / P`` with, to first order (eq. 4)::

      d_psi = b_a cos psi - b_b sin psi + (rho - 1)/2 sin 2 psi + Phi_1/2 (1 + cos 2 psi)

  i.e. orders ``P`` and ``2P`` of the shaft angle (orders 1 and 2 for a two-pole magnet,
  ``P = 1``, where they coincide with the base model's orders 1 and 2 and cannot be told
  apart from them). The constant ``Phi_1/2`` goes into the run constants.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from ._quadrature import SignalErrors, phase_error_exact_rad

__all__ = [
    "CATALOG_REFERENCE",
    "REFERENCE_PARAM_UNITS",
    "direction_hysteresis_rad",
    "reading_delay_rad",
    "scale_error_rad",
    "blurred_sawtooth",
    "quantization_rad",
    "quantize_rad",
    "interpolation_harmonics_rad",
    "interpolation_exact_rad",
    "interpolation_params_from_harmonics",
]

CATALOG_REFERENCE = (
    "direction_hysteresis",
    "reading_delay",
    "quantization",
    "scale_error",
    "interpolation_error",
)
"""Candidate effects of one sensor against a reference, named as in ``docs/effects.md``."""

REFERENCE_PARAM_UNITS: dict[str, dict[str, str]] = {
    "direction_hysteresis": {"hysteresis_rad": "rad"},
    "reading_delay": {"delay_s": "s"},
    "quantization": {"lsb_rad": "rad", "lattice_offset_rad": "rad"},
    "scale_error": {"scale": "1"},
    "interpolation_error": {
        "offset_a": "1",
        "offset_b": "1",
        "amplitude_ratio": "1",
        "phase_error_rad": "rad",
    },
}
"""Parameters of each term and their units (``"1"``: dimensionless, relative)."""


# ----------------------------------------------------------------------------- terms


def direction_hysteresis_rad(
    velocity_rad_s: ArrayLike, hysteresis_rad: ArrayLike, velocity_width_rad_s: float
) -> Array:
    """Offset between the two directions: ``(h / 2) tanh(omega / omega_w)`` (rad).

    Args:
        velocity_rad_s: reference velocity ``omega`` per sample, rad/s.
        hysteresis_rad: ``h``, forward-minus-backward offset of the reading, rad.
        velocity_width_rad_s: ``omega_w`` (> 0), speed below which the sign is smoothed,
            rad/s; a few percent of the steady speed (:func:`velocity_width_rad_s`).
    """
    w = jnp.asarray(velocity_rad_s, dtype=jnp.float64)
    return 0.5 * jnp.asarray(hysteresis_rad) * jnp.tanh(w / velocity_width_rad_s)


def reading_delay_rad(velocity_rad_s: ArrayLike, delay_s: ArrayLike) -> Array:
    """Time lag ``tau`` (s) of the sensor behind the reference: ``-omega tau`` (rad)."""
    return -jnp.asarray(velocity_rad_s, dtype=jnp.float64) * jnp.asarray(delay_s)


def scale_error_rad(theta_ref_rad: ArrayLike, scale: ArrayLike) -> Array:
    """Sensor advancing ``(1 + s)`` turns per reference turn: ``s * theta_ref`` (rad)."""
    return jnp.asarray(theta_ref_rad, dtype=jnp.float64) * jnp.asarray(scale)


def blurred_sawtooth(u: ArrayLike, blur: ArrayLike = 0.0, n_harmonics: int = 64) -> Array:
    """``u - round(u)`` averaged over a Gaussian jitter of ``blur`` (std, in units of ``u``).

    ``sum_k (-1)^(k+1) g_k sin(2 pi k u) / (pi k)`` with ``g_k = exp(-2 pi^2 k^2 b^2)``,
    ``b = sqrt(blur^2 + b_min^2)`` (``b_min = 1 / n_harmonics``: the series is then converged
    and the steps stay differentiable). ``blur = 0`` is the sharp sawtooth rounded over
    ``b_min``; a reading with noise ``sigma`` before its quantizer has ``blur = sigma / q``.
    """
    b2 = jnp.square(jnp.asarray(blur, dtype=jnp.float64)) + (1.0 / n_harmonics) ** 2
    k = jnp.arange(1, 4 * n_harmonics + 1, dtype=jnp.float64)
    g = (-1.0) ** (k + 1) * jnp.exp(-2.0 * jnp.pi**2 * k**2 * b2) / (jnp.pi * k)
    x = 2.0 * jnp.pi * jnp.asarray(u, dtype=jnp.float64)
    return jnp.sum(g * jnp.sin(x[..., None] * k), axis=-1)


def quantization_rad(
    reading_rad: ArrayLike,
    lsb_rad: ArrayLike,
    lattice_offset_rad: ArrayLike = 0.0,
    noise_rad: ArrayLike = 0.0,
    n_harmonics: int = 64,
) -> Array:
    """Staircase error of a reading on the lattice ``c + q k``: ``-q saw((x - c) / q)``.

    The expected error ``E[Q(x + n) - x]`` of a quantizer fed the reading ``x`` plus noise
    ``n`` of std ``sigma``: the sawtooth blurred by ``sigma / q``
    (:func:`blurred_sawtooth`; dither: with ``sigma >~ q / 2`` the staircase averages out).

    Args:
        reading_rad: the unquantized (modelled) reading ``x``, rad.
        lsb_rad: the step ``q`` (one LSB), rad.
        lattice_offset_rad: ``c``, where the lattice sits, rad.
        noise_rad: ``sigma``, noise before the quantizer, rad.
        n_harmonics: resolution of the steps (static; they are rounded over ``q / n``).

    Returns:
        The staircase error in rad.
    """
    x = jnp.asarray(reading_rad, dtype=jnp.float64)
    q = jnp.asarray(lsb_rad, dtype=jnp.float64)
    u = (x - lattice_offset_rad) / q
    return -q * blurred_sawtooth(u, jnp.asarray(noise_rad) / q, n_harmonics)


def quantize_rad(reading_rad: ArrayLike, lsb_rad: float, lattice_offset_rad: float = 0.0):
    """The exact staircase ``c + q round((x - c) / q)`` (rad), for simulation."""
    x = jnp.asarray(reading_rad, dtype=jnp.float64)
    return lattice_offset_rad + lsb_rad * jnp.round((x - lattice_offset_rad) / lsb_rad)


def interpolation_harmonics_rad(
    theta_rad: ArrayLike, periods_per_rev: int, coef: ArrayLike
) -> Array:
    """First-order interpolation error at orders ``P`` and ``2P``, linear in ``coef``.

    ``[c1 cos P theta + s1 sin P theta + c2 cos 2P theta + s2 sin 2P theta] / P`` (rad) with
    ``coef = (c1, s1, c2, s2)`` in rad of signal phase; see
    :func:`interpolation_params_from_harmonics` for the signal errors they stand for.
    """
    psi = periods_per_rev * jnp.asarray(theta_rad, dtype=jnp.float64)
    c = jnp.asarray(coef, dtype=jnp.float64)
    return (
        c[0] * jnp.cos(psi)
        + c[1] * jnp.sin(psi)
        + c[2] * jnp.cos(2.0 * psi)
        + c[3] * jnp.sin(2.0 * psi)
    ) / periods_per_rev


def interpolation_exact_rad(
    theta_rad: ArrayLike,
    periods_per_rev: int,
    offset_a: ArrayLike = 0.0,
    offset_b: ArrayLike = 0.0,
    amplitude_ratio: ArrayLike = 1.0,
    phase_error_rad: ArrayLike = 0.0,
) -> Array:
    """Exact arctangent interpolation error of a ``P``-period sensor, shaft angle (rad).

    ``wrap(atan2(S_A, S_B) - psi) / P`` with ``psi = P theta`` and the signals of seed 002
    eq. 1 (``encdesign.physics._quadrature.quadrature_signals``): offsets ``b_a``, ``b_b``
    relative to the amplitude, amplitude ratio ``rho``, phase error ``Phi_1`` (rad).
    """
    psi = periods_per_rev * jnp.asarray(theta_rad, dtype=jnp.float64)
    err = SignalErrors(offset_a, offset_b, amplitude_ratio, phase_error_rad)
    return phase_error_exact_rad(psi, err) / periods_per_rev


def interpolation_params_from_harmonics(coef: ArrayLike) -> dict[str, float]:
    """Signal errors from the harmonic coefficients (first order, seed 002 eq. 4).

    ``b_a = c1``, ``b_b = -s1``, ``rho = 1 + 2 s2``, ``Phi_1 = 2 c2`` (the constant
    ``Phi_1 / 2`` is in the run constants).
    """
    c = np.asarray(coef, dtype=np.float64)
    return {
        "offset_a": float(c[0]),
        "offset_b": float(-c[1]),
        "amplitude_ratio": float(1.0 + 2.0 * c[3]),
        "phase_error_rad": float(2.0 * c[2]),
    }
