"""The clock's rounding constant within a run where the clock is nearly locked to the motor
(issue 41, session 40: ``_sds_clock_lock.rounding_common_excess``, the run means' common
excess in ``_sds_noise._common_excess``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from encdesign.diagnose.kinds.sds._sds_clock_lock import rounding_common_excess
from tests.test_sds_clock_lock import level_rows

TICK = 1e-8
MARKS = 100
PSI_F = np.radians([0.0, 180.0])
PSI_M = np.radians([0.0, 120.0, 240.0])


def _simulated_excess(ticks: float, runs: int, rng) -> float:
    """The rounding's common excess (rad^2) of ``runs`` runs of a bench whose edges all
    repeat each revolution: per run a clock phase, a platform angle and a disk (the marks'
    sub-tick phases: graduation errors over a tick; a disk per run gives the expectation
    over disks), each edge rounded to the tick; a pair's reading is the moving sensor's
    rounding less the fixed sensors' mean."""
    omega = 2 * math.pi / (ticks * TICK)
    theta = rng.uniform(0, 1, (runs, 1, MARKS))  # the marks' phases

    def rounding(u):  # round(u) - u at the marks' phases, mean over the marks
        x = u[..., None] + theta
        return np.mean(np.round(x) - x, -1)

    p = rng.uniform(0, 1, runs)[:, None]
    plat = rng.uniform(0, 1, runs)[:, None]
    fixed = rounding(p + ticks * PSI_F / (2 * math.pi)).mean(1, keepdims=True)
    moving = rounding(p + ticks * (PSI_M / (2 * math.pi) + plat))
    y = omega * TICK * (moving - fixed)
    M = PSI_M.size
    common = M * np.var(y.mean(1))
    diff = np.sum((y - y.mean(1, keepdims=True)) ** 2) / (runs * (M - 1))
    return float(common - diff)


@pytest.mark.parametrize("ticks", [9999594.0, 9999812.0, 10000001.5])
def test_excess_is_what_a_simulated_rounding_adds_to_the_common_component(ticks):
    """Moving sensors a third of a revolution apart at one phase (a revolution a multiple of
    3 ticks), a third of a tick apart, and the fixed sensors half a tick apart: the excess
    the model predicts at full lock is the simulated one within its sampling error."""
    rng = np.random.default_rng(5)
    run_clock = np.stack([np.zeros(4), np.full(4, ticks * TICK)], 1)
    want = rounding_common_excess(run_clock, TICK, PSI_F, PSI_M, MARKS, 1.0)
    got = _simulated_excess(ticks, 1500, rng)
    scale = (2 * math.pi / ticks) ** 2 * 0.5 / MARKS  # the largest: every sensor at one phase
    assert want >= 0.0
    assert abs(got - want) < 0.08 * scale


def test_excess_is_zero_unlocked_or_without_a_clock():
    run_clock = np.stack([np.zeros(4), np.full(4, 9999594.0 * TICK)], 1)
    assert rounding_common_excess(run_clock, TICK, PSI_F, PSI_M, MARKS, 0.0) == 0.0
    assert rounding_common_excess(run_clock, None, PSI_F, PSI_M, MARKS, 1.0) == 0.0
    assert rounding_common_excess(None, TICK, PSI_F, PSI_M, MARKS, 1.0) == 0.0
    half = rounding_common_excess(run_clock, TICK, PSI_F, PSI_M, MARKS, 0.5)
    full = rounding_common_excess(run_clock, TICK, PSI_F, PSI_M, MARKS, 1.0)
    assert half == pytest.approx(0.5 * full)


@pytest.mark.parametrize("switch", [0, 1])
def test_common_tests_read_the_predicted_rounding_and_no_effect_raises_it(switch):
    """Run means whose common component carries the clock's rounding (6 times the
    differences' level, constant within each run: the contrasts and the fixed sensors'
    differences do not see it), with the record's predicted rounding ``e``
    (``clock_round_excess``) where the level is built (:func:`run_mean_levels`). The level
    every channel is whitened with is the same with and without it (a one-sensor test is not
    charged with a common noise); a test of a pattern common to the moving sensors reads its
    chi-square at ``(g / g_c)^2``, ``g_c = sqrt(1 + e / s^2)`` (below what the common
    component supports, which caps it). A common effect added to the run means, which raises
    what the common component supports, does not change that factor. Switched off
    (``sds_clock_lock_level`` 0), the factor is 1."""
    from encdesign.diagnose import FinderSettings
    from encdesign.diagnose.kinds.sds._sds_noise import run_mean_levels

    rng = np.random.default_rng(2)
    R, M, K = 12, 3, 4
    rows = level_rows(rng, R, K)
    consts = {"psi_m": np.array([0.3, 2.4, 4.5]), "proj": np.asarray(0.0)}
    means = rng.standard_normal((R, M)) + 6.0 * rng.standard_normal((R, 1))
    resid = np.concatenate([means, 0.5 * rng.standard_normal((R, M * (K - 1)))], 1)
    settings = FinderSettings(sds_clock_lock_level=switch)

    def level(resid, rounding):
        info: dict = {}
        state: dict = {}
        c = dict(consts, clock_round_excess=np.asarray(rounding))
        sig = run_mean_levels(K, rows, c, [], settings)(resid, info, state)
        return sig, info, state["common_scale"]

    sig0, info0, scale0 = level(resid, 0.0)
    s, g = info0["run_means_rad"], info0["run_means_common_factor"]
    assert scale0 == 1.0
    e = 3.0 * s**2
    sig1, info1, scale1 = level(resid, e)
    np.testing.assert_allclose(sig1, sig0)
    assert info1["run_means_common_factor_direct"] > math.sqrt(1.0 + e / s**2)
    if not switch:
        assert scale1 == 1.0
        return
    assert scale1 == pytest.approx((g / math.sqrt(1.0 + e / s**2)) ** 2)
    assert scale1 < 0.5
    tilt = np.repeat(12.0 * np.cos(rows["phi"] + 0.4)[:, None], M, 1)
    _, info2, scale2 = level(resid + np.concatenate([tilt, 0 * resid[:, M:]], 1), e)
    assert info2["run_means_common_factor_direct"] > info1["run_means_common_factor_direct"]
    assert scale2 == pytest.approx(scale1, rel=0.02)
