"""Quadrature signals (eq. 1-4): exact vs first-order error, shaft mapping, bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import QUADRATURE_ERRORS

import encdesign as ed
from encdesign.physics._quadrature import check_signals

PSI = jnp.linspace(0.0, 2 * np.pi, 721)


def rel_rms(a, b):
    return float(jnp.sqrt(jnp.mean((a - b) ** 2)) / jnp.sqrt(jnp.mean(b**2)))


def test_ideal_signals_have_no_error():
    e = ed.SignalErrors()
    sa, sb = ed.quadrature_signals(PSI, e, 2.0)
    np.testing.assert_allclose(sa, 2 * np.sin(PSI), atol=1e-15)
    np.testing.assert_allclose(sb, 2 * np.cos(PSI), atol=1e-15)
    assert float(jnp.max(jnp.abs(ed.phase_error_exact_rad(PSI, e)))) < 1e-14
    assert float(jnp.max(jnp.abs(ed.physics.phase_error_eq4_rad(PSI, e).total))) == 0.0


@pytest.mark.parametrize(
    "kw",
    [
        {"offset_a": 0.01},
        {"offset_b": 0.01},
        {"amplitude_ratio": 1.01},
        {"phase_error_rad": 0.01},
        {"harmonics_a": [[0.0, 0.0], [0.01, 0.0]]},
        {"offset_a": 0.01, "offset_b": -0.01, "amplitude_ratio": 0.99, "phase_error_rad": 0.01},
    ],
)
def test_eq4_matches_exact_to_first_order(kw):
    e1 = ed.SignalErrors(**kw)
    exact = ed.phase_error_exact_rad(PSI, e1)
    first = ed.physics.phase_error_eq4_rad(PSI, e1).total
    r1 = rel_rms(first, exact)
    assert r1 < 0.05  # acceptance: 5 % at 1 % errors
    # and the disagreement is second order: doubling the errors doubles the relative gap
    kw2 = {
        k: (1 + 2 * (np.asarray(v) - 1)) if k == "amplitude_ratio" else 2 * np.asarray(v)
        for k, v in kw.items()
    }
    r2 = rel_rms(
        ed.physics.phase_error_eq4_rad(PSI, ed.SignalErrors(**kw2)).total,
        ed.phase_error_exact_rad(PSI, ed.SignalErrors(**kw2)),
    )
    assert 1.6 < r2 / r1 < 2.4


def test_eq4_terms_are_the_seed_expressions():
    p = 20e-6
    x = jnp.linspace(0, 3 * p, 301)
    psi = 2 * np.pi * x / p
    e = ed.SignalErrors(offset_a=0.02, amplitude_ratio=1.03, phase_error_rad=0.04)
    t = ed.physics.eq4_terms_m(x, p, e)
    np.testing.assert_allclose(t.offset, p / (2 * np.pi) * np.cos(psi) * 0.02, atol=1e-20)
    np.testing.assert_allclose(t.amplitude, p / (4 * np.pi) * np.sin(2 * psi) * 0.03, atol=1e-20)
    np.testing.assert_allclose(t.phase, p / (2 * np.pi) * np.cos(psi) ** 2 * 0.04, atol=1e-20)
    exact = ed.physics.interpolation_error_m(x, p, e)
    assert rel_rms(t.total, exact) < 0.06


def test_error_harmonics_line_frequency_and_twice():
    e = ed.SignalErrors(**QUADRATURE_ERRORS)
    mean, amp = ed.physics.error_harmonics(e, first_order=True)
    b = np.hypot(QUADRATURE_ERRORS["offset_a"], QUADRATURE_ERRORS["offset_b"])
    two = 0.5 * np.hypot(
        QUADRATURE_ERRORS["amplitude_ratio"] - 1, QUADRATURE_ERRORS["phase_error_rad"]
    )
    np.testing.assert_allclose(amp[:2], [b, two], rtol=1e-12)
    assert float(amp[2]) < 1e-12 and float(amp[3]) < 1e-12
    np.testing.assert_allclose(mean, QUADRATURE_ERRORS["phase_error_rad"] / 2, rtol=1e-12)
    mean_x, amp_x = ed.physics.error_harmonics(e)
    np.testing.assert_allclose(amp_x[:2], amp[:2], rtol=0.1)


def test_third_harmonic_gives_orders_two_and_four():
    e = ed.SignalErrors(harmonics_a=[[0.0, 0.0], [0.02, 0.0]])  # 2 % third harmonic on S_A
    _, amp = ed.physics.error_harmonics(e, max_order=5)
    assert float(amp[1]) > 0.009 and float(amp[3]) > 0.009
    assert float(amp[0]) < 1e-4 and float(amp[2]) < 1e-3


def test_interpolation_error_shaft_angle_per_head_jit_grad():
    lines = 3600
    heads = 3
    e = ed.SignalErrors(
        offset_a=jnp.array([0.01, 0.0, -0.02]),
        offset_b=jnp.array([0.0, 0.015, 0.0]),
        amplitude_ratio=jnp.array([1.0, 1.02, 0.99]),
        phase_error_rad=jnp.array([0.0, 0.01, 0.02]),
    )
    theta = jnp.linspace(0, 2 * np.pi / lines * 2, 200)[:, None] + jnp.zeros(heads)
    f = jax.jit(ed.physics.interpolation_error_rad, static_argnums=1)
    err = f(theta, lines, e)
    assert err.shape == (200, heads)
    psi = lines * theta
    np.testing.assert_allclose(err, ed.phase_error_exact_rad(psi, e) / lines, atol=1e-18)
    # vmap over a batch of designs
    batch = jax.vmap(
        lambda oa: ed.physics.interpolation_error_rad(theta, lines, ed.SignalErrors(oa))
    )(jnp.array([0.0, 0.01]))
    assert batch.shape == (2, 200, heads)
    assert float(jnp.max(jnp.abs(batch[0]))) < 1e-18

    def loss(x):
        ee = ed.SignalErrors(x[0], x[1], x[2], x[3])
        return jnp.sum(ed.physics.interpolation_error_rad(theta, lines, ee) ** 2) * 1e12

    x0 = jnp.array([0.01, -0.02, 1.03, 0.02])
    # compiled (eagerly, every operation compiles): one program for the values and gradient
    fg, h = jax.jit(jax.value_and_grad(loss)), 1e-6
    g = fg(x0)[1]
    fd = [(fg(x0.at[i].add(h))[0] - fg(x0.at[i].add(-h))[0]) / (2 * h) for i in range(4)]
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-9)


def test_composes_with_kinematic_model():
    kin = pytest.importorskip("encdesign.physics._kinematics")
    lines = 512
    model = kin.make_model(
        0.02, jnp.deg2rad(jnp.array([0.0, 120.0, 240.0])), eccentricity_m=(2e-6, 0.0)
    )
    n = 8192
    theta = jnp.arange(n) * (2 * np.pi / n)
    e = ed.SignalErrors(
        offset_a=jnp.array([0.02, 0.0, 0.0]), phase_error_rad=jnp.array([0.0, 0.0, 0.03])
    )

    @jax.jit
    def total(ecc_x):
        m = kin.make_model(
            0.02, jnp.deg2rad(jnp.array([0.0, 120.0, 240.0])), eccentricity_m=(ecc_x, 0.0)
        )
        r = kin.head_readings(m, theta)
        return r + ed.physics.interpolation_error_rad(r, lines, e)

    r = kin.head_readings(model, theta)
    err = total(2e-6) - r
    spec = np.abs(np.fft.rfft(np.asarray(err), axis=0)) * 2 / n
    # head 0: offsets -> order L, amplitude 0.02 / L; head 2: phase -> order 2L, 0.015 / L
    np.testing.assert_allclose(spec[lines, 0], 0.02 / lines, rtol=0.02)
    np.testing.assert_allclose(spec[2 * lines, 2], 0.015 / lines, rtol=0.02)
    assert spec[lines, 1] < 1e-9 / lines
    g = jax.grad(lambda x: jnp.sum(total(x)[:, 0]))(2e-6)
    assert np.isfinite(float(g))


def test_bad_signal_errors_and_signals():
    with pytest.raises(ed.EncdesignInputError, match="harmonics_a"):
        ed.SignalErrors(harmonics_a=[0.1, 0.2, 0.3])
    with pytest.raises(ed.EncdesignInputError, match="amplitude_ratio"):
        ed.SignalErrors(amplitude_ratio=-1.0)
    with pytest.raises(ed.EncdesignInputError, match="offset_a"):
        ed.SignalErrors(offset_a=float("nan"))
    with pytest.raises(ed.EncdesignInputError, match="phase_error_rad"):
        ed.SignalErrors(phase_error_rad=2.0)
    with pytest.raises(ed.EncdesignInputError, match="equal lengths"):
        check_signals(np.ones(10), np.ones(11))
    with pytest.raises(ed.EncdesignInputError, match="constant"):
        check_signals(np.full(10, 0.3), np.sin(np.arange(10.0)))
    x = np.sin(np.arange(10.0))
    x[4] = np.nan
    with pytest.raises(ed.EncdesignInputError, match=r"sa\[4\]"):
        check_signals(x, np.cos(np.arange(10.0)))
    with pytest.raises(ed.EncdesignInputError, match="key"):
        ed.synthesize_signals(jnp.zeros(3), 20e-6, ed.SignalErrors(), noise_std=0.1)


def test_matches_discrepancy_finder_convention():
    eff = pytest.importorskip("encdesign.physics._effects")
    lines = 100
    r = jnp.linspace(0.0, 0.2, 500)[:, None]
    oa, ob, eps, d = 0.02, -0.01, 0.03, 0.04
    theirs = eff.interpolation_error_exact_rad(
        r, lines, jnp.array([oa]), jnp.array([ob]), jnp.array([eps]), jnp.array([d])
    )
    e = ed.SignalErrors(oa / (1 + eps), ob / (1 + eps), 1 / (1 + eps), -d)
    ours = ed.physics.interpolation_error_rad(r, lines, e, phase_offset_rad=d) + d / lines
    np.testing.assert_allclose(ours, theirs, atol=1e-15)
