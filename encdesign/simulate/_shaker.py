"""Stepped-sine shaker test simulator (seed ``002_…`` §3.2 step 2): the captures a vibration
LUT is built from (:func:`encdesign.calibrate.build_stepped_lut`), on the project's quadrature
model (:func:`~encdesign.physics.quadrature_signals`, eq. 1) with the shaker controller's
acceleration scatter and the control accelerometer's reading per step.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._errors import input_error
from ..calibrate._vibration_lut import ShakerSteps
from ..physics import SignalErrors, Vibration, quadrature_signals

__all__ = ["simulate_shaker_steps"]


def simulate_shaker_steps(
    key: Array,
    frequency_hz: ArrayLike,
    repeats: int,
    response: Callable[[Array, Array], tuple[Array, Array]],
    *,
    errors: SignalErrors,
    signal_period_m: float,
    sample_rate_hz: float,
    n_samples: int,
    acceleration_m_s2: float = 100.0,
    acceleration_scatter: float = 0.05,
    accelerometer_noise: float = 0.0,
    position_m: float = 0.0,
    amplitude: float = 1.0,
    noise_std: float = 0.0,
    direction: str = "x",
) -> ShakerSteps:
    """A stepped-sine shaker test on the quadrature model (seed step 2, one direction).

    At every step the controller holds the acceleration only to within
    ``acceleration_scatter`` (relative std; the seed's controller uses an accelerometer in
    closed loop), the control accelerometer reads it with relative noise
    ``accelerometer_noise``, and the gratings move by ``response(f, a)`` (amplitude m and
    phase rad against the acceleration, e.g. :func:`mount_relative_displacement_m`). The
    phase of the base motion is random per capture.

    Args:
        key: ``jax.random`` key.
        frequency_hz: step frequencies (Hz), strictly increasing.
        repeats: captures per frequency (>= 2, so that a standard error exists).
        response: ``(f_hz, a_m_s2) -> (X_m, phase_rad)`` of the encoder's mount.
        errors: the encoder's signal errors (offsets, amplitude ratio, phase).
        signal_period_m: signal period p (m).
        sample_rate_hz, n_samples: capture sampling (Hz) and length.
        acceleration_m_s2: nominal severity (m/s²; seed: 100).
        position_m: the fixed scale position (m).
        amplitude, noise_std: signal amplitude and white noise std (signal units).
        direction: label of the vibration direction.
    """
    f = np.asarray(frequency_hz, dtype=float)
    if f.ndim != 1 or f.shape[0] < 2 or not np.all(np.diff(f) > 0) or not np.all(f > 0):
        raise input_error(
            "simulate_shaker_steps: frequency_hz", f"got {f!r}", "increasing frequencies > 0 Hz"
        )
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 2:
        raise input_error("simulate_shaker_steps: repeats", f"got {repeats!r}", "an integer >= 2")
    if not acceleration_m_s2 > 0:
        raise input_error(
            "simulate_shaker_steps: acceleration_m_s2", f"got {acceleration_m_s2!r}", "> 0 m/s^2"
        )
    k1, k2, k3, k4 = jax.random.split(key, 4)
    shape = (f.shape[0], repeats)
    a_true = acceleration_m_s2 * (1 + acceleration_scatter * jax.random.normal(k1, shape))
    a_read = a_true * (1 + accelerometer_noise * jax.random.normal(k2, shape))
    a_phase = jax.random.uniform(k3, shape, minval=0.0, maxval=2 * jnp.pi)
    t = jnp.arange(n_samples) / sample_rate_hz
    fk = jnp.broadcast_to(jnp.asarray(f)[:, None], shape)
    x_amp, x_phase = response(fk, a_true)
    # the gratings' relative motion (Vibration, broadcast over steps and repeats) read
    # through the quadrature model (eq. 1), as :func:`~encdesign.physics.vibrating_signals` does
    vib = Vibration(x_amp[..., None], fk[..., None], (a_phase + x_phase)[..., None])
    psi = 2 * jnp.pi * (position_m + vib.displacement_m(t)) / signal_period_m
    sa, sb = quadrature_signals(psi, errors, amplitude)
    ka, kb = jax.random.split(k4)
    sa = sa + noise_std * jax.random.normal(ka, sa.shape)
    sb = sb + noise_std * jax.random.normal(kb, sb.shape)
    return ShakerSteps(
        jnp.asarray(f), t, sa, sb, a_read, a_phase, float(acceleration_m_s2), direction
    )
