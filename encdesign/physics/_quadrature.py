"""Quadrature head signals and their arctangent interpolation error (seed 002, eq. 1-4).

A head does not output an angle: it outputs two periodic signals, one period per grating
line (or per signal period ``p`` of a linear scale), and the electronics interpolate the
position inside a period with an arctangent. Following seed 002 (Lopez & Artes), eq. 1::

    S_A(psi) = A [ b_a + rho F_A(psi + Phi_1) ]
    S_B(psi) = A [ b_b +     F_B(psi + pi/2) ]

with ``psi = 2 pi x / p`` the line phase (rad), ``A`` the nominal amplitude (the amplitude of
``S_B``), ``b_a = B_1/A`` and ``b_b = B_2/A`` the relative offsets, ``rho = A_1/A_2`` the
amplitude ratio, ``Phi_1`` the phase error of ``S_A`` (``S_B`` kept at the ideal ``pi/2``)
and ``F(u) = sin u + sum_k (s_k sin(k u) + c_k cos(k u))``, ``k = 2 … K+1``, the signal shape
(harmonic distortion). Ideal signals (eq. 2) have ``b = 0``, ``rho = 1``, ``Phi_1 = 0`` and
pure sines; the arctangent ``atan2(S_A, S_B)`` (eq. 3) then returns ``psi`` exactly.

The interpolation error is computed exactly (the arctangent of the imperfect signals minus
the true phase) and in the closed first-order form of eq. 4 (Sanchez-Brea & Morlanes), here
generalised to offsets on both signals and to harmonics::

    d_psi ~ b_a cos psi - b_b sin psi                 (u_off, line frequency)
          + (rho - 1) sin psi cos psi                 (u_amp, twice the line frequency)
          + Phi_1 cos^2 psi                           (u_ph, mean Phi_1/2 plus 2x line freq.)
          + cos psi H_A(psi + Phi_1) - sin psi H_B(psi + pi/2)   (shape)

where ``H`` is the harmonic part of ``F``. In metres ``u = p d_psi / (2 pi)``; on a disk
with ``L = grating_lines`` lines the shaft-angle error is ``d_psi / L`` (rad).

Everything here is pure JAX (jit, vmap and grad work); input checks that need values run
only on concrete arrays.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._array import f64 as _f64
from .._array import is_traced as _is_traced
from .._errors import input_error
from ._types import Angles, Averaged

__all__ = [
    "SignalErrors",
    "Eq4Terms",
    "quadrature_signals",
    "signal_phase_rad",
    "phase_error_exact_rad",
    "phase_error_eq4_rad",
    "interpolation_error_rad",
    "interpolation_error_m",
    "eq4_terms_m",
    "line_period_error",
    "error_harmonics",
    "synthesize_signals",
    "check_signals",
]


class SignalErrors(eqx.Module):
    """Imperfections of one head's quadrature signals (seed 002, eq. 1), all relative.

    Every field may carry leading batch dimensions (e.g. ``(H,)`` for ``H`` heads) that
    broadcast against the phases they are applied to.

    Attributes:
        offset_a: ``B_1/A``, offset of ``S_A`` relative to the nominal amplitude (1).
        offset_b: ``B_2/A``, offset of ``S_B`` relative to the nominal amplitude (1).
        amplitude_ratio: ``A_1/A_2``, amplitude of ``S_A`` over that of ``S_B`` (1; ideal 1).
        phase_error_rad: ``Phi_1``, phase of ``S_A`` (rad); ``S_B`` is at the ideal ``pi/2``,
            so the two signals are ``pi/2 - Phi_1`` apart.
        harmonics_a: ``(..., K, 2)``: ``(s_k, c_k)`` coefficients of ``sin(k u)``, ``cos(k u)``
            for orders ``k = 2 … K+1`` of ``F_A`` relative to its fundamental (1).
        harmonics_b: the same for ``F_B``.
    """

    offset_a: Array
    offset_b: Array
    amplitude_ratio: Array
    phase_error_rad: Array
    harmonics_a: Array
    harmonics_b: Array

    def __init__(
        self,
        offset_a: ArrayLike = 0.0,
        offset_b: ArrayLike = 0.0,
        amplitude_ratio: ArrayLike = 1.0,
        phase_error_rad: ArrayLike = 0.0,
        harmonics_a: ArrayLike | None = None,
        harmonics_b: ArrayLike | None = None,
    ):
        self.offset_a = _f64(offset_a)
        self.offset_b = _f64(offset_b)
        self.amplitude_ratio = _f64(amplitude_ratio)
        self.phase_error_rad = _f64(phase_error_rad)
        self.harmonics_a = jnp.zeros((0, 2)) if harmonics_a is None else _f64(harmonics_a)
        self.harmonics_b = jnp.zeros((0, 2)) if harmonics_b is None else _f64(harmonics_b)

    def __check_init__(self):
        for name in ("harmonics_a", "harmonics_b"):
            h = getattr(self, name)
            if h.ndim < 2 or h.shape[-1] != 2:
                raise input_error(
                    f"SignalErrors.{name}",
                    f"shape {h.shape}",
                    "shape (..., K, 2): (sin, cos) coefficients of orders 2 … K+1",
                )
        for name in ("offset_a", "offset_b", "amplitude_ratio", "phase_error_rad"):
            v = getattr(self, name)
            if not _is_traced(v) and not bool(np.all(np.isfinite(np.asarray(v)))):
                raise input_error(f"SignalErrors.{name}", f"got {np.asarray(v)!r}", "finite")
        r = self.amplitude_ratio
        if not _is_traced(r) and bool(np.any(np.asarray(r) <= 0)):
            raise input_error(
                "SignalErrors.amplitude_ratio", f"got {np.asarray(r)!r}", "a positive ratio A1/A2"
            )
        p = self.phase_error_rad
        if not _is_traced(p) and bool(np.any(np.abs(np.asarray(p)) >= np.pi / 2)):
            raise input_error(
                "SignalErrors.phase_error_rad", f"got {np.asarray(p)!r}", "|Phi_1| < pi/2 rad"
            )

    def as_dict(self) -> dict:
        """Fields as plain floats / lists (for JSON and printing)."""
        names = ("offset_a", "offset_b", "amplitude_ratio", "phase_error_rad")
        names += ("harmonics_a", "harmonics_b")
        return {k: np.asarray(getattr(self, k)).tolist() for k in names}

    @property
    def relative_amplitude_error(self) -> Array:
        """``Delta A_1 / A = rho - 1`` of eq. 4 (1)."""
        return self.amplitude_ratio - 1.0


def _harmonic_part(u: Array, h: Array) -> tuple[Array, Array]:
    """Harmonic part ``H(u)`` of the shape function and its derivative ``dH/du``."""
    k = h.shape[-2]
    if k == 0:
        z = jnp.zeros_like(u)
        return z, z
    orders = jnp.arange(2, k + 2, dtype=jnp.float64)
    ku = u[..., None] * orders
    s, c = h[..., 0], h[..., 1]
    val = jnp.sum(s * jnp.sin(ku) + c * jnp.cos(ku), axis=-1)
    der = jnp.sum(orders * (s * jnp.cos(ku) - c * jnp.sin(ku)), axis=-1)
    return val, der


def quadrature_signals(
    line_phase_rad: ArrayLike, errors: SignalErrors, amplitude: ArrayLike = 1.0
) -> tuple[Array, Array]:
    """The two head signals of eq. 1 at line phase ``psi`` (rad).

    Args:
        line_phase_rad: ``psi = 2 pi x / p`` (rad), any shape broadcasting with ``errors``.
        errors: the signal imperfections.
        amplitude: nominal amplitude ``A`` (signal units, e.g. V).

    Returns:
        ``(S_A, S_B)`` in signal units; ideal signals are ``A sin psi`` and ``A cos psi``.
    """
    psi = _f64(line_phase_rad)
    ua = psi + errors.phase_error_rad
    ub = psi + jnp.pi / 2
    ha, _ = _harmonic_part(ua, errors.harmonics_a)
    hb, _ = _harmonic_part(ub, errors.harmonics_b)
    sa = errors.offset_a + errors.amplitude_ratio * (jnp.sin(ua) + ha)
    sb = errors.offset_b + jnp.sin(ub) + hb
    a = _f64(amplitude)
    return a * sa, a * sb


def signal_phase_rad(sa: Angles, sb: Angles) -> Averaged:
    """The arctangent interpolation of eq. 3: ``atan2(S_A, S_B)`` in (-pi, pi] (rad)."""
    return jnp.arctan2(_f64(sa), _f64(sb))


def phase_error_exact_rad(line_phase_rad: ArrayLike, errors: SignalErrors) -> Array:
    """Exact interpolation error ``atan2(S_A, S_B) - psi`` wrapped to (-pi, pi] (rad of line phase).

    Computed as the angle between the measured vector ``(S_B, S_A)`` and ``(cos psi, sin psi)``,
    so it is smooth (no wrapping jumps) while the signals circle the origin.
    """
    psi = _f64(line_phase_rad)
    sa, sb = quadrature_signals(psi, errors)
    c, s = jnp.cos(psi), jnp.sin(psi)
    return jnp.arctan2(sa * c - sb * s, sb * c + sa * s)


class Eq4Terms(NamedTuple):
    """First-order interpolation error terms of eq. 4 (same unit as the call that made them)."""

    offset: Array
    amplitude: Array
    phase: Array
    shape: Array

    @property
    def total(self) -> Array:
        """Sum of the four terms."""
        return self.offset + self.amplitude + self.phase + self.shape


def phase_error_eq4_rad(line_phase_rad: ArrayLike, errors: SignalErrors) -> Eq4Terms:
    """Closed-form first-order interpolation error of eq. 4, per term (rad of line phase).

    ``offset = b_a cos psi - b_b sin psi``; ``amplitude = (rho-1) sin psi cos psi``;
    ``phase = Phi_1 cos^2 psi``; ``shape = cos psi H_A - sin psi H_B`` (harmonics).
    """
    psi = _f64(line_phase_rad)
    c, s = jnp.cos(psi), jnp.sin(psi)
    ha, _ = _harmonic_part(psi, errors.harmonics_a)
    hb, _ = _harmonic_part(psi + jnp.pi / 2, errors.harmonics_b)
    off = errors.offset_a * c - errors.offset_b * s
    amp = errors.relative_amplitude_error * s * c
    ph = errors.phase_error_rad * c * c
    shape = c * ha - s * hb
    off, amp, ph, shape = jnp.broadcast_arrays(off, amp, ph, shape)
    return Eq4Terms(off, amp, ph, shape)


def interpolation_error_rad(
    reading_rad: ArrayLike,
    grating_lines: ArrayLike,
    signal_errors: SignalErrors,
    *,
    first_order: bool = False,
    phase_offset_rad: ArrayLike = 0.0,
) -> Array:
    """Extra shaft-angle reading error (rad) caused by imperfect quadrature signals.

    The catalog effect ``interpolation_error``: a head at disk-frame angle ``theta`` sees
    line phase ``psi = L theta`` (``L = grating_lines``); its arctangent interpolation is off
    by ``d_psi(psi)`` and the reading by ``d_psi / L``. Periodic in the grating pitch, so it
    appears at orders ``L`` and ``2 L`` (and ``k L`` with harmonics).

    Args:
        reading_rad: disk-frame angle under each head (rad), e.g. ``head_readings(...)`` of
            shape ``(n, H)``.
        grating_lines: lines per revolution ``L`` (int or array broadcasting with readings).
        signal_errors: per-head parameters, fields of shape ``()`` or ``(H,)``.
        first_order: use the closed form of eq. 4 instead of the exact arctangent.
        phase_offset_rad: line phase at reading 0 per head (rad), e.g. ``L alpha_k`` when
            readings are referred to the head azimuth ``alpha_k``; default 0.

    Returns:
        Reading error (rad of shaft angle), the broadcast shape of the inputs. jit/vmap/grad
        friendly (no value-dependent control flow).
    """
    lines = _f64(grating_lines)
    psi = lines * _f64(reading_rad) + _f64(phase_offset_rad)
    if first_order:
        d = phase_error_eq4_rad(psi, signal_errors).total
    else:
        d = phase_error_exact_rad(psi, signal_errors)
    return d / lines


def interpolation_error_m(
    position_m: ArrayLike, signal_period_m: ArrayLike, errors: SignalErrors
) -> Array:
    """Exact interpolation error of a linear scale at position ``x`` (m): ``p d_psi / (2 pi)``."""
    p = _f64(signal_period_m)
    psi = 2 * jnp.pi * _f64(position_m) / p
    return p / (2 * jnp.pi) * phase_error_exact_rad(psi, errors)


def eq4_terms_m(
    position_m: ArrayLike, signal_period_m: ArrayLike, errors: SignalErrors
) -> Eq4Terms:
    """Eq. 4 in metres: ``u_off``, ``u_amp``, ``u_ph`` (and the shape term) at position ``x`` (m).

    With only ``B_1``, ``A_1`` and ``Phi_1`` errors these are the seed's expressions
    ``p/(2 pi) cos(psi) dB1/A``, ``p/(4 pi) sin(2 psi) dA1/A`` and ``p/(2 pi) cos^2(psi) dPhi1``.
    """
    p = _f64(signal_period_m)
    psi = 2 * jnp.pi * _f64(position_m) / p
    t = phase_error_eq4_rad(psi, errors)
    k = p / (2 * jnp.pi)
    return Eq4Terms(k * t.offset, k * t.amplitude, k * t.phase, k * t.shape)


def line_period_error(
    errors: SignalErrors, n_points: int = 256, *, first_order: bool = False
) -> tuple[Array, Array]:
    """Interpolation error over one line period on a uniform phase grid.

    Returns:
        ``(psi, d_psi)``: ``n_points`` phases in [0, 2 pi) (rad) and the error at each (rad of
        line phase; divide by ``grating_lines`` for shaft rad or multiply by ``p/(2 pi)`` for m).
    """
    psi = jnp.arange(n_points, dtype=jnp.float64) * (2 * jnp.pi / n_points)
    if errors.offset_a.ndim:
        psi = psi.reshape((n_points,) + (1,) * errors.offset_a.ndim)
    d = (
        phase_error_eq4_rad(psi, errors).total
        if first_order
        else phase_error_exact_rad(psi, errors)
    )
    return psi, d


def error_harmonics(
    errors: SignalErrors, max_order: int = 4, n_points: int = 256, *, first_order: bool = False
) -> tuple[Array, Array]:
    """Mean and harmonic amplitudes of the interpolation error over a line period.

    Returns:
        ``(mean, amplitudes)``: the mean error (rad of line phase) and the amplitude of
        orders ``1 … max_order`` of the line frequency (rad), last axis ``max_order``.
        Order 1 comes from offsets, order 2 from amplitude and phase errors (seed 002 §2.1).
    """
    psi, d = line_period_error(errors, n_points, first_order=first_order)
    d = jnp.moveaxis(d, 0, -1)
    psi = jnp.reshape(psi, (-1,))
    k = jnp.arange(1, max_order + 1, dtype=jnp.float64)
    e = jnp.exp(-1j * psi[:, None] * k)
    coef = 2.0 * (d.astype(jnp.complex128) @ e) / n_points
    return jnp.mean(d, axis=-1), jnp.abs(coef)


def synthesize_signals(
    position_m: ArrayLike,
    signal_period_m: ArrayLike,
    errors: SignalErrors,
    *,
    amplitude: ArrayLike = 1.0,
    noise_std: ArrayLike = 0.0,
    key: Array | None = None,
) -> tuple[Array, Array]:
    """Signals of eq. 1 along a path ``x(t)`` (m), with optional white noise.

    Args:
        position_m: scale position under the head (m), any shape.
        signal_period_m: signal period ``p`` (m) (grating pitch, or lambda/2 for an
            interferometer).
        errors: signal imperfections.
        amplitude: nominal amplitude ``A`` (signal units).
        noise_std: standard deviation of additive white noise (signal units); needs ``key``.
        key: ``jax.random`` key for the noise.

    Returns:
        ``(S_A, S_B)`` (signal units).
    """
    psi = 2 * jnp.pi * _f64(position_m) / _f64(signal_period_m)
    sa, sb = quadrature_signals(psi, errors, amplitude)
    if key is None:
        if not _is_traced(noise_std) and float(np.max(np.asarray(noise_std))) > 0:
            raise input_error("synthesize_signals", "noise_std > 0 but no key", "a jax.random key")
        return sa, sb
    ka, kb = jax.random.split(key)
    sa = sa + noise_std * jax.random.normal(ka, sa.shape)
    sb = sb + noise_std * jax.random.normal(kb, sb.shape)
    return sa, sb


def check_signals(sa, sb, where: str = "signals", *, min_points: int = 6) -> tuple:
    """Validate a pair of measured quadrature signals; return them as float64 arrays.

    Raises:
        EncdesignInputError: not 1-D, unequal lengths, fewer than ``min_points`` samples,
            non-finite values (the first one is named), or a signal that is constant
            (nothing to fit). Value checks are skipped for traced (jit) arguments.
    """
    out = []
    for name, s in (("sa", sa), ("sb", sb)):
        if _is_traced(s):
            out.append(s)
            if s.ndim != 1:
                raise input_error(f"{where}: {name}", f"shape {s.shape}", "a 1-D array")
            continue
        try:
            a = np.asarray(s, dtype=np.float64)
        except (TypeError, ValueError):
            raise input_error(f"{where}: {name}", f"got {type(s).__name__}", "numbers") from None
        if a.ndim != 1:
            raise input_error(f"{where}: {name}", f"shape {a.shape}", "a 1-D array")
        out.append(a)
    a, b = out
    if a.shape[0] != b.shape[0]:
        raise input_error(
            where, f"sa has {a.shape[0]} samples but sb has {b.shape[0]}", "equal lengths"
        )
    if a.shape[0] < min_points:
        raise input_error(where, f"{a.shape[0]} samples", f"at least {min_points}")
    for name, x in (("sa", a), ("sb", b)):
        if _is_traced(x):
            continue
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            i = int(bad[0])
            raise input_error(
                f"{where}: {name}[{i}]", f"got {x[i]!r} ({bad.size} non-finite)", "finite"
            )
        scale = max(1.0, float(np.max(np.abs(x))))
        if float(np.ptp(x)) <= 1e-12 * scale:
            raise input_error(
                f"{where}: {name}",
                f"all {x.size} samples are constant ({x[0]!r})",
                "a varying quadrature signal",
            )
    return a, b
