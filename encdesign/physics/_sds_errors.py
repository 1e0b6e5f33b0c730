"""Error physics of the shifted-delta-sum instrument (seed ``001_…``, eqs. 25–53).

:class:`SDSErrors` collects the error sources besides motor ripple and mark errors (those
live in :class:`~encdesign.Motor` and :class:`~encdesign.DiskMarks`). Every source is off
(zero) by default; all amplitudes are differentiable.

* ``axis_tilt``: the disk axis is tilted by β (``axis_tilt_rad``, towards azimuth
  ``axis_tilt_azimuth_rad``) from the platform axis. The sensors look along the disk axis,
  so a sensor at platform azimuth ψ reads the disk at the projected azimuth
  ``χ + atan2(sin(ψ−χ), cos(ψ−χ) cos β)`` (seed eq. 26). Error in φ ≈ −(β²/4) sin 2φ:
  a nearly pure order-2 term, below 0.5 mas for β = 20 arcsec.
* ``beam_tilt_axial``: each sensor's optical axis is tilted tangentially by γ (rad); an
  axial shift ``dz`` of its disk moves the read point by ``γ·dz`` along the track, i.e.
  shifts the sensor by ``γ·dz/R`` rad. For the moving sensors ``dz`` = constant offset +
  axial runout of the platform bearing (Fourier orders in φ) + thermal expansion; for the
  fixed sensors, thermal expansion only.
* ``bearing_wobble``: the shaft's radial bearings move the disk centre by
  ``d(t) = Σ_c a_c (cos, sin)(ρ_c Ω t + φ_c)`` (non-synchronous orders ρ_c, e.g. cage 0.4);
  a sensor at azimuth ψ then reads the disk ``a_c sin(ρ_c Ω t + φ_c − ψ)/R`` early. Opposed
  sensors cancel it (seed: 0.42 arcsec p-p with one pair, 0.02 with two). Use
  :func:`bearing_noise` to draw a random spectrum from a ``key``.
* ``thermal_drift``: the moving sensors drift against their disk by
  ``thermal_drift_rad_per_k · ΔT(t)`` with ``ΔT(t) = temperature_offset_k +
  temperature_rate_k_per_s · t`` (seed: ~0.7 arcsec/°C).
* ``timing_quantization``: edges stamped at the next tick of a clock of period
  ``clock_period_s`` (0 = off), plus white jitter of std ``jitter_s`` (needs a ``key``).

:func:`~encdesign.physics.predict_speed_mark_error` (``physics._sds_prediction``) is the
seed's analysis of how the speed error and the mark errors interact (eqs. 46–53).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from .._array import f64 as _f
from .._array import wrap_rad as _wrap
from .._errors import input_error

__all__ = [
    "SDSErrors",
    "axis_tilt_error",
    "bearing_noise",
]

ARCSEC = math.pi / (180 * 3600)


class SDSErrors(eqx.Module):
    """Error sources of an SDS instrument besides motor ripple and mark errors (SI).

    Attributes:
        axis_tilt_rad: tilt β of the disk axis to the platform axis, rad.
        axis_tilt_azimuth_rad: azimuth χ towards which the axis tilts, rad.
        optical_tilt_fixed_rad: tangential optical-axis tilt γ of the fixed sensors, rad
            (scalar or one per fixed sensor).
        optical_tilt_moving_rad: same for the moving sensors.
        axial_offset_m: constant axial shift of disk B against the moving sensors, m.
        axial_runout_cos_m, axial_runout_sin_m: platform-bearing axial runout, Fourier
            coefficients of orders 1…K in the platform angle φ, m.
        axial_expansion_m_per_k: axial shift of the disks per kelvin, m/K.
        thermal_drift_rad_per_k: drift of the moving sensors against disk B per kelvin,
            rad/K.
        temperature_offset_k, temperature_rate_k_per_s: ΔT(t) = offset + rate · t (K, K/s).
        bearing_amplitude_m, bearing_ratio, bearing_phase_rad: radial runout components of
            the shaft bearings: amplitude (m), frequency as a multiple of the shaft speed,
            phase (rad); arrays of one length C.
        clock_period_s: time-stamp clock period, s (0 = exact times).
        jitter_s: white timing jitter std, s (needs a key).
    """

    axis_tilt_rad: Array = eqx.field(default=0.0, converter=_f)
    axis_tilt_azimuth_rad: Array = eqx.field(default=0.0, converter=_f)
    optical_tilt_fixed_rad: Array = eqx.field(default=0.0, converter=_f)
    optical_tilt_moving_rad: Array = eqx.field(default=0.0, converter=_f)
    axial_offset_m: Array = eqx.field(default=0.0, converter=_f)
    axial_runout_cos_m: Array = eqx.field(default=(), converter=_f)
    axial_runout_sin_m: Array = eqx.field(default=(), converter=_f)
    axial_expansion_m_per_k: Array = eqx.field(default=0.0, converter=_f)
    thermal_drift_rad_per_k: Array = eqx.field(default=0.0, converter=_f)
    temperature_offset_k: Array = eqx.field(default=0.0, converter=_f)
    temperature_rate_k_per_s: Array = eqx.field(default=0.0, converter=_f)
    bearing_amplitude_m: Array = eqx.field(default=(), converter=_f)
    bearing_ratio: Array = eqx.field(default=(), converter=_f)
    bearing_phase_rad: Array = eqx.field(default=(), converter=_f)
    clock_period_s: Array = eqx.field(default=0.0, converter=_f)
    jitter_s: Array = eqx.field(default=0.0, converter=_f)

    def __check_init__(self):
        if self.axial_runout_cos_m.shape != self.axial_runout_sin_m.shape:
            raise input_error(
                "SDSErrors.axial_runout_sin_m",
                f"shape {self.axial_runout_sin_m.shape}",
                f"the shape of axial_runout_cos_m {self.axial_runout_cos_m.shape}",
            )
        shapes = {
            self.bearing_amplitude_m.shape,
            self.bearing_ratio.shape,
            self.bearing_phase_rad.shape,
        }
        if len(shapes) != 1 or len(next(iter(shapes))) != 1:
            raise input_error(
                "SDSErrors.bearing_*",
                f"shapes {sorted(shapes)}",
                "three 1-D arrays of one length (amplitude, ratio, phase)",
            )
        for name in (
            "axis_tilt_rad",
            "axis_tilt_azimuth_rad",
            "axial_offset_m",
            "axial_expansion_m_per_k",
            "thermal_drift_rad_per_k",
            "temperature_offset_k",
            "temperature_rate_k_per_s",
            "clock_period_s",
            "jitter_s",
        ):
            if getattr(self, name).shape != ():
                raise input_error(f"SDSErrors.{name}", "not a scalar", "a scalar")

    # ------------------------------------------------------------------ geometry

    def tilt_map(self, azimuth_rad: ArrayLike) -> Array:
        """Disk azimuth read by a sensor at platform azimuth ψ (axis tilt, eq. 26), rad.

        Returns ``ψ + wrap(χ + atan2(sin(ψ−χ), cos(ψ−χ) cos β) − ψ)``: continuous in ψ.
        """
        psi = _f(azimuth_rad)
        chi = self.axis_tilt_azimuth_rad
        a = psi - chi
        proj = jnp.arctan2(jnp.sin(a), jnp.cos(a) * jnp.cos(self.axis_tilt_rad))
        return psi + _wrap(proj - a)

    def delta_t_k(self, t_s: ArrayLike) -> Array:
        """Temperature change ΔT(t) in K."""
        return self.temperature_offset_k + self.temperature_rate_k_per_s * _f(t_s)

    def axial_shift_m(self, phi_rad: ArrayLike) -> Array:
        """Axial shift of disk B against the moving sensors at platform angle φ, m (no ΔT)."""
        phi = _f(phi_rad)
        out = self.axial_offset_m + jnp.zeros_like(phi)
        for i in range(self.axial_runout_cos_m.shape[0]):
            n = i + 1
            out = out + self.axial_runout_cos_m[i] * jnp.cos(n * phi)
            out = out + self.axial_runout_sin_m[i] * jnp.sin(n * phi)
        return out

    def bearing_shift_rad(
        self, t_s: ArrayLike, azimuth_rad: ArrayLike, speed_rad_s: ArrayLike, radius_m: ArrayLike
    ) -> Array:
        """Shift of a sensor's effective azimuth due to radial bearing runout, rad."""
        t = _f(t_s)
        psi = _f(azimuth_rad)
        out = jnp.zeros(jnp.broadcast_shapes(t.shape, psi.shape))
        for c in range(self.bearing_amplitude_m.shape[0]):
            a = self.bearing_ratio[c] * speed_rad_s * t + self.bearing_phase_rad[c]
            out = out - self.bearing_amplitude_m[c] * jnp.sin(a - psi)
        return out / radius_m

    @property
    def has_time_shift(self) -> bool:
        """Whether any effect moves the sensors with time (static: array sizes only)."""
        return self.bearing_amplitude_m.shape[0] > 0


def axis_tilt_error(phi_rad: ArrayLike, tilt_rad: ArrayLike) -> Array:
    """Seed eq. 26: ``atan2(sin φ, cos φ cos β) − φ`` wrapped to (−π, π], rad."""
    phi = _f(phi_rad)
    return _wrap(jnp.arctan2(jnp.sin(phi), jnp.cos(phi) * jnp.cos(_f(tilt_rad))) - phi)


def bearing_noise(
    key: Array,
    rms_m: float,
    n_components: int = 8,
    ratio_range: tuple[float, float] = (0.3, 6.0),
) -> dict[str, Array]:
    """Draw a random radial-runout spectrum for :class:`SDSErrors` (``bearing_*`` fields).

    Args:
        key: ``jax.random`` key.
        rms_m: RMS radial displacement of the disk centre, m.
        n_components: number of sinusoidal components.
        ratio_range: range of their frequencies as multiples of the shaft speed
            (non-integer: cage ≈ 0.4, ball pass ≈ 3.6 for small bearings).

    Returns:
        ``{"bearing_amplitude_m", "bearing_ratio", "bearing_phase_rad"}`` arrays.
    """
    if n_components < 1:
        raise input_error("bearing_noise n_components", f"got {n_components}", ">= 1")
    k1, k2, k3 = jax.random.split(key, 3)
    ratio = jax.random.uniform(k1, (n_components,), minval=ratio_range[0], maxval=ratio_range[1])
    w = jax.random.exponential(k2, (n_components,))
    amp = rms_m * jnp.sqrt(w / jnp.sum(w))  # sum of squares = rms² (|d| rms over 2-D whirl)
    phase = jax.random.uniform(k3, (n_components,), minval=0.0, maxval=2 * jnp.pi)
    return {"bearing_amplitude_m": amp, "bearing_ratio": ratio, "bearing_phase_rad": phase}
