"""The SDS run-mean level without a test's own columns (issue 41, session 23:
``kinds/sds/_sds_level_out.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from encdesign.diagnose.kinds.sds._sds_level_out import (
    LevelOut,
    modulated_scale,
    order_columns,
    orders_scale,
)
from encdesign.diagnose.kinds.sds._sds_noise import span_basis


def _setup(rng, R=24, M=3, k=30, proj=False):
    """A residual of noise off ``k`` random columns (the saturating fit's stand-in)."""
    Q = span_basis(rng.standard_normal((R * M, k)))
    y = rng.standard_normal(R * M)
    e = y - Q @ (Q.T @ y)
    n_ind = R * (M - 1) if proj else R * M
    return e, Q, n_ind


def test_factor_is_the_f_tests_denominator():
    """With the level a plain ``sqrt(SSR / nu)`` (no widening), the factor of columns ``X``
    is ``(SSR / nu) / ((SSR - g_X) / (nu - r))``, ``g_X`` the power ``X`` takes off ``Q``;
    a structure along ``X`` raises it (the level without it is smaller), and columns ``Q``
    holds leave the level as it is."""
    rng = np.random.default_rng(0)
    R, M = 24, 3
    e, Q, n_ind = _setup(rng)
    phi = rng.uniform(0, 2 * np.pi, R)
    X = order_columns(phi, M, 5, 1)
    lo = LevelOut(e, Q, n_ind, lambda s, n: s, False, M)
    Xp = X.reshape(R * M, 2) - Q @ (Q.T @ X.reshape(R * M, 2))
    U = span_basis(Xp)
    g = float(np.sum((U.T @ e) ** 2))
    nu = n_ind - Q.shape[1]
    want = (float(e @ e) / nu) / ((float(e @ e) - g) / (nu - 2))
    assert lo(X) == pytest.approx(want, rel=1e-10)
    # the batched pairs agree with the single call
    A = np.stack([order_columns(phi, M, m, k) for k in range(M) for m in (1, 5, 9)], 2)
    single = [lo(A[:, :, i]) for i in range(A.shape[2])]
    np.testing.assert_allclose(lo.pairs(A), single, rtol=1e-9)
    # a structure along X: the level without it is the level of the noise
    s = Xp @ np.array([3.0, -2.0])
    lo2 = LevelOut(e + s, Q, n_ind, lambda s, n: s, False, M)
    assert lo2(X) > 1.5
    # columns inside Q: no degree of freedom, no change
    assert lo(Q[:, :2].reshape(R, M, 2)) == 1.0


def _assert_f_tail(rng, X, R: int, M: int, k: int, factor) -> None:
    """Under noise alone (4000 draws of ``R * M`` run means less ``k`` random saturating
    columns), a view's chi-square of the columns ``X`` times ``factor(LevelOut)`` is an
    F-statistic times 2: its upper tail stays at the F distribution's 1e-2 quantile, and the
    factor averages about 1 (the structure-free level is not biased low)."""
    from scipy import stats

    Q = span_basis(rng.standard_normal((R * M, k)))
    Xp = X.reshape(R * M, 2) - Q @ (Q.T @ X.reshape(R * M, 2))
    U = span_basis(Xp)
    nu = R * M - k
    f_all, stat = [], []
    for _ in range(4000):
        y = rng.standard_normal(R * M)
        e = y - Q @ (Q.T @ y)
        f = factor(LevelOut(e, Q, R * M, lambda s, n: s, False, M))
        g = float(np.sum((U.T @ e) ** 2))
        f_all.append(f)
        stat.append(g / (float(e @ e) / nu) * f / 2)
    assert np.mean(f_all) == pytest.approx(1.0, abs=0.05)
    rate = np.mean(np.asarray(stat) > stats.f.isf(1e-2, 2, nu - 2))
    assert rate == pytest.approx(1e-2, abs=5e-3)


def test_factor_keeps_the_tests_false_alarm_rate():
    """Under noise alone the view's chi-square times the factor is an F-statistic times 2:
    its upper tail stays at the F distribution's (checked at the 1e-2 quantile over 4000
    draws), where the factor itself averages about 1 (the structure-free level is not
    biased low)."""

    rng = np.random.default_rng(1)
    R, M, k = 24, 3, 30
    phi = rng.uniform(0, 2 * np.pi, R)
    X = order_columns(phi, M, 7, 0)
    _assert_f_tail(rng, X, R, M, k, lambda lo: lo(X))


def test_orders_scale_is_per_sensor_and_order():
    """:func:`orders_scale` lays the pairs' factors out per order and channel (1 on the
    channels past the moving sensors): a structure at order 4 of sensor 2 raises that
    entry most."""
    rng = np.random.default_rng(2)
    R, M = 24, 3
    e, Q, n_ind = _setup(rng)
    phi = rng.uniform(0, 2 * np.pi, R)
    X = order_columns(phi, M, 4, 2).reshape(R * M, 2)
    s = (X - Q @ (Q.T @ X)) @ np.array([4.0, 1.0])
    lo = LevelOut(e + s, Q, n_ind, lambda s, n: s, False, M)
    sc = orders_scale(lo, phi, M, 10, M + 2)
    assert sc.shape == (10, M + 2)
    np.testing.assert_array_equal(sc[:, M:], 1.0)
    assert np.unravel_index(np.argmax(sc), sc.shape) == (3, 2)
    assert sc[3, 2] == pytest.approx(lo(order_columns(phi, M, 4, 2)), rel=1e-9)


@pytest.mark.parametrize("seed", [7783, 7784])
def test_two_x_one_sensor_order_is_located_and_modelled(seed):
    """A static order of one moving sensor at 2x the run-mean noise (training seeds 7783:
    order 5 of sensor m1, 7784: order 5 of m2; ``benchmarks/discovery.outside_record``,
    class ``sensor_frame``): read against the level without its own columns the ``orders``
    view locates it and discovery models it in that sensor's frame. On main (the level with
    the structure in it) both records are ``consistent``."""
    from encdesign.diagnose._dispatch import diagnose
    from encdesign.simulate._outside import outside_record

    rec, truth = outside_record(np.random.default_rng(seed), "sensor_frame", 2.0, "sds", 3000)
    d = diagnose(rec)
    assert d.verdict == "unexplained"
    terms = [
        t
        for u in d.doc["unexplained"]
        if u.get("model")
        for t in u["model"]["terms"]
        if t["frame"] == truth["frame"] and t["modulation"] == "static"
    ]
    assert terms, (d.verdict, [u.get("model") for u in d.doc["unexplained"]])
    assert not d.effects


def _shapes(R: int, edges=(8, 16)) -> np.ndarray:
    """The ``modulated_orders`` view's shapes on ``R`` runs in time order: growth, decay,
    switch on / off at each edge."""
    g = np.arange(R) / (R - 1)
    rows = [g, 1 - g]
    for e in edges:
        on = (np.arange(R) >= e).astype(float)
        rows += [on, 1 - on]
    return np.stack(rows)


def test_modulated_scale_is_the_factor_of_the_shaped_order():
    """:func:`modulated_scale` gives per shape, order and channel the factor of the order's
    cos / sin times the shape on that sensor's run means (1 past the moving sensors); a
    growth at order 3 of sensor 1 raises the growth's entry there most."""
    rng = np.random.default_rng(3)
    R, M = 24, 3
    e, Q, n_ind = _setup(rng)
    phi = rng.uniform(0, 2 * np.pi, R)
    W = _shapes(R)
    X = order_columns(phi, M, 3, 1) * W[0][:, None, None]
    Xf = X.reshape(R * M, 2)
    s = (Xf - Q @ (Q.T @ Xf)) @ np.array([5.0, 2.0])
    lo = LevelOut(e + s, Q, n_ind, lambda s, n: s, False, M)
    sc = modulated_scale(lo, phi, W, M, 6, M + 1)
    assert sc.shape == (W.shape[0], 6, M + 1)
    np.testing.assert_array_equal(sc[..., M:], 1.0)
    assert np.unravel_index(np.argmax(sc), sc.shape) == (0, 2, 1)
    for j, m, k in [(0, 3, 1), (3, 5, 0), (4, 1, 2)]:
        want = lo(order_columns(phi, M, m, k) * W[j][:, None, None])
        assert sc[j, m - 1, k] == pytest.approx(want, rel=1e-9)


@pytest.mark.parametrize("shape", [0, 2, 5])
def test_modulated_scale_keeps_the_false_alarm_rate(shape):
    """Under noise alone the ``modulated_orders`` view's chi-square of a growth or a switch
    times its factor is an F-statistic times 2 (the level without the shaped order's own
    columns): its upper tail stays at the F distribution's 1e-2 quantile over 4000 draws,
    and the factor averages about 1."""

    rng = np.random.default_rng(10 + shape)
    R, M, k = 24, 3, 30
    phi = rng.uniform(0, 2 * np.pi, R)
    W = _shapes(R)
    X = order_columns(phi, M, 7, 2) * W[shape][:, None, None]
    _assert_f_tail(
        rng,
        X,
        R,
        M,
        k,
        lambda lo: float(modulated_scale(lo, phi, W[shape : shape + 1], M, 7, M)[0, 6, 2]),
    )
