"""Objective and constraint functions for encoder design (public: ``from encdesign.objectives
import …``).

Every function is JAX: ``jit``, ``vmap`` and ``grad`` work through it in the continuous
design variables and tolerances (gradients are checked against finite differences in
``tests/test_objectives.py``). All values are SI (rad, m); randomness only through ``key``.

Pipeline of one Monte Carlo *build* (:func:`build_residual`):

1. draw the build's deviations ``sigma_i * z_i`` from the :class:`Tolerances` (``z`` a
   standard-normal vector, common random numbers across designs, see
   :func:`encdesign.design._drivers.build_normals`) and make an
   :class:`~encdesign.physics._kinematics.EncoderModel` of ``N`` symmetric heads plus one reference
   head (seed 000, section V.A);
2. read all heads over one revolution (``n_angles`` equally spaced shaft angles);
3. average the ``N`` symmetric heads (encoder theorem, seed 000 eq. 1);
4. self-compensate with the reference head: cotangent equations on the head differences
   (seed 000 eq. 16), encoder map of the symmetric average (eq. 17), using the *nominal*
   head angles (the builder does not know the placement errors);
5. the residual is ``averaged error - map``, mean removed (a constant is no error).

Scalar metrics of a build: RMS (:func:`residual_rms`) and peak (:func:`residual_peak`) of the
residual; calibration read noise adds its expected mean square through the cotangent
amplification (:func:`calibration_noise_ms`). Population metrics: :func:`residual_percentile`
(percentile of the per-build RMS or peak over Monte Carlo builds), :func:`build_yield`
(fraction of builds within an accuracy spec, optionally smoothed for gradients) and
:func:`tolerance_cost` (``sum_i c_i * ref_i / sigma_i``: tighter costs more).

:data:`~encdesign.design._registry.PROBLEM_OBJECTIVES` (``_registry``) registers these for
problem files (:mod:`encdesign.design._problem`).
"""

# no ``from __future__ import annotations``: equinox reads the ``AbstractVar`` of
# :class:`AbstractBuildDesign` at class creation and refuses it as a string
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from equinox import AbstractVar
from jaxtyping import Array, ArrayLike

from .._array import f64 as _f64
from .._array import is_traced
from .._distributed import shard_builds
from .._errors import EncdesignInputError, input_error
from ..physics._kinematics import EncoderModel, errors_scaled_grating
from ..physics._layout import (
    check_layout,
    layout_map,
    layout_noise_amplification,
    least_squares_compensate,
)
from ..physics._motor import Motor
from ..physics._selfcomp import cotangent_sensitivity as _cot_sensitivity
from ..physics._selfcomp import encoder_map, self_compensate
from ..physics._theorem import averaged_error
from ..physics._types import (
    AngleValues,
    BuildNormals,
    BuildValues,
    HeadAnglesOut,
    SampleValues,
    Scalar,
    ScalarOut,
)
from ._sampling import build_normals, map_builds
from ._tolerance import tolerance_cost

__all__ = [
    "TOLERANCE_NAMES",
    "TOLERANCE_UNITS",
    "Tolerances",
    "AbstractBuildDesign",
    "EncoderDesign",
    "symmetric_angles",
    "cotangent_sensitivity",
    "expected_sensitivity",
    "n_build_normals",
    "build_model",
    "build_residual",
    "residual_rms",
    "residual_peak",
    "calibration_noise_ms",
    "build_metric",
    "build_metrics",
    "residual_percentile",
    "build_yield",
    "smooth_yield",
    "tolerance_cost",
    "SDSTolerances",
    "sds_design",
    "sds_motor",
    "sds_residuals",
    "LayoutDesign",
    "layout_residual",
    "layout_noise_ms",
    "layout_metric",
    "layout_metrics",
]

TOLERANCE_NAMES = (
    "eccentricity",
    "tilt",
    "placement",
    "grating",
    "beam_tilt",
    "axial_runout",
    "noise",
)
"""The tolerance groups of a multihead build, in vector order."""

TOLERANCE_UNITS = {
    "eccentricity": "m",
    "tilt": "rad",
    "placement": "rad",
    "grating": "rad",
    "beam_tilt": "rad",
    "axial_runout": "m",
    "noise": "rad",
}
"""SI unit of each tolerance's standard deviation."""


class Tolerances(eqx.Module):
    """Standard deviations of the build-to-build deviations (all SI, all ``>= 0``).

    Attributes:
        eccentricity: disk centring, per axis, m (effect ``disk_eccentricity``).
        tilt: disk tilt, per axis, rad, added to the design's nominal tilt
            (effect ``disk_tilt``).
        placement: azimuth error of every head, rad (effect ``head_placement``).
        grating: grating error spectrum: the ``S_j`` and ``C_j`` of order ``j`` have std
            ``grating / j``, rad (effect ``grating_error``).
        beam_tilt: tangential beam tilt of every head, rad (effect ``beam_tilt_axial``).
        axial_runout: axial disk motion, std of each Fourier coefficient of orders
            ``1 … axial_orders``, m (effect ``beam_tilt_axial``, motion hook).
        noise: white read noise per reading during self-compensation, rad (effect
            ``noise``; enters through its expected mean square, not sampled).
    """

    eccentricity: Array = eqx.field(converter=_f64, default=0.0)
    tilt: Array = eqx.field(converter=_f64, default=0.0)
    placement: Array = eqx.field(converter=_f64, default=0.0)
    grating: Array = eqx.field(converter=_f64, default=0.0)
    beam_tilt: Array = eqx.field(converter=_f64, default=0.0)
    axial_runout: Array = eqx.field(converter=_f64, default=0.0)
    noise: Array = eqx.field(converter=_f64, default=0.0)

    def __check_init__(self) -> None:
        for name in TOLERANCE_NAMES:
            v = getattr(self, name)
            if hasattr(v, "shape") and v.shape != ():
                raise EncdesignInputError(f"Tolerances.{name}: shape {v.shape}, expected a scalar")
            if not is_traced(v) and hasattr(v, "shape") and float(v) < 0:
                raise EncdesignInputError(f"Tolerances.{name}: {float(v)}, expected >= 0")

    def vector(self) -> Array:
        """The standard deviations in :data:`TOLERANCE_NAMES` order (SI)."""
        return jnp.stack([getattr(self, n) for n in TOLERANCE_NAMES])

    @staticmethod
    def from_vector(v: ArrayLike) -> "Tolerances":
        """Inverse of :meth:`vector`."""
        v = _f64(v)
        return Tolerances(*[v[i] for i in range(len(TOLERANCE_NAMES))])

    def only(self, name: str) -> "Tolerances":
        """A copy with every tolerance except ``name`` set to zero."""
        return Tolerances(**{n: (getattr(self, n) if n == name else 0.0) for n in TOLERANCE_NAMES})


def symmetric_angles(n_heads: int) -> HeadAnglesOut:
    """Azimuths of ``n_heads`` equally spaced heads starting at 0, rad."""
    return jnp.arange(n_heads, dtype=jnp.float64) * (2 * jnp.pi / n_heads)


class AbstractBuildDesign(eqx.Module):
    """What every multihead design built with :class:`Tolerances` holds besides its heads:
    the disk's geometry and the orders and sampling of its self-compensation.
    :class:`EncoderDesign` and :class:`LayoutDesign` add their heads (``head_angles_rad``);
    the checks and :attr:`theta_rad` here are never overridden.

    Attributes:
        radius_m: optical radius, m.
        tilt_rad: nominal disk tilt about x, rad (seed figure 8: 6 mrad); keyword only.
        gap_m: head-to-disk distance, m; keyword only.
        max_order: highest order ``M`` self-compensation determines (static); keyword only.
        grating_orders: orders ``1 … grating_orders`` of the grating error (static); keyword
            only.
        axial_orders: orders of the axial runout (static); keyword only.
        n_angles: samples per revolution (static); keyword only.
    """

    radius_m: Array = eqx.field(converter=_f64)
    tilt_rad: Array = eqx.field(converter=_f64, default=0.0, kw_only=True)
    gap_m: Array = eqx.field(converter=_f64, default=1e-3, kw_only=True)
    max_order: int = eqx.field(static=True, default=16, kw_only=True)
    grating_orders: int = eqx.field(static=True, default=16, kw_only=True)
    axial_orders: int = eqx.field(static=True, default=2, kw_only=True)
    n_angles: int = eqx.field(static=True, default=256, kw_only=True)
    head_angles_rad: AbstractVar[Array]

    def __check_init__(self) -> None:
        name = type(self).__name__
        if self.max_order < 1 or self.grating_orders < 1 or self.axial_orders < 0:
            raise EncdesignInputError(f"{name}: max_order, grating_orders >= 1, axial_orders >= 0")
        if 2 * max(self.max_order, self.grating_orders) + 1 > self.n_angles:
            raise EncdesignInputError(
                f"{name}.n_angles: {self.n_angles} cannot resolve order "
                f"{max(self.max_order, self.grating_orders)}"
            )
        r = self.radius_m
        if not is_traced(r) and hasattr(r, "shape") and not float(r) > 0:
            raise EncdesignInputError(f"{name}.radius_m: {float(r)}, expected > 0")

    @property
    def theta_rad(self) -> Array:
        """The ``n_angles`` equally spaced shaft angles of one revolution, rad."""
        return jnp.arange(self.n_angles, dtype=jnp.float64) * (2 * jnp.pi / self.n_angles)


class EncoderDesign(AbstractBuildDesign):
    """An ``N+1`` encoder design: ``N`` equally spaced heads plus a reference head.

    ``EncoderDesign(radius_m, reference_angle_rad, *, n_heads=3, …)``; the geometry, orders
    and sampling (``tilt_rad``, ``gap_m``, ``max_order``, ``grating_orders``,
    ``axial_orders``, ``n_angles``) are those of :class:`AbstractBuildDesign`.

    Attributes:
        reference_angle_rad: azimuth of the reference head, rad (a design variable).
        n_heads: number ``N`` of symmetric heads (static); keyword only.
    """

    reference_angle_rad: Array = eqx.field(converter=_f64)
    n_heads: int = eqx.field(static=True, default=3, kw_only=True)

    def __check_init__(self) -> None:
        if self.n_heads < 2:
            raise EncdesignInputError(f"EncoderDesign.n_heads: {self.n_heads}, expected >= 2")

    @property
    def head_angles_rad(self) -> Array:
        """All nominal azimuths, rad: the ``N`` symmetric heads, then the reference head."""
        return jnp.concatenate([symmetric_angles(self.n_heads), self.reference_angle_rad[None]])


# ----------------------------------------------------------------------------- sensitivity


def cotangent_sensitivity(reference_angle_rad: Scalar, n_heads: int, max_order: int) -> ScalarOut:
    """Noise amplification of self-compensation over modes ``1 … max_order`` (seed 000,
    section III.D), for ``n_heads`` equally spaced heads and a reference head at
    ``reference_angle_rad`` (rad). Dimensionless; see
    :func:`encdesign.physics._selfcomp.cotangent_sensitivity` for the definition (RMS over the
    degenerate orders of the per-coefficient amplification)."""
    return _cot_sensitivity(reference_angle_rad, symmetric_angles(n_heads), max_order)[1]


def expected_sensitivity(
    reference_angle_rad: Scalar,
    n_heads: int,
    max_order: int,
    placement_sigma_rad: Scalar,
    *,
    key: Array,
    n_builds: int = 256,
) -> ScalarOut:
    """Mean cotangent sensitivity over builds whose heads are misplaced by
    ``N(0, placement_sigma_rad**2)`` each (all ``n_heads + 1`` heads), rad.

    Common random numbers: the same ``key`` gives the same builds for every reference
    angle, so the mean is a smooth function of ``reference_angle_rad``.
    """
    z = build_normals(key, jnp.arange(n_builds), n_heads + 1)
    sig = _f64(placement_sigma_rad)
    base = symmetric_angles(n_heads)

    def one(zi):
        return _cot_sensitivity(
            reference_angle_rad + sig * zi[-1], base + sig * zi[:-1], max_order
        )[1]

    return jnp.mean(jax.vmap(one)(z))


# ----------------------------------------------------------------------------- builds


def deviation_sizes(design: AbstractBuildDesign) -> dict[str, int]:
    """The parts of one build's standard-normal vector ``z``, in order, and their sizes."""
    h = design.head_angles_rad.shape[0]
    mg, ka = design.grating_orders, design.axial_orders
    return {
        "eccentricity": 2,
        "tilt": 2,
        "placement": h,
        "grating_sin": mg,
        "grating_cos": mg,
        "beam_tilt": h,
        "axial_cos": ka,
        "axial_sin": ka,
    }


def n_build_normals(design: AbstractBuildDesign) -> int:
    """Length of the standard-normal vector ``z`` of one build of ``design``."""
    return sum(deviation_sizes(design).values())


def _unit_deviations(design: AbstractBuildDesign, z: ArrayLike) -> dict[str, Array]:
    """The deviations of one build per unit tolerance, by name.

    ``z`` (``[n_build_normals(design)]``) is split in order: eccentricity (x, y), tilt
    (x, y), placement (per head), grating (``S_1…S_M``, ``C_1…C_M``, scaled by ``1/j``),
    beam tilt (per head), axial runout (cos, sin per order).
    """
    z = _f64(z)
    out, i = {}, 0
    for name, n in deviation_sizes(design).items():
        out[name] = z[i : i + n]
        i += n
    j = jnp.arange(1, design.grating_orders + 1, dtype=jnp.float64)
    out["grating_sin"] = out["grating_sin"] / j
    out["grating_cos"] = out["grating_cos"] / j
    return out


def build_model(design: EncoderDesign, tol: Tolerances, z: BuildNormals) -> EncoderModel:
    """The kinematic model of one build: ``design`` with deviations ``sigma * z`` (the
    layout of ``z``: :func:`_unit_deviations`)."""
    return _model_of(design, tol, _unit_deviations(design, z))


def _model_of(design: AbstractBuildDesign, tol: Tolerances, u: dict[str, Array]) -> EncoderModel:
    """:func:`build_model` from the unit deviations ``u`` of :func:`_unit_deviations`."""
    h = design.head_angles_rad.shape[0]
    mg, ka = design.grating_orders, design.axial_orders
    ecc = tol.eccentricity * u["eccentricity"]
    tilt = tol.tilt * u["tilt"] + jnp.array([1.0, 0.0]) * design.tilt_rad
    place = tol.placement * u["placement"]
    gs = tol.grating * u["grating_sin"]
    gc = tol.grating * u["grating_cos"]
    beam = tol.beam_tilt * u["beam_tilt"]
    ac = tol.axial_runout * u["axial_cos"]
    asn = tol.axial_runout * u["axial_sin"]
    # The kinematic classes validate concrete values in __check_init__; build a nominal
    # template eagerly and swap the (possibly traced) leaves in with tree_at.
    with jax.ensure_compile_time_eval():
        template = EncoderModel.nominal(1.0, jnp.zeros(h), mg, gap_m=1e-3, n_axial_orders=ka)
    return eqx.tree_at(
        lambda m: (
            m.disk.optical_radius_m,
            m.disk.eccentricity_m,
            m.disk.tilt_rad,
            m.disk.grating_sin_rad,
            m.disk.grating_cos_rad,
            m.heads.angles_rad,
            m.heads.placement_error_rad,
            m.heads.beam_tilt_rad,
            m.heads.gap_m,
            m.motion.axial_cos_m,
            m.motion.axial_sin_m,
        ),
        template,
        (
            jnp.asarray(design.radius_m, dtype=jnp.float64),
            ecc,
            tilt,
            gs,
            gc,
            design.head_angles_rad,
            place,
            beam,
            jnp.asarray(design.gap_m, dtype=jnp.float64),
            ac,
            asn,
        ),
    )


def build_residual(design: EncoderDesign, tol: Tolerances, z: BuildNormals) -> AngleValues:
    """Residual error of one build after symmetry averaging and self-compensation, rad,
    at :attr:`EncoderDesign.theta_rad` (mean removed; see the module docstring)."""
    u = _unit_deviations(design, z)
    model = _model_of(design, tol, u)
    theta = design.theta_rad
    # the same errors as head_errors(model, theta), with the grating error written as
    # tol.grating times its unit shape: cheaper reverse-mode gradients (see
    # encdesign.physics._kinematics.errors_scaled_grating)
    err = errors_scaled_grating(model, theta, tol.grating, u["grating_sin"], u["grating_cos"])
    readings = theta[:, None] + err
    n = design.n_heads
    avg = averaged_error(err[:, :n])
    comp = self_compensate(theta, readings, design.head_angles_rad, n, design.max_order)
    emap = encoder_map(comp, design.head_angles_rad[:n])
    res = avg - emap(theta)
    return res - jnp.mean(res)


def calibration_noise_ms(design: EncoderDesign, tol: Tolerances) -> ScalarOut:
    """Expected mean square (rad²) that read noise during self-compensation leaves in the
    map: each Fourier coefficient of one head's noise over ``n_angles`` samples has std
    ``noise * sqrt(2 / n_angles)``, amplified by ``|T_j| A_j`` (cotangent sensitivity per
    order, :func:`encdesign.physics._selfcomp.cotangent_sensitivity`); order ``j`` contributes
    ``|T_j|^2 A_j^2 sigma_c^2`` to the mean square."""
    sym = symmetric_angles(design.n_heads)
    amp, _ = _cot_sensitivity(design.reference_angle_rad, sym, design.max_order)
    j = jnp.arange(1, design.max_order + 1, dtype=jnp.float64)
    h = design.reference_angle_rad - sym
    t2 = jnp.abs(jnp.mean(jnp.exp(1j * j[:, None] * h[None, :]), axis=1)) ** 2
    sigma_c2 = tol.noise**2 * 2.0 / design.n_angles
    return jnp.sum(t2 * amp**2) * sigma_c2


def residual_rms(design: EncoderDesign, tol: Tolerances, z: BuildNormals) -> ScalarOut:
    """RMS residual of one build, rad, including the expected calibration-noise term."""
    r = build_residual(design, tol, z)
    return jnp.sqrt(jnp.mean(r * r) + calibration_noise_ms(design, tol))


def residual_peak(design: EncoderDesign, tol: Tolerances, z: BuildNormals) -> ScalarOut:
    """Peak absolute residual of one build (noise-free), rad."""
    return jnp.max(jnp.abs(build_residual(design, tol, z)))


def build_metric(
    design: EncoderDesign, tol: Tolerances, z: BuildNormals, metric: str = "rms"
) -> ScalarOut:
    """``"rms"`` (:func:`residual_rms`), ``"peak"`` (:func:`residual_peak`) or ``"ms"``
    (mean square including the expected calibration-noise term, rad²) of one build."""
    if metric == "rms":
        return residual_rms(design, tol, z)
    if metric == "peak":
        return residual_peak(design, tol, z)
    if metric == "ms":
        r = build_residual(design, tol, z)
        return jnp.mean(r * r) + calibration_noise_ms(design, tol)
    raise EncdesignInputError(f"metric: {metric!r}, expected 'rms', 'peak' or 'ms'")


def build_metrics(
    design: EncoderDesign,
    tol: Tolerances,
    *,
    key: Array,
    n_builds: int,
    metric: str = "rms",
    chunk_size: int = 256,
    first_build: int = 0,
) -> BuildValues:
    """Per-build metric for builds ``first_build … first_build + n_builds - 1`` of ``key``
    (common random numbers), chunked with ``lax.map``; rad (rad² for ``"ms"``).

    Memory is bounded by one chunk of ``chunk_size`` builds; within a chunk, builds are
    vectorised 8 at a time (:func:`encdesign.design._drivers.map_builds`), which keeps the
    working set in the CPU caches (the fastest setting measured on CPU for the value and
    its gradient, ``benchmarks/optimize.py``)."""
    return map_builds(
        lambda zi: build_metric(design, tol, zi, metric),
        key,
        n_builds,
        n_build_normals(design),
        first=first_build,
        block=chunk_size,
    )


def residual_percentile(
    design: EncoderDesign,
    tol: Tolerances,
    *,
    key: Array,
    n_builds: int,
    q: float = 99.0,
    metric: str = "rms",
    chunk_size: int = 256,
) -> ScalarOut:
    """The ``q``-th percentile (0–100) of the per-build metric over Monte Carlo builds,
    rad (linear interpolation between order statistics; differentiable almost
    everywhere)."""
    vals = build_metrics(
        design, tol, key=key, n_builds=n_builds, metric=metric, chunk_size=chunk_size
    )
    return jnp.percentile(vals, q)


def smooth_yield(values: SampleValues, spec: Scalar, width: Scalar) -> ScalarOut:
    """Smooth surrogate of the fraction of ``values <= spec``: the mean of
    ``sigmoid((spec - v) / width)`` (same units for ``values``, ``spec``, ``width``)."""
    return jnp.mean(jax.nn.sigmoid((_f64(spec) - _f64(values)) / _f64(width)))


def build_yield(
    design: EncoderDesign,
    tol: Tolerances,
    spec_rad: Scalar,
    *,
    key: Array,
    n_builds: int,
    metric: str = "rms",
    smooth_width_rad: float | None = None,
    chunk_size: int = 256,
) -> ScalarOut:
    """Fraction of Monte Carlo builds whose metric is ``<= spec_rad``.

    With ``smooth_width_rad`` the indicator is replaced by a sigmoid of that width (a
    differentiable yield for gradient solvers); without it the exact fraction (zero
    gradient) is returned.
    """
    vals = build_metrics(
        design, tol, key=key, n_builds=n_builds, metric=metric, chunk_size=chunk_size
    )
    if smooth_width_rad is None:
        return jnp.mean((vals <= spec_rad).astype(jnp.float64))
    return smooth_yield(vals, spec_rad, smooth_width_rad)


# ----------------------------------------------------------------------------- free layouts


class LayoutDesign(AbstractBuildDesign):
    """An encoder whose heads sit at arbitrary azimuths (free head placement).

    Self-compensation recovers the disk's error function from all head differences by least
    squares per order (:func:`encdesign.physics.least_squares_compensate`); the encoder's
    output is the weighted average of all heads (``weights``, equal by default) corrected by
    its map. Cramer's ``N + 1`` layout is the special case ``head_angles_rad = [0, 2 pi/N,
    …, reference]``.

    ``LayoutDesign(radius_m, head_angles_rad, *, weights=None, …)``; the geometry, orders
    and sampling (``tilt_rad``, ``gap_m``, ``max_order``, ``grating_orders``,
    ``axial_orders``, ``n_angles``) are those of :class:`AbstractBuildDesign`.

    Attributes:
        head_angles_rad: nominal azimuths of all ``H >= 2`` heads, rad (a design variable).
        weights: weights of the heads in the output (``None``: equal); keyword only.
    """

    head_angles_rad: Array = eqx.field(converter=_f64)
    weights: Array | None = eqx.field(default=None, kw_only=True)

    def __check_init__(self) -> None:
        a = self.head_angles_rad
        if a.ndim != 1 or a.shape[0] < 2:
            raise EncdesignInputError(
                f"LayoutDesign.head_angles_rad: shape {a.shape}, expected (H >= 2,)"
            )
        if self.weights is not None and jnp.shape(self.weights) != a.shape:
            raise EncdesignInputError(
                f"LayoutDesign.weights: shape {jnp.shape(self.weights)}, expected {a.shape}"
            )
        if not is_traced(a):
            try:
                check_layout(a, where="LayoutDesign.head_angles_rad")
            except EncdesignInputError as exc:
                raise EncdesignInputError(str(exc)) from None

    @property
    def n_heads(self) -> int:
        """Number of heads ``H``."""
        return int(self.head_angles_rad.shape[0])

    @staticmethod
    def symmetric(
        n_heads: int, reference_angle_rad: ArrayLike, radius_m: ArrayLike, **kw: Any
    ) -> "LayoutDesign":
        """Cramer's ``N + 1`` layout: ``n_heads`` equally spaced heads plus a reference head
        at ``reference_angle_rad``, all averaged."""
        ang = jnp.concatenate([symmetric_angles(n_heads), _f64(reference_angle_rad)[None]])
        return LayoutDesign(radius_m=radius_m, head_angles_rad=ang, **kw)


def layout_residual(design: LayoutDesign, tol: Tolerances, z: BuildNormals) -> AngleValues:
    """Residual error of one build of a free layout after least-squares self-compensation,
    rad, at :attr:`LayoutDesign.theta_rad` (mean removed). The build's deviations follow
    :func:`build_model` (``z`` of length :func:`n_build_normals`); the builder knows only
    the nominal azimuths."""
    u = _unit_deviations(design, z)
    model = _model_of(design, tol, u)
    theta = design.theta_rad
    err = errors_scaled_grating(model, theta, tol.grating, u["grating_sin"], u["grating_cos"])
    comp = least_squares_compensate(theta, err, design.head_angles_rad, design.max_order)
    avg = averaged_error(err, design.weights)
    res = avg - layout_map(comp, design.weights)(theta)
    return res - jnp.mean(res)


def layout_noise_ms(design: LayoutDesign, tol: Tolerances) -> ScalarOut:
    """Expected mean square (rad²) that read noise during self-compensation leaves in the
    map of a free layout: ``sum_j |T_j|^2 A_j^2 sigma_c^2``, ``sigma_c^2 = 2 noise^2 /
    n_angles`` (:func:`encdesign.physics.layout_noise_amplification`)."""
    _, gain, _ = layout_noise_amplification(
        design.head_angles_rad, design.max_order, design.weights
    )
    return jnp.sum(gain**2) * tol.noise**2 * 2.0 / design.n_angles


def layout_metric(
    design: LayoutDesign, tol: Tolerances, z: BuildNormals, metric: str = "rms"
) -> ScalarOut:
    """``"rms"`` (with the calibration-noise term), ``"peak"`` (noise-free) or ``"ms"``
    (rad²) of one build of a free layout."""
    r = layout_residual(design, tol, z)
    if metric == "peak":
        return jnp.max(jnp.abs(r))
    ms = jnp.mean(r * r) + layout_noise_ms(design, tol)
    if metric == "ms":
        return ms
    if metric == "rms":
        return jnp.sqrt(ms)
    raise EncdesignInputError(f"metric: {metric!r}, expected 'rms', 'peak' or 'ms'")


def layout_metrics(
    design: LayoutDesign,
    tol: Tolerances,
    *,
    key: Array,
    n_builds: int,
    metric: str = "rms",
    chunk_size: int = 256,
    first_build: int = 0,
) -> BuildValues:
    """Per-build :func:`layout_metric` of builds ``first_build …`` of ``key`` (common random
    numbers, chunked like :func:`build_metrics`); differentiable in the azimuths and
    tolerances."""
    return map_builds(
        lambda zi: layout_metric(design, tol, zi, metric),
        key,
        n_builds,
        n_build_normals(design),
        first=first_build,
        block=chunk_size,
    )


# ----------------------------------------------------------------------------- SDS


class SDSTolerances(eqx.Module):
    """Build-to-build tolerances of a shifted-delta-sum instrument (seed 001), SI.

    Attributes:
        eccentricity_rad: order-1 mark error of each disk (centring e/R), rad.
        ellipticity_rad: order-2 mark error, rad.
        harmonic_rad: orders ``3 … n_harmonics`` have amplitude ``harmonic_rad / n``, rad.
        random_rad: white mark-position error per mark, rad.
        speed_ripple: relative torque ripple of the motor at orders 1 and 2 (coil mismatch);
            the motor's own orders follow its pole pairs (``physics.reference_motor``).
        axis_tilt_rad: tilt of the disk axis to the platform axis, rad.
    """

    eccentricity_rad: float = 2e-3
    ellipticity_rad: float = 8e-4
    harmonic_rad: float = 2e-5
    random_rad: float = 2e-6
    speed_ripple: float = 0.012
    axis_tilt_rad: float = 0.0


def sds_motor(pole_pairs: int, tol: SDSTolerances, max_order: int | None = None) -> Motor:
    """The motor of :func:`sds_design`: the reference family with ``pole_pairs``
    (``physics.reference_motor``) and coil-mismatch ripple ``tol.speed_ripple`` at order 1
    (2/3 of it at order 2); as a dense motor of orders ``1 … max_order``
    (:meth:`~encdesign.Motor.as_dense`: the same shapes for every pole count) when
    ``max_order`` is given (at least the motor's own highest order, ``12 · pole_pairs``)."""
    from ..physics._sds import reference_motor

    motor = reference_motor(
        pole_pairs, low_order_torque=(tol.speed_ripple, 2.0 * tol.speed_ripple / 3.0)
    )
    if max_order is None:
        return motor
    if max_order < motor.max_order:
        raise input_error("sds_motor.max_order", f"got {max_order}", f">= {motor.max_order}")
    return motor.as_dense(max_order)


def sds_design(
    pole_pairs: int,
    n_sensors: int,
    tol: SDSTolerances,
    *,
    key: Array,
    marks_per_rev: int = 1000,
    n_harmonics: int = 16,
    fixed_azimuths_rad: Any = None,
    moving_azimuths_rad: Any = None,
    motor: Motor | None = None,
) -> Any:
    """One SDS build: motor with ``pole_pairs`` (3-phase, six-step drive, coil-mismatch
    ripple ``tol.speed_ripple``), two disks whose mark errors are drawn from ``key`` with
    the amplitudes of ``tol``, ``n_sensors`` fixed and moving sensors: equally spaced, or at
    ``fixed_azimuths_rad`` / ``moving_azimuths_rad`` (rad, ``n_sensors`` each; may be
    traced: the build is differentiable in the azimuths and in the tolerances).

    ``motor``: that motor instead (:func:`sds_motor` of ``pole_pairs`` and ``tol``, or its
    :meth:`~encdesign.Motor.as_dense` form, which may be traced: one compiled program then
    serves every pole count); ``pole_pairs`` is then not used."""
    from ..physics._sds import SDSDesign, equally_spaced, reference_disk

    fixed = equally_spaced(n_sensors) if fixed_azimuths_rad is None else fixed_azimuths_rad
    moving = equally_spaced(n_sensors) if moving_azimuths_rad is None else moving_azimuths_rad
    for name, a in (("fixed_azimuths_rad", fixed), ("moving_azimuths_rad", moving)):
        if jnp.shape(a) != (n_sensors,):
            raise input_error(
                f"sds_design.{name}", f"shape {jnp.shape(a)}", f"({n_sensors},) = n_sensors"
            )

    ka, kb = jax.random.split(key)
    if motor is None:
        motor = sds_motor(pole_pairs, tol)
    kw: dict[str, Any] = dict(
        eccentricity_rad=tol.eccentricity_rad,
        ellipticity_rad=tol.ellipticity_rad,
        n_harmonics=n_harmonics,
        harmonic_rad=tol.harmonic_rad,
        random_rad=tol.random_rad,
    )
    return SDSDesign(
        motor,
        reference_disk(ka, marks_per_rev, **kw),
        reference_disk(kb, marks_per_rev, **kw),
        fixed,
        moving,
    )


def sds_residuals(
    pole_pairs: int,
    n_sensors: int,
    tol: SDSTolerances,
    *,
    key: Array,
    n_builds: int,
    marks_per_rev: int = 1000,
    n_phi: int = 32,
    fixed_azimuths_rad: Any = None,
    moving_azimuths_rad: Any = None,
    motor: Motor | None = None,
) -> Array:
    """SDS residual over the platform turn (RMS of the φ error minus its mean, rad;
    :func:`encdesign.physics._sds.sds_residual`) of ``n_builds`` Monte Carlo builds. Build ``i``
    draws its disks from ``fold_in(key, i)`` (common random numbers across designs); the
    builds are split over the devices of the ``"builds"`` mesh
    (:func:`encdesign.design.shard_builds`). Sensors equally spaced unless
    ``fixed_azimuths_rad`` / ``moving_azimuths_rad`` are given (:func:`sds_design`);
    differentiable in the azimuths and in the tolerances ``tol``. ``motor``: as in
    :func:`sds_design` (a traced dense motor: one program for every pole count)."""
    from ..physics._sds import sds_residual
    from ..physics._sds_errors import SDSErrors

    errors = SDSErrors(axis_tilt_rad=tol.axis_tilt_rad)

    def one(i):
        d = sds_design(
            pole_pairs,
            n_sensors,
            tol,
            key=jax.random.fold_in(key, i),
            marks_per_rev=marks_per_rev,
            fixed_azimuths_rad=fixed_azimuths_rad,
            moving_azimuths_rad=moving_azimuths_rad,
            motor=motor,
        )
        return sds_residual(d, errors, n_phi=n_phi)

    return shard_builds(lambda offset, m: jax.lax.map(one, offset + jnp.arange(m)), n_builds)
