"""The moving sensors' common component at its own unbiased level in the SDS run-mean level
without a test's columns (issue 41, session 28: ``kinds/sds/_sds_level_common.py``, behind
``FinderSettings.sds_level_common_direct``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import sweep
from scipy import stats

from encdesign.diagnose.kinds.sds._sds_level_out import (
    LevelOut,
    RunMeanLevel,
    order_columns,
    orders_scale,
)
from encdesign.diagnose.kinds.sds._sds_noise import dof_widening, span_basis


def _saturating(phi: np.ndarray, M: int, L: int) -> np.ndarray:
    """``(R*M, k)``: every run's mean over the moving sensors (the common component: the
    finder's saturating columns leave it no degrees of freedom) and per moving sensor a
    constant and the orders ``1..L`` of ``phi``."""
    R = phi.size
    cols = [np.kron(np.eye(R), np.ones((M, 1)))]
    for m in range(M):
        c = np.zeros((R, M, 2 * L + 1))
        c[:, m, 0] = 1.0
        for n in range(1, L + 1):
            c[:, m, 2 * n - 1], c[:, m, 2 * n] = np.cos(n * phi), np.sin(n * phi)
        cols.append(c.reshape(R * M, -1))
    return np.concatenate(cols, 1)


def _draw(rng, R: int, M: int, sc: float) -> np.ndarray:
    """Run means (R, M) of noise with the level 1 along every difference of the moving
    sensors and ``sc`` along their common component."""
    y = rng.standard_normal((R, M))
    y = y - y.mean(1, keepdims=True)
    return y + sc * rng.standard_normal((R, 1)) / math.sqrt(M)


def _order_7(phi: np.ndarray, M: int, frame: str) -> tuple[np.ndarray, np.ndarray]:
    """``(X, U)``: the columns (R, M, 2) of order 7 on moving sensor 0 (``frame`` "sensor")
    or common to the moving sensors ("common"), and the orthonormal basis of their span off
    the per-sensor constants (what the false-alarm tests project the noise on)."""
    R = phi.size
    X = order_columns(phi, M, 7, 0)
    if frame == "common":
        X = np.repeat(order_columns(phi, 1, 7, 0), M, axis=1)
    B = np.kron(np.ones((R, 1)), np.eye(M))
    Xb = X.reshape(R * M, 2) - B @ np.linalg.lstsq(B, X.reshape(R * M, 2), rcond=None)[0]
    return X, span_basis(Xb)


def _level_out(y, phi, L, excess, p=None, direct=True, Q=None) -> LevelOut:
    """The :class:`LevelOut` of run means ``y`` (the share on) with the saturating columns
    of :func:`_saturating`, the base's common columns the constant, the common factor's
    excess ``excess`` and no widening (``p``: :func:`dof_widening` at ``p``). ``Q``: the
    saturating columns' basis, ``span_basis(_saturating(phi, M, L))``, where the caller
    has it (it depends on ``phi`` alone)."""
    R, M = y.shape
    Q = span_basis(_saturating(phi, M, L)) if Q is None else Q
    e = y.ravel() - Q @ (Q.T @ y.ravel())
    widen = (lambda n: 1.0) if p is None else (lambda n: dof_widening(n, p=p))
    common = (y, np.ones((R, 1))) if direct else None
    return LevelOut(e, Q, R * M, RunMeanLevel(widen, excess, None), False, M, True, common)


def test_one_sensor_level_mixes_the_common_part_at_its_share():
    """A one-sensor order's level is ``s'^2 + (sc'^2 - s'^2) / M`` (no widening here):
    ``s'`` :class:`LevelOut`'s level without the order's columns (the saturated fit leaves
    the common component nothing: ``e`` is on the differences), ``sc'`` the common
    component's level off the base's constant and without the order's common part; a
    common part quieter than the differences lowers it below session 27's (whose factor is
    floored at 1); a common order's level is ``sc'^2`` alone; the batched ``orders`` scale
    equals the single calls."""
    rng = np.random.default_rng(1)
    R, M, L = 24, 3, 3
    phi = rng.uniform(0, 2 * np.pi, R)
    y = _draw(rng, R, M, 0.3)
    lo = _level_out(y, phi, L, 0.5)
    E = lo.e.reshape(R, M)
    assert float(np.sum(E.sum(1) ** 2)) < 1e-20 * lo.ssr  # no common part left in e
    z = y.sum(1) / math.sqrt(M)
    z = z - z.mean()
    for X, kappa in [
        (order_columns(phi, M, 7, 2), 1 / M),
        (np.repeat(order_columns(phi, 1, 7, 0), M, 1), 1.0),
    ]:
        U = span_basis(X.reshape(R * M, 2) - lo.Q @ (lo.Q.T @ X.reshape(R * M, 2)))
        s2 = (lo.ssr - float(np.sum((U.T @ lo.e) ** 2))) / (lo.nu - U.shape[1])
        xc = X.sum(1) / math.sqrt(M)
        xc = xc - xc.mean(0)
        sc2 = (z @ z - float(np.sum((span_basis(xc).T @ z) ** 2))) / (R - 1 - 2)
        assert lo(X) == pytest.approx(lo.sigma**2 / (s2 + kappa * (sc2 - s2)), rel=1e-10)
    X = order_columns(phi, M, 7, 2)
    old = _level_out(y, phi, L, 0.5, direct=False)  # session 27
    assert old.common is None and lo.common is not None
    assert lo(X) > 1.1 * old(X)
    sc = orders_scale(lo, phi, M, 9, M)
    assert sc[6, 2] == pytest.approx(lo(X), rel=1e-9)
    assert sc[3, 0] == pytest.approx(lo(order_columns(phi, M, 4, 0)), rel=1e-9)


# ``make test`` runs the kept cases; the others are the ``sweep`` tier (``make
# test-sweeps``; session 31, CI time)
@pytest.mark.parametrize(
    ("sc", "frame"),
    sweep(
        [(0.4, "sensor"), (0.4, "common"), (2.5, "sensor"), (2.5, "common")],
        ((0.4, "sensor"), (2.5, "common")),
    ),
)
def test_one_sensor_and_common_tests_keep_their_false_alarm_rate(sc, frame):
    """Under noise whose common component is quieter (0.4) or louder (2.5) than the
    differences, the chi-square of an order on one moving sensor or common to all of them
    (off the per-sensor constants) read against its level with the common part at its own
    level, widened at 1e-2 for the mix's Welch-Satterthwaite degrees of freedom, keeps the
    chi-square(2) tail at 1e-2: the rate over 2000 draws within [0.4, 1.6] x 1e-2. With
    session 27's factor (the excess ``sc^2 - 1`` known exactly, floored at 0) the quiet
    one-sensor case's rate is far lower: the test paid for a common part the record does
    not have."""
    rng = np.random.default_rng(int(sc * 10) + (frame == "common"))
    R, M, L, p = 24, 3, 3, 1e-2
    phi = rng.uniform(0, 2 * np.pi, R)
    X, U = _order_7(phi, M, frame)
    excess = max(sc**2 - 1.0, 0.0)
    compare = sc < 1 and frame == "sensor"  # session 27's factor read only where compared
    Q = span_basis(_saturating(phi, M, L))  # the same for every draw (phi is fixed)
    new, old = [], []
    for _ in range(2000):
        y = _draw(rng, R, M, sc)
        lo = _level_out(y, phi, L, excess, p, Q=Q)
        chi = float(np.sum((U.T @ y.ravel()) ** 2)) / lo.sigma**2
        new.append(chi * lo(X))
        if compare:
            old.append(chi * _level_out(y, phi, L, excess, p, direct=False, Q=Q)(X))
    thr = stats.chi2.isf(p, 2)
    rate = np.mean(np.asarray(new) > thr)
    assert 0.4e-2 <= rate <= 1.6e-2
    if compare:
        assert np.mean(np.asarray(old) > thr) < 0.6 * rate


@pytest.mark.parametrize("direct", [0, 1])
def test_the_setting_reaches_the_level(direct):
    """``FinderSettings.sds_level_common_direct`` reaches the level where it is built
    (:func:`_sds_noise._level_sigma`): with it, and the share on, the factor has the common
    component (with ``phi_ref``); without it (the default), or without ``phi_ref``, or with
    the share off, session 27's factor."""
    from encdesign.diagnose import FinderSettings
    from encdesign.diagnose.kinds.sds._sds_noise import _level_sigma

    settings = FinderSettings(sds_level_common_direct=direct)
    rng = np.random.default_rng(5)
    R, M, K = 24, 3, 4
    phi = rng.uniform(0, 2 * np.pi, R)
    resid = rng.standard_normal((R, M * K))
    for proj in (False, True):
        for share in (False, True):
            state: dict = {}
            _level_sigma(
                resid,
                K,
                _saturating(phi, M, 5),
                proj,
                test_p=1e-4,
                level_alpha=1e-3,
                common_base=np.ones((R, 1)),
                common_quantile=0.2,
                state=state,
                share=share,
                direct=settings.sds_level_common_direct > 0,
            )
            want = bool(direct) and share and not proj
            assert (state["factor"].common is not None) == want
