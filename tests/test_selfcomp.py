"""Self-compensation: cotangent equations, pair averaging, encoder map, sensitivity."""

import jax
import jax.numpy as jnp
import numpy as np
from helpers import CRAMER_HEADS_DEG, CRAMER_REFERENCE_HEAD, cramer_model

from encdesign import (
    apply_map,
    cotangent_sensitivity,
    encoder_map,
    head_errors,
    head_readings,
    make_model,
    self_compensate,
)
from encdesign.physics import averaged_error, cotangent_equations, mode_amplitudes

N = 256
THETA = jnp.arange(N) * (2 * np.pi / N)
ANGLES = np.deg2rad(CRAMER_HEADS_DEG)
REF = CRAMER_REFERENCE_HEAD


def test_cotangent_equations_invert_head_difference():
    rng = np.random.default_rng(1)
    s, c = rng.normal(size=8), rng.normal(size=8)
    h = 0.77
    j = np.arange(1, 9)
    # e_n(theta) = e_0(theta + h): difference coefficients in closed form
    a = c - 1j * s
    ad = a * (np.exp(1j * j * h) - 1)
    s_rec, c_rec = cotangent_equations(-ad.imag, ad.real, h)
    np.testing.assert_allclose(s_rec, s, atol=1e-13)
    np.testing.assert_allclose(c_rec, c, atol=1e-13)


def test_exact_recovery_of_grating_modes_noise_free():
    rng = np.random.default_rng(2)
    gs, gc = rng.normal(0, 3e-6, 9), rng.normal(0, 3e-6, 9)
    m = make_model(0.0254, ANGLES, grating_sin_rad=gs, grating_cos_rad=gc)
    r = head_readings(m, THETA)
    sc = self_compensate(THETA, r, ANGLES, REF, 9)
    assert bool(jnp.all(sc.observable))
    # the reference head's error function is g(theta - alpha_ref)
    expected = head_errors(m, THETA)[:, REF]
    np.testing.assert_allclose(sc.error_function(THETA), expected, atol=1e-17)
    a = (gc - 1j * gs) * np.exp(-1j * np.arange(1, 10) * ANGLES[REF])
    np.testing.assert_allclose(sc.sin_rad, -a.imag, atol=1e-17)
    np.testing.assert_allclose(sc.cos_rad, a.real, atol=1e-17)
    assert float(jnp.max(sc.spread_rad)) < 1e-15  # all pairs agree (to rounding)


def test_cramer_case_residual_after_selfcomp_below_0_01_urad():
    m = cramer_model()
    r = head_readings(m, THETA)
    avg = averaged_error(r[:, :3])  # no reference encoder: abscissa = averaged reading
    sc = self_compensate(avg, r, ANGLES, REF, 12)
    emap = encoder_map(sc, ANGLES[:3])
    before = avg - THETA
    resid = apply_map(emap, avg) - THETA
    resid = resid - jnp.mean(resid)
    assert float(jnp.max(jnp.abs(before - jnp.mean(before)))) > 4.9e-6
    assert float(jnp.max(jnp.abs(resid))) < 1e-8  # 0.01 urad
    # the map (eq. 17) holds only the degenerate orders 3, 6, 9, 12
    amp = np.hypot(emap.sin_rad, emap.cos_rad)
    j = np.arange(1, 13)
    assert np.all(amp[j % 3 != 0] < 1e-15)
    np.testing.assert_allclose(amp[2], 5e-6, rtol=1e-3)
    th, tab = emap.table(64)
    assert th.shape == tab.shape == (64,)


def test_spread_flags_head_specific_error():
    m = cramer_model()
    clean = self_compensate(THETA, head_readings(m, THETA), ANGLES, REF, 6)
    # one head's beam is tilted and the disk moves axially at order 2: breaks the
    # "same error up to a phase" assumption for that head only
    bad_model = cramer_model(beam_tilt_rad=[0.0, 0.05, 0.0, 0.0], axial_cos_m=[0.0, 5e-6])
    bad = self_compensate(THETA, head_readings(bad_model, THETA), ANGLES, REF, 6)
    assert float(jnp.max(clean.spread_rad)) < 1e-12
    assert float(bad.spread_rad[1]) > 1e-6  # order 2 disagrees between pairs
    assert float(bad.spread_rad[1]) > 1e3 * float(clean.spread_rad[1])


def test_unobservable_order_is_masked():
    angles = np.deg2rad([0.0, 180.0, 90.0])  # 2+1 with the reference at 90 deg
    m = make_model(0.02, angles, grating_sin_rad=[0, 0, 0, 1e-6])
    sc = self_compensate(THETA, head_readings(m, THETA), angles, 2, 4)
    # order 4: 4 * 90 / 2 = 180 deg -> sin = 0 for both pairs
    assert not bool(jnp.any(sc.observable[:, 3]))
    assert float(sc.sin_rad[3]) == 0.0 and float(sc.cos_rad[3]) == 0.0
    assert bool(jnp.all(jnp.isfinite(sc.sin_rad)))


def test_cotangent_sensitivity_single_pair_closed_form():
    h = 0.9
    amp, agg = cotangent_sensitivity(h, [0.0], 5)
    j = np.arange(1, 6)
    np.testing.assert_allclose(amp, np.sqrt(2) / (2 * np.abs(np.sin(j * h / 2))), rtol=1e-12)
    np.testing.assert_allclose(agg, np.sqrt(np.mean(np.asarray(amp) ** 2)), rtol=1e-12)


def test_cotangent_sensitivity_matches_monte_carlo():
    ref = np.deg2rad(35.0)
    sym = np.deg2rad([0.0, 120.0, 240.0])
    angles = np.concatenate([sym, [ref]])
    n, trials, sigma = 64, 400, 1e-6
    theta = jnp.arange(n) * (2 * np.pi / n)

    def one(k):
        noise = sigma * jax.random.normal(k, (n, 4))
        sc = self_compensate(theta, noise, angles, 3, 6)
        return sc.sin_rad

    s = jax.vmap(one)(jax.random.split(jax.random.key(0), trials))
    measured = np.std(np.asarray(s), axis=0) / (sigma * np.sqrt(2 / n))
    predicted = np.asarray(cotangent_sensitivity(ref, sym, 6)[0])
    np.testing.assert_allclose(measured, predicted, rtol=0.15)


def test_sensitivity_blows_up_at_blind_angle_and_is_differentiable():
    sym = jnp.deg2rad(jnp.array([0.0, 120.0, 240.0]))
    _, near = cotangent_sensitivity(jnp.deg2rad(40.0001), sym, 9)  # 9 * 40 = 360
    _, good = cotangent_sensitivity(jnp.deg2rad(21.8), sym, 9)
    assert float(near) > 1e3 * float(good)

    def f(r):
        return cotangent_sensitivity(r, sym, 12)[1]

    r0 = jnp.deg2rad(27.0)
    h = 1e-6
    fd = (f(r0 + h) - f(r0 - h)) / (2 * h)
    np.testing.assert_allclose(jax.grad(f)(r0), fd, rtol=1e-5)


def test_gradient_of_residual_objective_matches_finite_differences():
    theta = THETA[::2]

    @jax.jit
    def objective(p):
        # A 3+1 build whose heads are misplaced (unknown to the self-compensation, which
        # uses the nominal angles): mean-square residual after averaging + map, urad^2.
        # p = eccentricity (um), tilt (mrad), placement of head 1 (mrad), grating mode 5
        # (urad): scaled so that one unit moves the objective by a comparable amount.
        m = cramer_model(
            eccentricity_m=(p[0] * 1e-6, 0.0),
            tilt_rad=(p[1] * 1e-3, 0.0),
            placement_error_rad=jnp.array([0.0, p[2] * 1e-3, -15e-3, 0.0]),
            grating_sin_rad=jnp.array([0.0, 0.0, 5e-6, 0.0, p[3] * 1e-6]),
        )
        r = head_readings(m, theta)
        avg = averaged_error(r[:, :3])
        sc = self_compensate(theta, r, ANGLES, REF, 6)
        res = apply_map(encoder_map(sc, ANGLES[:3]), avg) - theta
        res = res - jnp.mean(res)
        return jnp.mean(res**2) * 1e12

    p0 = jnp.array([5.0, 6.0, 20.0, 3.0])
    fg = jax.jit(jax.value_and_grad(objective))  # one program for the values and gradient
    value, g = fg(p0)
    assert float(value) > 0.1  # a real, non-trivial residual
    h = 0.01
    for i in range(4):

        def f(d, i=i):
            return fg(p0.at[i].add(d))[0]

        fd = (8 * (f(h) - f(-h)) - (f(2 * h) - f(-2 * h))) / (12 * h)  # central, 4th order
        np.testing.assert_allclose(g[i], fd, rtol=1e-5)


def test_mode_amplitudes_of_selfcomp_residual_show_mode_six_only():
    m = cramer_model()
    r = head_readings(m, THETA)
    avg = averaged_error(r[:, :3])
    sc = self_compensate(avg, r, ANGLES, REF, 12)
    res = apply_map(encoder_map(sc, ANGLES[:3]), avg) - THETA
    amp = np.asarray(mode_amplitudes(THETA, res, 8))
    assert np.argmax(amp) == 5  # order 6, as in the seed's fig. 8
    assert amp[5] < 1e-10


def test_reference_head_study_quick_json(tmp_path):
    import json

    from encdesign.cli import main

    out = tmp_path / "rh.json"
    argv = ["study", "run", "reference-head", "--quick", "--out", str(tmp_path), "--json", str(out)]
    assert main(argv) == 0
    d = json.loads(out.read_text())
    assert set(d["layouts"]) == {"2+1", "3+1", "4+1"}
    best = d["layouts"]["3+1"]
    assert 15.0 < best["best_reference_angle_deg"] < 30.0
    assert best["best_aggregate_amplification"] < 1.0
    assert all(abs(b - a) > 0.5 for b in best["blind_angles_deg"] for a in [21.8])
    for lay in d["layouts"].values():
        assert 0.75 < lay["monte_carlo_over_predicted_min"] <= lay["monte_carlo_over_predicted_max"]
        assert lay["monte_carlo_over_predicted_max"] < 1.25
    assert (tmp_path / "sensitivity_vs_reference_angle.png").stat().st_size > 10_000
