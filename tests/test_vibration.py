"""Vibration (eq. 5), the doublet, the accelerometer-free excitation estimate, the study."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import QUADRATURE_ERRORS, QUADRATURE_PITCH_M

import encdesign as ed
from encdesign.cli import main as cli_main

FS = 16384.0
T = jnp.arange(2048) / FS


def test_eq5_piecewise_form_equals_product_form():
    f, fe, phi, delta = 40.0, 700.0, 0.4, 0.1
    t = np.asarray(T)
    big_t = 1 / f
    i = np.floor((t + big_t / 4) / (big_t / 2))  # (2i-1)T/4 < t <= (2i+1)T/4
    theta = 2 * np.pi * fe * t + phi
    seed = (-1) ** i * delta * np.abs(np.sinc(np.sin(0.5 * theta)) * np.cos(2 * np.pi * f * t))
    d_a, d_b = ed.physics.eq5_signal_terms(t, 2 * np.pi * f * t, delta, fe, phi)
    ok = np.abs(np.cos(2 * np.pi * f * t)) > 1e-9  # boundaries: both are ~0 there
    np.testing.assert_allclose(np.asarray(d_a)[ok], seed[ok], atol=1e-12)
    np.testing.assert_allclose(
        d_b, -delta * np.sinc(np.sin(0.5 * theta)) * np.sin(2 * np.pi * f * t)
    )


def test_eq5_is_first_order_of_displacement():
    e = ed.SignalErrors()
    v, fe, a = 0.8e-3, 700.0, 0.02e-6
    vib = ed.Vibration(a, fe, 0.3, shape="sinc")
    sa, sb = ed.physics.vibrating_signals(T, v, QUADRATURE_PITCH_M, e, vib)
    sa0, sb0 = ed.physics.vibrating_signals(T, v, QUADRATURE_PITCH_M, e)
    psi = 2 * np.pi * v * T / QUADRATURE_PITCH_M
    d_a, d_b = ed.physics.eq5_signal_terms(T, psi, 2 * np.pi * a / QUADRATURE_PITCH_M, fe, 0.3)
    np.testing.assert_allclose(sa - sa0, d_a, atol=1e-4 * float(jnp.max(jnp.abs(d_a))) * 100)
    np.testing.assert_allclose(sb - sb0, d_b, atol=1e-2 * float(jnp.max(jnp.abs(d_b))))


def test_doublet_and_excitation_estimate():
    e = ed.SignalErrors(**QUADRATURE_ERRORS)
    v, fe, phi, a = 2.0e-3, 1000.0, 1.1, 0.4e-6
    sa, _ = ed.physics.vibrating_signals(
        T,
        v,
        QUADRATURE_PITCH_M,
        e,
        ed.Vibration(a, fe, phi),
        amplitude=0.5,
        noise_std=0.003,
        key=jax.random.PRNGKey(0),
    )
    freq, spec = ed.physics.signal_spectrum(T, sa)
    f = v / QUADRATURE_PITCH_M

    def at(x):
        return spec[np.argmin(np.abs(freq - x))]

    # a doublet at f_exc -+ f and (almost) nothing at f_exc itself
    assert at(fe - f) > 0.02 and at(fe + f) > 0.02
    assert at(fe) < 0.05 * at(fe - f)
    est = ed.physics.estimate_excitation(T, sa)
    assert est.success
    assert abs(est.f_signal_hz - f) < 0.05
    assert abs(est.f_exc_hz - fe) < 0.05
    assert abs(np.angle(np.exp(1j * (est.vibration_phase_rad - phi)))) < 0.05
    np.testing.assert_allclose(
        est.phase_amplitude_rad * QUADRATURE_PITCH_M / (2 * np.pi), a, rtol=0.05
    )


def test_no_vibration_no_doublet():
    sa, _ = ed.physics.vibrating_signals(
        T,
        1e-3,
        QUADRATURE_PITCH_M,
        ed.SignalErrors(),
        amplitude=0.5,
        noise_std=0.003,
        key=jax.random.PRNGKey(1),
    )
    est = ed.physics.estimate_excitation(T, sa, throw=False)
    assert est.status == 1
    with pytest.raises(ed.EncdesignInputError, match="doublet"):
        ed.physics.estimate_excitation(T, sa)


def test_bad_time_and_vibration_input():
    sa = jnp.sin(jnp.arange(100.0))
    t = np.arange(100) / FS
    t[50] = t[49]
    with pytest.raises(ed.EncdesignInputError, match="increasing"):
        ed.physics.estimate_excitation(t, sa)
    with pytest.raises(ed.EncdesignInputError, match="t_s"):
        ed.physics.estimate_excitation(np.arange(99) / FS, sa)
    with pytest.raises(ed.EncdesignInputError, match="shape"):
        ed.Vibration(1e-6, 700.0, shape="square")
    with pytest.raises(ed.EncdesignInputError, match="frequency"):
        ed.Vibration(1e-6, -5.0)


def test_vibration_error_rad_grad():
    g = jax.grad(lambda a: jnp.sum(ed.physics.vibration_error_rad(T[:10], a, 700.0, 0.2)))(1e-6)
    np.testing.assert_allclose(g, np.sum(np.sin(2 * np.pi * 700 * np.asarray(T[:10]) + 0.2)))


def test_study_quick_writes_error_area_reduction(tmp_path):
    out = tmp_path / "q.json"
    assert (
        cli_main(
            [
                "study",
                "run",
                "quadrature",
                "--quick",
                "--out",
                str(tmp_path),
                "--json",
                str(out),
                "--no-plots",
            ]
        )
        == 0
    )
    d = json.loads(out.read_text())
    assert set(d["error_area_reduction"]) == {c["case"] for c in d["cases"]}
    assert len(d["cases"]) == 5
    for c in d["cases"]:
        assert 0.5 < c["error_area_reduction"] < 1.0
        assert abs(c["estimated_f_exc_hz"] - c["f_exc_hz"]) < 0.5
    comp = d["error_components_no_vibration_um"]
    np.testing.assert_allclose(
        comp["line_frequency_measured"], comp["line_frequency_eq4"], rtol=0.15
    )
    np.testing.assert_allclose(
        comp["twice_line_frequency_measured"], comp["twice_line_frequency_eq4"], rtol=0.15
    )
