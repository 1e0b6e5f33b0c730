"""Multihead records of less than one turn without a reference (issue 44): each run's own
disk orders are not separable there, so the start aligns the runs by the base fitted to both
arcs together, and the issue-41 hold leaves such a run's fitted zero alone; the base holds the
heads at their nominal azimuths, says its orders are not separable, and may grow its orders
where held-out error (which measures that ill-conditioning) would refuse them."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from encdesign import Recording
from encdesign.diagnose import FinderSettings, diagnose
from encdesign.diagnose.engine._prepare import part_turn_span
from encdesign.diagnose.kinds.multihead._multihead import _hold_run_offsets, multihead_base


class _Rows(dict):
    def column(self, name, a, b):
        return self[name][a:b]


def _short_runs(seed: int, C: int, turns: float, M: int = 9, n: int = 1200):
    """Two runs of ``turns`` of a turn each (forward, then forward and back), ``C`` heads and
    no reference, their zeros ``z`` apart; returns the prepared record and the true
    ``delta_1`` (rad, against run 0)."""
    rng = np.random.default_rng(seed)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.4, 5.9, C - 1))])
    half = n // 2
    u = np.linspace(0, 1, half)
    th = np.concatenate(
        [
            2 * np.pi * turns * u + rng.uniform(0, 2 * np.pi),
            2 * np.pi * turns * (1 - np.abs(2 * u - 1)) + rng.uniform(0, 2 * np.pi),
        ]
    )
    run = np.repeat([0, 1], half)
    sigma = 1e-7
    err = np.zeros((n, C))
    for m in range(1, M + 1):
        err += 30 * sigma / m * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6))
    y = err + rng.uniform(-3, 3, (2, C))[run] + rng.normal(0, sigma, (n, C))
    zero = rng.uniform(-3, 3, 2)  # the heads' mean reading's zero in each run
    y -= y.mean(1, keepdims=True)
    raw = th + zero[run]
    prep = types.SimpleNamespace(
        settings=FinderSettings(),
        keep=np.ones(n, bool),
        rows=_Rows(theta=raw, theta_raw=raw),
        run=run,
        n_channels=C,
        y=y,
        sigma=np.full(C, sigma),
        consts={"alpha": alpha},
        kd=types.SimpleNamespace(project=True, shaft=raw),
        ctx=types.SimpleNamespace(n_runs=2, has_ref=False),
        count_jumps=[],
        angle_steps=[],
        part_turn_span=part_turn_span(raw, np.ones(n, bool), run),
    )
    return prep, float(np.angle(np.exp(1j * (zero[0] - zero[1]))))


def _wrapped(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


@pytest.mark.parametrize("seed,C,turns", [(1, 2, 0.6), (2, 3, 0.45), (3, 4, 0.8), (4, 3, 0.7)])
def test_part_turn_runs_start_at_their_true_zero_and_are_not_held_away(seed, C, turns):
    prep, truth = _short_runs(seed, C, turns)
    terms, _ = multihead_base(prep, 12)
    start = float(terms[0][1]["run_angle_offset_rad"][0])
    assert _wrapped(start, truth) < 0.02, (start, truth)
    name = "run_angle_offset_rad"
    base = types.SimpleNamespace(
        cand=types.SimpleNamespace(name="base"),
        values={"fourier_cos_rad": np.zeros(12), name: np.array([truth])},
        free={name: np.ones(1, bool)},
    )
    assert _hold_run_offsets([base], prep) is None
    assert base.values[name][0] == truth and base.free[name].all()


def _arc_record(
    seed: int, H: int = 3, n: int = 1200, M: int = 18, turns: float = 0.6, size: float = 300.0
):
    """A clean record of ``H`` heads without a reference turned ``turns`` of a turn forward
    and back, its disk error orders 1..M at ``size`` / m times the noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    th = 2 * np.pi * turns * (1 - np.abs(2 * np.arange(n) / (n - 1) - 1)) + rng.uniform(0, 6.3)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.4, 5.9, H - 1))])
    noise = 1e-7
    err = sum(
        size * noise / m * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6.3))
        for m in range(1, M + 1)
    )
    y = th[:, None] + err + rng.normal(0, noise, (n, H)) + rng.uniform(-3, 3, H)
    cols = {"t": t, "run": np.zeros(n, int), **{f"h{k}": y[:, k] for k in range(H)}}
    enc = {
        "head_angles_deg": [float(a) for a in np.degrees(alpha)],
        "optical_radius_m": 0.03,
        "grating_lines": 4096,
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


def test_a_clean_record_of_part_of_a_turn_is_consistent_and_says_what_it_cannot_separate():
    """On main this record named ``beam_tilt_axial`` and ``vibration`` (wild head placements
    fitted against an ill-conditioned base, its orders' growth refused by held-out error)."""
    d = diagnose(_arc_record(1, n=800)).doc  # (800 rows fail on the rule before, as 1200 did)
    assert d["verdict"] == "consistent", ([e["name"] for e in d["effects"]], d["unexplained"])
    assert "placement_rad" not in d["base"]["terms"]["base"]
    assert any("not separable" in u for u in d["base"]["unidentifiable"])


@pytest.mark.parametrize("seed,H,turns", [(12, 3, 0.55), (13, 3, 0.8)])
def test_part_of_a_turn_takes_a_large_errors_second_order_term_where_the_data_show_it(
    seed, H, turns
):
    """A disk error 3000 / m times the noise: without ``theta_ref`` the shaft (the heads' mean)
    carries its head mean, and the base evaluated there leaves ``e' * mean_k e_k`` (second
    order), far above the noise. Session 18 skipped the shaft refinement on records of part
    of a turn, and these were left ``unexplained`` or named ``vibration`` (as
    ``finder_variations --set high --seed 6205`` record 2, ``unexplained``); the refinement
    is now kept where the refit lowers chi-square by
    ``FinderSettings.refine_part_turn_chi2_drop``."""
    d = diagnose(_arc_record(seed, H=H, n=600, M=8, turns=turns, size=3e3)).doc
    assert d["verdict"] == "consistent", ([e["name"] for e in d["effects"]], d["unexplained"])
    assert "heads' mean reading" in d["base"]["refined"]


def _part_turn_shift_record(seed: int):
    """3-4 heads without a reference, one run of 0.4-0.9 turn in one direction (600 rows),
    disk error orders 1..M (M 3-8) of 10-100x the noise, and an eccentricity shift of 10-15x
    the noise at 30-70 % of the run. Returns ``(recording, shift time s)``."""
    rng = np.random.default_rng(seed)
    H, n = int(rng.integers(3, 5)), 600
    turns, rate = rng.uniform(0.4, 0.9), 10 ** rng.uniform(2, 3)
    noise = 10 ** rng.uniform(-7, -6)
    t = np.arange(n) / rate
    th = turns * 2 * np.pi * t / t[-1] + rng.uniform(0, 6.3)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.5, 5.8, H - 1))])
    M = int(rng.integers(3, 9))
    amp0 = noise * 10 ** rng.uniform(1.0, 2.0)
    err = np.zeros((n, H))
    for m in range(1, M + 1):
        err += amp0 / m * np.sin(m * (th[:, None] - alpha) + rng.uniform(0, 6.3))
    ts = t[-1] * rng.uniform(0.3, 0.7)
    A = rng.uniform(10, 15) * noise
    err += (t >= ts)[:, None] * A * np.sin(th[:, None] - alpha + rng.uniform(0, 6.3))
    y = th[:, None] + err + rng.normal(0, noise, err.shape) + rng.uniform(-3, 3, H)
    cols = {"t": t, **{f"h{k}": y[:, k] for k in range(H)}}
    enc = {
        "head_angles_deg": [float(a) for a in np.degrees(alpha)],
        "optical_radius_m": 0.03,
        "grating_lines": 4096,
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), float(ts)


@pytest.mark.parametrize("seed", [5, 12])
def test_an_eccentricity_shift_on_part_of_a_turn_is_named_alone_at_its_time(seed):
    """Session 20: the ``order_step`` view (the order-1 change's time) runs from a quarter
    turn in all (``order_step_revolutions_min``; it needed a full turn): without it the
    shift's start came from the time view alone, and on ``main`` these records name a false
    ``beam_tilt_axial`` (and ``vibration``) instead of the shift."""
    rec, ts = _part_turn_shift_record(seed)
    doc = diagnose(rec).doc
    assert [e["name"] for e in doc["effects"]] == ["eccentricity_shift"], doc["report"]
    p = doc["effects"][0]["params"]["shift_time_s"]
    lo, hi = p["interval_s"]
    step = float(np.median(np.diff(np.asarray(rec.columns["t"]))))
    assert lo - step <= ts <= hi + step, (ts, p)


def _disjoint_runs_record(seed: int, n: int = 1200):
    """3-4 heads without a reference, two runs of 0.3-0.45 turn forward on arcs that do not
    overlap (a gap of 0.1 rad or more between them), disk error orders 1..M (M 4-9) of
    30-300 / m times the noise. Returns ``(recording, true delta_1 rad against run 0)``:
    the heads' mean reading's zero of each run is the mean of its head constants."""
    rng = np.random.default_rng(seed)
    H = int(rng.integers(3, 5))
    turns, rate = float(rng.uniform(0.3, 0.45)), 10 ** rng.uniform(2, 3)
    noise = 10 ** rng.uniform(-7, -6)
    nr = n // 2
    u = np.arange(nr) / (nr - 1)
    span = 2 * np.pi * turns
    th0 = rng.uniform(0, 2 * np.pi)
    gap = rng.uniform(0.1, 2 * np.pi - 2 * span - 0.1)
    th = np.concatenate([th0 + span * u, th0 + span + gap + span * u])
    run = np.repeat([0, 1], nr)
    t = np.concatenate([u, u + 1]) * (nr - 1) / rate + np.repeat([0.0, 2.0], nr)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.5, 5.8, H - 1))])
    M = int(rng.integers(4, 10))
    amp0 = noise * 10 ** rng.uniform(1.5, 2.5)
    err = np.zeros((n, H))
    for m in range(1, M + 1):
        err += amp0 / m * np.sin(m * (th[:, None] - alpha) + rng.uniform(0, 6.3))
    c = rng.uniform(-3, 3, (2, H))
    y = th[:, None] + err + rng.normal(0, noise, err.shape) + c[run]
    cols = {"t": t, "run": run, **{f"h{k}": y[:, k] for k in range(H)}}
    enc = {
        "head_angles_deg": [float(a) for a in np.degrees(alpha)],
        "optical_radius_m": 0.03,
        "grating_lines": 4096,
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), math.remainder(
        float(c[0].mean() - c[1].mean()), 2 * math.pi
    )


@pytest.mark.parametrize("seed", [7563, 7566, 7569])
def test_runs_on_disjoint_arcs_start_at_the_zero_their_heads_arcs_agree_on(seed):
    """Issue 44 (session 21): two runs of part of a turn whose true zero makes them share no
    shaft arc. The match of a run's heads with run 0's at the same shaft angle cannot see that
    zero, and took the best of those that share a short arc: on ``main`` these records' zero
    lands 0.7-2.2 rad off and the base misfits (named ``beam_tilt_axial`` or left
    ``unexplained``; ``short_arcs.py --set effects --seed 6215`` record 1: 29x the noise).
    The match is now refused where the runs' observations contradict it and the base fitted
    to both runs prefers another zero by more than its own misfit allows; each head's arc
    overlaps other heads' arcs of the other run, and the profile sees it."""
    rec, truth = _disjoint_runs_record(seed)
    doc = diagnose(rec).doc
    off = doc["base"]["terms"]["base"]["run_angle_offset_rad"]["value"][0]
    assert _wrapped(off, truth) < 0.01, (off, truth)
    assert doc["verdict"] == "consistent", ([e["name"] for e in doc["effects"]], doc["unexplained"])
