"""Candidate terms of one sensor read against a reference (``docs/effects.md``).

Setting: a ``multihead`` recording with one head ``h0`` (the sensor's reading, rad) and a
``theta_ref`` column (the reference angle, rad). The sensor's error is::

    e = h0 - theta_ref = f(theta) + c_r + sum(terms) + noise

with ``f`` the sensor's error function of the shaft angle (the base model: Fourier orders of
``theta_ref``), ``c_r`` one constant per run (each run re-zeroes) and the candidate terms
below. Every term is a differentiable JAX function of data arrays (``theta_ref``, the
reference velocity ``omega``, the modelled reading) and of its parameters; it returns the
additive error in rad per sample, shape ``(n,)``. No Python control flow on traced values;
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

import dataclasses
import functools
import math

import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from ..physics._quadrature import SignalErrors, phase_error_exact_rad
from ._candidates import Candidate, Context, Param

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
    "reference_velocity_rad_s",
    "velocity_width_rad_s",
    "Lattice",
    "detect_lsb",
    "reference_summary",
    "dominant_orders",
    "CANDIDATES",
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


# ----------------------------------------------------------------------------- data helpers


def reference_velocity_rad_s(
    t_s: np.ndarray, theta_ref_rad: np.ndarray, run: np.ndarray | None = None
) -> np.ndarray:
    """Reference velocity per sample (rad/s): central differences within each run.

    A run of one sample gets zero velocity. Data preparation (NumPy), not a traced term.
    """
    t = np.asarray(t_s, dtype=np.float64)
    th = np.asarray(theta_ref_rad, dtype=np.float64)
    run = np.zeros(t.size, dtype=np.int64) if run is None else np.asarray(run)
    out = np.zeros_like(th)
    for r in np.unique(run):
        idx = np.flatnonzero(run == r)
        if idx.size >= 2:
            out[idx] = np.gradient(th[idx], t[idx])
    return out


def velocity_width_rad_s(velocity_rad_s: np.ndarray, fraction: float = 0.05) -> float:
    """Smoothing width of the direction sign: ``fraction`` of the median ``|omega|`` (rad/s).

    Falls back to 1 rad/s for a record that does not move (the term is then zero anyway).
    """
    w = np.abs(np.asarray(velocity_rad_s, dtype=np.float64))
    w = w[w > 0]
    med = float(np.median(w)) if w.size else 0.0
    return fraction * med if med > 0 else 1.0


@dataclasses.dataclass(frozen=True)
class Lattice:
    """Result of :func:`detect_lsb`.

    Attributes:
        lsb_rad: the lattice step ``q`` (rad), or ``None`` when the values lie on no lattice.
        offset_rad: per-run lattice offsets ``c_r`` in ``[0, q)`` (rad), run id -> offset.
        fraction_on_lattice: share of values within ``tolerance * q`` of ``c_r + q k``.
        counts_per_turn: ``2 pi / q`` (levels per turn), ``None`` without a lattice.
        bits_per_turn: ``log2(2 pi / q)``, ``None`` without a lattice.
        n_levels: number of distinct lattice levels seen.
        single_step: every consecutive difference is one step (a stepped sweep, not
            necessarily a quantized reading).
        note: how it was decided.
    """

    lsb_rad: float | None
    offset_rad: dict[int, float]
    fraction_on_lattice: float
    counts_per_turn: float | None
    bits_per_turn: float | None
    n_levels: int
    single_step: bool
    note: str

    def as_dict(self) -> dict:
        """JSON-ready dict."""
        d = dataclasses.asdict(self)
        d["offset_rad"] = {str(k): v for k, v in self.offset_rad.items()}
        return d


def _unique_sorted(v: np.ndarray, eps: float) -> np.ndarray:
    u = np.unique(v)
    if u.size < 2:
        return u
    keep = np.concatenate([[True], np.diff(u) > eps])
    return u[keep]


def _approximate_gcd(x: np.ndarray, tol: float, max_iter: int = 200) -> float | None:
    """Largest ``g`` of which every ``x`` is an integer multiple within ``tol`` (Euclid)."""
    S = np.unique(x[x > tol])
    for _ in range(max_iter):
        if S.size == 0:
            return None
        g = float(S[0])
        r = np.mod(S, g)
        r = np.minimum(r, g - r)
        r = r[r > tol]
        if r.size == 0:
            return g
        S = np.unique(np.concatenate([[g], r]))
    return None


def detect_lsb(
    values_rad: np.ndarray,
    run: np.ndarray | None = None,
    *,
    tolerance: float = 0.1,
    max_divisor: int = 12,
    min_fraction: float = 0.99,
    min_differences: int = 20,
) -> Lattice:
    """Find the step of the value lattice of a quantized reading (rad).

    Values of one run lie on ``c_r + q k`` (integers ``k``; each run may have its own zero
    ``c_r``). The smallest gap ``d_min`` between distinct values of a run is ``q`` or a
    multiple of it: the step is the largest ``d_min / j`` (``j = 1 … max_divisor``) of which
    at least ``min_fraction`` of all gaps are integer multiples within ``tolerance * q``
    (values printed with a few digits pass). When that fails, or finds only an even sweep,
    readings computed from integer counts still sit on their lattice to rounding error: the
    step is then the approximate greatest common divisor of the gaps (Euclid's algorithm
    with an absolute tolerance of ``1e-12`` of the largest value), even when every gap is
    hundreds of steps (a fast sweep); a "step" of the size of that tolerance (continuous
    values) or over 1e4 times below the typical gap (a file's printed decimals) is refused.
    Either step is refined by least squares over the gaps. A record without a lattice
    (continuous values) fails the first test: the fractional parts of its gaps are spread
    uniformly, so only about ``2 tolerance`` of them pass. Values that step evenly by one gap
    and never repeat are a uniform sweep sampled evenly, not a quantized reading: no lattice.

    Args:
        values_rad: the readings, rad (any unwrapped angle).
        run: run id per value (``None``: one run).
        tolerance: allowed distance from the lattice, in steps (covers values printed with
            a few significant digits).
        max_divisor: largest ``j`` tried.
        min_fraction: share of gaps (and of values) that must sit on the lattice.
        min_differences: fewer distinct gaps than this: no decision (``lsb_rad = None``).

    Returns:
        A :class:`Lattice`.
    """
    v = np.asarray(values_rad, dtype=np.float64)
    run = np.zeros(v.size, dtype=np.int64) if run is None else np.asarray(run)
    scale = float(np.max(np.abs(v))) if v.size else 0.0
    eps = 64.0 * np.finfo(np.float64).eps * max(scale, 1.0)
    gaps = []
    for r in np.unique(run):
        u = _unique_sorted(v[run == r], eps)
        if u.size >= 2:
            gaps.append(np.diff(u))
    none = Lattice(None, {}, 0.0, None, None, 0, False, "")
    if not gaps or sum(g.size for g in gaps) < min_differences:
        return dataclasses.replace(
            none, note=f"fewer than {min_differences} distinct gaps between values: no decision"
        )
    d = np.concatenate(gaps)
    d_min = float(d.min())
    q = None
    # 1) a lattice seen through rounded numbers (printed with a few digits): the largest
    #    d_min / j of which the gaps are multiples within ``tolerance`` steps
    for j in range(1, max_divisor + 1):
        cand = d_min / j
        r = d / cand
        if np.mean(np.abs(r - np.round(r)) <= tolerance) >= min_fraction:
            q = cand
            break
    repeats = int(v.size) - sum(g.size + 1 for g in gaps)
    even = q is not None and bool(np.all(np.round(d / q) == 1)) and repeats == 0
    if q is None or even:
        # 2) an exact lattice (readings computed from integer counts): Euclid's algorithm on
        #    the gaps with an absolute tolerance finds a step far below the smallest gap (a
        #    fast sweep whose gaps are all ~250 LSB). Continuous values only reach a "step"
        #    of the size of the tolerance; a step over 1e4 times below the typical gap (the
        #    decimal digits a file was printed with) is not a reading's resolution either
        exact_tol = 1e-12 * max(scale, 1.0)
        g = _approximate_gcd(d, exact_tol)
        if g is not None and g > 1e3 * exact_tol and np.median(d) / g <= 1e4:
            q, tolerance = g, 10 * exact_tol / g  # tolerance in steps
    if q is None:
        return dataclasses.replace(
            none,
            note=f"gaps are not integer multiples of d_min/j (j <= {max_divisor}): no lattice",
        )
    k = np.round(d / q)
    ok = np.abs(d / q - k) <= tolerance
    q = float(np.sum(k[ok] * d[ok]) / np.sum(k[ok] ** 2))
    offsets: dict[int, float] = {}
    on = np.zeros(v.size, dtype=bool)
    levels = set()
    for r in np.unique(run):
        m = run == r
        ph = np.mod(v[m], q) / q * 2.0 * np.pi
        c = float(np.mod(np.angle(np.mean(np.exp(1j * ph))) / (2 * np.pi), 1.0) * q)
        kk = np.round((v[m] - c) / q)
        on[m] = np.abs((v[m] - c) / q - kk) <= tolerance
        levels.update((int(r), int(x)) for x in kk)
        offsets[int(r)] = c
    frac = float(np.mean(on))
    if frac < min_fraction:
        return dataclasses.replace(
            none,
            fraction_on_lattice=frac,
            note=f"gaps fit a step of {q:.6g} rad but only {frac:.1%} of the values do",
        )
    single = bool(np.all(np.round(d / q) == 1))
    repeats = int(v.size) - sum(g.size + 1 for g in gaps)
    if single and repeats == 0:
        return dataclasses.replace(
            none,
            fraction_on_lattice=frac,
            single_step=True,
            note=(
                f"consecutive values step evenly by {q:.6g} rad and none repeats: a uniform "
                "sweep sampled evenly, not a quantized reading"
            ),
        )
    cpt = 2.0 * np.pi / q
    return Lattice(
        lsb_rad=q,
        offset_rad=offsets,
        fraction_on_lattice=frac,
        counts_per_turn=float(cpt),
        bits_per_turn=float(math.log2(cpt)),
        n_levels=len(levels),
        single_step=single,
        note=(
            f"{d.size} gaps between distinct values are integer multiples of {q:.6g} rad "
            f"(smallest gap / {int(round(d_min / q))}); {frac:.1%} of the values on the lattice"
        ),
    )


def reference_summary(
    t_s: np.ndarray,
    theta_ref_rad: np.ndarray,
    reading_rad: np.ndarray,
    run: np.ndarray | None = None,
) -> dict:
    """What a sensor-against-reference record is, before any fit (JSON-ready).

    Returns a dict with ``span_turns`` (per run), ``directions`` (``forward``, ``backward``
    or ``both`` per run, from the sign of the reference velocity), ``speed_rad_s`` (median
    ``|omega|`` per run), ``sensor_lattice`` and ``reference_lattice`` (:func:`detect_lsb`,
    with ``floor_rms_rad = lsb / sqrt(12)`` when a lattice is found).
    """
    t = np.asarray(t_s, dtype=np.float64)
    th = np.asarray(theta_ref_rad, dtype=np.float64)
    rd = np.asarray(reading_rad, dtype=np.float64)
    run = np.zeros(t.size, dtype=np.int64) if run is None else np.asarray(run)
    w = reference_velocity_rad_s(t, th, run)
    span, dirs, speed = {}, {}, {}
    for r in np.unique(run):
        m = run == r
        span[str(int(r))] = float(np.ptp(th[m]) / (2 * np.pi))
        fwd, bwd = bool(np.any(w[m] > 0)), bool(np.any(w[m] < 0))
        dirs[str(int(r))] = "both" if fwd and bwd else ("forward" if fwd else "backward")
        speed[str(int(r))] = float(np.median(np.abs(w[m])))
    out = {"span_turns": span, "directions": dirs, "speed_rad_s": speed}
    for name, vals in (("sensor_lattice", rd), ("reference_lattice", th)):
        lat = detect_lsb(vals, run).as_dict()
        lat["floor_rms_rad"] = None if lat["lsb_rad"] is None else lat["lsb_rad"] / math.sqrt(12)
        out[name] = lat
    return out


def dominant_orders(
    cos_rad: np.ndarray,
    sin_rad: np.ndarray,
    se_cos_rad: np.ndarray | None = None,
    se_sin_rad: np.ndarray | None = None,
    n: int = 5,
) -> list[dict]:
    """The ``n`` largest orders of a Fourier error function ``sum a_m cos m th + b_m sin m th``.

    Returns ``[{"order", "amplitude_rad", "se_rad", "share"}, ...]`` by decreasing amplitude
    ``sqrt(a^2 + b^2)``; ``share`` is the order's part of the function's mean square
    (``amp^2 / sum amp^2``); ``se_rad`` the amplitude's standard error (linear propagation,
    ``None`` without standard errors).
    """
    a = np.asarray(cos_rad, dtype=np.float64)
    b = np.asarray(sin_rad, dtype=np.float64)
    amp = np.hypot(a, b)
    tot = float(np.sum(amp**2))
    out = []
    for i in np.argsort(amp)[::-1][:n]:
        se = None
        if se_cos_rad is not None and se_sin_rad is not None and amp[i] > 0:
            sa, sb = float(np.asarray(se_cos_rad)[i]), float(np.asarray(se_sin_rad)[i])
            se = float(np.hypot(a[i] * sa, b[i] * sb) / amp[i])
            se = se if np.isfinite(se) else None
        out.append(
            {
                "order": int(i + 1),
                "amplitude_rad": float(amp[i]),
                "se_rad": se,
                "share": float(amp[i] ** 2 / tot) if tot > 0 else 0.0,
            }
        )
    return out


# ----------------------------------------------------------------------------- candidates
# The engine's registration API (``encdesign.diagnose._candidates``): each term above as a
# :class:`Candidate` of the multihead kind, tried on a sensor against a reference.

MAX_DIRECTION_OFFSET_RAD = 0.35
"""Largest direction offset accepted as backlash or hysteresis (20 degrees), rad."""
MAX_DELAY_ANGLE_RAD = 0.35
"""Largest lag angle ``|omega| tau`` accepted as a reading delay, rad."""
MAX_SCALE = 0.1
"""Largest relative scale error accepted (10 %: beyond it the declared ratio is wrong)."""
MAX_SIGNAL_ERROR = 0.5 * math.pi
"""Largest harmonic (rad of signal phase) of an interpolation error: an arctangent reading is
off by less than a quarter period for any signal error that leaves the quadrature readable."""
FIRST_ORDER_SIGNAL_ERROR = 0.3
"""Above it (rad of signal phase) the first-order conversion of the harmonics into offsets,
amplitude ratio and phase error is approximate (second-order terms ~ c^2 / 2); the
harmonics themselves are still the fitted error."""


def _by_run(ctx: Context, name: str) -> list[np.ndarray]:
    rows = ctx.rows
    onehot = np.asarray(rows["run_onehot"])
    col = np.asarray(rows[name])
    return [col[onehot[:, r] > 0.5] for r in range(onehot.shape[1])]


def _both_directions(ctx: Context) -> bool:
    return any(d.size and d.min() < 0 < d.max() for d in _by_run(ctx, "direction"))


def _need_ref(ctx: Context) -> str | None:
    if not ctx.has_ref or ctx.n_channels != 1:
        return "only for one sensor against a reference (one head and theta_ref)"
    return None


def _hyst_fn(p: dict, x: dict) -> Array:
    return (0.5 * p["hysteresis_rad"] * x["direction"])[:, None]


def _hyst_applies(ctx: Context) -> str | None:
    why = _need_ref(ctx)
    if why:
        return why
    if not _both_directions(ctx):
        return "no run turns in both directions: a direction offset is a run constant"
    return None


def _hyst_plausible(ctx: Context, p: dict) -> str | None:
    h = abs(float(np.asarray(p["hysteresis_rad"])))
    if h > MAX_DIRECTION_OFFSET_RAD:
        return f"an offset of {h:.3g} rad between directions is not backlash or hysteresis"
    return None


def _hyst_derived(ctx: Context, p: dict, se: dict) -> dict:
    w = np.abs(np.asarray(ctx.rows["omega"], dtype=np.float64))
    if w.size == 0 or np.max(w) <= 0 or np.ptp(w) > 0.2 * np.max(w):
        return {}
    h = float(np.asarray(p["hysteresis_rad"]))
    s_h = float(np.asarray(se.get("hysteresis_rad", np.nan)))
    wm = float(np.median(w))
    return {"equivalent_delay_s": {"value": -h / (2 * wm), "se": s_h / (2 * wm), "unit": "s"}}


def _delay_fn(p: dict, x: dict) -> Array:
    return reading_delay_rad(x["omega"], p["delay_s"])[:, None]


def _delay_applies(ctx: Context) -> str | None:
    why = _need_ref(ctx)
    if why:
        return why
    runs = [np.abs(w) for w in _by_run(ctx, "omega") if w.size]
    within = any(np.ptp(w) > 0.2 * np.max(w) for w in runs if np.max(w) > 0)
    if within:
        return None
    allw = np.concatenate(runs) if runs else np.zeros(0)
    vary = allw.size > 0 and np.ptp(allw) > 0.2 * np.max(allw)
    if _both_directions(ctx):
        # at one speed in both directions a delay -omega*tau is the same column as a
        # direction offset h = -2|omega|tau: it is tried, and the engine reports the two as
        # confounded (two speeds separate them)
        del vary
        return None
    return "the speed is the same throughout every run: -omega*tau is a run constant"


def _delay_plausible(ctx: Context, p: dict) -> str | None:
    tau = abs(float(np.asarray(p["delay_s"])))
    w = float(np.max(np.abs(np.asarray(ctx.rows["omega"])))) if ctx.rows["omega"].size else 0.0
    if tau * w > MAX_DELAY_ANGLE_RAD:
        return f"a lag of {tau:.3g} s is {tau * w:.3g} rad at {w:.3g} rad/s: not a reading delay"
    return None


def _scale_fn(p: dict, x: dict) -> Array:
    # about each run's mid angle (the run constants take the rest): the term's own size is
    # then the ramp's, not s times the angle's distance from zero
    th = x["theta"] - x["run_onehot"] @ p["center_rad"]
    return scale_error_rad(th, p["scale"])[:, None]


def _scale_start(ctx: Context, residual: np.ndarray, findings: list) -> list[dict]:
    th = np.asarray(ctx.rows["theta"], dtype=np.float64)
    onehot = np.asarray(ctx.rows["run_onehot"], dtype=np.float64)
    n = np.maximum(onehot.sum(0), 1.0)
    return [{"center_rad": (onehot.T @ th) / n, "scale": np.asarray(0.0)}]


def _scale_plausible(ctx: Context, p: dict) -> str | None:
    s = abs(float(np.asarray(p["scale"])))
    if s > MAX_SCALE:
        return f"a scale error of {s:.3g} means the declared ratio is wrong, not a sensor error"
    return None


def _interp_fn(p: dict, x: dict) -> Array:
    # the sensor interpolates its own signals: their phase is P times the angle the sensor
    # sees, theta_ref plus its own error function (held: a smooth fit of the reading, so
    # neither its noise nor its quantization enters the phase), not P times the reference
    # angle: at P = 2048 an error of 1 mrad is 2 rad of phase
    P = x["signal_periods"]
    psi = P * _sensor_angle(p, x)
    c = p["coef"]
    if c.ndim == 2:  # (4, R): one set per run (a re-zeroed reading moves the signal phase)
        c = (x["run_onehot"] @ c.T).T
    e = (
        c[0] * jnp.cos(psi)
        + c[1] * jnp.sin(psi)
        + c[2] * jnp.cos(2.0 * psi)
        + c[3] * jnp.sin(2.0 * psi)
    ) / jnp.maximum(P, 1.0)
    return e[:, None]


INTERP_SMOOTH_ORDERS = 12
"""Fourier orders of the sensor's own error function in its angle (held, for the phase)."""


def _sensor_angle(p: dict, x: dict) -> Array:
    """The angle the sensor sees, ``theta + e(theta)`` (the held smooth fit; its zero per
    run is the reference's: a re-zeroed reading's offset is not a signal phase)."""
    th = x["theta"]
    return th + _smooth_basis(th, INTERP_SMOOTH_ORDERS) @ p["smooth_rad"]


def _sensor_angle_fit(ctx: Context) -> dict:
    """Least squares of ``reading - theta`` on a constant per run and orders
    ``1..INTERP_SMOOTH_ORDERS`` of ``theta`` over the kept rows: ``smooth_rad``."""
    rows = ctx.rows
    th = np.asarray(rows["theta"], dtype=np.float64)
    oh = np.asarray(rows["run_onehot"], dtype=np.float64)
    d = np.asarray(rows["reading"], dtype=np.float64)[:, 0] - th
    F = np.asarray(_smooth_basis(jnp.asarray(th), INTERP_SMOOTH_ORDERS))
    coef, *_ = np.linalg.lstsq(np.concatenate([oh, F], 1), d, rcond=None)
    R = oh.shape[1]
    return {"smooth_rad": coef[R:]}


INTERP_SPREAD_MIN = 0.1
"""Smallest eigenvalue of the mean of ``X X^T`` (``X = cos psi, sin psi, cos 2psi, sin 2psi``
over the kept rows; 0.5 for phases spread over the period) for the harmonics to be told
apart: below it the sampled phases sit on a few points of the signal period."""


def _interp_applies(ctx: Context) -> str | None:
    why = _need_ref(ctx)
    if why:
        return why
    P = int(ctx.signal_periods)
    if P < 1:
        return "signal_periods_per_rev (or grating_lines) unknown"
    th = np.asarray(ctx.rows["theta"])
    turns = float(np.sum(ctx.revolutions))
    if turns <= 0 or th.size < 8:
        return "the record does not turn"
    # each sample's signal phase is known (P times the angle the sensor sees), so orders P
    # and 2P beyond the sampling's Nyquist order are no obstacle (they alias in time, not in
    # phase); what is needed is that the sampled phases cover the signal period
    x = {k: jnp.asarray(ctx.rows[k]) for k in ("theta", "run_onehot")}
    psi = P * np.asarray(_sensor_angle(_sensor_angle_fit(ctx), x))
    X = np.stack([np.cos(psi), np.sin(psi), np.cos(2 * psi), np.sin(2 * psi)], 1)
    lam = float(np.linalg.eigvalsh(X.T @ X / psi.size)[0])
    if lam < INTERP_SPREAD_MIN:
        return (
            f"the sampled signal phases sit on a few points of the period (smallest "
            f"eigenvalue {lam:.3f} of the harmonics' mean square, needs {INTERP_SPREAD_MIN})"
        )
    return None


def _interp_start(ctx: Context, residual: np.ndarray, findings: list) -> list[dict]:
    """The angle the sensor sees, held (:func:`_sensor_angle_fit`): the signal phase is then
    ``P`` times the reference angle plus the sensor's own error function."""
    return [_sensor_angle_fit(ctx)]


def _interp_plausible(ctx: Context, p: dict) -> str | None:
    c = np.abs(np.asarray(p["coef"], dtype=np.float64))
    if np.max(c) > MAX_SIGNAL_ERROR:
        return (
            f"a harmonic of {np.max(c):.3g} rad of signal phase is beyond what an arctangent "
            "interpolation of readable signals gives"
        )
    return None


def _interp_derived(ctx: Context, p: dict, se: dict) -> dict:
    c = np.asarray(p["coef"], dtype=np.float64)
    s = np.asarray(se.get("coef", np.full(c.shape, np.nan)), dtype=np.float64)
    if c.ndim == 2:  # one set per run: the signal errors at run 0's zero of the reference
        c, s = c[:, 0], s.reshape(c.shape)[:, 0]
    v = interpolation_params_from_harmonics(c)
    err = {"offset_a": s[0], "offset_b": s[1], "amplitude_ratio": 2 * s[3]}
    err["phase_error_rad"] = 2 * s[2]
    units = REFERENCE_PARAM_UNITS["interpolation_error"]
    out = {k: {"value": v[k], "se": float(err[k]), "unit": units[k]} for k in v}
    P = int(ctx.signal_periods)
    out["orders"] = {"value": [P, 2 * P], "se": None, "unit": "1"}
    big = float(np.max(np.abs(c)))
    if big > FIRST_ORDER_SIGNAL_ERROR:
        out["first_order_note"] = {
            "value": big,
            "se": None,
            "unit": "rad",
            "note": f"a harmonic of {big:.3g} rad of signal phase: beyond first order, the "
            "offsets, amplitude ratio and phase error are approximate (the fitted harmonics "
            "at orders P and 2P are not)",
        }
    return out


QUANT_SMOOTH_ORDERS = 48
"""Fourier orders of the smooth (unquantized) reading the quantization term rebuilds."""
QUANT_POLY_DEGREE = 8
"""Degree of the per-run Legendre polynomials in the angle (part of a turn, drifts)."""


def _smooth_basis(theta: Array, n_orders: int) -> Array:
    m = jnp.arange(1, n_orders + 1, dtype=jnp.float64)
    arg = theta[:, None] * m[None, :]
    return jnp.concatenate([jnp.cos(arg), jnp.sin(arg)], axis=1)


def _legendre(u: Array, degree: int) -> Array:
    """``P_0 … P_degree`` at ``u`` (Bonnet's recursion), shape ``(n, degree + 1)``."""
    out = [jnp.ones_like(u), u]
    for k in range(1, degree):
        out.append(((2 * k + 1) * u * out[k] - k * out[k - 1]) / (k + 1))
    return jnp.stack(out[: degree + 1], axis=1)


def _poly_basis(theta: Array, onehot: Array, mid: Array, half: Array) -> Array:
    """Per-run Legendre polynomials of the angle scaled to ``[-1, 1]`` over the run,
    shape ``(n, R * (degree + 1))`` (run-major)."""
    u = (theta - onehot @ mid) / (onehot @ half)
    L = _legendre(u, QUANT_POLY_DEGREE)
    return (onehot[:, :, None] * L[:, None, :]).reshape(theta.shape[0], -1)


_POLY = tuple(f"poly{k}_rad" for k in range(QUANT_POLY_DEGREE + 1))


def _quant_smooth(p: dict, x: dict) -> Array:
    th = x["theta"]
    oh = x["run_onehot"]
    poly = jnp.stack([p[k] for k in _POLY], axis=1)  # (R, degree + 1)
    return (
        th
        + _smooth_basis(th, QUANT_SMOOTH_ORDERS) @ p["smooth_rad"]
        + _poly_basis(th, oh, p["run_mid_rad"], p["run_half_rad"]) @ poly.ravel()
    )


def _quant_fn(p: dict, x: dict) -> Array:
    off = x["run_onehot"] @ p["lattice_offset_rad"]
    e = quantization_rad(_quant_smooth(p, x), p["lsb_rad"], off, p["blur_rad"])
    return (p["amplitude"] * e)[:, None]


def _quant_lattice(ctx: Context) -> Lattice:
    rows = ctx.rows
    run = np.argmax(np.asarray(rows["run_onehot"]), axis=1)
    return detect_lsb(np.asarray(rows["reading"])[:, 0], run)


def _quant_applies(ctx: Context) -> str | None:
    why = _need_ref(ctx)
    if why:
        return why
    lat = _quant_lattice(ctx)
    if lat.lsb_rad is None:
        return f"the readings lie on no value lattice ({lat.note})"
    return None


def _quant_start(ctx: Context, residual: np.ndarray, findings: list) -> list[dict]:
    """Rebuild the unquantized reading as a smooth least-squares fit of the reading itself
    (``QUANT_SMOOTH_ORDERS`` Fourier orders of the angle and per-run Legendre polynomials of
    degree ``QUANT_POLY_DEGREE``, for part of a turn; the staircase, about white, averages
    out), take the lattice of the readings, and pick the blur (noise ahead of the quantizer)
    on a grid ``0 … q`` by least squares of the engine's residual on the staircase."""
    rows = ctx.rows
    lat = _quant_lattice(ctx)
    q = float(lat.lsb_rad)
    th = np.asarray(rows["theta"], dtype=np.float64)
    onehot = np.asarray(rows["run_onehot"], dtype=np.float64)
    reading = np.asarray(rows["reading"], dtype=np.float64)[:, 0]
    n_runs = onehot.shape[1]
    lo, hi = np.zeros(n_runs), np.ones(n_runs)
    for r in range(n_runs):
        m = onehot[:, r] > 0.5
        if m.sum() > 1:
            lo[r], hi[r] = th[m].min(), th[m].max()
    mid, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), 1e-9)
    F = np.asarray(_smooth_basis(jnp.asarray(th), QUANT_SMOOTH_ORDERS))
    Pb = np.asarray(_poly_basis(*(jnp.asarray(v) for v in (th, onehot, mid, half))))
    coef, *_ = np.linalg.lstsq(np.concatenate([F, Pb], 1), reading - th, rcond=None)
    nf = 2 * QUANT_SMOOTH_ORDERS
    poly = coef[nf:].reshape(n_runs, QUANT_POLY_DEGREE + 1)
    p0 = {
        "lsb_rad": np.asarray(q),
        "lattice_offset_rad": np.array([lat.offset_rad.get(r, 0.0) for r in range(n_runs)]),
        "smooth_rad": coef[:nf],
        "run_mid_rad": mid,
        "run_half_rad": half,
        "blur_rad": np.asarray(0.0),
        "amplitude": np.asarray(1.0),
    }
    p0.update({k: poly[:, i] for i, k in enumerate(_POLY)})
    x = {k: jnp.asarray(v) for k, v in rows.items()}
    r = np.asarray(residual, dtype=np.float64).reshape(reading.size, -1)[:, 0]
    best = (np.inf, 0.0)
    for b in np.linspace(0.0, 1.0, 21) * q:
        col = np.asarray(_quant_fn({**p0, "blur_rad": np.asarray(b)}, x))[:, 0]
        a = float(col @ r / max(col @ col, 1e-300))
        sse = float(np.sum((r - a * col) ** 2))
        if sse < best[0]:
            best = (sse, b)
    p0["blur_rad"] = np.asarray(best[1])
    return [p0]


def _quant_plausible(ctx: Context, p: dict) -> str | None:
    a = float(np.asarray(p["amplitude"]))
    if not 0.7 <= a <= 1.3:
        return (
            f"the staircase of the detected step explains the residual with an amplitude of "
            f"{a:.2f}, not 1: the residual is not the quantization"
        )
    return None


def _quant_derived(ctx: Context, p: dict, se: dict) -> dict:
    q = float(np.asarray(p["lsb_rad"]))
    cpt = 2 * np.pi / q
    return {
        "lsb_rad": {"value": q, "se": 0.0, "unit": "rad"},
        "counts_per_turn": {"value": cpt, "se": 0.0, "unit": "1"},
        "bits_per_turn": {"value": float(np.log2(cpt)), "se": 0.0, "unit": "bit"},
        "floor_rms_rad": {"value": q / np.sqrt(12.0), "se": 0.0, "unit": "rad"},
    }


def _candidates() -> tuple:
    hyst = Candidate(
        name="direction_hysteresis",
        fn=_hyst_fn,
        params=(
            Param(
                "hysteresis_rad",
                "rad",
                scale=1e-3,
                description="reading offset forward minus backward",
            ),
        ),
        signature=("direction",),
        explanation=(
            "the error profile moves by a constant when the direction of rotation reverses "
            "(backlash in the coupling or drive, magnetic hysteresis of the sensor); at one "
            "speed it is also what a reading delay tau = -h / (2|omega|) gives "
            "(equivalent_delay_s)"
        ),
        applies=_hyst_applies,
        plausible=_hyst_plausible,
        derived=_hyst_derived,
    )
    delay = Candidate(
        name="reading_delay",
        fn=_delay_fn,
        params=(
            Param("delay_s", "s", scale=1e-4, description="lag of the sensor behind the reference"),
        ),
        signature=("speed", "direction"),
        explanation=(
            "a time lag between sensor and reference (filtering, latency): an error "
            "-omega*tau that grows with speed and flips with direction; at one speed in both "
            "directions it equals a direction offset h = -2|omega|tau"
        ),
        applies=_delay_applies,
        plausible=_delay_plausible,
    )
    scale = Candidate(
        name="scale_error",
        fn=_scale_fn,
        params=(
            Param("scale", "1", scale=1e-4, description="sensor turns per reference turn - 1"),
            Param(
                "center_rad",
                "rad",
                shape="runs",
                linear=False,
                fit=False,
                description="mid angle of each run (held)",
            ),
        ),
        signature=("angle_trend",),
        explanation=(
            "the sensor advances (1 + s) turns per reference turn (gear ratio, counts per "
            "turn, a stepper's steps): an error growing linearly with the reference angle"
        ),
        applies=_need_ref,
        start=_scale_start,
        plausible=_scale_plausible,
    )
    interp = Candidate(
        name="interpolation_error",
        fn=_interp_fn,
        params=(
            Param(
                "coef",
                "rad",
                shape=(4,),
                scale=1e-3,
                description="(c1, s1, c2, s2) of the signal phase at orders P and 2P",
            ),
            Param(
                "smooth_rad",
                "rad",
                shape=(2 * INTERP_SMOOTH_ORDERS,),
                linear=False,
                fit=False,
                description="the sensor's own error function, for its signal phase (held)",
            ),
        ),
        signature=("orders", "spectrum", "line_phase"),
        explanation=(
            "offsets, amplitude mismatch and phase error of the sensor's own sin/cos signals "
            "(signal_periods_per_rev periods per turn) give orders P and 2P of the shaft"
        ),
        applies=_interp_applies,
        start=_interp_start,
        plausible=_interp_plausible,
        derived=_interp_derived,
    )
    quant = Candidate(
        name="quantization",
        fn=_quant_fn,
        params=(
            # held at their start values (found from the data); they enter nonlinearly
            Param(
                "lsb_rad",
                "rad",
                linear=False,
                fit=False,
                description="step of the value lattice (LSB)",
            ),
            Param("lattice_offset_rad", "rad", shape="runs", linear=False, fit=False),
            Param("smooth_rad", "rad", shape=(2 * QUANT_SMOOTH_ORDERS,), linear=False, fit=False),
            *(
                Param(k, "rad", shape="runs", linear=False, fit=False, description="smooth")
                for k in _POLY
            ),
            Param("run_mid_rad", "rad", shape="runs", linear=False, fit=False),
            Param("run_half_rad", "rad", shape="runs", linear=False, fit=False),
            Param(
                "blur_rad",
                "rad",
                linear=False,
                fit=False,
                description="noise ahead of the quantizer",
            ),
            Param("amplitude", "1", scale=1.0, description="1 when the staircase explains it"),
        ),
        signature=("floor", "spectrum", "time", "orders"),
        explanation=(
            "a reading of finite resolution: a staircase of one LSB on the value lattice of "
            "the readings, a uniform error of +-LSB/2 (RMS LSB/sqrt(12)), blurred by the "
            "noise ahead of the quantizer"
        ),
        applies=_quant_applies,
        start=_quant_start,
        plausible=_quant_plausible,
        derived=_quant_derived,
    )
    return (hyst, delay, scale, interp, quant)


CANDIDATES = _candidates()
"""The sensor-against-reference candidates, for the engine (multihead kind, one head)."""


@functools.lru_cache(maxsize=8)
def interpolation_candidate(n_runs: int) -> Candidate:
    """``interpolation_error`` with one coefficient set per run (``coef`` of shape
    ``(4, R)``): a reading re-zeroed by any amount between runs moves its signal phase by
    ``P`` times that amount, so the harmonics keep their sizes but not their phases; one run:
    the catalog's candidate."""
    base = next(c for c in CANDIDATES if c.name == "interpolation_error")
    if n_runs <= 1:
        return base
    q, *rest = base.params
    per_run = dataclasses.replace(q, shape=(4, int(n_runs)))
    return dataclasses.replace(base, params=(per_run, *rest))
