"""SDS instrument design variables (issue 14 item 2): sensor azimuths and mark-error
tolerances are continuous and differentiable; pole pairs and sensor counts are static."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from encdesign import EncdesignInputError
from encdesign.objectives import SDSTolerances, sds_motor, sds_residuals

SMALL = {"n_builds": 2, "marks_per_rev": 120, "n_phi": 8}


def _mean_residual_urad(moving, fixed, tol_vec, pole_pairs=5, n_sensors=3):
    ecc, ell, har, rnd = tol_vec
    tol = SDSTolerances(eccentricity_rad=ecc, ellipticity_rad=ell, harmonic_rad=har,
                        random_rad=rnd)  # fmt: skip
    vals = sds_residuals(pole_pairs, n_sensors, tol, key=jax.random.key(4),
                         fixed_azimuths_rad=fixed, moving_azimuths_rad=moving, **SMALL)  # fmt: skip
    return jnp.mean(vals) * 1e6


def _central(f, x, h):
    x = np.asarray(x, dtype=float)
    return np.array(
        [
            (float(f(jnp.asarray(x + h * e))) - float(f(jnp.asarray(x - h * e)))) / (2 * h)
            for e in np.eye(x.size)
        ]  # fmt: skip
    )


def test_gradient_in_azimuths_and_mark_tolerances_matches_finite_differences():
    moving = np.radians([0.0, 131.0, 229.0])
    fixed = np.radians([0.0, 120.0, 240.0])
    t0 = SDSTolerances()
    tv = np.array([t0.eccentricity_rad, t0.ellipticity_rad, t0.harmonic_rad, t0.random_rad])
    # one function of everything (one compilation): moving, fixed azimuths (rad) and the
    # tolerances in relative units (a multiplies each one)
    x0 = np.concatenate([moving, fixed, np.ones(4)])
    # the values and the gradient from one compiled program (not one for each)
    fg = jax.jit(jax.value_and_grad(lambda x: _mean_residual_urad(x[:3], x[3:6], x[6:] * tv)))
    g = np.asarray(fg(jnp.asarray(x0))[1])
    fd = _central(lambda x: fg(x)[0], x0, 1e-5)
    g_m, g_f, g_t = g[:3], g[3:6], g[6:]
    # component 0 is nearly a common rotation (small): compared to the gradient's size
    np.testing.assert_allclose(g_m, fd[:3], rtol=1e-4, atol=1e-5 * np.max(np.abs(fd[:3])))
    np.testing.assert_allclose(g_t, fd[6:], rtol=1e-4, atol=1e-5 * np.max(np.abs(fd[6:])))
    assert g_t[0] > 0 and g_t[1] > 0  # looser centring / ellipticity: a larger residual
    # the fixed sensors read every mark at the same shaft angles for every phi: a constant,
    # removed by the zeroing, so their gradient is nil next to the moving sensors' (finite
    # differences see only round-off)
    assert np.max(np.abs(g_f)) < 1e-6 * np.max(np.abs(g_m))
    assert np.max(np.abs(fd[3:6])) < 1e-3 * np.max(np.abs(g_m))


def test_equally_spaced_sensors_cancel_what_a_random_layout_leaves():
    t0 = SDSTolerances()
    tv = jnp.array([t0.eccentricity_rad, t0.ellipticity_rad, t0.harmonic_rad, t0.random_rad])
    eq = jnp.radians(jnp.array([0.0, 120.0, 240.0]))
    rnd = jnp.radians(jnp.array([0.0, 80.0, 200.0]))
    f = jax.jit(_mean_residual_urad)  # one compilation for both layouts
    assert float(f(eq, eq, tv)) < 0.05 * float(f(rnd, eq, tv))


def test_azimuths_must_match_the_sensor_count():
    with pytest.raises(EncdesignInputError, match=r"moving_azimuths_rad.*\(3,\) = n_sensors"):
        sds_residuals(5, 3, SDSTolerances(), key=jax.random.key(0), n_builds=1,
                      moving_azimuths_rad=jnp.zeros(2), **{k: v for k, v in SMALL.items()
                                                           if k != "n_builds"})  # fmt: skip


def test_a_dense_motor_argument_gives_every_pole_count_the_same_residuals_in_one_program():
    """``sds_motor(p, tol, max_order)`` (dense to a common highest order) as an argument: the
    residuals and their azimuth gradient of pole counts 5 and 6 equal those of their own
    motors bit for bit, and one compiled program serves both (``pole-sensor-opt``)."""
    tol = SDSTolerances()
    moving = jnp.radians(jnp.array([0.0, 131.0, 229.0]))
    fixed = jnp.radians(jnp.array([0.0, 120.0, 240.0]))
    key = jax.random.key(4)
    traces = []

    def own(m, p):
        vals = sds_residuals(p, 3, tol, key=key, n_builds=2, marks_per_rev=120, n_phi=8,
                             fixed_azimuths_rad=fixed, moving_azimuths_rad=m)  # fmt: skip
        return jnp.sum(vals)

    def dense(m, motor):
        traces.append(1)  # once per compiled program
        vals = sds_residuals(0, 3, tol, key=key, n_builds=2, marks_per_rev=120, n_phi=8,
                             fixed_azimuths_rad=fixed, moving_azimuths_rad=m,
                             motor=motor)  # fmt: skip
        return jnp.sum(vals)

    f_dense = jax.jit(jax.value_and_grad(dense))
    for p in (5, 6):
        v0, g0 = jax.jit(jax.value_and_grad(own), static_argnums=1)(moving, p)
        v1, g1 = f_dense(moving, sds_motor(p, tol, 72))
        assert float(v1) == float(v0) and np.array_equal(np.asarray(g1), np.asarray(g0)), p
    assert len(traces) == 1
    with pytest.raises(EncdesignInputError, match="max_order"):
        sds_motor(6, tol, 71)  # below the motor's own highest order (72)
