"""Vibration look-up tables from a stepped-sine shaker test, scaled by an accelerometer, one
per vibration direction (seed ``002_…`` §3.2–3.3, steps 2–4 and the closing paragraph of §3.3).

Procedure (seed): the encoder, at a fixed position, is shaken at a set acceleration over a
frequency range; at each frequency the relative motion of the gratings turns the Lissajous
point into an arc whose angle gives the peak-to-peak relative displacement ``δ_gm(f)``; the
table is the mean of several repeats (seed: ten). In the field an accelerometer gives the
machine's acceleration amplitude and ``δ_gm`` is read from the table. A table per vibration
direction is built when the encoder responds differently to each; the seed combines them
"proportional to the relative level of accelerations detected by the accelerometer between
each one of the axis".

What is here:

* :func:`mount_relative_displacement_m`: the closed form of a base-excited one-degree-of-
  freedom mount, ``X(f) = a / |ω_n² − ω² + 2iζω_nω|`` (m, zero to peak) and its phase: the
  truth the simulations use and the tests check against.
* :func:`encdesign.simulate.simulate_shaker_steps` (the bench simulator, in ``simulate``): a
  stepped-sine test (frequencies × repeats) on the project's quadrature model
  (:func:`~encdesign.quadrature_signals`, eq. 1), with the shaker controller's acceleration
  scatter and the control accelerometer's reading per step.
* :func:`build_stepped_lut` → :class:`SteppedLUT`: per step the arc's phase, corrected with
  the ellipse fitted without vibration, is fitted by least squares with a sine at the step
  frequency (amplitude and phase against the control accelerometer). Each repeat is
  **scaled by the accelerometer**: normalised to the nominal severity with the acceleration
  measured in that step (the response of a linear mount is proportional to it), then the
  repeats are averaged; the standard error of the mean is kept per frequency.
* :meth:`SteppedLUT.delta_gm_m` reads the table by linear interpolation (seed step 4) and
  scales it to a field acceleration ``a``: ``δ_gm(f, a) = δ_LUT(f) · a / a_LUT``
  (accelerometer scaling, step 3). Differentiable in ``f``, ``a`` and the table.
* :func:`accelerometer_levels`: amplitude and phase of each accelerometer axis at the
  excitation frequency (least-squares sine, with standard errors).
* :func:`combine_luts`: one LUT per direction combined with the accelerometer's levels,
  both as the seed writes it (``Σ_d (a_d/a_LUT,d) δ_d(f)``: the seed's weights
  ``a_d/Σa`` times the total level; exact when the directions respond in phase, an upper
  bound otherwise) and with the phases the shaker test also measures
  (``2 |Σ_d H_d(f) A_d|``, exact for a linear mount).

Units: frequencies Hz, accelerations m/s² (amplitude, zero to peak), displacements m,
``δ_gm`` peak to peak (as the seed's eq. 6 uses it: ``u_vib = M_me + δ_gm/2 sin(…)``).
"""

from __future__ import annotations

from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._errors import input_error
from ..physics import (
    EllipseParams,
    VibrationLUT,
    corrected_phase_rad,
)

__all__ = [
    "AccelerometerLevels",
    "CombinedLUT",
    "ShakerSteps",
    "SteppedLUT",
    "accelerometer_levels",
    "build_stepped_lut",
    "combine_luts",
    "mount_relative_displacement_m",
]


def _f(x: ArrayLike) -> Array:
    return jnp.asarray(x, dtype=float)


def mount_relative_displacement_m(
    frequency_hz: ArrayLike,
    acceleration_m_s2: ArrayLike,
    natural_hz: ArrayLike,
    damping_ratio: ArrayLike,
) -> tuple[Array, Array]:
    """Relative displacement of a base-excited 1-dof mount (closed form).

    ``x'' + 2ζω_n x' + ω_n² x = −a_base``: for ``a_base = a sin(ωt)`` the relative
    displacement is ``X sin(ωt + ϕ)`` with ``X = a / |ω_n² − ω² + 2iζω_nω|`` and
    ``ϕ = π − arg(ω_n² − ω² + 2iζω_nω)`` (below resonance the gratings lag the base by π:
    they move against the acceleration; the sign convention is irrelevant to ``δ_gm``).

    Args:
        frequency_hz: excitation frequency f (Hz, > 0).
        acceleration_m_s2: base acceleration amplitude a (m/s², zero to peak).
        natural_hz: mount natural frequency f_n (Hz, > 0).
        damping_ratio: ζ (dimensionless, > 0).

    Returns:
        ``(X_m, phase_rad)``: amplitude (m, zero to peak) and phase against the base
        acceleration (rad). ``δ_gm = 2 X``. Differentiable.
    """
    w = 2 * jnp.pi * _f(frequency_hz)
    wn = 2 * jnp.pi * _f(natural_hz)
    den = (wn**2 - w**2) + 2j * _f(damping_ratio) * wn * w
    return _f(acceleration_m_s2) / jnp.abs(den), jnp.pi - jnp.angle(den)


# ----------------------------------------------------------------------------- test data


class ShakerSteps(eqx.Module):
    """Captures of a stepped-sine shaker test at a fixed scale position.

    Attributes:
        frequency_hz: step frequencies (Hz), strictly increasing, ``(K,)``.
        t_s: sample times of each capture (s), ``(n,)``.
        sa, sb: quadrature signals (signal units), ``(K, R, n)`` (R repeats).
        acceleration_m_s2: control-accelerometer amplitude measured in each step (m/s²),
            ``(K, R)``.
        acceleration_phase_rad: its sine phase at ``t = 0`` (rad), ``(K, R)``.
        nominal_acceleration_m_s2: the test severity set on the controller (m/s²).
        direction: vibration direction of this test (a label, e.g. ``"x"``).
    """

    frequency_hz: Array
    t_s: Array
    sa: Array
    sb: Array
    acceleration_m_s2: Array
    acceleration_phase_rad: Array
    nominal_acceleration_m_s2: float = eqx.field(static=True)
    direction: str = eqx.field(static=True, default="x")

    def __check_init__(self):
        k = self.frequency_hz.shape[0] if self.frequency_hz.ndim == 1 else -1
        if k < 2 or self.sa.ndim != 3 or self.sa.shape != self.sb.shape:
            raise input_error(
                "ShakerSteps",
                f"frequency_hz {self.frequency_hz.shape}, sa {self.sa.shape}, sb {self.sb.shape}",
                "(K,) frequencies with K >= 2 and (K, R, n) signals",
            )
        if self.sa.shape[0] != k or self.sa.shape[2] != self.t_s.shape[0]:
            raise input_error(
                "ShakerSteps",
                f"sa {self.sa.shape} for {k} frequencies and {self.t_s.shape[0]} times",
                "(K, R, n)",
            )
        for name in ("acceleration_m_s2", "acceleration_phase_rad"):
            if getattr(self, name).shape != self.sa.shape[:2]:
                raise input_error(
                    f"ShakerSteps.{name}", f"shape {getattr(self, name).shape}", "(K, R)"
                )


# ----------------------------------------------------------------------------- the table


class SteppedLUT(eqx.Module):
    """Vibration LUT of one direction from a stepped-sine test (seed Fig. 3), with errors.

    Attributes:
        frequency_hz: step frequencies (Hz), ``(K,)``, strictly increasing.
        delta_gm_lut_m: mean peak-to-peak relative grating displacement at the severity
            ``acceleration_m_s2`` (m), ``(K,)`` (repeats scaled by their accelerometer
            reading before averaging).
        delta_gm_se_m: standard error of that mean over the repeats (m), ``(K,)``.
        response_cos_m_per_m_s2, response_sin_m_per_m_s2: the mount's transmissibility
            ``H(f) = X/a`` as ``X/a (cos ϕ, sin ϕ)`` (m per m/s², phase ϕ against the
            control accelerometer), repeat means, ``(K,)``.
        repeat_delta_gm_m: every repeat's scaled value (m), ``(K, R)``.
        acceleration_m_s2: the severity the table refers to (m/s²).
        direction: the vibration direction (label).
    """

    frequency_hz: Array
    delta_gm_lut_m: Array
    delta_gm_se_m: Array
    response_cos_m_per_m_s2: Array
    response_sin_m_per_m_s2: Array
    repeat_delta_gm_m: Array
    acceleration_m_s2: float = eqx.field(static=True, default=100.0)
    direction: str = eqx.field(static=True, default="x")

    def __check_init__(self):
        k = self.frequency_hz.shape
        for name in (
            "delta_gm_lut_m",
            "delta_gm_se_m",
            "response_cos_m_per_m_s2",
            "response_sin_m_per_m_s2",
        ):
            if getattr(self, name).shape != k:
                raise input_error(
                    f"SteppedLUT.{name}", f"shape {getattr(self, name).shape}", f"shape {k}"
                )
        if not self.acceleration_m_s2 > 0:
            raise input_error(
                "SteppedLUT.acceleration_m_s2", f"got {self.acceleration_m_s2!r}", "> 0 m/s^2"
            )

    @property
    def repeats(self) -> int:
        """Repeats per frequency."""
        return int(self.repeat_delta_gm_m.shape[1])

    def delta_gm_m(self, f_exc_hz: ArrayLike, acceleration_m_s2: ArrayLike | None = None) -> Array:
        """``δ_gm`` (m, peak to peak) at ``f_exc_hz`` (linear interpolation, clamped at the
        ends), scaled to the field acceleration amplitude ``acceleration_m_s2`` (m/s²;
        default the table's severity): ``δ_LUT(f) · a / a_LUT``."""
        d = jnp.interp(_f(f_exc_hz), self.frequency_hz, self.delta_gm_lut_m)
        if acceleration_m_s2 is None:
            return d
        return d * _f(acceleration_m_s2) / self.acceleration_m_s2

    def delta_gm_se_at_m(
        self, f_exc_hz: ArrayLike, acceleration_m_s2: ArrayLike | None = None
    ) -> Array:
        """Standard error of :meth:`delta_gm_m` (m): the interpolation weights applied to
        the neighbouring steps' errors (independent), scaled like the value."""
        f = _f(f_exc_hz)
        fk = self.frequency_hz
        j = jnp.clip(jnp.searchsorted(fk, f) - 1, 0, fk.shape[0] - 2)
        w = jnp.clip((f - fk[j]) / (fk[j + 1] - fk[j]), 0.0, 1.0)
        se = jnp.sqrt(((1 - w) * self.delta_gm_se_m[j]) ** 2 + (w * self.delta_gm_se_m[j + 1]) ** 2)
        if acceleration_m_s2 is None:
            return se
        return se * _f(acceleration_m_s2) / self.acceleration_m_s2

    def response_m_per_m_s2(self, f_exc_hz: ArrayLike) -> Array:
        """Complex transmissibility ``H(f)`` (m per m/s²), interpolated linearly in its real
        and imaginary parts."""
        f = _f(f_exc_hz)
        re = jnp.interp(f, self.frequency_hz, self.response_cos_m_per_m_s2)
        im = jnp.interp(f, self.frequency_hz, self.response_sin_m_per_m_s2)
        return re + 1j * im

    def as_vibration_lut(self, acceleration_m_s2: float | None = None) -> VibrationLUT:
        """The physics :class:`~encdesign.physics.VibrationLUT` (used by the compensation signal),
        scaled to ``acceleration_m_s2`` (m/s²; default the table's severity)."""
        a = self.acceleration_m_s2 if acceleration_m_s2 is None else float(acceleration_m_s2)
        return VibrationLUT(self.frequency_hz, self.delta_gm_lut_m * a / self.acceleration_m_s2, a)


def _sine_fit(y: Array, t: Array, f: Array) -> tuple[Array, Array]:
    """Least-squares ``c0 + s sin(2πft) + c cos(2πft)``: returns ``(s, c)``."""
    w = 2 * jnp.pi * f * t
    d = jnp.stack([jnp.ones_like(t), jnp.sin(w), jnp.cos(w)], axis=1)
    coef = jnp.linalg.solve(d.T @ d, d.T @ y)
    return coef[1], coef[2]


@jax.jit
def _arc_sines(sa, sb, params, t, f):
    """Sine fit (sin, cos parts, rad) of every capture's corrected, unwrapped phase."""
    phase = jnp.unwrap(corrected_phase_rad(sa, sb, params), axis=-1)
    fk = jnp.broadcast_to(f[:, None], sa.shape[:2])
    return jax.vmap(jax.vmap(lambda y, fr: _sine_fit(y, t, fr)))(phase, fk)


def build_stepped_lut(
    steps: ShakerSteps,
    params: EllipseParams,
    signal_period_m: float,
    *,
    scale_by_accelerometer: bool = True,
) -> SteppedLUT:
    """Build the LUT of one direction from a stepped-sine test (seed §3.2, step 2).

    Each capture's phase, corrected with the ellipse fitted without vibration (offsets,
    amplitude and phase removed, seed step 1), is fitted with a sine at the step frequency
    (noise-insensitive, unlike the arc's max − min span); its amplitude is ``δ_gm/2`` in
    phase units and its phase is taken against the control accelerometer's. With
    ``scale_by_accelerometer`` each capture is multiplied by ``a_nominal / a_measured``
    before the repeats are averaged (a linear mount's response is proportional to the
    acceleration, so this removes the controller's scatter); without it the seed's plain
    mean is taken.

    Args:
        steps: the captures (:func:`encdesign.simulate.simulate_shaker_steps` or measured).
        params: ellipse of the encoder without vibration.
        signal_period_m: signal period p (m).
        scale_by_accelerometer: normalise every capture by its measured acceleration.

    Returns:
        :class:`SteppedLUT`; differentiable with respect to the captures.
    """
    if not signal_period_m > 0:
        raise input_error("build_stepped_lut: signal_period_m", f"got {signal_period_m!r}", "> 0 m")
    a = steps.acceleration_m_s2
    if not bool(jnp.all(jnp.isfinite(a) & (a > 0))):
        raise input_error(
            "build_stepped_lut: acceleration_m_s2", "a non-positive or non-finite reading", "> 0"
        )
    if not bool(jnp.all(jnp.isfinite(steps.sa)) and jnp.all(jnp.isfinite(steps.sb))):
        raise input_error("build_stepped_lut: signals", "non-finite sample", "finite signals")
    k = signal_period_m / (2 * jnp.pi)
    s, c = _arc_sines(steps.sa, steps.sb, params, steps.t_s, steps.frequency_hz)
    x_amp = k * jnp.hypot(s, c)  # m, zero to peak
    x_ph = jnp.arctan2(c, s) - steps.acceleration_phase_rad
    a0 = steps.nominal_acceleration_m_s2
    scale = a0 / a if scale_by_accelerometer else jnp.ones_like(a)
    rep = 2 * x_amp * scale
    n_rep = a.shape[1]
    mean = jnp.mean(rep, axis=1)
    se = jnp.std(rep, axis=1, ddof=1) / np.sqrt(n_rep)
    h = x_amp * scale / a0
    return SteppedLUT(
        frequency_hz=steps.frequency_hz,
        delta_gm_lut_m=mean,
        delta_gm_se_m=se,
        response_cos_m_per_m_s2=jnp.mean(h * jnp.cos(x_ph), axis=1),
        response_sin_m_per_m_s2=jnp.mean(h * jnp.sin(x_ph), axis=1),
        repeat_delta_gm_m=rep,
        acceleration_m_s2=float(a0),
        direction=steps.direction,
    )


# ----------------------------------------------------------------------------- the field


class AccelerometerLevels(eqx.Module):
    """Acceleration of each accelerometer axis at one frequency (seed step 3).

    Attributes:
        frequency_hz: the frequency fitted (Hz).
        amplitude_m_s2: amplitude per axis (m/s², zero to peak), ``(D,)``.
        phase_rad: sine phase at ``t = 0`` per axis (rad), ``(D,)``.
        amplitude_se_m_s2: standard error of each amplitude (m/s²), ``(D,)``.
        directions: axis labels, static.
    """

    frequency_hz: Array
    amplitude_m_s2: Array
    phase_rad: Array
    amplitude_se_m_s2: Array
    directions: tuple[str, ...] = eqx.field(static=True)

    def as_dict(self) -> dict[str, float]:
        """``{direction: amplitude (m/s²)}``."""
        return {d: float(a) for d, a in zip(self.directions, self.amplitude_m_s2)}


def accelerometer_levels(
    t_s: ArrayLike,
    acceleration_m_s2: ArrayLike,
    frequency_hz: float,
    directions: tuple[str, ...] = ("x", "y", "z"),
) -> AccelerometerLevels:
    """Amplitude and phase of each axis of an accelerometer record at ``frequency_hz``.

    Least-squares ``c0 + s sin(2πft) + c cos(2πft)`` per axis (``f`` e.g. the excitation
    frequency estimated from the encoder's doublet); the amplitude's standard error is
    ``σ̂ √(2/n)`` from the residual.

    Args:
        t_s: sample times (s), ``(n,)``.
        acceleration_m_s2: record (m/s²), ``(n, D)`` or ``(n,)`` for one axis.
        frequency_hz: frequency (Hz, > 0).
        directions: one label per axis.
    """
    t = _f(t_s)
    acc = _f(acceleration_m_s2)
    if acc.ndim == 1:
        acc = acc[:, None]
    if t.ndim != 1 or acc.ndim != 2 or acc.shape[0] != t.shape[0] or t.shape[0] < 8:
        raise input_error(
            "accelerometer_levels",
            f"t_s {t.shape}, acceleration_m_s2 {acc.shape}",
            "(n,) times and (n, D) accelerations with n >= 8",
        )
    if len(directions) != acc.shape[1]:
        raise input_error(
            "accelerometer_levels: directions",
            f"{len(directions)} labels for {acc.shape[1]} axes",
            "one label per axis",
        )
    if not bool(jnp.all(jnp.isfinite(acc))):
        raise input_error("accelerometer_levels", "non-finite acceleration", "finite samples")
    if not frequency_hz > 0:
        raise input_error("accelerometer_levels: frequency_hz", f"got {frequency_hz!r}", "> 0 Hz")
    f = _f(frequency_hz)
    w = 2 * jnp.pi * f * t
    d = jnp.stack([jnp.ones_like(t), jnp.sin(w), jnp.cos(w)], axis=1)
    coef = jnp.linalg.solve(d.T @ d, d.T @ acc)  # (3, D)
    resid = acc - d @ coef
    sigma = jnp.sqrt(jnp.sum(resid**2, axis=0) / (t.shape[0] - 3))
    return AccelerometerLevels(
        frequency_hz=f,
        amplitude_m_s2=jnp.hypot(coef[1], coef[2]),
        phase_rad=jnp.arctan2(coef[2], coef[1]),
        amplitude_se_m_s2=sigma * jnp.sqrt(2.0 / t.shape[0]),
        directions=tuple(directions),
    )


class CombinedLUT(eqx.Module):
    """Per-direction LUTs combined with the accelerometer's levels (:func:`combine_luts`).

    Attributes:
        delta_gm_seed_m: seed's combination ``Σ_d (a_d/a_LUT,d) δ_d(f)`` (m, peak to peak).
        delta_gm_seed_se_m: its standard error from the LUTs' (m).
        delta_gm_phasor_m: ``2 |Σ_d H_d(f) A_d|`` with the accelerometer phasors ``A_d``
            (m, peak to peak).
        phase_rad: phase of ``Σ_d H_d A_d`` (rad): the vibration term's phase at ``t = 0``.
        weights: the seed's weights ``a_d / Σa`` per direction, ``(D,)``.
        directions: labels, static.
    """

    delta_gm_seed_m: Array
    delta_gm_seed_se_m: Array
    delta_gm_phasor_m: Array
    phase_rad: Array
    weights: Array
    directions: tuple[str, ...] = eqx.field(static=True)


def combine_luts(
    luts: Mapping[str, SteppedLUT],
    levels: AccelerometerLevels | Mapping[str, float],
    f_exc_hz: ArrayLike,
) -> CombinedLUT:
    """Combine one LUT per direction with the field accelerometer's levels (seed §3.3).

    Args:
        luts: ``{direction: SteppedLUT}``.
        levels: :class:`AccelerometerLevels` (amplitudes and phases) or
            ``{direction: amplitude m/s²}`` (then all in phase).
        f_exc_hz: excitation frequency (Hz).

    Returns:
        :class:`CombinedLUT`. Differentiable in the levels, the tables and ``f_exc_hz``.

    Raises:
        EncdesignInputError: a direction of the levels without a table, or none in common.
    """
    if isinstance(levels, AccelerometerLevels):
        amp = dict(zip(levels.directions, levels.amplitude_m_s2))
        ph = dict(zip(levels.directions, levels.phase_rad))
    else:
        amp = {d: _f(a) for d, a in levels.items()}
        ph = {d: _f(0.0) for d in levels}
    missing = sorted(set(amp) - set(luts))
    if missing or not amp:
        raise input_error(
            "combine_luts: levels",
            f"direction(s) {missing or '(none)'} without a LUT",
            f"directions among {sorted(luts)}",
        )
    dirs = tuple(d for d in luts if d in amp)
    f = _f(f_exc_hz)
    seed = sum(luts[d].delta_gm_m(f, amp[d]) for d in dirs)
    seed_se = jnp.sqrt(sum(luts[d].delta_gm_se_at_m(f, amp[d]) ** 2 for d in dirs))
    z = sum(luts[d].response_m_per_m_s2(f) * amp[d] * jnp.exp(1j * ph[d]) for d in dirs)
    a = jnp.stack([amp[d] for d in dirs])
    return CombinedLUT(
        delta_gm_seed_m=seed,
        delta_gm_seed_se_m=seed_se,
        delta_gm_phasor_m=2 * jnp.abs(z),
        phase_rad=jnp.angle(z),
        weights=a / jnp.sum(a),
        directions=dirs,
    )
