"""Vibration of the head relative to the scale, seen in the quadrature signals (seed 002 §2.2).

While the scale moves at speed ``v`` (line frequency ``f = v/p``), a structural vibration at
``f_exc`` adds a relative displacement ``w(t)`` of head and scale. The encoder registers it
as position, so the reading error gains a component at ``f_exc``. In the signals, to first
order ``S_A(x + w) ~ S_A(x) + S_A'(x) w``: the vibration term is modulated by the derivative
of the signal (largest where the gratings half overlap, zero at full or no illumination,
changing sign at each extreme of light). Its spectrum is therefore the doublet
``f_exc +- f`` rather than a line at ``f_exc``.

Seed eq. 5 writes the same thing phenomenologically for the photodetector signal::

    S_0,vib = S_0 + (-1)^i delta | sinc(sin(1/2 (2 pi f_exc t + phi))) cos(2 pi f t) |

on the half periods ``(2i-1) T/4 < t <= (2i+1) T/4``. Because the normalised sinc of a value
in [-1, 1] is non-negative and ``cos(2 pi f t)`` has the sign ``(-1)^i`` on those intervals, the
sign-switched absolute value equals ``delta sinc(sin(theta/2)) cos(2 pi f t)``
(``theta = 2 pi f_exc t + phi``): a pulse train at ``f_exc`` (values 0 ... 1, the ``1/2``
undoes the frequency doubling of ``sinc``) times the signal's derivative.

Both forms are here: a :class:`Vibration` displacement (``"sine"``, the physical relative
oscillation, or ``"sinc"``, eq. 5's pulse shape) applied to eq. 1 exactly, and the additive
eq. 5 term. :func:`estimate_excitation` finds ``f``, ``f_exc`` and the vibration phase from
one signal without an accelerometer: it searches the pair of spectral lines symmetric about
``f_exc`` at distance ``f`` and refines all frequencies by least squares.
"""

from __future__ import annotations

import dataclasses
from typing import Any, cast

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike
from scipy.optimize import minimize_scalar

from .._array import f64 as _f64
from .._array import is_traced as _is_traced
from .._errors import input_error
from ._quadrature import SignalErrors, check_signals, quadrature_signals


def _argmin(res: object) -> float:
    """The minimiser ``x`` of a :func:`scipy.optimize.minimize_scalar` result."""
    return float(cast(Any, res).x)


__all__ = [
    "Vibration",
    "vibrating_signals",
    "eq5_signal_terms",
    "vibration_error_rad",
    "signal_spectrum",
    "ExcitationEstimate",
    "estimate_excitation",
]

_SHAPES = ("sine", "sinc")


class Vibration(eqx.Module):
    """Relative head/scale oscillation at one structural frequency.

    Attributes:
        amplitude_m: amplitude of the relative displacement (m): zero-to-peak for
            ``"sine"``, the pulse height for ``"sinc"``. For a rotary head divide by the
            optical radius to get rad.
        frequency_hz: excitation frequency ``f_exc`` (Hz, >= 0).
        phase_rad: phase ``phi`` at ``t = 0`` (rad).
        shape: ``"sine"`` (``a sin(theta)``) or ``"sinc"`` (eq. 5: ``a sinc(sin(theta/2))``,
            between 0 and ``a``), ``theta = 2 pi f_exc t + phi``.
    """

    amplitude_m: Array
    frequency_hz: Array
    phase_rad: Array
    shape: str = eqx.field(static=True)

    def __init__(self, amplitude_m, frequency_hz, phase_rad=0.0, shape: str = "sine"):
        self.amplitude_m = _f64(amplitude_m)
        self.frequency_hz = _f64(frequency_hz)
        self.phase_rad = _f64(phase_rad)
        self.shape = shape

    def __check_init__(self):
        if self.shape not in _SHAPES:
            raise input_error("Vibration.shape", f"got {self.shape!r}", f"one of {_SHAPES}")
        f = self.frequency_hz
        if not _is_traced(f) and bool(np.any(~(np.asarray(f) >= 0))):
            raise input_error("Vibration.frequency_hz", f"got {np.asarray(f)!r}", ">= 0 Hz")

    def displacement_m(self, t_s: ArrayLike) -> Array:
        """Relative displacement ``w(t)`` (m) at times ``t_s`` (s)."""
        theta = 2 * jnp.pi * self.frequency_hz * _f64(t_s) + self.phase_rad
        if self.shape == "sine":
            return self.amplitude_m * jnp.sin(theta)
        return self.amplitude_m * jnp.sinc(jnp.sin(0.5 * theta))


def vibrating_signals(
    t_s: ArrayLike,
    speed_m_s: ArrayLike,
    signal_period_m: ArrayLike,
    errors: SignalErrors,
    vibration: Vibration | None = None,
    *,
    x0_m: ArrayLike = 0.0,
    amplitude: ArrayLike = 1.0,
    noise_std: ArrayLike = 0.0,
    key=None,
) -> tuple[Array, Array]:
    """Signals (eq. 1) of a scale moving at constant speed while the head vibrates.

    The head reads position ``x(t) = x0 + v t + w(t)``; the nominal position is ``x0 + v t``,
    so ``w`` ends up as reading error.

    Args:
        t_s: sample times (s).
        speed_m_s: scale speed ``v`` (m/s); line frequency ``f = v / p``.
        signal_period_m: signal period ``p`` (m).
        errors: signal imperfections.
        vibration: the relative oscillation (``None``: none).
        x0_m: position at ``t = 0`` (m).
        amplitude: nominal signal amplitude (signal units).
        noise_std: white noise std (signal units); needs ``key``.
        key: ``jax.random`` key.

    Returns:
        ``(S_A, S_B)`` (signal units).
    """
    import jax

    t = _f64(t_s)
    x = x0_m + _f64(speed_m_s) * t
    if vibration is not None:
        x = x + vibration.displacement_m(t)
    psi = 2 * jnp.pi * x / _f64(signal_period_m)
    sa, sb = quadrature_signals(psi, errors, amplitude)
    if key is None:
        if not _is_traced(noise_std) and float(np.max(np.asarray(noise_std))) > 0:
            raise input_error("vibrating_signals", "noise_std > 0 but no key", "a jax.random key")
        return sa, sb
    ka, kb = jax.random.split(key)
    return (
        sa + noise_std * jax.random.normal(ka, sa.shape),
        sb + noise_std * jax.random.normal(kb, sb.shape),
    )


def eq5_signal_terms(
    t_s: ArrayLike,
    line_phase_rad: ArrayLike,
    delta: ArrayLike,
    frequency_hz: ArrayLike,
    phase_rad: ArrayLike = 0.0,
) -> tuple[Array, Array]:
    """Additive vibration terms of eq. 5 for ``S_A = sin psi`` and ``S_B = cos psi``.

    ``dS_A = delta m(t) cos psi`` and ``dS_B = -delta m(t) sin psi`` with the pulse train
    ``m(t) = sinc(sin(theta/2))`` (normalised sinc, 0 ... 1), ``theta = 2 pi f_exc t + phi``.
    ``delta`` is in signal units; ``delta/A`` is the phase excursion (rad) it amounts to.
    """
    theta = 2 * jnp.pi * _f64(frequency_hz) * _f64(t_s) + phase_rad
    m = _f64(delta) * jnp.sinc(jnp.sin(0.5 * theta))
    psi = _f64(line_phase_rad)
    return m * jnp.cos(psi), -m * jnp.sin(psi)


def vibration_error_rad(
    time_s: ArrayLike, amplitude_rad: ArrayLike, frequency_hz: ArrayLike, phase_rad: ArrayLike
) -> Array:
    """Catalog effect ``vibration`` on an angle reading: ``a sin(2 pi f t + phi)`` (rad)."""
    return _f64(amplitude_rad) * jnp.sin(2 * jnp.pi * _f64(frequency_hz) * _f64(time_s) + phase_rad)


def _check_time(t_s, n: int, where: str) -> tuple[np.ndarray, float]:
    t = np.asarray(t_s, dtype=np.float64)
    if t.ndim != 1 or t.shape[0] != n:
        raise input_error(f"{where}: t_s", f"shape {t.shape}", f"a 1-D array of {n} times (s)")
    if not np.all(np.isfinite(t)):
        raise input_error(f"{where}: t_s", "non-finite time", "finite")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0])
        raise input_error(f"{where}: t_s[{i + 1}]", "time not increasing", "increasing times")
    step = float(np.mean(dt))
    if np.max(np.abs(dt - step)) > 1e-3 * step:
        raise input_error(f"{where}: t_s", "non-uniform sampling", "uniform sampling")
    return t, step


def signal_spectrum(t_s: ArrayLike, s: ArrayLike, pad: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """One-sided amplitude spectrum (Hann window, zero-padded ``pad`` times) of ``s(t)``.

    Returns:
        ``(freq_hz, amplitude)``: a pure sine of amplitude ``a`` shows a peak close to ``a``
        (signal units). NumPy, not differentiable.
    """
    x = np.asarray(s, dtype=np.float64)
    t, dt = _check_time(t_s, x.shape[0], "signal_spectrum")
    n = x.shape[0]
    win = np.hanning(n)
    nfft = int(2 ** np.ceil(np.log2(pad * n)))
    spec = np.abs(np.fft.rfft((x - x.mean()) * win, nfft)) * 2 / win.sum()
    return np.fft.rfftfreq(nfft, dt), spec


@dataclasses.dataclass(frozen=True)
class ExcitationEstimate:
    """Vibration parameters found in one signal (:func:`estimate_excitation`).

    Attributes:
        f_signal_hz: line frequency ``f`` (Hz), the signal's fundamental.
        f_exc_hz: excitation frequency (Hz), centre of the doublet.
        f_lower_hz, f_upper_hz: the doublet lines ``f_exc - f`` and ``f_exc + f`` (Hz).
        phase_lower_rad, phase_upper_rad: sine phases of the doublet lines at ``t = 0`` (rad).
        signal_phase_rad: sine phase of the fundamental at ``t = 0`` (rad).
        vibration_phase_rad: phase ``phi`` of the displacement ``sin(2 pi f_exc t + phi)``
            (rad), from ``phase_upper - signal_phase`` and ``phase_lower + signal_phase``.
        phase_amplitude_rad: vibration amplitude in line phase (rad) from the doublet
            (sum of the two line amplitudes over the fundamental's); times ``p/(2 pi)`` is m.
        snr: weaker doublet line over the noise of its amplitude estimate.
        status: 0 success, 1 no doublet above the noise (snr < ``min_snr``).
    """

    f_signal_hz: float
    f_exc_hz: float
    f_lower_hz: float
    f_upper_hz: float
    phase_lower_rad: float
    phase_upper_rad: float
    signal_phase_rad: float
    vibration_phase_rad: float
    phase_amplitude_rad: float
    snr: float
    status: int

    @property
    def success(self) -> bool:
        return self.status == 0


def _lsq(t: np.ndarray, x: np.ndarray, freqs) -> tuple[np.ndarray, float]:
    cols = [np.ones_like(t)]
    for f in freqs:
        w = 2 * np.pi * f * t
        cols += [np.sin(w), np.cos(w)]
    d = np.stack(cols, axis=1)
    c, *_ = np.linalg.lstsq(d, x, rcond=None)
    r = x - d @ c
    return c, float(r @ r)


def _refine(t, x, freqs, idx, width):
    def cost(f):
        fr = list(freqs)
        fr[idx] = f
        return _lsq(t, x, fr)[1]

    f0 = freqs[idx]
    res = minimize_scalar(
        cost, bounds=(f0 - width, f0 + width), method="bounded", options={"xatol": 1e-6 * f0}
    )
    return _argmin(res)


def estimate_excitation(
    t_s: ArrayLike,
    sa: ArrayLike,
    *,
    f_exc_range_hz: tuple[float, float] | None = None,
    min_snr: float = 5.0,
    refine: bool = True,
    throw: bool = True,
) -> ExcitationEstimate:
    """Find the line frequency, the excitation frequency and the vibration phase from ``S_A``.

    Accelerometer-free (seed §3.2, step 4): the fundamental ``f`` is the largest spectral
    peak; after removing it, ``f_exc`` maximises the weaker of the two lines at
    ``f_exc -+ f`` (the doublet). ``f``, then ``f_exc``, are refined by least squares on
    the time signal, and the line phases come from the same fit. The vibration phase is
    made unambiguous with the fundamental's phase (see :class:`ExcitationEstimate`) instead
    of the seed's eq. 7 rule (:func:`~encdesign.physics.seed_eq7_choice`).

    Args:
        t_s: uniform sample times (s).
        sa: one quadrature signal (signal units).
        f_exc_range_hz: search range for ``f_exc`` (Hz); default ``(f + 2/T, fs/2 - f)``.
        min_snr: weakest doublet line over its amplitude noise for ``status = 0``.
        refine: refine the frequencies by least squares; ``False`` keeps the FFT bins of
            the peaks (resolution ``1/T``, as in the seed, whose residual error it explains).
        throw: raise :class:`~encdesign.EncdesignInputError` when no doublet is found.

    Returns:
        :class:`ExcitationEstimate`. NumPy/SciPy, not differentiable (a peak search).
    """
    x, _ = check_signals(sa, sa, "estimate_excitation", min_points=16)
    t, dt = _check_time(t_s, x.shape[0], "estimate_excitation")
    n = x.shape[0]
    duration = n * dt
    x = x - x.mean()
    freq, spec = signal_spectrum(t, x, pad=4 if refine else 1)
    lo_bin = int(np.searchsorted(freq, 2.0 / duration))
    f1 = float(freq[lo_bin + int(np.argmax(spec[lo_bin:]))])
    if refine:
        f1 = _refine(t, x, [f1], 0, 1.0 / duration)
    c, _ = _lsq(t, x, [f1])
    w = 2 * np.pi * f1 * t
    resid = x - (c[0] + c[1] * np.sin(w) + c[2] * np.cos(w))
    _, rspec = signal_spectrum(t, resid, pad=4 if refine else 1)
    lo, hi = f_exc_range_hz if f_exc_range_hz is not None else (0.0, np.inf)
    lo = max(lo, f1 + 2.0 / duration)
    hi = min(hi, freq[-1] - f1)
    cand = freq[(freq >= lo) & (freq <= hi)]
    if cand.size == 0:
        raise input_error(
            "estimate_excitation: f_exc_range_hz",
            f"no frequency between {lo:.6g} and {hi:.6g} Hz to search",
            "a range above the line frequency and below Nyquist minus it",
        )
    score = np.minimum(np.interp(cand - f1, freq, rspec), np.interp(cand + f1, freq, rspec))
    fe = float(cand[int(np.argmax(score))])
    width = 1.0 / duration
    for _ in range(2 if refine else 0):

        def cost(fe_, f1_=f1):
            return _lsq(t, x, [f1_, fe_ - f1_, fe_ + f1_])[1]

        fe = _argmin(
            minimize_scalar(
                cost, bounds=(fe - width, fe + width), method="bounded", options={"xatol": 1e-7}
            )
        )

        def cost1(f1_, fe_=fe):
            return _lsq(t, x, [f1_, fe_ - f1_, fe_ + f1_])[1]

        f1 = _argmin(
            minimize_scalar(
                cost1, bounds=(f1 - width, f1 + width), method="bounded", options={"xatol": 1e-7}
            )
        )
    freqs = [f1, fe - f1, fe + f1]
    c, rss = _lsq(t, x, freqs)
    amp = [float(np.hypot(c[1 + 2 * k], c[2 + 2 * k])) for k in range(3)]
    ph = [float(np.arctan2(c[2 + 2 * k], c[1 + 2 * k])) for k in range(3)]
    sigma = np.sqrt(rss / max(n - 7, 1))
    snr = min(amp[1], amp[2]) / (sigma * np.sqrt(2.0 / n))
    z = np.exp(1j * (ph[2] - ph[0])) + np.exp(1j * (ph[1] + ph[0]))
    status = 0 if snr >= min_snr else 1
    if throw and status:
        raise input_error(
            "estimate_excitation",
            f"no vibration doublet above the noise (snr {snr:.3g} < {min_snr})",
            "a signal with a vibration doublet at f_exc -+ f",
        )
    return ExcitationEstimate(
        f_signal_hz=f1,
        f_exc_hz=fe,
        f_lower_hz=fe - f1,
        f_upper_hz=fe + f1,
        phase_lower_rad=ph[1],
        phase_upper_rad=ph[2],
        signal_phase_rad=ph[0],
        vibration_phase_rad=float(np.angle(z)),
        phase_amplitude_rad=(amp[1] + amp[2]) / amp[0],
        snr=float(snr),
        status=status,
    )
