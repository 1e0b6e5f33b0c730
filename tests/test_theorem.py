"""Encoder theorem: exact cancellation, degenerate modes, modal leakage, Fourier fits."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import cramer_model

from encdesign import head_errors, make_model, surviving_orders
from encdesign.physics import (
    averaged_error,
    fourier_coefficients,
    fourier_series,
    mode_amplitudes,
    mode_transfer,
    model_mode_transfer,
)

N = 256
THETA = jnp.arange(N) * (2 * np.pi / N)
MAX_ORDER = 12


@pytest.mark.parametrize("n_heads", [2, 3, 4, 5])
def test_symmetry_averaging_cancels_non_degenerate_modes_exactly(n_heads):
    rng = np.random.default_rng(n_heads)
    gs = rng.normal(0, 1e-5, MAX_ORDER)
    gc = rng.normal(0, 1e-5, MAX_ORDER)
    angles = np.arange(n_heads) * 2 * np.pi / n_heads + 0.3
    m = make_model(0.02, angles, grating_sin_rad=gs, grating_cos_rad=gc)
    e = head_errors(m, THETA)
    avg = averaged_error(e)
    amp_in = np.hypot(gs, gc)
    amp_out = np.asarray(mode_amplitudes(THETA, avg, MAX_ORDER))
    j = np.arange(1, MAX_ORDER + 1)
    degenerate = j % n_heads == 0
    # cancelled orders: below 1e-9 of the input (acceptance), in fact at rounding level
    assert np.all(amp_out[~degenerate] < 1e-9 * amp_in[~degenerate])
    assert np.all(amp_out[~degenerate] < 1e-12 * amp_in.max())
    # degenerate orders survive unchanged in amplitude
    np.testing.assert_allclose(amp_out[degenerate], amp_in[degenerate], rtol=1e-9)


def test_cramer_case_average_keeps_only_mode_three():
    m = cramer_model()
    e = head_errors(m, THETA)
    single = np.asarray(mode_amplitudes(THETA, e[:, 0], 6)) * 1e6
    avg = np.asarray(mode_amplitudes(THETA, averaged_error(e[:, :3]), 6)) * 1e6
    np.testing.assert_allclose(single[:4], [196.85, 9.0, 5.0, 2.5], rtol=0.003)
    assert abs(avg[2] - 5.0) < 0.01
    assert avg[0] < 1e-3 and avg[1] < 1e-3 and avg[3] < 1e-3
    assert avg[0] < 1e-9 * single[0]


def test_surviving_orders_closed_form():
    t3 = np.asarray(surviving_orders(np.deg2rad([0, 120, 240]), 9))
    np.testing.assert_allclose(t3, [0, 0, 1, 0, 0, 1, 0, 0, 1], atol=1e-14)
    t2 = np.asarray(surviving_orders([0.0, np.pi], 4))
    np.testing.assert_allclose(t2, [0, 1, 0, 1], atol=1e-14)
    # unequal spacing: heads at 0 and 90 deg average order 1 with |(1 + e^{-i pi/2})/2|
    np.testing.assert_allclose(
        surviving_orders([0.0, np.pi / 2], 2), [np.sqrt(0.5), 0.0], atol=1e-15
    )
    # weights: all weight on one head passes everything
    np.testing.assert_allclose(surviving_orders([0.0, 1.0, 2.0], 5, [1, 0, 0]), np.ones(5))


def test_modal_leakage_closed_form_matches_model():
    place = np.array([0.0, 2e-3, -1.5e-3])
    nominal = np.deg2rad([0.0, 120.0, 240.0])
    m = make_model(0.02, nominal, placement_error_rad=place)
    analytic = np.asarray(surviving_orders(nominal + place, MAX_ORDER))
    numeric = np.asarray(model_mode_transfer(m, MAX_ORDER, n_angles=128))
    np.testing.assert_allclose(numeric, analytic, rtol=1e-6, atol=1e-12)
    # leakage of order 1 is first order in the placement error
    lin = abs(np.mean(place * np.exp(-1j * nominal)))
    np.testing.assert_allclose(analytic[0], lin, rtol=1e-2)
    assert analytic[0] > 1e-4  # it does leak


def test_mode_transfer_phase_convention():
    # e_k(theta) = e(theta - alpha_k): the average of a pure mode is T_m times the mode
    angles = np.array([0.0, 0.4, 1.9])
    gs = np.zeros(3)
    gs[1] = 1e-6  # order 2, sin
    m = make_model(0.02, angles, grating_sin_rad=gs)
    avg = averaged_error(head_errors(m, THETA))
    _, s, c = fourier_coefficients(THETA, avg, 3)
    t = complex(mode_transfer(angles, 3)[1])
    a = complex(c[1], -s[1])  # C - i S
    np.testing.assert_allclose(a, t * (0 - 1j * 1e-6), atol=1e-18)


def test_fourier_coefficients_on_uneven_samples():
    rng = np.random.default_rng(0)
    th = np.sort(rng.uniform(0, 4 * np.pi, 300))
    y = 0.5 + 2 * np.sin(th) - 3 * np.cos(2 * th) + 0.25 * np.sin(5 * th)
    c0, s, c = fourier_coefficients(th, y, 6)
    np.testing.assert_allclose(c0, 0.5, atol=1e-12)
    np.testing.assert_allclose(s, [2, 0, 0, 0, 0.25, 0], atol=1e-12)
    np.testing.assert_allclose(c, [0, -3, 0, 0, 0, 0], atol=1e-12)
    with pytest.raises(ValueError, match="cannot resolve"):
        fourier_coefficients(th[:10], y[:10], 6)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_fourier_series_inverts_fourier_coefficients(seed):
    """The series of the fitted coefficients is the sampled function less its constant, at
    any angle shape; the compensation results and the map evaluate it the same way."""
    from encdesign.physics import EncoderMap

    rng = np.random.default_rng(seed)
    m = int(rng.integers(2, 9))
    s_true, c_true = rng.normal(size=m), rng.normal(size=m)
    th = np.sort(rng.uniform(0, 2 * np.pi, 4 * m + 3))
    y = sum(s_true[j] * np.sin((j + 1) * th) + c_true[j] * np.cos((j + 1) * th) for j in range(m))
    c0, s, c = fourier_coefficients(th, y + 0.7, m)
    np.testing.assert_allclose(fourier_series(th, s, c), y, atol=1e-10)
    grid = rng.uniform(-7, 7, (2, 3))
    direct = sum(
        s_true[j] * np.sin((j + 1) * grid) + c_true[j] * np.cos((j + 1) * grid) for j in range(m)
    )
    np.testing.assert_allclose(fourier_series(grid, s_true, c_true), direct, atol=1e-12)
    emap = EncoderMap(sin_rad=jnp.asarray(s_true), cos_rad=jnp.asarray(c_true))
    assert emap.max_order == m
    np.testing.assert_allclose(emap(grid), direct, atol=1e-12)
    np.testing.assert_allclose(emap.error_function(grid), direct, atol=1e-12)


def test_averaged_error_weights():
    e = jnp.array([[1.0, 2.0, 4.0]])
    np.testing.assert_allclose(averaged_error(e), [7 / 3])
    np.testing.assert_allclose(averaged_error(e, [1, 1, 2]), [11 / 4])


def test_transfer_differentiable_in_head_angles():
    def f(a):
        return jnp.sum(surviving_orders(a, 6) ** 2)

    a0 = jnp.array([0.1, 2.0, 4.5])
    g = jax.grad(f)(a0)
    h = 1e-6
    for i in range(3):
        fd = (f(a0.at[i].add(h)) - f(a0.at[i].add(-h))) / (2 * h)
        np.testing.assert_allclose(g[i], fd, rtol=1e-5)


def test_cramer_study_quick_json(tmp_path):
    import json

    from encdesign.cli import main

    out = tmp_path / "cramer.json"
    rc = main(["study", "run", "cramer", "--quick", "--out", str(tmp_path), "--json", str(out)])
    assert rc == 0
    d = json.loads(out.read_text())
    head, avg = d["head_mode_amplitude_urad"], d["averaged_mode_amplitude_urad"]
    assert len(head) == 6 and len(avg) == 6
    np.testing.assert_allclose(head[:4], [196.85, 9.0, 5.0, 2.5], rtol=0.003)
    assert abs(avg[2] - 5.0) < 0.01
    assert max(avg[0], avg[1], avg[3]) < 1e-3
    assert d["selfcomp_residual_max_urad"] < 0.01
    for png in ("error_vs_angle.png", "mode_spectra.png", "modal_leakage.png"):
        assert (tmp_path / png).stat().st_size > 10_000
