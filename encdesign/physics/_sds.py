"""Shifted-delta-sum (SDS) timing instrument: disks, marks, sensors, edge times, measurement.

The instrument of seed ``001_…`` (Mikkelson): two disks with ``marks_per_rev`` marks each
turn together on one shaft (:class:`~encdesign.Motor`). Disk A is read by *fixed* sensors
on the base, disk B by *moving* sensors on the platform whose angle φ is measured.

Conventions (all angles in rad, times in s):

* The shaft angle θ(t) increases counter-clockwise (``θ(0) = 0``).
* Mark ``j`` of a disk (counted from the index mark: mark 0 is the first mark after the
  index) sits at the *mark angle* ``μ_j = index_angle + 2πj/N + err(j)``: the shaft angle
  at which it passes a sensor at azimuth 0. A sensor at azimuth ψ sees mark j when
  ``θ(t) = ψ + μ_j + 2πr`` (revolution r). ``err(j)`` holds the effective mark errors:
  Fourier orders 1 (eccentricity), 2 (ellipticity), higher orders, and a random part.
* Moving sensor m sits at azimuth ``ψ_m + φ``; φ > 0 delays its edges (seed eq. 1).

Measurement (seed eqs. 10–24): every sensor contributes the N consecutive edges (one per
mark) that follow a common start time, the mark-0 edge of fixed sensor 0. For fixed sensor
f (times α_j, revolution time T from its first edge to the same mark one turn later) and
moving sensor m (times τ_j), with k = pos(B_0) − pos(A_0) the difference of the positions
of the two mark-0 edges in their time-ordered windows,

    S_k(φ) = (2π/T) Σ_j (τ_j − α_j),    φ = S_k/N + 2πk/N − S_0(0)/N,

with the constant ``S_0(0)/N = ψ_m − ψ_f + mean(μ^B) − mean(μ^A)`` (design zero). The
result is exact for constant speed and any mark errors; it is averaged over all F × M
pairs and over ``revs_per_reading`` revolutions.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._array import wrap_rad as _wrap
from .._errors import input_error
from ._motor import Motor, time_at_angle
from ._sds_errors import ARCSEC, SDSErrors, bearing_noise
from ._types import (
    Angles,
    ArrayInput,
    Averaged,
    FixedEdgeTimes,
    FixedValues,
    MarkAngles,
    MovingEdgeTimes,
    MovingValues,
    PairAngles,
    PairOffsets,
)

__all__ = [
    "DiskMarks",
    "SDSDesign",
    "SDSReadings",
    "edge_times",
    "equally_spaced",
    "mark_angles",
    "perfect_disk",
    "reference_design",
    "reference_disk",
    "reference_errors",
    "reference_motor",
    "sds_from_edges",
    "sds_phi_error",
    "sds_residual",
    "simulate_readings",
    "validate_design",
]


def _f(x: ArrayInput) -> Array:
    return jnp.asarray(x, dtype=float)


class DiskMarks(eqx.Module):
    """Marks of one disk, with effective mark errors.

    Attributes:
        marks_per_rev: N, edges per revolution (static; 10,000 for 2,500 lines in quadrature).
        harmonic_cos_rad, harmonic_sin_rad: mark-error Fourier coefficients of orders
            1…H in the nominal mark angle ``2πj/N`` (order 1 = eccentricity e/R, order 2 =
            ellipticity), rad.
        random_rad: per-mark random error, rad, shape (N,).
        index_angle_rad: mark angle of mark 0 (where the index sits), rad.
    """

    marks_per_rev: int = eqx.field(static=True)
    harmonic_cos_rad: Array = eqx.field(converter=_f)
    harmonic_sin_rad: Array = eqx.field(converter=_f)
    random_rad: Array = eqx.field(converter=_f)
    index_angle_rad: Array = eqx.field(default=0.0, converter=_f)

    def __check_init__(self):
        n = self.marks_per_rev
        if isinstance(n, bool) or not isinstance(n, int) or n < 2:
            raise input_error("DiskMarks.marks_per_rev", f"got {n!r}", "an integer >= 2")
        if self.harmonic_cos_rad.ndim != 1 or (
            self.harmonic_cos_rad.shape != self.harmonic_sin_rad.shape
        ):
            raise input_error(
                "DiskMarks.harmonic_*_rad",
                f"shapes {self.harmonic_cos_rad.shape}, {self.harmonic_sin_rad.shape}",
                "two 1-D arrays of one length (orders 1…H)",
            )
        if self.random_rad.shape != (n,):
            raise input_error(
                "DiskMarks.random_rad", f"shape {self.random_rad.shape}", f"shape ({n},)"
            )


def perfect_disk(marks_per_rev: int, n_harmonics: int = 2) -> DiskMarks:
    """A disk without mark errors."""
    return DiskMarks(
        marks_per_rev, jnp.zeros(n_harmonics), jnp.zeros(n_harmonics), jnp.zeros(marks_per_rev)
    )


def mark_angles(disk: DiskMarks) -> MarkAngles:
    """Mark angles μ_j (rad) of marks 0…N−1, counted from the index (see module doc)."""
    n = disk.marks_per_rev
    x = 2 * jnp.pi * jnp.arange(n) / n
    k = jnp.arange(1, disk.harmonic_cos_rad.shape[0] + 1, dtype=float)
    kx = x[:, None] * k
    err = (
        disk.random_rad + jnp.cos(kx) @ disk.harmonic_cos_rad + jnp.sin(kx) @ disk.harmonic_sin_rad
    )
    return disk.index_angle_rad + x + err


class SDSDesign(eqx.Module):
    """A shifted-delta-sum instrument: motor, two disks, fixed and moving sensors.

    Static (discrete) settings: ``marks_per_rev``, ``n_fixed``, ``n_moving`` and the
    motor's ``pole_pairs``, ``stator_coils``, ``commutation_states`` (properties here).
    Everything else is a differentiable parameter.

    Attributes:
        motor: shaft motion (:class:`~encdesign.Motor`).
        disk_a: disk read by the fixed sensors; disk_b: read by the moving sensors.
        fixed_azimuths_rad: azimuths ψ_f of the fixed sensors, rad, shape (F,).
        moving_azimuths_rad: azimuths ψ_m of the moving sensors at φ = 0, rad, shape (M,).
        radius_m: read radius of the marks, m.
        marks_per_rev, n_fixed, n_moving: static counts.
    """

    motor: Motor
    disk_a: DiskMarks
    disk_b: DiskMarks
    fixed_azimuths_rad: Array = eqx.field(converter=_f)
    moving_azimuths_rad: Array = eqx.field(converter=_f)
    radius_m: Array = eqx.field(default=0.0254, converter=_f)
    marks_per_rev: int = eqx.field(static=True, default=0)
    n_fixed: int = eqx.field(static=True, default=0)
    n_moving: int = eqx.field(static=True, default=0)

    def __init__(
        self,
        motor: Motor,
        disk_a: DiskMarks,
        disk_b: DiskMarks,
        fixed_azimuths_rad: ArrayLike,
        moving_azimuths_rad: ArrayLike,
        radius_m: ArrayLike = 0.0254,
    ):
        self.motor = motor
        self.disk_a = disk_a
        self.disk_b = disk_b
        self.fixed_azimuths_rad = _f(fixed_azimuths_rad)
        self.moving_azimuths_rad = _f(moving_azimuths_rad)
        self.radius_m = _f(radius_m)
        self.marks_per_rev = disk_a.marks_per_rev
        self.n_fixed = int(np.shape(fixed_azimuths_rad)[0]) if np.ndim(fixed_azimuths_rad) else 0
        self.n_moving = int(np.shape(moving_azimuths_rad)[0]) if np.ndim(moving_azimuths_rad) else 0

    def __check_init__(self):
        if self.disk_b.marks_per_rev != self.disk_a.marks_per_rev:
            raise input_error(
                "SDSDesign.disk_b.marks_per_rev",
                f"got {self.disk_b.marks_per_rev}",
                f"the same as disk_a ({self.disk_a.marks_per_rev})",
            )
        for name, n in (
            ("fixed_azimuths_rad", self.n_fixed),
            ("moving_azimuths_rad", self.n_moving),
        ):
            arr = getattr(self, name)
            if arr.ndim != 1 or n < 1:
                raise input_error(
                    f"SDSDesign.{name}", f"shape {arr.shape}", "a non-empty 1-D array"
                )
        if self.radius_m.shape != ():
            raise input_error("SDSDesign.radius_m", "not a scalar", "a scalar in m")

    @property
    def pole_pairs(self) -> int:
        """Motor pole pairs (static)."""
        return self.motor.pole_pairs

    @property
    def stator_coils(self) -> int:
        """Motor stator coils (static)."""
        return self.motor.stator_coils

    @property
    def commutation_states(self) -> int:
        """Motor drive states per electrical revolution (static)."""
        return self.motor.commutation_states

    def zero_offsets_rad(self) -> Array:
        """Design constants ``S_0(0)/N`` per pair, shape (F, M), rad."""
        c = self.moving_azimuths_rad[None, :] - self.fixed_azimuths_rad[:, None]
        return c + jnp.mean(mark_angles(self.disk_b)) - jnp.mean(mark_angles(self.disk_a))


def validate_design(design: SDSDesign, errors: SDSErrors | None = None) -> None:
    """Check values (outside jit): positive speed and radius, marks in increasing order.

    Raises:
        EncdesignInputError: naming the field and what was expected.
    """
    m = design.motor
    if not float(m.speed_rad_s) > 0:
        raise input_error("Motor.speed_rad_s", f"got {float(m.speed_rad_s)!r}", "> 0 rad/s")
    if not float(m.corner_order) > 0:
        raise input_error("Motor.corner_order", f"got {float(m.corner_order)!r}", "> 0")
    eps_c, eps_s = m.speed_ripple()
    tot = float(jnp.sum(jnp.hypot(eps_c, eps_s)))
    if not tot < 0.5:
        raise input_error(
            "Motor.torque_*", f"total speed ripple {tot:.3g} of the mean speed", "< 0.5"
        )
    if not float(design.radius_m) > 0:
        raise input_error("SDSDesign.radius_m", f"got {float(design.radius_m)!r}", "> 0 m")
    for name in ("disk_a", "disk_b"):
        mu = np.asarray(mark_angles(getattr(design, name)))
        if not np.all(np.isfinite(mu)):
            raise input_error(f"SDSDesign.{name}", "non-finite mark angles", "finite mark errors")
        gaps = np.diff(np.append(mu, mu[0] + 2 * np.pi))
        if np.any(gaps <= 0):
            j = int(np.flatnonzero(gaps <= 0)[0])
            raise input_error(
                f"SDSDesign.{name}",
                f"mark {j + 1} does not follow mark {j} (mark errors larger than the spacing)",
                "mark errors smaller than half the mark spacing",
            )
    if errors is not None:
        for name in ("optical_tilt_fixed_rad", "optical_tilt_moving_rad"):
            n = design.n_fixed if "fixed" in name else design.n_moving
            shp = getattr(errors, name).shape
            if shp not in ((), (n,)):
                raise input_error(f"SDSErrors.{name}", f"shape {shp}", f"a scalar or shape ({n},)")
        if float(errors.clock_period_s) < 0 or float(errors.jitter_s) < 0:
            raise input_error("SDSErrors.clock_period_s/jitter_s", "negative", ">= 0 s")


# ----------------------------------------------------------------------------- edges


def _sensor_azimuths(design: SDSDesign, errors: SDSErrors, phi: Array) -> tuple[Array, Array]:
    """Static effective azimuths (tilt, axial shift × optical tilt) of fixed and moving."""
    r = design.radius_m
    dz_fixed = errors.axial_expansion_m_per_k * errors.temperature_offset_k
    psi_f = errors.tilt_map(design.fixed_azimuths_rad) + errors.optical_tilt_fixed_rad * (
        dz_fixed / r
    )
    dz_b = errors.axial_shift_m(phi) + dz_fixed
    psi_m = errors.tilt_map(design.moving_azimuths_rad + phi) + errors.optical_tilt_moving_rad * (
        dz_b / r
    )
    return psi_f, psi_m


def _solve_edges(
    design: SDSDesign,
    errors: SDSErrors,
    theta_f: Array,
    psi_f: Array,
    theta_m: Array,
    psi_m: Array,
    n_newton: int,
) -> tuple[Array, Array]:
    """Edge times of fixed (F, A) and moving (M, B) targets in one Newton solve.

    The time-dependent sensor shifts δ(t): bearing runout at each sensor's azimuth, and
    thermal drift ``κ ΔT(t)`` (``ΔT = temperature_offset_k + temperature_rate_k_per_s t``)
    for the moving sensors.
    """
    nf, nm = theta_f.size, theta_m.size
    target = jnp.concatenate([theta_f.reshape(-1), theta_m.reshape(-1)])
    psi = jnp.concatenate(
        [
            jnp.broadcast_to(psi_f[:, None], theta_f.shape).reshape(-1),
            jnp.broadcast_to(psi_m[:, None], theta_m.shape).reshape(-1),
        ]
    )
    moving = jnp.concatenate([jnp.zeros(nf), jnp.ones(nm)])
    has_bearing = errors.has_time_shift
    drift = errors.thermal_drift_rad_per_k * errors.temperature_rate_k_per_s
    # kappa dT(t) with dT = offset + rate t (its offset was left out: a temperature ramp from
    # t0, offset = -rate t0, then moved the sensors by kappa rate t0 at its onset, a jump)
    drift0 = errors.thermal_drift_rad_per_k * errors.temperature_offset_k

    def shift(t):
        out = moving * (drift0 + drift * t)
        if has_bearing:
            out = out + errors.bearing_shift_rad(t, psi, design.motor.speed_rad_s, design.radius_m)
        return out

    t = time_at_angle(design.motor, target, shift, n_newton)
    return t[:nf].reshape(theta_f.shape), t[nf:].reshape(theta_m.shape)


def _stamp(t: Array, errors: SDSErrors, key: Array | None) -> Array:
    if key is not None:
        t = t + errors.jitter_s * jax.random.normal(key, t.shape)
    p = errors.clock_period_s
    safe = jnp.where(p > 0, p, 1.0)
    return jnp.where(p > 0, jnp.ceil(t / safe) * safe, t)


def _revolution(
    design: SDSDesign,
    errors: SDSErrors,
    phi: Array,
    rev: Array,
    key: Array | None,
    n_newton: int,
):
    """Edge windows of one reading: every sensor's N consecutive edges from a common start.

    The start (anchor) is the mark-0 edge of fixed sensor 0 in revolution ``rev``. Returns
    fixed times by mark (F, N), fixed revolution times (F,), position of mark 0 in each
    fixed window (F,), moving times by mark (M, N), position of mark 0 (M,).
    """
    two_pi = 2 * jnp.pi
    mu_a = mark_angles(design.disk_a)
    mu_b = mark_angles(design.disk_b)
    psi_f, psi_m = _sensor_azimuths(design, errors, phi)
    psi_f = jnp.broadcast_to(psi_f, (design.n_fixed,))
    psi_m = jnp.broadcast_to(psi_m, (design.n_moving,))
    anchor = jax.lax.stop_gradient(psi_f[0] + mu_a[0] + two_pi * rev)

    def window(psi, mu):
        raw = psi[:, None] + mu[None, :]
        w = jnp.ceil(jax.lax.stop_gradient((anchor - raw) / two_pi - 1e-9))
        theta = raw + two_pi * w  # one edge per mark, in [anchor, anchor + 2π)
        k = jnp.sum(theta < theta[:, :1], axis=1)
        return theta, k

    theta_f, k_f = window(psi_f, mu_a)
    theta_m, k_m = window(psi_m, mu_b)
    first = jnp.argmin(jax.lax.stop_gradient(theta_f), axis=1)
    theta_first = jnp.take_along_axis(theta_f, first[:, None], axis=1)
    theta_f_all = jnp.concatenate([theta_f, theta_first + two_pi], axis=1)  # (F, N+1)
    t_f, t_m = _solve_edges(design, errors, theta_f_all, psi_f, theta_m, psi_m, n_newton)
    if key is not None:
        kf, km = jax.random.split(key)
        t_f, t_m = _stamp(t_f, errors, kf), _stamp(t_m, errors, km)
    else:
        t_f, t_m = _stamp(t_f, errors, None), _stamp(t_m, errors, None)
    n = design.marks_per_rev
    t_first = jnp.take_along_axis(t_f, first[:, None], axis=1)[:, 0]
    period = t_f[:, n] - t_first
    return t_f[:, :n], period, k_f, t_m, k_m


def sds_from_edges(
    alpha_s: FixedEdgeTimes,
    period_s: FixedValues,
    k_fixed: FixedValues,
    tau_s: MovingEdgeTimes,
    k_moving: MovingValues,
    zero_offsets_rad: PairOffsets,
) -> PairAngles:
    """Shifted delta sum per fixed × moving pair (seed eqs. 23–24), rad.

    Every sensor contributes N consecutive edges from (about) the same start time, one
    per mark; the sum does not depend on how the edges are paired, so they are passed in
    mark order.

    Args:
        alpha_s: fixed-sensor edge times by mark index 0…N−1, shape (..., F, N), s.
        period_s: revolution time T of each fixed sensor (from its window's first edge to
            the same mark one turn later), shape (..., F), s.
        k_fixed: position of mark 0 (A_0) in each fixed window ordered by time, (..., F).
        tau_s: moving-sensor edge times by mark index, shape (..., M, N), s.
        k_moving: position of mark 0 (B_0) in each moving window, shape (..., M).
        zero_offsets_rad: ``S_0(0)/N`` per pair, shape (F, M), rad.

    Returns:
        ``φ = S_k/N + 2πk/N − S_0(0)/N`` with ``k = pos(B_0) − pos(A_0)``, per pair, shape
        (..., F, M), rad (not wrapped: equal to φ modulo 2π).
    """
    alpha = jnp.asarray(alpha_s, dtype=float)
    tau = jnp.asarray(tau_s, dtype=float)
    n = tau.shape[-1]
    # Σ_j (τ_j − α_j) = Σ τ − Σ α; times taken from the window start so that the sums stay
    # small (N·T) and keep full precision
    t0 = jax.lax.stop_gradient(alpha[..., :1, :1])
    sum_a = jnp.sum(alpha - t0, axis=-1)  # (..., F)
    sum_t = jnp.sum(tau - t0, axis=-1)  # (..., M)
    diff = sum_t[..., None, :] - sum_a[..., :, None]  # (..., F, M)
    s = 2 * jnp.pi * diff / jnp.asarray(period_s)[..., :, None]
    k = jnp.asarray(k_moving)[..., None, :] - jnp.asarray(k_fixed)[..., :, None]
    return s / n + 2 * jnp.pi * k / n - jnp.asarray(zero_offsets_rad)


def _pair_errors(design, errors, phi, rev, key, n_newton):
    alpha, period, k_f, tau, k_m = _revolution(design, errors, phi, rev, key, n_newton)
    phis = sds_from_edges(alpha, period, k_f, tau, k_m, design.zero_offsets_rad())
    return _wrap(phis - phi)


def sds_phi_error(
    design: SDSDesign,
    phi_rad: Angles,
    errors: SDSErrors | None = None,
    *,
    rev: int = 0,
    n_newton: int = 2,
    batch_size: int = 8,
) -> Averaged:
    """Error of the SDS reading of φ (pair average, one revolution), rad. jit/grad-able.

    Deterministic (no jitter); the error is measured against the true φ with the design
    zero ``S_0(0)/N`` (so constant speed gives exactly 0 for any mark errors).

    Args:
        design: the instrument.
        phi_rad: platform angles, rad, shape (P,) or scalar.
        errors: error physics (default none).
        rev: revolution index of the reading window (matters only with drift or runout).
        n_newton: Newton iterations for the edge times.
        batch_size: platform angles evaluated at once (memory ~ batch · (F+M) · N).

    Returns:
        Error ``φ_measured − φ`` wrapped to (−π, π], rad, shape of ``phi_rad``.
    """
    errors = SDSErrors() if errors is None else errors
    phi = _f(phi_rad)
    flat = phi.reshape(-1)

    def one(p):
        return jnp.mean(_pair_errors(design, errors, p, jnp.asarray(rev, float), None, n_newton))

    out = jax.lax.map(one, flat, batch_size=min(batch_size, max(1, flat.shape[0])))
    return out.reshape(phi.shape)


def sds_residual(
    design: SDSDesign,
    errors: SDSErrors | None = None,
    *,
    n_phi: int = 64,
    n_newton: int = 2,
) -> Array:
    """SDS residual objective: RMS over a platform turn of the φ error minus its mean, rad.

    The constant part is removed because the instrument is zeroed at one position
    (seed: "set the device to the position we want to be the zero position").
    jit/grad-able; ``n_phi`` equally spaced φ in [0, 2π).
    """
    phi = 2 * jnp.pi * jnp.arange(n_phi) / n_phi
    err = sds_phi_error(design, phi, errors, n_newton=n_newton)
    return jnp.sqrt(jnp.mean((err - jnp.mean(err)) ** 2))


class SDSReadings(eqx.Module):
    """Simulated readings of one platform angle.

    Attributes:
        phi_rad: true platform angle, rad.
        pair_error_rad: error of each revolution and pair, rad, shape (R, F, M).
        reading_rad: φ readings (pair average over ``revs_per_reading`` revolutions), rad,
            shape (R // revs_per_reading,).
        error_rad: ``reading − φ`` wrapped, rad, same shape.
    """

    phi_rad: Array
    pair_error_rad: Array
    reading_rad: Array
    error_rad: Array


def simulate_readings(
    design: SDSDesign,
    phi_rad: ArrayLike,
    n_revs: int,
    errors: SDSErrors | None = None,
    *,
    key: Array | None = None,
    revs_per_reading: int = 1,
    first_rev: int = 0,
    n_newton: int = 2,
) -> SDSReadings:
    """Simulate the SDS readings of a platform at rest at ``phi_rad`` for ``n_revs`` turns.

    Memory stays bounded: revolutions are processed one after the other (``lax.map``),
    keeping only (F+M)·N edge times at a time.

    Args:
        design, errors: instrument and error physics.
        phi_rad: platform angle, rad (scalar).
        n_revs: revolutions simulated (>= revs_per_reading).
        key: ``jax.random`` key for jitter (``None``: no jitter).
        revs_per_reading: revolutions averaged into one reading.
        first_rev: index of the first revolution (sets the time, for drift and runout).
        n_newton: Newton iterations for the edge times.
    """
    errors = SDSErrors() if errors is None else errors
    if revs_per_reading < 1 or n_revs < revs_per_reading:
        raise input_error(
            "simulate_readings",
            f"n_revs={n_revs}, revs_per_reading={revs_per_reading}",
            "1 <= revs_per_reading <= n_revs",
        )
    phi = _f(phi_rad)
    revs = first_rev + jnp.arange(n_revs, dtype=float)

    def one(rev):
        sub = None if key is None else jax.random.fold_in(key, rev.astype(jnp.int32))
        return _pair_errors(design, errors, phi, rev, sub, n_newton)

    pair = jax.lax.map(one, revs)
    n_read = n_revs // revs_per_reading
    per_rev = jnp.mean(pair, axis=(1, 2))[: n_read * revs_per_reading]
    err = jnp.mean(per_rev.reshape(n_read, revs_per_reading), axis=1)
    return SDSReadings(
        phi_rad=phi, pair_error_rad=pair, reading_rad=_wrap(phi + err), error_rad=err
    )


def moved_sensor_pair_errors(
    design: SDSDesign,
    sensor: int,
    offset_rad: float,
    phis_rad: ArrayLike,
    errors: SDSErrors | None = None,
) -> Array:
    """Pair errors of ``design`` with moving sensor ``sensor`` moved ``offset_rad`` off its
    azimuth, read against the NOMINAL design's zero constants (the instrument still assumes
    the nominal placement, so the move shows in the readings, as a misplaced sensor does).

    The moved design is rebuilt as an :class:`SDSDesign`, one revolution is simulated at
    each platform angle with :func:`simulate_readings` (no jitter), and the change of the
    zero constants the move brought is added back.

    Args:
        design: the nominal instrument.
        sensor: index of the moving sensor moved, 0 <= sensor < ``design.n_moving``.
        offset_rad: the move, rad (positive: larger azimuth).
        phis_rad: platform angles, rad, shape (P,).
        errors: error physics (``None``: :class:`SDSErrors` defaults).

    Returns:
        Pair errors, rad, shape (P, F, M); e.g. ``e[:, 1, 1] − e[:, 0, 0]`` is the offset
        between the pairs (fixed 0, moving 0) and (fixed 1, moving 1).

    Raises:
        EncdesignInputError: ``sensor`` out of range.
    """
    if not 0 <= int(sensor) < design.n_moving:
        raise input_error(
            "moved_sensor_pair_errors.sensor",
            f"got {sensor}",
            f"a moving sensor index in [0, {design.n_moving})",
        )
    az = np.asarray(design.moving_azimuths_rad).copy()
    az[int(sensor)] += float(offset_rad)
    moved = SDSDesign(
        design.motor,
        design.disk_a,
        design.disk_b,
        design.fixed_azimuths_rad,
        jnp.asarray(az),
        design.radius_m,
    )
    dz = np.asarray(moved.zero_offsets_rad() - design.zero_offsets_rad())
    out = []
    for phi in np.atleast_1d(np.asarray(phis_rad, dtype=float)):
        r = simulate_readings(moved, float(phi), 1, errors)
        out.append(np.asarray(r.pair_error_rad)[0] + dz)
    return jnp.asarray(np.stack(out))


def edge_times(
    design: SDSDesign,
    phi_rad: ArrayLike,
    n_revs: int,
    errors: SDSErrors | None = None,
    *,
    key: Array | None = None,
    first_rev: int = 0,
    n_newton: int = 2,
) -> tuple[Array, Array]:
    """Edge times of every sensor for ``n_revs`` revolutions, s.

    Sensor s (azimuth ψ_s, moving ones at ψ_s + φ reduced to [0, 2π)) sees mark j of
    revolution r at ``θ(t) = ψ_s + μ_j + 2π r``.

    Returns:
        ``(fixed, moving)`` of shapes (F, n_revs, N) and (M, n_revs, N), s, ordered by
        revolution then mark index (increasing time for each sensor).
    """
    errors = SDSErrors() if errors is None else errors
    phi = _f(phi_rad)
    psi_f, psi_m = _sensor_azimuths(design, errors, phi)
    psi_f = jnp.broadcast_to(psi_f, (design.n_fixed,))
    psi_m = jnp.broadcast_to(psi_m, (design.n_moving,))
    mu_a = mark_angles(design.disk_a)
    mu_b = mark_angles(design.disk_b)
    two_pi = 2 * jnp.pi

    base_f = psi_f + (jnp.mod(psi_f, two_pi) - psi_f)  # static azimuths reduced to [0, 2π)
    base_m = psi_m + (jnp.mod(psi_m, two_pi) - psi_m)

    def one(rev):
        theta_f = base_f[:, None] + mu_a[None, :] + two_pi * rev
        theta_m = base_m[:, None] + mu_b[None, :] + two_pi * rev
        t_f, t_m = _solve_edges(design, errors, theta_f, psi_f, theta_m, psi_m, n_newton)
        if key is None:
            return _stamp(t_f, errors, None), _stamp(t_m, errors, None)
        kf, km = jax.random.split(jax.random.fold_in(key, rev.astype(jnp.int32)))
        return _stamp(t_f, errors, kf), _stamp(t_m, errors, km)

    revs = first_rev + jnp.arange(n_revs, dtype=float)
    f, m = jax.lax.map(one, revs)
    return jnp.moveaxis(f, 0, 1), jnp.moveaxis(m, 0, 1)


# ----------------------------------------------------------------------------- reference


def equally_spaced(n: int, start_rad: float = 0.0) -> Array:
    """``n`` azimuths equally spaced around the circle from ``start_rad``, rad."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise input_error("equally_spaced n", f"got {n!r}", "a positive integer")
    return start_rad + 2 * jnp.pi * jnp.arange(n) / n


def reference_motor(
    pole_pairs: int = 6,
    stator_coils: int | None = None,
    commutation_states: int = 6,
    *,
    speed_rad_s: float = 2 * math.pi * 10.0,
    corner_order: float = 4.0,
    low_order_torque: tuple[float, float] = (0.012, 0.008),
    max_order: int | None = None,
) -> Motor:
    """The seed's motor family: 3-phase, ``stator_coils = 3·pole_pairs``, six-step drive.

    Torque ripple recipe (relative to the mean torque; phases fixed so that cases compare):
    coil mismatch/rotor asymmetry ``low_order_torque`` at orders 1 and 2 and
    ``0.004/n²`` at orders 3…p; magnet poles ``0.01/m`` at order m·p; commutation and
    cogging ``0.01/m`` at their m-th multiple. Inertia corner order 4 (the speed ripple
    of order n is the torque ripple divided by |1 + i n/4|). With the defaults the speed
    error is about 1 % (seed: "variations on the order of 1%"), 10 rev/s.
    """
    q = 3 * pole_pairs if stator_coils is None else stator_coils
    src = Motor(pole_pairs, q, commutation_states, max_order=max_order).order_sources
    amp: dict[int, float] = {}
    for n, sources in src.items():
        a = 0.0
        for s in sources:
            if s == "coil_mismatch":
                a += low_order_torque[n - 1] if n <= 2 else 0.004 / n**2
            elif s == "pole_pairs":
                a += 0.01 / (n // pole_pairs)
            elif s == "commutation":
                a += 0.01 / (n // (pole_pairs * commutation_states))
            elif s == "cogging":
                a += 0.01 / (n // math.lcm(2 * pole_pairs, q))
        amp[n] = a
    # deterministic phases (golden-angle sequence) so that every case shares them
    cos = {n: a * math.cos(2.39996 * n) for n, a in amp.items()}
    sin = {n: a * math.sin(2.39996 * n) for n, a in amp.items()}
    return Motor(
        pole_pairs,
        q,
        commutation_states,
        speed_rad_s=speed_rad_s,
        torque_cos=cos,
        torque_sin=sin,
        corner_order=corner_order,
        max_order=max_order,
    )


def reference_disk(
    key: Array,
    marks_per_rev: int = 10_000,
    *,
    eccentricity_rad: float = 2e-3,
    ellipticity_rad: float = 8e-4,
    n_harmonics: int = 48,
    harmonic_rad: float = 2e-5,
    random_rad: float = 2e-6,
) -> DiskMarks:
    """A disk like the seed's (2,500-line Mylar disk epoxied on a hub).

    Order 1 ``eccentricity_rad`` (e/R: 50 µm at 25.4 mm ≈ 2e-3), order 2
    ``ellipticity_rad``, orders 3…H ``harmonic_rad/n``, white ``random_rad`` per mark;
    phases drawn from ``key``.
    """
    k1, k2 = jax.random.split(key)
    n = jnp.arange(1, n_harmonics + 1, dtype=float)
    amp = jnp.where(n == 1, eccentricity_rad, jnp.where(n == 2, ellipticity_rad, harmonic_rad / n))
    ph = jax.random.uniform(k1, (n_harmonics,), minval=0, maxval=2 * jnp.pi)
    rnd = random_rad * jax.random.normal(k2, (marks_per_rev,))
    return DiskMarks(marks_per_rev, amp * jnp.cos(ph), amp * jnp.sin(ph), rnd)


def reference_design(
    n_fixed: int = 2,
    n_moving: int | None = None,
    *,
    pole_pairs: int = 6,
    marks_per_rev: int = 10_000,
    key: Array | None = None,
    motor: Motor | None = None,
) -> SDSDesign:
    """The seed's first device: 6 pole pairs, 18 coils, six-step drive, 10,000 edges,
    sensors equally spaced (2 + 2 by default), read radius 25.4 mm, 10 rev/s.

    ``key`` (default ``PRNGKey(3)``) draws the disk errors, so every case built with the
    same key has the same mark errors.
    """
    key = jax.random.PRNGKey(3) if key is None else key
    ka, kb = jax.random.split(key)
    n_moving = n_fixed if n_moving is None else n_moving
    motor = reference_motor(pole_pairs) if motor is None else motor
    return SDSDesign(
        motor,
        reference_disk(ka, marks_per_rev),
        reference_disk(kb, marks_per_rev),
        equally_spaced(n_fixed),
        equally_spaced(n_moving),
    )


def reference_errors(*, systematic_only: bool = False, **kw) -> SDSErrors:
    """Error physics of the seed's device (each can be overridden by keyword):

    axis tilt 10 arcsec, optical-axis tilt 0.01 rad (0.001 in over 0.1 in) with 2.5 µm
    platform axial runout at order 1 and 1.2 µm at order 2, bearing runout 2.5 µm RMS
    (0.0001 in) at non-synchronous orders, thermal drift 0.7 arcsec/K at 0.1 K/h, clock
    100 MHz with 1 ns jitter.

    ``systematic_only=True`` keeps only what repeats every revolution (the tilts, the axial
    runout, the drift coefficient): no bearing runout, temperature rate 0, no clock
    quantisation and no jitter. Keywords still override either set.
    """
    bearing = bearing_noise_default()
    if systematic_only:
        bearing = {"bearing_amplitude_m": [], "bearing_ratio": [], "bearing_phase_rad": []}
    base = dict(
        axis_tilt_rad=10 * ARCSEC,
        axis_tilt_azimuth_rad=0.4,
        optical_tilt_fixed_rad=0.01,
        optical_tilt_moving_rad=0.01,
        axial_runout_cos_m=[2.5e-6, 1.2e-6],
        axial_runout_sin_m=[0.0, 0.0],
        thermal_drift_rad_per_k=0.7 * ARCSEC,
        temperature_rate_k_per_s=0.1 / 3600,
        clock_period_s=1e-8,
        jitter_s=1e-9,
        **bearing,
    )
    if systematic_only:
        base.update(temperature_rate_k_per_s=0.0, clock_period_s=0.0, jitter_s=0.0)
    base.update(kw)
    return SDSErrors(**base)


def bearing_noise_default() -> dict[str, Array]:
    """The reference bearing runout spectrum (2.5 µm RMS, fixed draw)."""
    return bearing_noise(jax.random.PRNGKey(11), 2.5e-6)
