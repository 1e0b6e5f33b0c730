"""The SDS run-mean level where the clock is nearly locked to the motor (issue 41, session 39:
``_sds_clock_lock.clock_lock_share``, ``lock_mixed_factor``, ``_sds_data._run_clock``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from encdesign.diagnose.kinds.sds._sds_clock_lock import clock_lock_share, lock_mixed_factor
from encdesign.diagnose.kinds.sds._sds_data import _run_clock
from encdesign.diagnose.kinds.sds._sds_noise import _level_sigma

TICK = 1e-8
MARKS = 500


def _clock(offset: float, R: int = 12) -> np.ndarray:
    """``run_clock`` (R, 2) of a bench at 10 rev/s times ``1 + offset`` on a 10 ns clock,
    runs eight revolutions apart."""
    period = 0.1 / (1.0 + offset)
    return np.stack([8 * period * np.arange(R), np.full(R, period)], 1)


@pytest.mark.parametrize(
    ("offset", "lo", "hi"),
    [
        (0.0, 0.0, 1e-9),  # exactly locked: every edge of a sensor at one clock phase
        (2.62007e-5, 0.99, 1.0),  # 0.0001 tick a revolution from lock, marks spread
        (1.0903e-5, 0.9, 0.97),  # 0.03 tick a revolution
        (999.5 / 9999000.5, 0.0, 1e-9),  # half a tick a revolution: averages over 4
    ],
)
def test_lock_share_follows_the_clock_phase_a_revolution_moves(offset, lo, hi):
    assert lo <= clock_lock_share(_clock(offset), TICK, 4, MARKS) <= hi


def test_lock_share_is_zero_without_a_clock():
    assert clock_lock_share(_clock(1e-5), None, 4, MARKS) == 0.0
    assert clock_lock_share(None, TICK, 4, MARKS) == 0.0


def test_run_clock_is_a_revolution_to_a_few_thousandths_of_a_tick():
    """The disk's once-per-revolution pattern (here 50 ticks) cancels in each revolution's
    difference; rounding to the tick and 1 ns jitter average out."""
    rng = np.random.default_rng(3)
    period = 0.1 / (1.0 + 1.0903e-5)
    j = np.arange(6 * MARKS)
    t = 0.0123 + j * period / MARKS + 50 * TICK * np.sin(2 * np.pi * j / MARKS + 0.4)
    t = np.ceil((t + 1e-9 * rng.standard_normal(j.size)) / TICK) * TICK
    t0, p = _run_clock(t, np.mod(j, MARKS), MARKS)
    assert abs(p - period) < 0.005 * TICK
    assert abs(t0 - t[0]) == 0.0
    # edges that are not consecutive marks: no revolution time
    assert _run_clock(t[::2], np.mod(j[::2], MARKS), MARKS)[1] == 0.0


def test_mixed_factor_is_the_direct_one_at_full_lock_and_the_minimum_unlocked():
    assert lock_mixed_factor(2.0, 5.0, 0.0) == 2.0
    assert lock_mixed_factor(2.0, 5.0, 1.0) == pytest.approx(5.0)
    assert lock_mixed_factor(2.0, 1.5, 1.0) == pytest.approx(1.5)
    assert lock_mixed_factor(2.0, None, 1.0) == 2.0
    assert lock_mixed_factor(2.0, 5.0, 0.5) == pytest.approx(math.sqrt(0.5 * 4 + 0.5 * 25))


def test_near_lock_the_run_mean_level_holds_the_common_component():
    """Run means with noise of level 1 along the moving sensors' differences and 4 along
    their common component, constant within each run (the clock's rounding near lock: the
    revolution contrasts do not see it, there are no fixed sensors' differences to show it):
    unlocked the level's common factor stays near the differences' (about 1), at full lock
    it is what the common component supports, and the level without a test's columns
    (``state["factor"]``'s ``sigma_of``) is the same number."""
    rng = np.random.default_rng(11)
    R, M, K = 12, 3, 4
    means = rng.standard_normal((R, M))
    means = means - means.mean(1, keepdims=True) + 4.0 * rng.standard_normal((R, 1))
    contrasts = 0.5 * rng.standard_normal((R, M * (K - 1)))
    resid = np.concatenate([means, contrasts], 1)
    # the saturating columns: every run's common component (none of its degrees of freedom
    # left to the level, as the finder's saturated fit leaves it) and a constant per sensor
    X = np.concatenate(
        [np.kron(np.eye(R), np.ones((M, 1))), np.kron(np.ones((R, 1)), np.eye(M))], 1
    )
    out = {}
    for lock in (0.0, 1.0):
        info: dict = {}
        state: dict = {}
        sigma = _level_sigma(
            resid,
            K,
            X,
            False,
            info,
            test_p=1e-4,
            level_alpha=1e-3,
            common_base=np.ones((R, 1)),
            common_quantile=0.2,
            state=state,
            lock=lock,
        )
        out[lock] = (sigma[0], info)
        s, nu = info["run_means_rad"], info["run_means_dof"]
        assert state["factor"].sigma_of(np.asarray([s]), np.asarray([nu]))[0] == pytest.approx(
            sigma[0], rel=1e-12
        )
    z = means.mean(1) * math.sqrt(M)  # the common component, level sqrt(1 + 3 * 16) = 7
    seen = float(np.std(z, ddof=1))
    g1 = out[1.0][1]["run_means_common_factor"]
    assert g1 == pytest.approx(out[1.0][1]["run_means_common_factor_direct"])
    assert out[0.0][0] < 0.4 * seen < seen < out[1.0][0]


def level_rows(rng: np.random.Generator, R: int, K: int) -> dict:
    """The per-run rows :func:`_sds_noise.run_mean_levels` reads, for ``R`` runs of ``K``
    sensors at sorted random platform angles (rad)."""
    phi = np.sort(rng.uniform(0, 2 * np.pi, R))
    return {
        "phi": phi,
        "theta": phi,
        "tmid_c": np.linspace(-1, 1, R)[:, None] + np.zeros((R, K)),
        "fixed_c": 0.1 * rng.standard_normal((R, 2)),
    }


@pytest.mark.parametrize("switch", [0, 1, 2])
def test_the_switch_reaches_the_level(switch):
    """``FinderSettings.sds_clock_lock_level`` and the record's ``clock_lock`` constant reach
    the level where the kind builds it (:func:`_sds_noise.run_mean_levels`): below 2 (1, the
    default since session 40, is the rounding's level of the common views, not this mixing)
    the factor is ``min(indirect, direct)`` whatever the share; at 2, at share 1, it is the
    direct one."""
    from encdesign.diagnose import FinderSettings
    from encdesign.diagnose.kinds.sds._sds_noise import run_mean_levels

    rng = np.random.default_rng(2)
    R, M, K = 12, 3, 4
    rows = level_rows(rng, R, K)
    consts = {
        "psi_m": np.array([0.3, 2.4, 4.5]),
        "proj": np.asarray(0.0),
        "clock_lock": np.asarray(1.0),
    }
    means = rng.standard_normal((R, M)) + 6.0 * rng.standard_normal((R, 1))
    resid = np.concatenate([means, 0.5 * rng.standard_normal((R, M * (K - 1)))], 1)
    levels = run_mean_levels(K, rows, consts, [], FinderSettings(sds_clock_lock_level=switch))
    info: dict = {}
    levels(resid, info)
    g, g_i = info["run_means_common_factor"], info["run_means_common_factor_indirect"]
    g_d = info["run_means_common_factor_direct"]
    assert g_d is not None and g_d > g_i
    assert g == pytest.approx(g_d if switch > 1 else min(g_i, g_d))
