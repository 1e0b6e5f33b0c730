"""Kinematic model of read heads on a spinning grating disk (Cramer, seed 000, section V.A).

Stator frame: ``z`` is the nominal rotation axis, azimuths are counter-clockwise from ``+x``
seen from ``+z``, the shaft turns by ``+theta`` counter-clockwise (see
``docs/recording-format.md``). For every shaft angle the model

1. rotates the disk's centre ``c0``, normal ``n0`` and index line ``l0`` about ``z``,
   then adds the motion hooks (non-synchronous radial runout, axial disk motion);
2. intersects each head's beam (a ray from the head position along its direction ``u``)
   with the plane of the rotated disk (seed eq. 36, written for a ray not through the
   origin);
3. measures the signed angle ``psi`` about the disk normal from the intersection direction
   to the index line: ``psi`` is the disk-frame coordinate of the grating point the head
   reads, counted clockwise from the index line, i.e. the shaft angle at which that point
   passes azimuth 0 on a perfect encoder;
4. adds the grating error ``g(psi) = sum_j S_j sin(j psi) + C_j cos(j psi)`` and returns
   ``reading_k = theta + error_k`` with ``error_k = wrap(psi_k + alpha_k - theta) + g(psi_k)``
   (``alpha_k`` = nominal azimuth, so a perfect encoder reads ``theta`` at every head).

All lengths in m, angles in rad, times in s. Everything is JAX: ``jit``, ``vmap`` and
``grad`` work through :func:`head_readings` and :func:`head_errors`. Batches of designs
(a Monte Carlo population) go through :func:`head_errors_batch`, chunked with
``lax.map`` so memory stays bounded.

Because the model is symmetric under rotations about ``z``, a head at azimuth ``alpha``
sees the error function of a head at azimuth 0 delayed by ``alpha``:
``error_alpha(theta) = error_0(theta - alpha)`` whenever the heads are identical and the
runout hook is off. The encoder theorem (:mod:`encdesign.physics._theorem`) and the cotangent
equations (:mod:`encdesign.physics._selfcomp`) rest on this.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .. import _tuning
from .._array import f64 as _f64
from .._array import is_traced
from ._reading_math import (
    _GRATING_LOOP_MAX,
    _angle_frame,
    _broadcast_frame,
    _core,
    _grating,
    _readings,
)
from ._types import Angles, ArrayInput, BatchHeadErrors, HeadAngles, HeadErrors

__all__ = [
    "Disk",
    "Heads",
    "Motion",
    "EncoderModel",
    "make_model",
    "head_readings",
    "head_errors",
    "head_errors_batch",
    "noisy_head_readings",
    "stack_models",
]

_CHUNK_READINGS = _tuning.CHUNK_READINGS  # readings per chunk in head_errors_batch (swept)


def _concrete(x: object) -> bool:
    return not is_traced(x)


def _check_shape(name: str, x: Array, shape: tuple[int, ...]) -> None:
    if not hasattr(x, "shape"):  # a sentinel placed by a JAX transformation
        return
    if tuple(x.shape) != shape:
        raise ValueError(f"{name}: shape {tuple(x.shape)}, expected {shape}")


class Disk(eqx.Module):
    """The grating disk as mounted on the shaft (rotor frame, at shaft angle 0).

    Attributes:
        optical_radius_m: radius of the track the heads read, m (> 0).
        eccentricity_m: ``(x, y)`` offset of the grating centre from the rotation axis, m
            (effect ``disk_eccentricity``; order-1 error of amplitude ``|e| / R``).
        tilt_rad: ``(x, y)`` tilt of the disk normal, rad: ``n0 ∝ (tan tx, tan ty, 1)``
            (effect ``disk_tilt``; mostly order 2 with amplitude ``tilt**2 / 4``).
        grating_sin_rad: ``S_j`` of the grating error for orders ``j = 1 … M``, rad.
        grating_cos_rad: ``C_j`` of the grating error for orders ``j = 1 … M``, rad
            (effect ``grating_error``: ``g(psi) = sum S_j sin(j psi) + C_j cos(j psi)``).
    """

    optical_radius_m: Array = eqx.field(converter=_f64)
    eccentricity_m: Array = eqx.field(converter=_f64)
    tilt_rad: Array = eqx.field(converter=_f64)
    grating_sin_rad: Array = eqx.field(converter=_f64)
    grating_cos_rad: Array = eqx.field(converter=_f64)

    def __check_init__(self) -> None:
        _check_shape("Disk.optical_radius_m", self.optical_radius_m, ())
        _check_shape("Disk.eccentricity_m", self.eccentricity_m, (2,))
        _check_shape("Disk.tilt_rad", self.tilt_rad, (2,))
        m = self.grating_sin_rad.shape
        if len(m) != 1:
            raise ValueError(f"Disk.grating_sin_rad: shape {m}, expected (M,)")
        _check_shape("Disk.grating_cos_rad", self.grating_cos_rad, m)
        if _concrete(self.optical_radius_m) and not bool(self.optical_radius_m > 0):
            raise ValueError(f"Disk.optical_radius_m: {self.optical_radius_m}, expected > 0")

    @property
    def n_orders(self) -> int:
        """Highest grating order ``M`` (static)."""
        return int(self.grating_sin_rad.shape[0])


class Heads(eqx.Module):
    """The read heads, fixed in the stator frame.

    Attributes:
        angles_rad: nominal azimuths ``alpha_k``, rad, shape ``(H,)``. Readings are
            reported relative to these: a perfect head at its nominal place reads ``theta``.
        placement_error_rad: azimuth error ``delta_k`` of each head, rad (effect
            ``head_placement``): the head sits at ``alpha_k + delta_k``.
        beam_tilt_rad: tangential tilt ``gamma_k`` of each head's beam from ``-z``, rad
            (effect ``beam_tilt_axial``): axial disk motion ``a`` then moves the point read
            along the track by ``a tan(gamma_k)``.
        gap_m: nominal distance from the heads to the disk plane along ``z``, m.
        noise_rad: white read-noise standard deviation per reading of each head, rad
            (effect ``noise``; used only by :func:`noisy_head_readings`).
    """

    angles_rad: Array = eqx.field(converter=_f64)
    placement_error_rad: Array = eqx.field(converter=_f64)
    beam_tilt_rad: Array = eqx.field(converter=_f64)
    gap_m: Array = eqx.field(converter=_f64)
    noise_rad: Array = eqx.field(converter=_f64)

    def __check_init__(self) -> None:
        h = self.angles_rad.shape
        if len(h) != 1 or h[0] < 1:
            raise ValueError(f"Heads.angles_rad: shape {h}, expected (H,) with H >= 1")
        _check_shape("Heads.placement_error_rad", self.placement_error_rad, h)
        _check_shape("Heads.beam_tilt_rad", self.beam_tilt_rad, h)
        _check_shape("Heads.noise_rad", self.noise_rad, h)
        _check_shape("Heads.gap_m", self.gap_m, ())

    @property
    def n_heads(self) -> int:
        """Number of heads ``H`` (static)."""
        return int(self.angles_rad.shape[0])


class Motion(eqx.Module):
    """Motion hooks of the disk beyond rigid rotation about ``z``.

    Attributes:
        axial_cos_m: axial disk motion ``a(theta) = sum_j A_j cos(j theta) + B_j sin(j theta)``,
            the ``A_j`` for orders ``j = 1 … K``, m (shape ``(K,)``, ``K`` may be 0).
        axial_sin_m: the ``B_j``, m.
        runout_amplitude_m: non-synchronous radial runout ``rho``, m (effect
            ``bearing_wobble``): the disk is displaced in the stator frame by
            ``rho (cos Phi, sin Phi, 0)`` with ``Phi = ratio * theta + 2 pi f t + phase``.
        runout_ratio: frequency ratio of the runout to the shaft (cage ≈ 0.4), 1.
        runout_phase_rad: runout phase at ``theta = 0, t = 0``, rad.
        runout_freq_hz: extra runout frequency fixed in time, Hz (0 for none).
    """

    axial_cos_m: Array = eqx.field(converter=_f64)
    axial_sin_m: Array = eqx.field(converter=_f64)
    runout_amplitude_m: Array = eqx.field(converter=_f64)
    runout_ratio: Array = eqx.field(converter=_f64)
    runout_phase_rad: Array = eqx.field(converter=_f64)
    runout_freq_hz: Array = eqx.field(converter=_f64)

    def __check_init__(self) -> None:
        k = self.axial_cos_m.shape
        if len(k) != 1:
            raise ValueError(f"Motion.axial_cos_m: shape {k}, expected (K,)")
        _check_shape("Motion.axial_sin_m", self.axial_sin_m, k)
        for name in ("runout_amplitude_m", "runout_ratio", "runout_phase_rad", "runout_freq_hz"):
            _check_shape(f"Motion.{name}", getattr(self, name), ())

    @staticmethod
    def still(n_axial_orders: int = 0) -> Motion:
        """No axial motion (``n_axial_orders`` zero coefficients) and no runout."""
        z = jnp.zeros(n_axial_orders)
        return Motion(z, z, 0.0, 0.0, 0.0, 0.0)


class EncoderModel(eqx.Module):
    """A complete encoder: disk, heads and motion hooks (a pytree of float64 arrays).

    Batches (Monte Carlo builds) are the same class with a leading axis on every leaf;
    use :func:`head_errors_batch` on them.
    """

    disk: Disk
    heads: Heads
    motion: Motion

    @staticmethod
    def nominal(
        radius_m: float,
        head_angles_rad: HeadAngles,
        n_orders: int,
        *,
        gap_m: float = 1e-3,
        n_axial_orders: int = 0,
    ) -> EncoderModel:
        """A perfect encoder: no eccentricity, tilt, grating error, placement error, beam
        tilt, motion or noise; ``n_orders`` grating orders (zero) to be filled in.

        Args:
            radius_m: optical radius, m.
            head_angles_rad: nominal head azimuths, rad, shape ``(H,)``.
            n_orders: number ``M`` of grating orders (1 … M).
            gap_m: head-to-disk distance, m.
            n_axial_orders: number of axial-motion orders.
        """
        return make_model(
            radius_m,
            head_angles_rad,
            grating_sin_rad=jnp.zeros(n_orders),
            grating_cos_rad=jnp.zeros(n_orders),
            gap_m=gap_m,
            axial_cos_m=jnp.zeros(n_axial_orders),
            axial_sin_m=jnp.zeros(n_axial_orders),
        )

    @property
    def n_heads(self) -> int:
        """Number of heads (static)."""
        return self.heads.n_heads


def make_model(
    radius_m: float,
    head_angles_rad: HeadAngles,
    *,
    eccentricity_m: ArrayInput = (0.0, 0.0),
    tilt_rad: ArrayInput = (0.0, 0.0),
    grating_sin_rad: ArrayInput = (),
    grating_cos_rad: ArrayInput | None = None,
    placement_error_rad: ArrayInput | None = None,
    beam_tilt_rad: ArrayInput | None = None,
    gap_m: float = 1e-3,
    noise_rad: ArrayInput = 0.0,
    axial_cos_m: ArrayInput = (),
    axial_sin_m: ArrayInput | None = None,
    runout_amplitude_m: float = 0.0,
    runout_ratio: float = 0.0,
    runout_phase_rad: float = 0.0,
    runout_freq_hz: float = 0.0,
) -> EncoderModel:
    """Build an :class:`EncoderModel` from keyword parameters (SI units, see the classes).

    Per-head parameters left out are zero; ``noise_rad`` may be a scalar (same for every
    head). ``grating_sin_rad``/``grating_cos_rad`` list orders ``1 … M`` (a missing one of
    the pair is zeros of the same length); likewise ``axial_cos_m``/``axial_sin_m``.

    Example: the seed's figure-8 encoder, 3+1 heads::

        make_model(0.0254, jnp.deg2rad(jnp.array([0, 120, 240, 50])),
                   eccentricity_m=(5e-6, 0), tilt_rad=(6e-3, 0),
                   grating_sin_rad=[0, 0, 5e-6, 2.5e-6])
    """
    angles = _f64(head_angles_rad).reshape(-1)
    zeros_h = jnp.zeros_like(angles)
    gs = _f64(grating_sin_rad).reshape(-1)
    gc = jnp.zeros_like(gs) if grating_cos_rad is None else _f64(grating_cos_rad).reshape(-1)
    if gc.shape != gs.shape:
        m = max(gs.shape[0], gc.shape[0])
        gs = jnp.pad(gs, (0, m - gs.shape[0]))
        gc = jnp.pad(gc, (0, m - gc.shape[0]))
    ac = _f64(axial_cos_m).reshape(-1)
    asn = jnp.zeros_like(ac) if axial_sin_m is None else _f64(axial_sin_m).reshape(-1)
    if asn.shape != ac.shape:
        k = max(ac.shape[0], asn.shape[0])
        ac = jnp.pad(ac, (0, k - ac.shape[0]))
        asn = jnp.pad(asn, (0, k - asn.shape[0]))
    noise = jnp.broadcast_to(_f64(noise_rad), angles.shape)
    return EncoderModel(
        disk=Disk(radius_m, eccentricity_m, tilt_rad, gs, gc),
        heads=Heads(
            angles,
            zeros_h if placement_error_rad is None else placement_error_rad,
            zeros_h if beam_tilt_rad is None else beam_tilt_rad,
            gap_m,
            noise,
        ),
        motion=Motion(ac, asn, runout_amplitude_m, runout_ratio, runout_phase_rad, runout_freq_hz),
    )


# ----------------------------------------------------------------------------- physics


@jax.jit
def _errors(model: EncoderModel, theta: Array, time: Array | None) -> Array:
    """Head errors ``(n, H)``, rad, for shaft angles ``theta (n,)`` rad and times ``(n,)`` s."""
    d = model.disk
    if d.grating_sin_rad.shape[0] <= _GRATING_LOOP_MAX:
        consts, per_head = _design(model)
        return _readings(consts, per_head, theta, time, d.grating_sin_rad, d.grating_cos_rad)
    geom, s1, c1, psi = _geometry(model, theta, time)
    return geom + _grating(d.grating_sin_rad, d.grating_cos_rad, s1, c1, psi)


def errors_scaled_grating(
    model: EncoderModel,
    theta_rad: Array,
    grating_scale_rad: Array,
    unit_sin: Array,
    unit_cos: Array,
) -> Array:
    """Head errors ``(n, H)``, rad, with the grating error written as a scale times a
    fixed shape: ``g(psi) = grating_scale_rad * sum_j unit_sin_j sin(j psi) + unit_cos_j
    cos(j psi)`` (the model's own grating coefficients are ignored).

    The same physics as :func:`head_errors`, arranged for Monte Carlo gradients with
    respect to a grating tolerance: reverse mode then needs one reduction for the scale
    instead of one per coefficient, and the forward pass is recomputed in the backward
    pass (``jax.checkpoint``) instead of stored: the gradient of a Monte Carlo mean costs
    about 3.4 forward evaluations (``benchmarks/optimize.py``).

    Args:
        model: the encoder (its ``disk.grating_*`` are not used).
        theta_rad: shaft angles, rad, ``(n,)``.
        grating_scale_rad: scalar, rad.
        unit_sin, unit_cos: the grating shape, orders ``1 … M`` (dimensionless).
    """
    return _errors_scaled(model, _f64(theta_rad).reshape(-1), grating_scale_rad, unit_sin, unit_cos)


@jax.checkpoint
def _errors_scaled(model, theta, scale, unit_sin, unit_cos):
    geom, s1, c1, psi = _geometry(model, theta, None)
    return geom + scale * _grating(_f64(unit_sin), _f64(unit_cos), s1, c1, psi)


def _design(model: EncoderModel) -> tuple[tuple[Array, ...], tuple[Array, ...]]:
    """Everything of the model that is neither per angle nor per reading: the disk normal
    ``n0``, index line ``l0`` and centre ``c0`` at ``theta = 0`` (unit vectors; m), the
    runout's amplitude (m), ratio, phase (rad) and frequency (Hz), the axial coefficients
    (m), and the heads' beam ``u`` and position ``r`` (``(H,)``; unit, m) with ``cos``/``sin``
    of their nominal azimuths (:func:`._reading_math._angle_frame` takes it from here)."""
    d, hd, mo = model.disk, model.heads, model.motion
    tx, ty = jnp.tan(d.tilt_rad[0]), jnp.tan(d.tilt_rad[1])
    nn = jnp.sqrt(1.0 + tx * tx + ty * ty)
    n0x, n0y, n0z = tx / nn, ty / nn, 1.0 / nn
    ln = jnp.sqrt(1.0 - n0x * n0x)  # index line: +x projected into the disk plane
    l0x, l0y, l0z = (1.0 - n0x * n0x) / ln, -n0x * n0y / ln, -n0x * n0z / ln
    consts = (
        n0x, n0y, n0z, l0x, l0y, l0z, d.eccentricity_m[0], d.eccentricity_m[1],
        mo.runout_amplitude_m, mo.runout_ratio, mo.runout_phase_rad, mo.runout_freq_hz,
        mo.axial_cos_m, mo.axial_sin_m,
    )  # fmt: skip
    # --- heads: position r, beam u (tangentially tilted from -z)
    beta = hd.angles_rad + hd.placement_error_rad
    cb, sb = jnp.cos(beta), jnp.sin(beta)
    tg = jnp.tan(hd.beam_tilt_rad)
    un = jnp.sqrt(1.0 + tg * tg)
    radius = d.optical_radius_m
    per_head = (
        -tg * sb / un, tg * cb / un, -1.0 / un, radius * cb, radius * sb,
        jnp.broadcast_to(hd.gap_m, beta.shape), jnp.cos(hd.angles_rad), jnp.sin(hd.angles_rad),
    )  # fmt: skip
    return consts, per_head


def _frame(model: EncoderModel, theta: Array, time: Array | None) -> tuple[Array, ...]:
    """The rotated disk frame per angle and the heads, broadcast for :func:`_core`
    (:func:`._reading_math._angle_frame`)."""
    consts, per_head = _design(model)
    return _broadcast_frame(_angle_frame(consts, theta, time), per_head)


def _geometry(
    model: EncoderModel, theta: Array, time: Array | None
) -> tuple[Array, Array, Array, Array]:
    """Geometric head errors ``(n, H)`` (rad, no grating error) and the read point's
    ``sin psi``, ``cos psi`` and ``psi`` (rad) on the disk."""
    geom, s1, c1, _ = _core(_frame(model, theta, time))
    psi = geom + (theta[:, None] - model.heads.angles_rad)  # only for orders > _GRATING_LOOP_MAX
    return geom, s1, c1, psi


def _as_theta(theta_rad: ArrayInput) -> tuple[Array, bool]:
    theta = _f64(theta_rad)
    scalar = theta.ndim == 0
    return theta.reshape(-1), scalar


def head_errors(model: EncoderModel, theta_rad: Angles, time_s: Angles | None = None) -> HeadErrors:
    """Error of every head at every shaft angle: ``reading_k - theta``, rad.

    Args:
        model: the encoder.
        theta_rad: shaft angles, rad, shape ``(n,)`` (or a scalar: result ``(H,)``).
        time_s: sample times, s, same shape (only the runout's ``runout_freq_hz`` term
            uses time; ``None`` means ``t = 0``).

    Returns:
        Errors, rad, shape ``(n, H)``; the constant of a head's placement error is kept
        (``-delta_k``), as a real head would report it.
    """
    theta, scalar = _as_theta(theta_rad)
    time = None if time_s is None else jnp.broadcast_to(_f64(time_s).reshape(-1), theta.shape)
    out = _errors(model, theta, time)
    return out[0] if scalar else out


def head_readings(
    model: EncoderModel, theta_rad: Angles, time_s: Angles | None = None
) -> HeadErrors:
    """Readings of every head, rad: ``reading_k = theta + error_k(theta, t)``, unwrapped.

    Same arguments as :func:`head_errors`; the sign convention is that of
    ``docs/recording-format.md`` (readings increase with ``theta``).
    """
    theta, scalar = _as_theta(theta_rad)
    out = theta[:, None] + head_errors(model, theta, time_s)
    return out[0] if scalar else out


def noisy_head_readings(
    model: EncoderModel,
    theta_rad: Angles,
    time_s: Angles | None = None,
    *,
    key: Array,
) -> HeadErrors:
    """:func:`head_readings` plus white read noise of std ``model.heads.noise_rad``, rad.

    Args:
        key: ``jax.random`` key for the noise.
    """
    clean = head_readings(model, theta_rad, time_s)
    return clean + model.heads.noise_rad * jax.random.normal(key, clean.shape, clean.dtype)


def head_errors_batch(
    models: EncoderModel,
    theta_rad: Angles,
    time_s: Angles | None = None,
    *,
    chunk: int | None = None,
    devices: int | None = None,
) -> BatchHeadErrors:
    """:func:`head_errors` for a batch of designs (every leaf with a leading axis ``B``).

    The designs are split over ``devices`` devices (default: every local device, one CPU
    device per core unless the user chose otherwise, ``docs/scale.md``; at most ``B``):
    each device evaluates a contiguous slice of ``ceil(B / devices)`` designs
    (``jax.shard_map``; the last slice padded with copies of the last design, which are
    dropped). Within a device, designs are processed ``chunk`` at a time (``lax.map`` with
    ``batch_size``), so peak memory is about ``devices * chunk * n * H`` times the few
    dozen temporaries of the model. The default picks ``chunk`` so that one chunk holds
    about ``_CHUNK_READINGS`` readings (from the sweep ``benchmarks/kinematics_sweep.py``:
    small enough for the CPU caches, which is markedly faster than one big batch).

    Every design is computed by the same program on every device, so the values do not
    depend on ``devices`` (tested to 1e-13 relative); differentiable. Inside a
    ``shard_map`` region (a driver that splits its builds already) nothing is split again.

    Returns:
        Errors, rad, shape ``(B, n, H)`` (laid out over the devices when split: it
        combines with any array JAX placed itself; one put on a single device by hand with
        ``jax.device_put(x, device)`` needs moving first, or ``devices=1``).
    """
    theta, _ = _as_theta(theta_rad)
    time = None if time_s is None else jnp.broadcast_to(_f64(time_s).reshape(-1), theta.shape)
    n_designs = jax.tree_util.tree_leaves(models)[0].shape[0]
    if chunk is None:
        chunk = max(1, _CHUNK_READINGS // (theta.shape[0] * models.heads.angles_rad.shape[-1]))
    if devices is None:
        manual = jax.sharding.get_abstract_mesh().manual_axes
        devices = 1 if manual else len(jax.local_devices())
    if isinstance(devices, bool) or not isinstance(devices, int) or devices < 1:
        raise ValueError(f"head_errors_batch: devices={devices!r}, expected an integer >= 1")
    split = min(devices, n_designs)
    if split <= 1:
        return _batch(models, theta, time, min(chunk, n_designs))
    per = -(-n_designs // split)
    return _batch_split(models, theta, time, min(chunk, per), split)


@functools.partial(jax.jit, static_argnums=3)
def _batch(models: EncoderModel, theta: Array, time: Array | None, chunk: int) -> Array:
    return jax.lax.map(lambda m: _errors(m, theta, time), models, batch_size=chunk)


_SPLIT_AXIS = "designs"


@functools.lru_cache(maxsize=8)
def _split_mesh(n: int) -> jax.sharding.Mesh:
    import numpy as np

    devs = jax.local_devices()
    if n > len(devs):
        raise ValueError(f"head_errors_batch: devices={n}, only {len(devs)} local devices")
    return jax.sharding.Mesh(np.array(devs[:n], dtype=object), (_SPLIT_AXIS,))


@functools.partial(jax.jit, static_argnums=(3, 4))
def _batch_split(
    models: EncoderModel, theta: Array, time: Array | None, chunk: int, split: int
) -> Array:
    """:func:`_batch` with the designs cut into ``split`` contiguous slices, one per device."""
    from jax.sharding import PartitionSpec as P

    n = jax.tree_util.tree_leaves(models)[0].shape[0]
    pad = -(-n // split) * split - n
    padded = jax.tree.map(
        lambda x: jnp.concatenate([x, jnp.broadcast_to(x[-1:], (pad, *x.shape[1:]))]), models
    )
    mesh = _split_mesh(split)
    if time is None:
        out = jax.shard_map(
            lambda m, th: _batch(m, th, None, chunk),
            mesh=mesh,
            in_specs=(P(_SPLIT_AXIS), P()),
            out_specs=P(_SPLIT_AXIS),
        )(padded, theta)
    else:
        out = jax.shard_map(
            lambda m, th, t: _batch(m, th, t, chunk),
            mesh=mesh,
            in_specs=(P(_SPLIT_AXIS), P(), P()),
            out_specs=P(_SPLIT_AXIS),
        )(padded, theta, time)
    return out[:n]


def stack_models(models: Sequence[EncoderModel]) -> EncoderModel:
    """Stack equally shaped models into one batched model (leading axis = design)."""
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *models)
