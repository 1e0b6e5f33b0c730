"""Issue 43: the base term's factored Jacobian (``kinds/multihead/_fourier.py``): the angle-addition
table of ``cos(m theta)``, ``sin(m theta)`` (``engine._views_orders.harmonics``) within its stated
bound, the factors ``J = X W`` against the compiled linear Jacobian, and the fitter's processed
static block made from them (one product, no compiled Jacobian) against the one made from ``J``."""

from __future__ import annotations

import numpy as np
import pytest

import encdesign  # noqa: F401  (float64)
from encdesign.diagnose.engine._views_orders import harmonics
from encdesign.diagnose.kinds.multihead._fourier import TRIG_TABLE_ERROR
from encdesign.diagnose.kinds.multihead._multihead import _base_candidate

EPS = np.finfo(float).eps


def test_trig_table_within_its_stated_bound():
    """Against ``cos(m theta)`` in extended precision (``m theta`` exact there): within
    ``TRIG_TABLE_ERROR m eps`` at every order; the error grows with ``m`` (it is the
    recurrence's, not the reference's)."""
    rng = np.random.default_rng(3)
    th = np.concatenate([rng.uniform(-7, 7, 4000), rng.uniform(0, 2e3, 4000)])
    M = 64
    cm, sm = harmonics(th, M)
    m = np.arange(1, M + 1)[:, None]
    arg = m.astype(np.longdouble) * th.astype(np.longdouble)[None, :]
    err = np.maximum(np.abs(cm - np.cos(arg)), np.abs(sm - np.sin(arg))).astype(float)
    assert np.all(err <= TRIG_TABLE_ERROR * m * EPS + EPS)
    assert err[-8:].max() > 4 * err[:8].max()  # grows with the order
    with pytest.raises(AssertionError):  # (a bound of eps alone would be broken)
        assert np.all(err <= 2 * EPS)


@pytest.mark.parametrize("C,R,M,held", [(4, 4, 12, ()), (3, 1, 7, (3,)), (1, 2, 5, ())])
def test_base_factors_equal_the_linear_jacobian(C, R, M, held):
    """``X W`` equals the compiled linear Jacobian (``linear_valjac``, gathered by a free
    mask with one order held) to the rounding of ``m phi``; the value at zero is 0."""
    from encdesign.diagnose.engine._normal import factors_of, linear_valjac

    cand = _base_candidate(C, R, M, held)
    rng = np.random.default_rng(C + 10 * R + 100 * M)
    n = 700
    x = {
        "theta_raw": np.cumsum(rng.uniform(0, 0.05, n)) + 30.0,
        "run_onehot": np.eye(R)[rng.integers(0, R, n)],
        "alpha": np.arange(C) * 2 * np.pi / C + 0.1,
    }
    p = {"offset_rad": np.zeros((R, C)), "fourier_cos_rad": np.zeros(M)}
    p["fourier_sin_rad"] = np.zeros(M)
    if C > 1:
        p["placement_rad"] = rng.normal(0, 1e-3, C - 1)
    if R > 1:
        p["run_angle_offset_rad"] = rng.normal(0, 0.1, R - 1)
    free = {q.name: np.full(np.shape(p[q.name]), q.linear) for q in cand.params}
    free["fourier_cos_rad"][1] = False
    v0, J = linear_valjac(cand)(p, x)
    lin = ("offset_rad", "fourier_cos_rad", "fourier_sin_rad")
    want = [np.asarray(J[k]).reshape(n, C, -1)[:, :, free[k].ravel()] for k in lin]
    want = np.concatenate(want, 2)
    factors = factors_of(cand)
    assert factors is not None
    v, X, W, E = factors(p, x, free, n)
    assert E is None
    assert X.shape == (n, R + 2 * M) and W.shape == (R + 2 * M, C, want.shape[2])
    got = (X @ W.reshape(W.shape[0], -1)).reshape(want.shape)
    bound = (TRIG_TABLE_ERROR * M + M * 120.0) * EPS  # the table's and m |phi| eps, |phi| < 120
    np.testing.assert_allclose(got, want, rtol=0, atol=bound)
    np.testing.assert_array_equal(v, np.asarray(v0))


def test_static_block_from_factors_equals_the_jacobian_and_compiles_nothing(monkeypatch):
    """The fitter's statistics of the held base (the static block), made from its factors,
    equal those made from the compiled Jacobian (the factors switched off) to rounding, and
    the pass evaluates no compiled Jacobian of the base (a counter: it fails without the
    factors)."""
    from encdesign.diagnose.engine import _fit
    from encdesign.diagnose.engine._fit import Fitter
    from tests.test_fit_fast import _bench_base

    real = _fit.linear_valjac
    calls: list = []
    monkeypatch.setattr(_fit, "linear_valjac", lambda c: calls.append(c) or real(c))
    for ref in (True, False):
        prep, cand, held = _bench_base(ref)
        calls.clear()
        A, g, c, ssr, sc = Fitter(prep).stats(held)
        assert cand not in calls  # no compiled Jacobian of the base: one product X (P W)
        with monkeypatch.context() as mp:
            mp.setattr(_fit, "factors_of", lambda c: None)
            A0, g0, c0, ssr0, sc0 = Fitter(prep).stats(held)
        assert cand in calls
        np.testing.assert_allclose(A, A0, rtol=1e-12, atol=1e-13 * np.abs(A0).max())
        # the gradient S^T r: to the rounding of the prediction (offsets of radians under a
        # micro-radian residual), |S_j| 10 eps |y| whitened (Cauchy-Schwarz)
        yw = np.sqrt(np.sum(prep.y[prep.keep] ** 2 / prep.sigma**2))
        assert np.all(np.abs(g - g0) <= 10 * EPS * np.sqrt(np.einsum("kjj->kj", A0)) * yw)
        # (chi-square: the same rounding, eps |y| / |r| ~ 1e-9 relative at most)
        np.testing.assert_allclose(c, c0, rtol=1e-9)
        np.testing.assert_allclose(ssr, ssr0, rtol=1e-9)
        np.testing.assert_array_equal(sc, sc0)


@pytest.mark.parametrize("C,R,M,held", [(4, 4, 12, ()), (3, 1, 7, (3,)), (1, 2, 5, ())])
def test_base_full_factors_equal_the_hand_jacobian(C, R, M, held):
    """With ``full`` (every parameter free, at nonzero values): ``[X W, E]`` and the value
    equal the candidate's compiled ``valjac`` (itself checked against ``jacfwd``) to the
    rounding of ``m phi``, the slope's columns to that times ``sum m (|a_m| + |b_m|)``."""
    import jax

    from encdesign.diagnose.engine._fit import Factored
    from encdesign.diagnose.engine._normal import factors_of

    cand = _base_candidate(C, R, M, held)
    rng = np.random.default_rng(7 + C + 10 * R + 100 * M)
    n = 600
    x = {
        "theta_raw": np.cumsum(rng.uniform(0, 0.05, n)) + 30.0,
        "run_onehot": np.eye(R)[rng.integers(0, R, n)],
        "alpha": np.arange(C) * 2 * np.pi / C + 0.1,
    }
    p = {q.name: rng.normal(0, 1e-3, q.resolved_shape(C, R)) for q in cand.params}
    free = {q.name: np.ones(q.resolved_shape(C, R), bool) for q in cand.params}
    assert cand.valjac is not None
    v_want, J = jax.jit(cand.valjac)(p, x)
    want = np.concatenate([np.asarray(J[q.name]).reshape(n, C, -1) for q in cand.params], 2)
    factors = factors_of(cand)
    assert factors is not None
    v, X, W, E = factors(p, x, free, n, full=True)
    assert (E is None) == (R == 1)
    got = Factored(X, W, E).whole()
    assert got.shape == want.shape
    size = 1.0 + np.sum(np.arange(1, M + 1) * (np.abs(p["fourier_cos_rad"]) + 1.0))
    bound = (TRIG_TABLE_ERROR * M + M * 120.0) * EPS * size
    np.testing.assert_allclose(got, want, rtol=0, atol=bound)
    np.testing.assert_allclose(v, np.asarray(v_want), rtol=0, atol=bound)
    order = rng.permutation(n)  # rows in a given order: the same rows
    np.testing.assert_array_equal(Factored(X, W, E).whole(order), got[order])


@pytest.mark.parametrize("ref", [True, False])
def test_free_base_gram_from_features_equals_the_whole_jacobian(monkeypatch, ref):
    """The base with its placements and run zeros free (no static block): the statistics
    summed from the factored columns' features (``StatsPass._gram_f``, ``_grad_f``: ``sum_c
    Wp_c^T (X^T X) Wp_c``) equal those summed from the whole processed Jacobian to rounding,
    beside a second free nonlinear term (a vibration: its columns the "other" ones) and
    beside a static block (the vibration at a held frequency: ``_cross_f``), and
    the pass forms no ``(rows, C, k)`` product of the factors (a counter: it fails with the
    features switched off)."""
    from encdesign.diagnose.engine import _stats_pass
    from encdesign.diagnose.engine._fit import Factored, Fitter, make_term
    from encdesign.diagnose.kinds.multihead._multihead_terms import VIBRATION
    from tests.test_fit_fast import _fitted

    prep, _, held = _fitted(ref)
    base = held[0].copy()
    for q in base.cand.params:  # the nonlinear parameters free again
        base.free[q.name][...] = q.fit
    vib = make_term(VIBRATION, prep, {"frequency_hz": 23.0, "cos_rad": 1e-7})
    made: list = []
    real = Factored.into
    monkeypatch.setattr(Factored, "into", lambda s, *a, **k: made.append(1) or real(s, *a, **k))
    vib_held = vib.copy()  # a static block beside the free base: the cross products S^T D
    vib_held.free["frequency_hz"][...] = False
    for terms in ([base], [base, vib], [vib_held, base]):
        made.clear()
        A, g, c, ssr, sc = Fitter(prep).stats(terms)
        assert not made
        with monkeypatch.context() as mp:
            mp.setattr(_stats_pass, "FEATURE_GRAM", False)
            A0, g0, c0, ssr0, sc0 = Fitter(prep).stats(terms)
        assert made
        d = np.sqrt(np.einsum("kjj->kj", A0))
        np.testing.assert_allclose(
            A / (d[:, :, None] * d[:, None, :]),
            A0 / (d[:, :, None] * d[:, None, :]),
            rtol=0,
            atol=1e-12,
        )
        np.testing.assert_allclose(g, g0, rtol=0, atol=1e-10 * np.abs(g0).max())
        np.testing.assert_array_equal(c, c0)
        np.testing.assert_array_equal(ssr, ssr0)
        np.testing.assert_array_equal(sc, sc0)
