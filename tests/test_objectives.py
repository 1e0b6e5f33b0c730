"""Objectives: physics of the residual pipeline and gradients of every objective vs FD."""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from encdesign.design._sampling import build_normals
from encdesign.objectives import (
    TOLERANCE_NAMES,
    EncoderDesign,
    SDSTolerances,
    Tolerances,
    build_metrics,
    build_residual,
    build_yield,
    calibration_noise_ms,
    cotangent_sensitivity,
    expected_sensitivity,
    n_build_normals,
    residual_peak,
    residual_percentile,
    residual_rms,
    sds_design,
    tolerance_cost,
)
from encdesign.physics._sds import sds_residual

DESIGN = EncoderDesign(
    radius_m=0.0254,
    reference_angle_rad=math.radians(18.09),
    tilt_rad=6e-3,
    n_heads=3,
    max_order=8,
    grating_orders=8,
    axial_orders=1,
    n_angles=40,
)
TOL = Tolerances(
    eccentricity=5e-6,
    tilt=1e-3,
    placement=2e-4,
    grating=5e-6,
    beam_tilt=5e-4,
    axial_runout=2e-6,
    noise=1e-7,
)


@functools.cache
def _z() -> jax.Array:
    """One build's normals for DESIGN, made on first use (not while pytest collects),
    eagerly even when the first use is inside a trace."""
    with jax.ensure_compile_time_eval():
        return build_normals(jax.random.key(4), jnp.arange(1), n_build_normals(DESIGN))[0]


def _check(f, x, rel_h=1e-4, rtol=2e-5):
    """AD gradient of scalar ``f`` at ``x`` against central finite differences."""
    x = jnp.asarray(x, dtype=jnp.float64)
    flat = x.reshape(-1)
    # the values and the gradient from one compiled program (eagerly, a Monte Carlo
    # objective's scans compile on every call; a program for f and another for its
    # gradient compile f twice)
    fg = jax.jit(jax.value_and_grad(lambda v: f(v.reshape(x.shape))))

    def fx(v):
        return fg(v)[0]

    value, g = fg(flat)
    g = np.asarray(g)
    scale = abs(float(value))
    for i in range(flat.size):
        h = rel_h * max(abs(float(flat[i])), 1e-12)
        e = jnp.zeros_like(flat).at[i].set(h)
        fd = float((fx(flat + e) - fx(flat - e)) / (2 * h))
        assert np.isfinite(g[i])
        assert g[i] == pytest.approx(fd, rel=rtol, abs=1e-10 * scale / h), i


def test_self_compensation_removes_degenerate_grating_modes():
    # perfect heads, grating at orders 3 and 6 only: averaging keeps them, the map removes them
    z = jnp.zeros(n_build_normals(DESIGN))
    j = 3  # S_3 sits at offset 2 (ecc) + 2 (tilt) + 4 (placement) + 2 (index of order 3)
    z = z.at[4 + 4 + j - 1].set(3.0).at[4 + 4 + 6 - 1].set(-2.0)
    tol = Tolerances(grating=5e-6)
    flat = EncoderDesign(
        0.0254,
        DESIGN.reference_angle_rad,
        tilt_rad=0.0,
        n_heads=3,
        max_order=8,
        grating_orders=8,
        axial_orders=1,
        n_angles=40,
    )
    rms = jax.jit(residual_rms)  # one compile for both builds (op by op: 125 compiles)
    assert float(rms(flat, tol, z)) < 1e-12
    worse = Tolerances(grating=5e-6, placement=1e-3)
    zp = z.at[4].set(1.0).at[7].set(-1.0)
    assert float(rms(flat, worse, zp)) > 1e-9  # placement error: modal leakage


def test_rms_peak_and_noise_terms_are_consistent():
    @jax.jit  # the four terms in one compiled program (eagerly, one compile per operation)
    def terms(tol):
        z = _z()
        return (build_residual(DESIGN, tol, z), calibration_noise_ms(DESIGN, tol),
                residual_rms(DESIGN, tol, z), residual_peak(DESIGN, tol, z))  # fmt: skip

    r, ms_noise, rms, peak = terms(TOL)
    ms_noise = float(ms_noise)
    assert abs(float(jnp.mean(r))) < 1e-18
    assert float(rms) ** 2 == pytest.approx(float(jnp.mean(r**2)) + ms_noise, rel=1e-12)
    assert float(peak) >= float(jnp.sqrt(jnp.mean(r**2)))
    # noise term scales with the noise variance and the cotangent amplification
    tol2 = eqx.tree_at(lambda t: t.noise, TOL, 2e-7)
    assert float(terms(tol2)[1]) == pytest.approx(4 * ms_noise, rel=1e-12)


def test_residual_rms_gradient_for_every_tolerance():
    # d rms / d ln sigma_i for all seven tolerances at once (one compile)
    base = TOL.vector()
    f = jax.jit(lambda u: residual_rms(DESIGN, Tolerances.from_vector(base * jnp.exp(u)), _z()))
    _check(f, jnp.zeros(len(TOLERANCE_NAMES)) + 0.05, rel_h=1e-3, rtol=1e-5)


SMALL = EncoderDesign(
    radius_m=0.0254,
    reference_angle_rad=math.radians(18.09),
    tilt_rad=6e-3,
    n_heads=3,
    max_order=4,
    grating_orders=4,
    axial_orders=1,
    n_angles=16,
)


def test_residual_peak_and_reference_angle_gradients():
    def f(a):
        d = eqx.tree_at(lambda d: d.reference_angle_rad, SMALL, a)
        return residual_peak(d, TOL, _z())

    _check(jax.jit(f), jnp.array(SMALL.reference_angle_rad), rel_h=1e-6)

    def g(a):
        d = eqx.tree_at(lambda d: d.reference_angle_rad, SMALL, a)
        return residual_rms(d, TOL, _z())

    _check(jax.jit(g), jnp.array(SMALL.reference_angle_rad), rel_h=1e-6)


def test_percentile_and_smooth_yield_gradients():
    key = jax.random.key(9)

    def p99(s):
        return residual_percentile(SMALL, Tolerances.from_vector(s), key=key, n_builds=24, q=90)

    def ys(s):
        return build_yield(
            SMALL, Tolerances.from_vector(s), 3e-6, key=key, n_builds=24, smooth_width_rad=3e-7
        )

    s0 = TOL.vector()

    def both(u):
        return jnp.stack([p99(s0 * jnp.exp(u)), ys(s0 * jnp.exp(u))])

    # the values and their derivative (forward mode) from one compiled program
    f_and_d = jax.jit(lambda u: jax.jvp(both, (u,), (jnp.ones_like(u),)))
    d_ad = np.asarray(f_and_d(jnp.asarray(0.1))[1])
    h = 1e-3
    d_fd = (
        np.asarray(f_and_d(jnp.asarray(0.1 + h))[0]) - np.asarray(f_and_d(jnp.asarray(0.1 - h))[0])
    ) / (2 * h)
    assert np.all(np.abs(d_ad) > 0)
    np.testing.assert_allclose(d_ad, d_fd, rtol=1e-4)
    exact, vals = jax.jit(  # one compiled program (eagerly, every operation compiles)
        lambda k: (
            build_yield(SMALL, TOL, 3e-6, key=k, n_builds=24),
            build_metrics(SMALL, TOL, key=k, n_builds=24),
        )
    )(key)
    exact, vals = float(exact), np.asarray(vals)
    assert exact == pytest.approx(np.mean(vals <= 3e-6))


def test_sensitivity_gradients():
    _check(lambda a: cotangent_sensitivity(a, 3, 16), jnp.array(0.3158), rel_h=1e-6)
    k = jax.random.key(0)
    _check(
        lambda a: expected_sensitivity(a, 3, 16, 1e-4, key=k, n_builds=16),
        jnp.array(0.3158),
        rel_h=1e-6,
    )
    _check(
        lambda s: expected_sensitivity(0.3158, 3, 16, s, key=k, n_builds=16),
        jnp.array(1e-3),
        rel_h=1e-4,
    )


def test_tolerance_cost_gradient_and_form():
    ref = jnp.array([5e-6, 1e-3, 0.0])
    s = jnp.array([2.5e-6, 2e-3, 7.0])
    assert float(tolerance_cost(s, ref)) == pytest.approx(2.0 + 0.5)
    _check(lambda x: tolerance_cost(x, ref, jnp.array([2.0, 1.0, 1.0])), s)


def test_sds_residual_gradient_in_mark_errors():
    # disk B (read by the moving sensors); see docs/optimization.md on disk A
    d = sds_design(5, 3, SDSTolerances(), key=jax.random.key(1), marks_per_rev=120, n_harmonics=4)

    def f(a):
        dd = eqx.tree_at(lambda d: d.disk_b.harmonic_cos_rad, d, d.disk_b.harmonic_cos_rad * a)
        return sds_residual(dd, n_phi=8) * 1e6

    _check(jax.jit(f), jnp.array(1.3), rel_h=1e-3, rtol=1e-3)
