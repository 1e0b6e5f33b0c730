"""Kinematic model: closed forms, symmetry, hooks, batching and gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import CRAMER_ECCENTRICITY_M, CRAMER_RADIUS_M, CRAMER_TILT_RAD, cramer_model

import encdesign
from encdesign import EncoderModel, head_errors, head_readings, make_model, noisy_head_readings
from encdesign.physics import head_errors_batch, mode_amplitudes, stack_models
from encdesign.physics._kinematics import _errors, _geometry
from encdesign.physics._reading_math import _atan, _atan_ratio, _grating

N = 512
THETA = jnp.arange(N) * (2 * np.pi / N)


def test_eccentricity_gives_order_one_e_over_r():
    for ecc in [(CRAMER_ECCENTRICITY_M, 0.0), (0.0, CRAMER_ECCENTRICITY_M), (3e-6, 4e-6)]:
        m = make_model(CRAMER_RADIUS_M, [0.0], eccentricity_m=ecc)
        amp = mode_amplitudes(THETA, head_errors(m, THETA)[:, 0], 4)
        expected = 5e-6 / 0.0254  # 196.85 urad
        assert abs(expected * 1e6 - 196.85) < 0.005
        assert abs(amp[0] / expected - 1) < 0.005  # acceptance: within 0.5 %
        assert abs(amp[0] / expected - 1) < 1e-6  # in fact exact to first order
        assert amp[1] < 1e-3 * amp[0]  # higher orders tiny ((e/R)^2 / 2)


def test_tilt_gives_order_two_tilt_squared_over_four():
    for tilt in [(CRAMER_TILT_RAD, 0.0), (0.0, CRAMER_TILT_RAD)]:
        m = make_model(CRAMER_RADIUS_M, [0.0], tilt_rad=tilt)
        amp = mode_amplitudes(THETA, head_errors(m, THETA)[:, 0], 4)
        assert abs(amp[1] * 1e6 - 9.0) < 0.01  # 6 mrad -> 9.0 urad
        assert amp[0] < 1e-15 and amp[2] < 1e-15
    # scales as tilt^2
    small = make_model(CRAMER_RADIUS_M, [0.0], tilt_rad=(1e-3, 0.0))
    amp = mode_amplitudes(THETA, head_errors(small, THETA)[:, 0], 2)
    np.testing.assert_allclose(amp[1], 1e-6 / 4, rtol=1e-5)


def test_perfect_encoder_reads_theta_everywhere():
    angles = jnp.array([0.0, 0.7, 2.5, -2.9, 3.1])
    m = EncoderModel.nominal(0.03, angles, 3)
    theta = jnp.linspace(-20.0, 20.0, 1001)  # several revolutions both ways
    r = head_readings(m, theta)
    assert r.shape == (1001, 5)
    np.testing.assert_allclose(r - theta[:, None], 0.0, atol=5e-15)


def test_grating_error_is_read_as_g_of_theta_by_head_at_zero():
    gs, gc = [1e-6, 0.0, 5e-6], [0.0, 2e-6, -1e-6]
    m = make_model(0.02, [0.0, 1.0], grating_sin_rad=gs, grating_cos_rad=gc)
    e = head_errors(m, THETA)
    j = np.arange(1, 4)
    th = np.asarray(THETA)

    def g(x):
        return np.sin(np.outer(x, j)) @ gs + np.cos(np.outer(x, j)) @ gc

    np.testing.assert_allclose(e[:, 0], g(th), atol=1e-17)
    np.testing.assert_allclose(e[:, 1], g(th - 1.0), atol=1e-17)  # e_k(t) = e_0(t - a_k)


def test_rotational_symmetry_of_full_model():
    m = cramer_model()
    e = head_errors(m, THETA)
    alpha = np.asarray(m.heads.angles_rad)
    for k in range(4):
        shifted = head_errors(m, THETA - alpha[k])[:, 0]
        np.testing.assert_allclose(e[:, k], shifted, atol=1e-15)


def test_placement_error_shifts_phase_and_offsets_reading():
    delta = 1e-3
    m = make_model(0.02, [0.5], placement_error_rad=[delta], grating_sin_rad=[0.0, 3e-6])
    e = head_errors(m, THETA)[:, 0]
    th = np.asarray(THETA)
    np.testing.assert_allclose(e, -delta + 3e-6 * np.sin(2 * (th - 0.5 - delta)), atol=1e-15)


def test_beam_tilt_with_axial_motion_moves_point_read():
    radius, gamma, a1 = 0.02, 0.01, 2e-6
    m = make_model(
        radius, [0.0, 1.0], beam_tilt_rad=[gamma, 0.0], axial_cos_m=[0.0, a1], gap_m=1e-3
    )
    e = np.asarray(head_errors(m, THETA))
    e = e - e.mean(axis=0)
    expected = a1 * np.cos(2 * np.asarray(THETA)) * np.tan(gamma) / radius
    np.testing.assert_allclose(e[:, 0], expected, rtol=1e-5, atol=1e-14)
    assert np.max(np.abs(e[:, 1])) < 1e-15  # an axial beam does not see axial motion


def test_non_synchronous_runout_uses_ratio_and_time():
    radius, rho = 0.02, 1e-6
    m = make_model(radius, [0.0], runout_amplitude_m=rho, runout_ratio=0.4, runout_phase_rad=0.2)
    theta = jnp.linspace(0, 6 * np.pi, 700)  # three revolutions: not periodic in theta
    e = np.asarray(head_errors(m, theta)[:, 0])
    np.testing.assert_allclose(e, rho / radius * np.sin(0.4 * theta + 0.2), rtol=1e-4)
    mt = make_model(radius, [0.0], runout_amplitude_m=rho, runout_freq_hz=3.0)
    t = jnp.linspace(0.0, 1.0, 300)
    et = np.asarray(head_errors(mt, jnp.zeros(300), t)[:, 0])
    np.testing.assert_allclose(et, rho / radius * np.sin(2 * np.pi * 3.0 * t), rtol=1e-4)
    # without time the hook is at t = 0
    np.testing.assert_allclose(head_errors(mt, jnp.zeros(3)), 0.0, atol=1e-20)


def test_scalar_theta_and_shapes():
    m = cramer_model()
    e = head_errors(m, 0.3)
    assert e.shape == (4,)
    np.testing.assert_allclose(head_readings(m, 0.3), 0.3 + e, atol=1e-16)


def test_batch_matches_single_and_chunking():
    models = [cramer_model(eccentricity_m=(x, 0.0)) for x in (1e-6, 2e-6, 3e-6, 4e-6, 5e-6)]
    batch = stack_models(models)
    out = head_errors_batch(batch, THETA[:64], chunk=2)  # 5 designs, chunks of 2
    assert out.shape == (5, 64, 4)
    for i, m in enumerate(models):
        np.testing.assert_allclose(out[i], head_errors(m, THETA[:64]), atol=1e-18)
    vm = jax.vmap(lambda mm: head_errors(mm, THETA[:64]))(batch)
    np.testing.assert_allclose(out, vm, atol=1e-18)


def test_simulated_noise_has_requested_std():
    m = cramer_model(noise_rad=1e-6)
    clean = head_readings(m, THETA)
    noisy = noisy_head_readings(m, THETA, key=jax.random.key(1))
    d = np.asarray(noisy - clean)
    assert 0.9e-6 < d.std() < 1.1e-6
    again = noisy_head_readings(m, THETA, key=jax.random.key(1))
    np.testing.assert_array_equal(noisy, again)


def test_gradient_matches_central_differences():
    theta = THETA[::8]

    @jax.jit
    def f(p):
        m = cramer_model(
            eccentricity_m=(p[0], p[1]),
            tilt_rad=(p[2], 0.0),
            placement_error_rad=jnp.array([0.0, p[3], 0.0, 0.0]),
            beam_tilt_rad=jnp.array([p[4], 0.0, 0.0, 0.0]),
            axial_cos_m=[1e-6],
        )
        e = head_errors(m, theta)
        return jnp.sum(jnp.sin(3 * theta)[:, None] * e) + jnp.sum(e**2) * 1e3

    p0 = jnp.array([5e-6, -2e-6, 6e-3, 1e-4, 0.01])
    fg = jax.jit(jax.value_and_grad(f))  # one program for the values and the gradient
    g = fg(p0)[1]
    steps = jnp.array([1e-8, 1e-8, 1e-6, 1e-7, 1e-6])
    for i in range(5):
        h = steps[i]
        fd = (fg(p0.at[i].add(h))[0] - fg(p0.at[i].add(-h))[0]) / (2 * h)
        np.testing.assert_allclose(g[i], fd, rtol=1e-5)


@pytest.mark.parametrize(
    ("orders", "with_time", "seed"), [(0, False, 0), (3, True, 1), (8, True, 2)]
)
def test_hand_written_reverse_pass_matches_autodiff(orders, with_time, seed):
    """The per-reading reverse pass of ``_errors`` (``_readings_bwd``) against JAX's own
    reverse mode through the same equations (``_geometry`` + ``_grating``), for every leaf
    of a random build with every hook switched on, and for the shaft angles and times."""
    k = jax.random.split(jax.random.key(seed), 10)
    nrm, h = jax.random.normal, 3
    m = make_model(
        0.0254,
        jnp.array([0.0, 2.0, 4.1]),
        eccentricity_m=5e-6 * nrm(k[0], (2,)),
        tilt_rad=3e-3 * nrm(k[1], (2,)),
        grating_sin_rad=1e-6 * nrm(k[2], (orders,)),
        grating_cos_rad=1e-6 * nrm(k[3], (orders,)),
        placement_error_rad=20e-6 * nrm(k[4], (h,)),
        beam_tilt_rad=1e-3 * nrm(k[5], (h,)),
        axial_cos_m=1e-6 * nrm(k[6], (2,)),
        axial_sin_m=1e-6 * nrm(k[7], (2,)),
        runout_amplitude_m=1e-6,
        runout_ratio=0.4,
        runout_phase_rad=0.3,
        runout_freq_hz=0.7 if with_time else 0.0,
    )
    theta = THETA[::4]
    t = theta / (2 * np.pi) if with_time else None
    w = jax.random.normal(k[8], (theta.shape[0], h))

    def plain_at(mm, th, tt):
        geom, s1, c1, psi = _geometry(mm, th, tt)
        d = mm.disk
        return geom + _grating(d.grating_sin_rad, d.grating_cos_rad, s1, c1, psi)

    # every leaf of the model, and the shaft angles and times (inputs, also differentiable)
    # compiled, both in one program (eagerly, every operation is a compile of its own)
    @jax.jit
    def grads(mm, th, tt):
        g_hand = jax.grad(lambda mm, th, tt: jnp.sum(w * _errors(mm, th, tt)), (0, 1, 2))
        g_auto = jax.grad(lambda mm, th, tt: jnp.sum(w * plain_at(mm, th, tt)), (0, 1, 2))
        return g_hand(mm, th, tt), g_auto(mm, th, tt)

    g_hand, g_auto = grads(m, theta, t)
    for a, b in zip(jax.tree.leaves(g_hand), jax.tree.leaves(g_auto), strict=True):
        scale = float(jnp.max(jnp.abs(b))) if b.size else 0.0
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 * scale + 1e-300)


def test_gradient_finite_at_perfect_encoder():
    @jax.jit
    def f(ex):
        return jnp.sum(head_errors(make_model(0.02, [0.0], eccentricity_m=(ex, 0.0)), THETA))

    g = jax.grad(f)(0.0)
    assert np.isfinite(g)
    np.testing.assert_allclose(jax.grad(lambda x: _atan(x))(0.0), 1.0)


def test_atan_matches_numpy():
    x = np.concatenate([np.linspace(-30, 30, 20001), np.logspace(-12, 6, 500), [0.0]])
    x = np.concatenate([x, -x])
    np.testing.assert_allclose(_atan(jnp.asarray(x)), np.arctan(x), rtol=4e-16, atol=1e-300)


@pytest.mark.parametrize("seed", [0, 1])
def test_atan_ratio_matches_arctan2_and_its_derivative(seed):
    """One division per element: every branch of the range reduction (|a/b| below 0.66,
    up to tan(3 pi / 8), beyond), b from 1e-3 to 2, against NumPy's arctan2 (rad)."""
    rng = np.random.default_rng(seed)
    b = rng.uniform(1e-3, 2.0, 20000)
    a = b * np.concatenate(
        [
            rng.uniform(-0.66, 0.66, 5000),
            rng.uniform(0.66, 2.42, 5000),
            -rng.uniform(0.66, 2.42, 5000),
            rng.uniform(-400, 400, 5000),
        ]
    )
    got = np.asarray(_atan_ratio(jnp.asarray(a), jnp.asarray(b)))
    np.testing.assert_allclose(got, np.arctan2(a, b), rtol=1e-15, atol=1e-300)
    da, db = jax.vmap(jax.grad(_atan_ratio, argnums=(0, 1)))(
        jnp.asarray(a[:50]), jnp.asarray(b[:50])
    )
    r2 = a[:50] ** 2 + b[:50] ** 2
    np.testing.assert_allclose(da, b[:50] / r2, rtol=1e-14)
    np.testing.assert_allclose(db, -a[:50] / r2, rtol=1e-14)


def test_invalid_shapes_raise():
    with pytest.raises(ValueError, match="placement_error_rad"):
        make_model(0.02, [0.0, 1.0], placement_error_rad=[0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="optical_radius_m"):
        make_model(-0.02, [0.0])
    with pytest.raises(ValueError, match="eccentricity_m"):
        make_model(0.02, [0.0], eccentricity_m=(1.0, 2.0, 3.0))


def test_public_names():
    for name in ("EncoderModel", "head_readings", "head_errors", "make_model", "Disk"):
        assert hasattr(encdesign, name)


@pytest.mark.parametrize("m", [1, 2, 7, 64])
def test_grating_series_matches_direct_sum_and_its_derivatives(m):
    from encdesign.physics._reading_math import _grating_series

    rng = np.random.default_rng(m)
    psi = jnp.asarray(np.concatenate([rng.uniform(-np.pi, np.pi, 50), [0.0, np.pi, 1e-9]]))
    s = jnp.asarray(rng.normal(size=m) * 1e-6)
    c = jnp.asarray(rng.normal(size=m) * 1e-6)
    j = jnp.arange(1, m + 1)

    def direct(s, c, psi):
        return jnp.sin(psi[:, None] * j) @ s + jnp.cos(psi[:, None] * j) @ c

    def series(s, c, psi):
        return _grating_series(s, c, jnp.sin(psi), jnp.cos(psi))

    np.testing.assert_allclose(series(s, c, psi), direct(s, c, psi), rtol=0, atol=1e-18 * m**2)
    w = jnp.asarray(rng.normal(size=psi.shape))

    @jax.jit  # every derivative of both in one compiled program (eagerly, a compile per op)
    def grads(s, c, psi):
        ga = jax.grad(lambda *a: w @ series(*a), argnums=(0, 1, 2))(s, c, psi)
        gd = jax.grad(lambda *a: w @ direct(*a), argnums=(0, 1, 2))(s, c, psi)
        return ga, gd

    for ga, gd in zip(*grads(s, c, psi), strict=True):  # d/ds, d/dc, d/dpsi
        np.testing.assert_allclose(ga, gd, rtol=1e-9, atol=1e-15 * m**2)
