"""Ellipse fit, Heydemann correction, compensation signal (eq. 4, 6, 7) and the LUT."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import QUADRATURE_ERRORS, QUADRATURE_PITCH_M

import encdesign as ed

AMP = 0.5


def noisy_signals(n=2000, noise=0.01 * AMP, key=0, errors=None):
    e = errors or ed.SignalErrors(**QUADRATURE_ERRORS)
    x = jnp.linspace(0.0, 37.3 * QUADRATURE_PITCH_M, n)
    return ed.synthesize_signals(
        x, QUADRATURE_PITCH_M, e, amplitude=AMP, noise_std=noise, key=jax.random.PRNGKey(key)
    )


@pytest.mark.parametrize("method", ["direct", "heydemann"])
def test_fit_recovers_parameters_from_noisy_signals(method):
    # noise 1 % of the amplitude, 2000 samples: stated tolerances 0.3 % of A for offsets and
    # amplitude ratio, 3 mrad for the phase
    sa, sb = noisy_signals()
    fit = ed.fit_ellipse(sa, sb, method=method)
    assert int(fit.status) == 0
    got = fit.params.to_signal_errors()
    assert abs(float(got.offset_a) - QUADRATURE_ERRORS["offset_a"]) < 0.003
    assert abs(float(got.offset_b) - QUADRATURE_ERRORS["offset_b"]) < 0.003
    assert abs(float(got.amplitude_ratio) - QUADRATURE_ERRORS["amplitude_ratio"]) < 0.003
    assert abs(float(got.phase_error_rad) - QUADRATURE_ERRORS["phase_error_rad"]) < 0.003
    assert abs(float(fit.params.amplitude_b) - AMP) < 0.003 * AMP
    assert 0.007 < float(fit.rms_radial_residual) < 0.013  # the 1 % noise


def test_no_error_gives_zero_correction():
    sa, sb = noisy_signals(noise=0.0, errors=ed.SignalErrors())
    fit = ed.fit_ellipse(sa, sb)
    p = fit.params
    np.testing.assert_allclose(
        [p.offset_a, p.offset_b, p.amplitude_a, p.amplitude_b, p.phase_rad],
        [0, 0, AMP, AMP, 0],
        atol=1e-10,
    )
    raw = jnp.arctan2(sa, sb)
    assert float(jnp.max(jnp.abs(ed.physics.corrected_phase_rad(sa, sb, p) - raw))) < 1e-10
    comp = ed.physics.compensation_signal_m(
        jnp.arange(sa.size) * 1e-4, raw, QUADRATURE_PITCH_M, p.to_signal_errors()
    )
    assert float(jnp.max(jnp.abs(comp))) < 1e-15


def test_correction_removes_metrological_error():
    e = ed.SignalErrors(**QUADRATURE_ERRORS)
    sa, sb = noisy_signals(noise=0.0)
    x = jnp.linspace(0.0, 37.3 * QUADRATURE_PITCH_M, sa.size)
    fit = ed.fit_ellipse(sa, sb)
    before = ed.physics.position_from_signals_m(sa, sb, QUADRATURE_PITCH_M) - x
    after = ed.physics.position_from_signals_m(sa, sb, QUADRATURE_PITCH_M, fit.params) - x
    assert float(jnp.max(jnp.abs(before))) > 1e-7
    assert float(jnp.max(jnp.abs(after))) < 1e-15 * 1e3
    # the seed's eq.-4 compensation signal removes it to first order
    phase = 2 * np.pi * (before + x) / QUADRATURE_PITCH_M
    comp = ed.physics.compensation_signal_m(
        0.0, phase, QUADRATURE_PITCH_M, fit.params.to_signal_errors()
    )
    resid = before - comp
    assert float(jnp.max(jnp.abs(resid))) < 0.1 * float(jnp.max(jnp.abs(before)))
    np.testing.assert_allclose(ed.EllipseParams.from_signal_errors(e, AMP).phase_rad, 0.05)


def test_fit_differentiable_jit_vmap_and_chunked():
    sa, sb = noisy_signals(n=60, key=3)

    def phase(a):
        return ed.fit_ellipse(a, sb, method="direct").params.phase_rad

    fg = jax.jit(jax.value_and_grad(phase))  # one program for the values and the gradient
    g = fg(sa)[1]
    h = 1e-6
    for i in (0, 17, 41):
        fd = (fg(sa.at[i].add(h))[0] - fg(sa.at[i].add(-h))[0]) / (2 * h)
        np.testing.assert_allclose(g[i], fd, rtol=1e-5, atol=1e-9)
    f_chunk = ed.fit_ellipse(sa, sb, chunk_size=7)
    np.testing.assert_allclose(f_chunk.params.phase_rad, phase(sa), rtol=1e-10)
    batch = jax.vmap(lambda a, b: ed.fit_ellipse(a, b, throw=False).params.offset_a)(
        jnp.stack([sa, sa + 0.1]), jnp.stack([sb, sb])
    )
    np.testing.assert_allclose(batch[1] - batch[0], 0.1, atol=1e-10)


def test_bad_input_is_refused():
    sa, sb = noisy_signals(n=50)
    with pytest.raises(ed.EncdesignInputError, match="equal lengths"):
        ed.fit_ellipse(sa, sb[:-1])
    with pytest.raises(ed.EncdesignInputError, match="constant"):
        ed.fit_ellipse(jnp.ones(50), sb)
    with pytest.raises(ed.EncdesignInputError, match="non-finite"):
        ed.fit_ellipse(sa.at[3].set(jnp.nan), sb)
    with pytest.raises(ed.EncdesignInputError, match="method"):
        ed.fit_ellipse(sa, sb, method="magic")
    t = jnp.linspace(0, 1, 50)
    with pytest.raises(ed.EncdesignInputError, match="ellipse"):
        ed.fit_ellipse(t, 2 * t + 1, method="heydemann")  # a line: no ellipse
    fit = ed.fit_ellipse(t, 2 * t + 1, method="heydemann", throw=False)
    assert int(fit.status) != 0


def test_lut_from_shaker_arcs():
    e = ed.SignalErrors(**QUADRATURE_ERRORS)
    fs = 16384.0
    t = jnp.arange(1024) / fs
    freqs = jnp.array([300.0, 700.0, 1500.0])
    amps = jnp.array([0.2e-6, 0.5e-6, 0.35e-6])
    rows = [
        ed.physics.vibrating_signals(
            t,
            0.0,
            QUADRATURE_PITCH_M,
            e,
            ed.Vibration(a, f, 0.4),
            x0_m=6e-6,
            amplitude=AMP,
            noise_std=0.002,
            key=jax.random.PRNGKey(i),
        )
        for i, (a, f) in enumerate(zip(amps, freqs))
    ]
    sa = jnp.stack([r[0] for r in rows])
    sb = jnp.stack([r[1] for r in rows])
    params = ed.EllipseParams.from_signal_errors(e, AMP)
    lut = ed.physics.build_vibration_lut(freqs, t, sa, sb, params, QUADRATURE_PITCH_M)
    np.testing.assert_allclose(lut.delta_gm_m, 2 * amps, rtol=0.02)
    span = ed.physics.build_vibration_lut(
        freqs, t, sa, sb, params, QUADRATURE_PITCH_M, method="span"
    )
    assert bool(jnp.all(span.delta_gm_m > 0.95 * 2 * amps))
    np.testing.assert_allclose(lut(500.0), 0.5 * (lut.delta_gm_m[0] + lut.delta_gm_m[1]))
    g = jax.grad(lambda f: lut(f))(500.0)
    np.testing.assert_allclose(g, (lut.delta_gm_m[1] - lut.delta_gm_m[0]) / 400.0)
    with pytest.raises(ed.EncdesignInputError, match="increasing"):
        ed.physics.VibrationLUT(jnp.array([2.0, 1.0]), jnp.array([1e-6, 1e-6]))
    with pytest.raises(ed.EncdesignInputError, match="frequencies"):
        ed.physics.build_vibration_lut(freqs[:2], t, sa, sb, params, QUADRATURE_PITCH_M)


def test_eq6_and_eq7():
    t = jnp.linspace(0, 0.01, 11)
    u = ed.physics.vibration_compensation_m(t, 1e-6, 700.0, 0.3, 2e-8)
    np.testing.assert_allclose(u, 2e-8 + 0.5e-6 * np.sin(2 * np.pi * 700 * t + 0.3))
    assert ed.physics.seed_eq7_choice(0.2, 3.0, -0.01) == (0.2, 1)
    assert ed.physics.seed_eq7_choice(0.2, 3.0, 0.01) == (3.0, -1)


NMM = Path("/work/shared/realdata/nmm_X_raw.csv")


@pytest.mark.skipif(not NMM.exists(), reason="shared real data not present")
def test_fit_on_real_interferometer_capture():
    from encdesign.io._realdata import read_nmm_csv

    phase, r = read_nmm_csv(NMM)
    fit = ed.fit_ellipse(r * np.cos(phase), r * np.sin(phase))
    p = fit.params
    assert int(fit.status) == 0
    assert abs(float(p.offset_a)) < 10 and abs(float(p.offset_b)) < 10  # ADC counts
    assert 490 < float(p.amplitude_a) < 510 and 490 < float(p.amplitude_b) < 510
    assert abs(float(p.phase_rad)) < 0.05
    assert float(fit.rms_radial_residual) < 0.01
