"""Ellipse fitting of the Lissajous figure and correction of quadrature signals (seed 002 §3).

Signals of eq. 1 with offsets ``B_1, B_2``, amplitudes ``A_1, A_2`` and phase error ``Phi_1``
trace the ellipse::

    (x - B_1)^2/A_1^2 + (y - B_2)^2/A_2^2 - 2 sin(Phi_1) (x - B_1)(y - B_2)/(A_1 A_2) = cos^2 Phi_1

(``x = S_A``, ``y = S_B``). A conic ``a x^2 + b xy + c y^2 + d x + e y + f = 0`` is fitted to the
samples, either by the direct least-squares ellipse fit of Fitzgibbon, Pilu & Fisher (seed
ref. 23, in the numerically stable form of Halir & Flusser, always an ellipse) or by
Heydemann's linear least squares (seed ref. 11, ``f = -1``). The five signal parameters follow
in closed form (centre; ``A_2/A_1 = sqrt(a/c)``; ``sin Phi_1 = -b / (2 sqrt(ac))``; scale from the
conic's value at the centre), and the Heydemann correction maps each sample back onto the
unit circle, removing offset, amplitude and phase errors (not harmonic distortion).

The seed's own compensation (§3.1-3.3) is also here: the compensation signal
``S_comp = u_off + u_amp + u_ph + u_vib`` built from eq. 4 with the fitted parameters and from
eq. 6 ``u_vib = M_me + delta_gm/2 sin(2 pi f_exc t + phi)``, where ``delta_gm`` is read from a
look-up table over excitation frequency (:class:`VibrationLUT`) measured on a shaker.

Fits are jit-able and differentiable (scatter matrices accumulated over chunks, so memory
stays bounded for long captures); input checks run on concrete arrays.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._array import f64 as _f64
from .._array import is_traced as _is_traced
from .._errors import input_error
from ._quadrature import SignalErrors, check_signals, phase_error_eq4_rad
from ._types import Angles, Averaged, SampleValues, SampleValuesOut, Scalar

__all__ = [
    "EllipseParams",
    "EllipseFit",
    "fit_ellipse",
    "correct_signals",
    "corrected_phase_rad",
    "position_from_signals_m",
    "compensation_signal_m",
    "vibration_compensation_m",
    "seed_eq7_choice",
    "VibrationLUT",
    "build_vibration_lut",
]

STATUS_OK = 0
STATUS_NOT_ELLIPSE = 1
STATUS_MESSAGES = {
    STATUS_OK: "success",
    STATUS_NOT_ELLIPSE: "the fitted conic is not a real ellipse (degenerate Lissajous figure)",
}


_ELLIPSE_FIELDS = ("offset_a", "offset_b", "amplitude_a", "amplitude_b", "phase_rad")


class EllipseParams(eqx.Module):
    """Parameters of the Lissajous ellipse, in the units of the signals.

    Attributes:
        offset_a: ``B_1``, mean of ``S_A`` (signal units).
        offset_b: ``B_2``, mean of ``S_B`` (signal units).
        amplitude_a: ``A_1`` (signal units, > 0).
        amplitude_b: ``A_2`` (signal units, > 0).
        phase_rad: ``Phi_1``, phase error of ``S_A`` (rad; the signals are ``pi/2 - Phi_1`` apart).
    """

    offset_a: Array
    offset_b: Array
    amplitude_a: Array
    amplitude_b: Array
    phase_rad: Array

    def __init__(self, offset_a, offset_b, amplitude_a, amplitude_b, phase_rad):
        self.offset_a = _f64(offset_a)
        self.offset_b = _f64(offset_b)
        self.amplitude_a = _f64(amplitude_a)
        self.amplitude_b = _f64(amplitude_b)
        self.phase_rad = _f64(phase_rad)

    def __check_init__(self):
        for name in ("amplitude_a", "amplitude_b"):
            v = getattr(self, name)
            if not _is_traced(v) and bool(np.any(~(np.asarray(v) > 0))):
                raise input_error(f"EllipseParams.{name}", f"got {np.asarray(v)!r}", "> 0")

    @classmethod
    def from_signal_errors(cls, errors: SignalErrors, amplitude: ArrayLike = 1.0) -> EllipseParams:
        """The ellipse that signals with ``errors`` and nominal amplitude ``A`` trace."""
        a = _f64(amplitude)
        return cls(
            a * errors.offset_a,
            a * errors.offset_b,
            a * errors.amplitude_ratio,
            a * jnp.ones_like(errors.amplitude_ratio),
            errors.phase_error_rad,
        )

    def to_signal_errors(self) -> SignalErrors:
        """Relative errors (offsets over ``A_2``, ratio ``A_1/A_2``, ``Phi_1``), no harmonics."""
        return SignalErrors(
            self.offset_a / self.amplitude_b,
            self.offset_b / self.amplitude_b,
            self.amplitude_a / self.amplitude_b,
            self.phase_rad,
        )

    def as_dict(self) -> dict:
        """Fields as plain floats / lists (for JSON and printing)."""
        return {k: np.asarray(getattr(self, k)).tolist() for k in _ELLIPSE_FIELDS}

    def points(self, n: int = 361) -> tuple[Array, Array]:
        """``n`` points ``(S_A, S_B)`` on the ellipse (signal units), for plotting."""
        psi = jnp.linspace(0.0, 2 * jnp.pi, n)
        return (
            self.offset_a + self.amplitude_a * jnp.sin(psi + self.phase_rad),
            self.offset_b + self.amplitude_b * jnp.cos(psi),
        )

    def seed_terms(self, ideal_amplitude: ArrayLike) -> dict[str, Array]:
        """The seed's scalar error measures (§3.1), relative to the ideal amplitude ``A``.

        ``dB1_rel = sqrt(Cx^2 + Cy^2)/A``, ``dA1_rel = sqrt((Rx - A)^2 + (Ry - A)^2)/A`` and
        ``dPhi1_rad``. (The seed needs an interpolating surface for ``dPhi1`` because it uses
        the axes of the rotated ellipse; the parametrisation here gives it directly.)
        """
        a = _f64(ideal_amplitude)
        return {
            "dB1_rel": jnp.hypot(self.offset_a, self.offset_b) / a,
            "dA1_rel": jnp.hypot(self.amplitude_a - a, self.amplitude_b - a) / a,
            "dPhi1_rad": self.phase_rad,
        }


class EllipseFit(eqx.Module):
    """Result of :func:`fit_ellipse`.

    Attributes:
        params: fitted :class:`EllipseParams` (meaningless when ``status != 0``).
        conic: ``(a, b, c, d, e, f)`` of the conic in normalised coordinates
            ``((S_A - mean)/std, (S_B - mean)/std)``, unit norm.
        rms_radial_residual: RMS of ``|corrected phasor| - 1`` over the samples (1, relative
            to the amplitude): noise plus whatever the ellipse cannot take (harmonics,
            vibration, drift of the parameters).
        status: 0 success, 1 not an ellipse (see ``STATUS_MESSAGES``).
        method: ``"direct"`` or ``"heydemann"``.
    """

    params: EllipseParams
    conic: Array
    rms_radial_residual: Array
    status: Array
    method: str = eqx.field(static=True)

    @property
    def success(self) -> Array:
        return self.status == STATUS_OK


def _scatter(u: Array, w: Array, chunk: int) -> Array:
    """``sum d d^T`` with ``d = (u^2, uw, w^2, u, w, 1)``, accumulated over chunks (6x6)."""
    n = u.shape[0]
    nchunks = -(-n // chunk)
    pad = nchunks * chunk - n
    mask = jnp.concatenate([jnp.ones(n), jnp.zeros(pad)]).reshape(nchunks, chunk)
    up = jnp.concatenate([u, jnp.zeros(pad)]).reshape(nchunks, chunk)
    wp = jnp.concatenate([w, jnp.zeros(pad)]).reshape(nchunks, chunk)

    def one(args):
        uu, ww, mm = args
        d = jnp.stack([uu * uu, uu * ww, ww * ww, uu, ww, jnp.ones_like(uu)], axis=1)
        return (d * mm[:, None]).T @ d

    return jnp.sum(jax.lax.map(one, (up, wp, mask)), axis=0)


_C1_INV = np.array([[0.0, 0.0, 0.5], [0.0, -1.0, 0.0], [0.5, 0.0, 0.0]])


def _conic_direct(s: Array) -> Array:
    s1, s2, s3 = s[:3, :3], s[:3, 3:], s[3:, 3:]
    t = -jnp.linalg.solve(s3, s2.T)
    m = _C1_INV @ (s1 + s2 @ t)
    _, vecs = jax.lax.linalg.eig(m, compute_left_eigenvectors=False, enable_eigvec_derivs=True)[:2]
    v = jnp.real(vecs)
    cond = 4 * v[0] * v[2] - v[1] ** 2
    a1 = v[:, jnp.argmax(cond)]
    return jnp.concatenate([a1, t @ a1])


def _conic_heydemann(s: Array) -> Array:
    coef = jnp.linalg.solve(s[:5, :5], s[:5, 5])
    return jnp.concatenate([coef, -jnp.ones(1)])


def _params_from_conic(q: Array) -> tuple[Array, ...]:
    q = q / jnp.linalg.norm(q)
    q = jnp.where(q[0] < 0, -q, q)
    a, b, c, d, e, f = q
    den = 4 * a * c - b * b
    ok_den = den > 0
    den_s = jnp.where(ok_den, den, 1.0)
    x0 = (b * e - 2 * c * d) / den_s
    y0 = (b * d - 2 * a * e) / den_s
    f0 = f + 0.5 * (d * x0 + e * y0)
    ac = jnp.where(ok_den, a * c, 1.0)
    s = jnp.clip(-b / (2 * jnp.sqrt(ac)), -0.999999, 0.999999)
    k = -f0 / (1 - s * s)
    ok = ok_den & (k > 0) & (a > 0)
    k_s = jnp.where(ok, k, 1.0)
    a1 = jnp.sqrt(k_s / jnp.where(ok, a, 1.0))
    a2 = jnp.sqrt(k_s / jnp.where(ok, c, 1.0))
    status = jnp.where(ok, STATUS_OK, STATUS_NOT_ELLIPSE)
    return q, x0, y0, a1, a2, jnp.arcsin(s), status


def _fit_core(sa: Array, sb: Array, method: str, chunk: int):
    ma, mb = jnp.mean(sa), jnp.mean(sb)
    da, db = jnp.std(sa), jnp.std(sb)
    u, w = (sa - ma) / da, (sb - mb) / db
    s = _scatter(u, w, chunk)
    q = _conic_direct(s) if method == "direct" else _conic_heydemann(s)
    q, x0, y0, a1, a2, ph, status = _params_from_conic(q)
    params = EllipseParams(ma + da * x0, mb + db * y0, da * a1, db * a2, ph)
    ca, cb = correct_signals(sa, sb, params)
    rms = jnp.sqrt(jnp.mean((jnp.hypot(ca, cb) - 1.0) ** 2))
    return EllipseFit(params, q, rms, status, method)


_fit_jit = eqx.filter_jit(_fit_core)


def fit_ellipse(
    sa: SampleValues,
    sb: SampleValues,
    *,
    method: str = "direct",
    throw: bool = True,
    chunk_size: int = 16384,
) -> EllipseFit:
    """Fit the Lissajous ellipse of two quadrature signals (Heydemann parameters).

    Args:
        sa, sb: the two signals, 1-D, equal length, any consistent unit; rows in any order.
        method: ``"direct"`` (Fitzgibbon direct least squares, Halir-Flusser form; always an
            ellipse, also for short arcs) or ``"heydemann"`` (linear least squares, ``f = -1``).
        throw: raise :class:`~encdesign.EncdesignInputError` when the data do not give an
            ellipse; otherwise return the result with ``status != 0``.
        chunk_size: samples per chunk when accumulating the scatter matrix (memory bound).

    Returns:
        :class:`EllipseFit`. Differentiable with respect to the signals (float64).

    Raises:
        EncdesignInputError: mismatched lengths, fewer than 6 samples, NaN/inf, a constant
            signal, an unknown method, or (with ``throw``) no ellipse.
    """
    if method not in ("direct", "heydemann"):
        raise input_error("fit_ellipse: method", f"got {method!r}", "'direct' or 'heydemann'")
    sa, sb = check_signals(sa, sb, "fit_ellipse")
    sa, sb = _f64(sa), _f64(sb)
    chunk = int(min(chunk_size, sa.shape[0]))
    if _is_traced(sa) or _is_traced(sb):
        fit = _fit_jit(sa, sb, method, chunk)
        if throw:
            fit = eqx.error_if(fit, fit.status != STATUS_OK, STATUS_MESSAGES[STATUS_NOT_ELLIPSE])
        return fit
    fit = _fit_jit(sa, sb, method, chunk)
    if throw and int(fit.status) != STATUS_OK:
        raise input_error(
            "fit_ellipse", STATUS_MESSAGES[int(fit.status)], "signals tracing an ellipse"
        )
    return fit


def correct_signals(sa: Angles, sb: Angles, params: EllipseParams) -> tuple[Averaged, Averaged]:
    """Heydemann correction: map samples back to the unit circle.

    Returns:
        ``(sin psi, cos psi)`` estimates (unit amplitude): offsets, amplitude ratio and phase
        error removed. An ideal signal (``B = 0``, ``A_1 = A_2``, ``Phi_1 = 0``) is only rescaled.
    """
    u = (_f64(sa) - params.offset_a) / params.amplitude_a
    w = (_f64(sb) - params.offset_b) / params.amplitude_b
    sin_psi = (u - w * jnp.sin(params.phase_rad)) / jnp.cos(params.phase_rad)
    return sin_psi, w


def corrected_phase_rad(sa: Angles, sb: Angles, params: EllipseParams) -> Averaged:
    """Line phase (rad, in (-pi, pi]) from the arctangent of the corrected signals."""
    s, c = correct_signals(sa, sb, params)
    return jnp.arctan2(s, c)


def position_from_signals_m(
    sa: SampleValues,
    sb: SampleValues,
    signal_period_m: Scalar,
    params: EllipseParams | None = None,
) -> SampleValuesOut:
    """Unwrapped position ``p/(2 pi) unwrap(atan2(S_A, S_B))`` (m) along a capture in time order.

    With ``params`` the signals are Heydemann-corrected first. Samples must be close enough
    that the phase moves less than pi between them.
    """
    if params is None:
        phase = jnp.arctan2(_f64(sa), _f64(sb))
    else:
        phase = corrected_phase_rad(sa, sb, params)
    return _f64(signal_period_m) / (2 * jnp.pi) * jnp.unwrap(phase)


def vibration_compensation_m(
    t_s: ArrayLike,
    delta_gm_m: ArrayLike,
    f_exc_hz: ArrayLike,
    phase_rad: ArrayLike,
    mean_metrological_m: ArrayLike = 0.0,
) -> Array:
    """Eq. 6: ``u_vib = M_me + delta_gm/2 sin(2 pi f_exc t + phi)`` (m).

    Args:
        t_s: time (s).
        delta_gm_m: peak-to-peak relative grating displacement from the LUT (m).
        f_exc_hz: excitation frequency (Hz).
        phase_rad: phase of the vibration (rad) at ``t = 0``.
        mean_metrological_m: ``M_me``, mean of the metrological errors (m).
    """
    t = _f64(t_s)
    return _f64(mean_metrological_m) + 0.5 * _f64(delta_gm_m) * jnp.sin(
        2 * jnp.pi * _f64(f_exc_hz) * t + phase_rad
    )


def compensation_signal_m(
    t_s: ArrayLike,
    measured_line_phase_rad: ArrayLike,
    signal_period_m: ArrayLike,
    errors: SignalErrors,
    *,
    delta_gm_m: ArrayLike = 0.0,
    f_exc_hz: ArrayLike = 0.0,
    vibration_phase_rad: ArrayLike = 0.0,
) -> Array:
    """The seed's compensation signal ``S_comp = u_off + u_amp + u_ph + u_vib`` (m).

    The metrological terms are eq. 4 with the fitted ``errors``, evaluated at the measured
    line phase (the true one is unknown; the difference is second order). ``u_vib`` is eq. 6.
    ``S_comp`` models the reading error (measured minus true), so the compensated position
    is ``x_measured - S_comp``. The mean of the metrological errors, ``M_me = p Phi_1/(4 pi)``
    (only the phase term has one), is counted once: in ``u_vib`` as eq. 6 writes it, with
    ``u_ph`` taken mean-free.

    Args:
        t_s: sample times (s).
        measured_line_phase_rad: arctangent phase of the measured signals (rad, unwrapped or
            not).
        signal_period_m: signal period ``p`` (m).
        errors: fitted signal errors (e.g. ``fit.params.to_signal_errors()``).
        delta_gm_m: peak-to-peak vibration displacement from the LUT (m); 0 for none.
        f_exc_hz: excitation frequency (Hz).
        vibration_phase_rad: vibration phase ``phi`` (rad).
    """
    p = _f64(signal_period_m)
    k = p / (2 * jnp.pi)
    terms = phase_error_eq4_rad(measured_line_phase_rad, errors)
    m_me = k * errors.phase_error_rad / 2
    u_vib = vibration_compensation_m(t_s, delta_gm_m, f_exc_hz, vibration_phase_rad, m_me)
    return k * (terms.offset + terms.amplitude + terms.shape) + (k * terms.phase - m_me) + u_vib


def seed_eq7_choice(
    phase_lower_rad: float, phase_upper_rad: float, phase_error_rad: float
) -> tuple[float, int]:
    """Eq. 7 of the seed: which doublet phase to use, and the sign of the compensation.

    ``phi = min(phi_1, phi_2)`` and *add* the compensation when ``dPhi_1 < 0``;
    ``phi = max(phi_1, phi_2)`` and *subtract* it when ``dPhi_1 > 0`` (phases taken in
    [0, 2 pi)). Returns ``(phi_rad, sign)`` with ``sign = +1`` for add, ``-1`` for subtract.
    This is the seed's empirical rule; :func:`~encdesign.physics.estimate_excitation` resolves the
    half-cycle ambiguity from the phase of the signal's fundamental instead.
    """
    p1 = float(np.mod(phase_lower_rad, 2 * np.pi))
    p2 = float(np.mod(phase_upper_rad, 2 * np.pi))
    if phase_error_rad < 0:
        return min(p1, p2), +1
    return max(p1, p2), -1


class VibrationLUT(eqx.Module):
    """Look-up table of the relative grating displacement under vibration (seed Fig. 3).

    Attributes:
        frequency_hz: excitation frequencies (Hz), strictly increasing, ``(K,)``.
        delta_gm_m: peak-to-peak relative displacement of the gratings ``delta_gm`` at each
            frequency (m), ``(K,)``, for the test severity ``acceleration_m_s2``.
        acceleration_m_s2: acceleration amplitude of the shaker test (m/s^2), metadata.
    """

    frequency_hz: Array
    delta_gm_m: Array
    acceleration_m_s2: float = eqx.field(static=True, default=100.0)

    def __check_init__(self):
        f, d = self.frequency_hz, self.delta_gm_m
        if f.ndim != 1 or d.shape != f.shape or f.shape[0] < 2:
            raise input_error(
                "VibrationLUT",
                f"frequency_hz shape {f.shape}, delta_gm_m shape {d.shape}",
                "two 1-D arrays of equal length >= 2",
            )
        if not _is_traced(f) and not bool(np.all(np.diff(np.asarray(f)) > 0)):
            raise input_error("VibrationLUT.frequency_hz", "not strictly increasing")
        if not _is_traced(d) and not bool(np.all(np.isfinite(np.asarray(d)))):
            raise input_error("VibrationLUT.delta_gm_m", "non-finite value", "finite")

    def __call__(self, f_exc_hz: ArrayLike) -> Array:
        """``delta_gm`` (m, peak to peak) at ``f_exc_hz`` by linear interpolation (clamped)."""
        return jnp.interp(_f64(f_exc_hz), self.frequency_hz, self.delta_gm_m)


def build_vibration_lut(
    frequency_hz: ArrayLike,
    t_s: ArrayLike,
    arcs_sa: ArrayLike,
    arcs_sb: ArrayLike,
    params: EllipseParams,
    signal_period_m: float,
    *,
    method: str = "sine",
    acceleration_m_s2: float = 100.0,
) -> VibrationLUT:
    """Build the LUT from shaker captures at a fixed scale position (seed §3.2).

    At a fixed position, vibration turns the Lissajous point into an arc. Each arc is
    corrected with the ellipse fitted without vibration (step 1: offset, amplitude and phase
    errors removed) and the angle it covers gives the peak-to-peak relative displacement
    ``delta_gm = span p / (2 pi)``.

    Args:
        frequency_hz: ``(K,)`` excitation frequencies (Hz), increasing.
        t_s: ``(n,)`` sample times of each capture (s).
        arcs_sa, arcs_sb: ``(K, n)`` signals recorded at each frequency.
        params: ellipse of the encoder without vibration.
        signal_period_m: signal period ``p`` (m).
        method: ``"sine"`` (twice the amplitude of a least-squares sine at the shaker
            frequency fitted to the arc's phase: insensitive to noise) or ``"span"``
            (max - min of the phase, as the seed describes: biased upwards by noise).
        acceleration_m_s2: severity of the test (m/s^2), kept as metadata.

    Returns:
        :class:`VibrationLUT`; differentiable with respect to the captures.
    """
    if method not in ("sine", "span"):
        raise input_error("build_vibration_lut: method", f"got {method!r}", "'sine' or 'span'")
    sa, sb = _f64(arcs_sa), _f64(arcs_sb)
    f = _f64(frequency_hz)
    t = _f64(t_s)
    if sa.ndim != 2 or sa.shape != sb.shape or sa.shape[0] != f.shape[0]:
        raise input_error(
            "build_vibration_lut",
            f"arcs of shapes {sa.shape}, {sb.shape} for {f.shape[0]} frequencies",
            "two (K, n) arrays, one row per frequency",
        )
    if t.shape != sa.shape[1:]:
        raise input_error("build_vibration_lut: t_s", f"shape {t.shape}", f"({sa.shape[1]},)")
    for row in range(sa.shape[0]):
        check_signals(sa[row], sb[row], f"build_vibration_lut: arc {row}")
    phase = jnp.unwrap(corrected_phase_rad(sa, sb, params), axis=1)
    if method == "span":
        span = jnp.max(phase, axis=1) - jnp.min(phase, axis=1)
    else:

        def amp(ph, fk):
            w = 2 * jnp.pi * fk * t
            d = jnp.stack([jnp.ones_like(t), jnp.sin(w), jnp.cos(w)], axis=1)
            c = jnp.linalg.solve(d.T @ d, d.T @ ph)
            return jnp.hypot(c[1], c[2])

        span = 2 * jax.vmap(amp)(phase, f)
    return VibrationLUT(f, span * signal_period_m / (2 * jnp.pi), float(acceleration_m_s2))
