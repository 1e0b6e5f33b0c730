"""Reading-space model terms of the physics catalog (``docs/effects.md``), multihead kind.

Every term is a differentiable JAX function returning an additive error, in rad, for each
sample and head, shape ``(n, H)``. Conventions (``docs/recording-format.md``): head ``k``
sits at stator azimuth ``alpha_k`` (rad) on the optical radius ``R`` (m); the disk turns by
``theta`` (rad, counter-clockwise); a head reads ``reading_k = theta + c_k + e_k``.

Derivations (first order in the small quantities; seed 000 section V.A, seed 001, seed 002):

* Grating centre offset ``(x, y)`` (m, disk frame at ``theta = 0``). The centre is at
  ``Rot(theta) (x, y)`` in the stator frame. The grating point under head ``k`` seen from
  that centre lies at stator angle ``alpha_k - c.t_k / R`` with ``t_k = (-sin, cos)(alpha_k)``
  the tangent, so the head reads ``theta + c.t_k / R``::

      e_k = [x sin(theta - alpha_k) + y cos(theta - alpha_k)] / R           (eccentricity)

  Disk tilt gives mostly order 2 (``~tilt^2 / 4``) and grating errors any order; all are a
  single disk error function ``e(theta - alpha_k)`` seen through each head's azimuth, which
  is the *base model*: ``e_k = sum_m a_m cos m(theta - alpha_k - d_k) + b_m sin m(...)``
  with small head-placement errors ``d_k`` (rad).
* ``bearing_wobble``: the shaft centre moves in the stator frame by
  ``rho (cos(nu theta + phi), sin(nu theta + phi))`` (``nu`` not an integer, e.g. a cage at
  ~0.4 of shaft speed). With the same projection ``e_k = d.t_k / R``::

      e_k = (rho / R) sin(nu theta + phi - alpha_k)

  For opposed heads (``alpha`` and ``alpha + pi``) the terms cancel in the sum.
* ``eccentricity_shift``: the disk-frame centre offset jumps by ``(dx, dy)`` (m) at time
  ``t_s``; the eccentricity formula applies to the jump times a step ``H(t - t_s)``
  (a logistic of width ``w`` of about one sample interval, to stay differentiable).
* ``beam_tilt_axial`` (seed 001, "axial shifts"): a beam tilted tangentially by ``beta_k``
  (rad) moves the read spot along the track by ``beta_k z`` when the disk moves axially by
  ``z`` (m); the angular error is ``e_k = beta_k z(theta) / R`` with the axial runout
  ``z(theta) = sum_m zc_m cos m theta + zs_m sin m theta`` synchronous with the shaft and the
  same at every head. Seed 001's numbers: 0.001 in / 0.1 in = 10 mrad tilt, 2.5 um runout,
  1 inch radius: 1 urad (0.2 arcsec). Only the products ``beta_k z_m`` are observable.
* ``vibration`` (seed 002): relative head-scale oscillation at a structural frequency
  ``f`` (Hz): ``e_k = A_{k,r} sin(2 pi f t + phi_{k,r})`` per head ``k`` and run ``r`` (the
  phase is not locked between runs). It is fixed in Hz, so its shaft order moves with speed.
* ``thermal_drift`` (seed 001: about 0.7 arcsec/K = 3.4 urad/K): ``e_k = kappa_k (T - T0)``
  with ``kappa_k`` in rad/K (or ``e_k = kappa_k (t - t0)`` in rad/s without ``temp_c``).
* ``interpolation_error`` (seed 002 eq. 1-4): the head interpolates quadrature signals
  ``S_A = sin psi + o_a``, ``S_B = (1 + eps) cos(psi + delta) + o_b`` by
  ``psi' = atan2(S_A, S_B)`` where ``psi = L * reading`` is the phase within the grating
  pitch (``L`` lines per revolution). The angular error is ``wrap(psi' - psi) / L``, to first
  order ``[o_a cos psi - o_b sin psi - (eps/2) sin 2 psi + (delta/2)(1 - cos 2 psi)] / L``:
  orders ``L`` and ``2L`` of the shaft angle.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

CATALOG_MULTIHEAD = (
    "beam_tilt_axial",
    "bearing_wobble",
    "vibration",
    "thermal_drift",
    "interpolation_error",
    "eccentricity_shift",
)
"""Candidate effects of the multihead kind, named exactly as in ``docs/effects.md``."""

ARCSEC_RAD = jnp.pi / (180.0 * 3600.0)


def base_error_rad(
    theta_rad: Array,
    head_angles_rad: Array,
    fourier_cos_rad: Array,
    fourier_sin_rad: Array,
    placement_rad: Array,
) -> Array:
    """Base multihead model: one disk error function seen through every head's azimuth.

    ``e_k(theta) = sum_{m=1..M} a_m cos m(theta - alpha_k - d_k) + b_m sin m(...)`` (rad).

    Args:
        theta_rad: shaft angle per sample, rad.
        head_angles_rad: nominal head azimuths ``alpha_k``, rad.
        fourier_cos_rad, fourier_sin_rad: ``a_m``, ``b_m`` for orders ``m = 1..M``, rad.
        placement_rad: head azimuth errors ``d_k``, rad.
    """
    m = jnp.arange(1, fourier_cos_rad.shape[0] + 1, dtype=theta_rad.dtype)
    arg = m[None, None, :] * (
        theta_rad[:, None, None] - (head_angles_rad + placement_rad)[None, :, None]
    )
    return jnp.sum(fourier_cos_rad * jnp.cos(arg) + fourier_sin_rad * jnp.sin(arg), axis=-1)


def eccentricity_rad(
    theta_rad: Array,
    head_angles_rad: Array,
    optical_radius_m: float,
    offset_x_m: Array,
    offset_y_m: Array,
) -> Array:
    """Error of a grating centre offset ``(x, y)`` (m, disk frame), first order in ``e/R``:
    ``e_k = [x sin(theta - alpha_k) + y cos(theta - alpha_k)] / R`` (rad)."""
    d = theta_rad[:, None] - head_angles_rad[None, :]
    return (offset_x_m * jnp.sin(d) + offset_y_m * jnp.cos(d)) / optical_radius_m


def beam_tilt_axial_rad(
    theta_rad: Array,
    optical_radius_m: float,
    beam_tilt_rad: Array,
    runout_cos_m: Array,
    runout_sin_m: Array,
    runout_orders: Array,
) -> Array:
    """Axial disk motion seen through tangentially tilted beams: ``beta_k z(theta) / R`` (rad).

    Args:
        theta_rad: shaft angle, rad.
        optical_radius_m: ``R``, m.
        beam_tilt_rad: tangential beam tilt per head ``beta_k``, rad.
        runout_cos_m, runout_sin_m: axial runout Fourier coefficients ``zc_m``, ``zs_m``, m.
        runout_orders: the orders ``m`` of those coefficients (shaft orders, float).
    """
    arg = runout_orders[None, :] * theta_rad[:, None]
    z = jnp.sum(runout_cos_m * jnp.cos(arg) + runout_sin_m * jnp.sin(arg), axis=-1)
    return z[:, None] * beam_tilt_rad[None, :] / optical_radius_m


def bearing_wobble_rad(
    theta_rad: Array,
    head_angles_rad: Array,
    optical_radius_m: float,
    frequency_ratio: Array,
    amp_cos_m: Array,
    amp_sin_m: Array,
) -> Array:
    """Non-synchronous radial runout: ``(rho/R) sin(nu theta + phi - alpha_k)`` (rad).

    Written linearly as ``[A sin(nu theta - alpha_k) + B cos(nu theta - alpha_k)] / R`` with
    ``A = rho cos phi``, ``B = rho sin phi`` (m), given per sample (the phase of a cage is
    not locked between runs, so callers pass each sample its run's ``A``, ``B``).
    """
    arg = frequency_ratio * theta_rad[:, None] - head_angles_rad[None, :]
    return (amp_cos_m[:, None] * jnp.sin(arg) + amp_sin_m[:, None] * jnp.cos(arg)) / (
        optical_radius_m
    )


def vibration_rad(
    time_s: Array,
    frequency_hz: Array,
    cos_rad: Array,
    sin_rad: Array,
) -> Array:
    """Relative head-scale oscillation: ``C cos(2 pi f t) + S sin(2 pi f t)`` (rad), with
    ``C``, ``S`` given per sample and head (a run's coefficients broadcast to its samples)."""
    w = 2.0 * jnp.pi * frequency_hz * time_s[:, None]
    return cos_rad * jnp.cos(w) + sin_rad * jnp.sin(w)


def thermal_drift_rad(delta_rad_per_unit: Array, driver: Array) -> Array:
    """``kappa_k * (T - T0)``: ``driver`` is ``T - T0`` in K (``kappa`` rad/K) or ``t - t0`` in
    s (``kappa`` rad/s)."""
    return driver[:, None] * delta_rad_per_unit[None, :]


def interpolation_error_exact_rad(
    reading_rad: Array,
    grating_lines: int,
    offset_a: Array,
    offset_b: Array,
    amplitude_error: Array,
    phase_error_rad: Array,
) -> Array:
    """Arctangent interpolation of imperfect quadrature signals (seed 002 eq. 1-3), rad.

    ``S_A = sin psi + o_a``, ``S_B = (1 + eps) cos(psi + delta) + o_b``, ``psi = L reading``;
    error ``wrap(atan2(S_A, S_B) - psi) / L``. Offsets are relative to the signal amplitude.
    """
    psi = grating_lines * reading_rad
    sa = jnp.sin(psi) + offset_a
    sb = (1.0 + amplitude_error) * jnp.cos(psi + phase_error_rad) + offset_b
    d = jnp.arctan2(sa, sb) - psi
    d = jnp.arctan2(jnp.sin(d), jnp.cos(d))
    return d / grating_lines


def interpolation_harmonics_rad(
    psi_rad: Array,
    grating_lines: int,
    coef: Array,
) -> Array:
    """First-order interpolation error ``[p1 cos psi + q1 sin psi + p2 cos 2psi + q2 sin 2psi]/L``
    (rad), linear in ``coef = (p1, q1, p2, q2)``. With a head zero on a grating line,
    ``o_a = p1``, ``o_b = -q1``, ``eps = -2 q2``, ``delta = -2 p2``."""
    return (
        coef[0] * jnp.cos(psi_rad)
        + coef[1] * jnp.sin(psi_rad)
        + coef[2] * jnp.cos(2.0 * psi_rad)
        + coef[3] * jnp.sin(2.0 * psi_rad)
    ) / grating_lines


def smooth_step(time_s: Array, t0_s: Array, width_s: float):
    """Logistic step ``1 / (1 + exp(-(t - t0)/w))``: differentiable in ``t0``."""
    return 0.5 * (1.0 + jnp.tanh(0.5 * (time_s - t0_s) / width_s))


def eccentricity_shift_rad(
    theta_rad: Array,
    time_s: Array,
    head_angles_rad: Array,
    optical_radius_m: float,
    shift_time_s: Array,
    shift_x_m: Array,
    shift_y_m: Array,
    width_s: float,
) -> Array:
    """A jump ``(dx, dy)`` (m, disk frame) of the grating centre at ``shift_time_s`` (rad).

    ``time_s`` is the record's global time (runs laid end to end in file order).
    """
    step = smooth_step(time_s, shift_time_s, width_s)
    return step[:, None] * eccentricity_rad(
        theta_rad, head_angles_rad, optical_radius_m, shift_x_m, shift_y_m
    )
