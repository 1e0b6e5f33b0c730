"""The base model's order growth (engine ``_grow_base_order``) on clean records with disk
orders above the default base order: a trace of structure tied to the signal period, the
direction or the speed (under ``FinderSettings.growth_veto_share`` of what the views located)
no longer keeps the base at order 12 and the record ``unexplained`` (issue 44 H: the
``high`` variation set's misses)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import sweep

from encdesign import Recording
from encdesign.diagnose import FinderSettings
from encdesign.diagnose._dispatch import diagnose


def _high_order_record(seed: int, M: int, turns: float, H: int = 3, R: int = 3, n: int = 1500):
    """A clean multihead record without ``theta_ref``: disk error orders 1..M of 3-300x the
    noise (falling as 1/m^0.5..1/m^1.5), R runs under one turn each at 100 Hz, a 1,000-line
    grating (its period far above the samples' Nyquist order), per-run head zeros."""
    rng = np.random.default_rng(seed)
    noise = 5e-6
    nr = n // R
    ts, ths, runs = [], [], []
    for r in range(R):
        t = np.arange(nr) / 100.0
        sp = turns * 2 * np.pi / t[-1] * (1 + 0.3 * r)
        ths.append(sp * t + rng.uniform(0, 6.3))
        ts.append(t + r * (t[-1] + 5))
        runs.append(np.full(nr, r))
    t, th, run = np.concatenate(ts), np.concatenate(ths), np.concatenate(runs)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.2, 6.1, H - 1))])
    err = np.zeros((t.size, H))
    amp0 = noise * 10 ** rng.uniform(0.5, 2.5)
    for m in range(1, M + 1):
        a = amp0 / m ** rng.uniform(0.5, 1.5)
        ph = rng.uniform(0, 6.3)
        for k in range(H):
            err[:, k] += a * np.sin(m * (th - alpha[k]) + ph)
    y = th[:, None] + err + rng.normal(0, noise, err.shape)
    for r in range(R):
        y[run == r] += rng.integers(-3, 4, H) * 2 * np.pi + rng.uniform(-3, 3, H)
    cols = {"t": t, "run": run, **{f"h{k}": y[:, k] for k in range(H)}}
    enc = {
        "head_angles_deg": [float(np.degrees(a)) for a in alpha],
        "optical_radius_m": 0.05,
        "grating_lines": 1000,
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


CASES = [
    (1401, 14, 0.8),
    (1402, 16, 0.9),
    (1403, 18, 0.7),
    (1404, 15, 0.85),
    (1409, 16, 0.8),
    (1410, 18, 0.9),
]


BLOCKED = [(1403, 18, 0.7), (1410, 18, 0.9)]
"""Two of :data:`CASES` whose growth a share of 1e-12 blocked while the direction, speed and
angle-trend views were judged before the growth (session 17: 5.2 s CPU of the 17.8 s all six
cost)."""


# ``make test`` runs the kept cases; the others are the ``sweep`` tier (``make
# test-sweeps``; session 31, CI time)
@pytest.mark.parametrize(
    ("seed", "M", "turns"),
    sweep([c for c in CASES if c not in BLOCKED], ((1401, 14, 0.8), (1404, 15, 0.85))),
)
def test_clean_record_with_orders_above_12_is_consistent(seed, M, turns):
    # (the two BLOCKED cases run in the test below at a share of 1e-12: the share only
    # enters the growth's vetoes, each a test `x > share * located`, so a record that grows
    # there grows alike at the default; session 20 left their default run out, 2 records)
    d = diagnose(_high_order_record(seed, M, turns)).doc
    assert d["verdict"] == "consistent", d["report"]
    assert d["base"]["max_order"] >= M - 1, d["base"]["max_order"]


def test_traces_the_growth_takes_with_it_do_not_block_it_at_any_share():
    """The control, since session 18 (issue 44, records of part of a turn): the direction,
    speed and angle-trend views are judged on the grown base's residual, so even a share of
    1e-12 lets these records grow: the traces that once blocked it were the missing orders'
    leakage and go with them (before, both stayed ``unexplained`` at order 12)."""
    st = dataclasses.replace(FinderSettings(), growth_veto_share=1e-12)
    for seed, M, turns in BLOCKED:
        d = diagnose(_high_order_record(seed, M, turns), settings=st).doc
        assert d["verdict"] == "consistent" and d["base"]["max_order"] >= M - 1, seed


def _wide_error_record(seed: int, H: int = 4, n: int = 1000, M: int = 15) -> Recording:
    """A clean record without ``theta_ref``: H heads, disk error orders 1..M of 100-300x the
    noise at order 1 (the shaft refinement's second-order part is many times the noise)."""
    rng = np.random.default_rng(seed)
    noise = 2e-5
    t = np.arange(n) / 50.0
    th = 2 * np.pi * 25.0 * t / t[-1] + rng.uniform(0, 6.3)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.2, 6.1, H - 1))])
    err = np.zeros((n, H))
    amp0 = noise * 10 ** rng.uniform(2.0, 2.5)
    for m in range(1, M + 1):
        a = amp0 / m ** rng.uniform(0.5, 1.5)
        err += a * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6.3))
    y = th[:, None] + err + rng.normal(0, noise, err.shape) + rng.uniform(-3, 3, H)
    cols = {"t": t, "run": np.zeros(n, int), **{f"h{k}": y[:, k] for k in range(H)}}
    enc = {"head_angles_deg": [float(np.degrees(a)) for a in alpha], "optical_radius_m": 0.05}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


def test_shaft_refined_again_once_the_base_grows():
    # the refinement of the shaft angle (heads' mean less the fitted error's head mean) was
    # computed from the base before its growth: the grown orders' second-order part stayed
    # in the residual and was reported at orders no effect has (main: missing_physics, a
    # beam tilt named, orders 6 and 13 unexplained)
    d = diagnose(_wide_error_record(5553)).doc
    assert d["verdict"] == "consistent", (d["verdict"], [e["name"] for e in d["effects"]])
    assert d["base"]["max_order"] >= 15


def test_one_sensor_base_grows_past_its_signal_period_inside_the_disk_orders():
    # one sensor against its reference, 7 signal periods, a disk error at orders 1-15: the
    # disk's order 14 is the sensor's 2 L. The line at the signal period is those shaft
    # orders, not an aliased line: the base grows past it (main left orders 13-15
    # unexplained and named interpolation_error for order 14)
    rng = np.random.default_rng(5501)
    n, noise = 1500, 2e-7
    t = np.arange(n) / 200.0
    th = 2 * np.pi * 15.0 * t / t[-1] + 0.3
    err = sum(noise * 40 / m * np.sin(m * th + rng.uniform(0, 2 * np.pi)) for m in range(1, 16))
    cols = {"t": t, "run": np.zeros(n, int), "theta_ref": th}
    cols["h0"] = th + err + rng.normal(0, noise, n) + 1.0
    enc = {"head_angles_deg": [0.0], "sensor": "magnetic", "signal_periods_per_rev": 7}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    d = diagnose(Recording("multihead", meta, cols)).doc
    assert d["verdict"] == "consistent", (d["verdict"], [e["name"] for e in d["effects"]])
    assert d["base"]["max_order"] >= 15


def _budget_record(seed: int, jitter: float, n: int = 400) -> tuple[Recording, float, int]:
    """One sensor against ``theta_ref`` on a few hundred rows: 2-3 runs at 1-1.6x speed,
    15-40 turns each at 60-150 Hz (sampling times jittered by ``jitter`` of a step, or
    even), disk orders 1..M (M 19-22) of 30-300x the noise at order 1, falling as
    1/m^0.5..1/m^1 (the orders past 16-17 cost more than ``max_param_fraction`` of the
    values). Returns the record, its noise (rad) and M."""
    rng = np.random.default_rng(seed)
    R = int(rng.integers(2, 4))
    nr = n // R
    noise = float(10 ** rng.uniform(-7, -5))
    turns, rate, M = (
        float(rng.uniform(15, 40)),
        float(rng.uniform(60, 150)),
        int(rng.integers(19, 23)),
    )
    ts, ths, runs = [], [], []
    for r in range(R):
        t = np.cumsum((1 + jitter * rng.uniform(-1, 1, nr)) / rate)
        sp = turns * 2 * np.pi * (1 + 0.3 * r) / (t[-1] - t[0])
        ths.append(sp * (t - t[0]) + rng.uniform(0, 6.3))
        ts.append(t + r * (t[-1] + 5))
        runs.append(np.full(nr, r))
    t, th, run = np.concatenate(ts), np.concatenate(ths), np.concatenate(runs)
    amp0 = noise * 10 ** rng.uniform(1.5, 2.5)
    err = sum(
        amp0 / m ** rng.uniform(0.5, 1.0) * np.sin(m * th + rng.uniform(0, 6.3))
        for m in range(1, M + 1)
    )
    y = th + err + rng.normal(0, noise, t.size) + rng.uniform(-3, 3, R)[run]
    cols = {"t": t, "run": run, "theta_ref": th + rng.uniform(-3, 3, R)[run], "h0": y}
    enc = {"head_angles_deg": [0.0], "sensor": "optical", "signal_periods_per_rev": 2048}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), noise, M


@pytest.mark.parametrize(("seed", "jitter"), [(7410, 0.0), (7411, 0.3)])
def test_disk_orders_past_the_parameter_budget_join_the_base(seed, jitter):
    # session 20 (issue 44, `high` 6237/7): the orders past the budget (max_param_fraction)
    # of a few hundred rows were left out of the base: evenly sampled, they alias into lines
    # and bands no effect explains (main: unexplained, or a false quantization, scale_error
    # or vibration, the noise estimate 4-30x the truth); jittered, they hid in a noise
    # estimate 10-30x the truth (main: consistent). The base grows past the budget where the
    # held-out chi-square says so, and the noise estimate, corrected for the share of its
    # parameters (about 0.88 of the truth without it: a line reported on seed 7411), is the
    # noise's.
    rec, noise, M = _budget_record(seed, jitter)
    d = diagnose(rec).doc
    b = d["base"]
    assert d["verdict"] == "consistent", (d["verdict"], [e["name"] for e in d["effects"]])
    assert b["max_order"] >= M - 1 and b["grown_past_budget"]["budget_order"] < M - 1, b
    assert 0.85 < d["noise"]["per_channel"][0] / noise < 1.15, d["noise"]


def test_a_growth_refused_at_the_highest_located_order_takes_the_one_heldout_error_favours():
    """Training ``finder_variations.py --set high --seed 6680`` record 7 (5 heads, 400 rows,
    0.73 turn forward and back, disk orders 1-17, no reference): the held-out choice lowered
    the base to 11, the orders view located 12-18 and higher, and the growth to the highest
    (24) raised the held-out chi-square and was undone, leaving the record ``unexplained``
    (main). The located order of least held-out chi-square (the disk's own 17) is grown to
    instead, and the record is ``consistent``."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from finder_variations import clean_record

    rec, desc = clean_record(np.random.default_rng([6680, 7]), 13, 21)
    doc = diagnose(rec).doc
    assert doc["base_order"]["lowered"], doc["base_order"]["reason"]
    assert doc["verdict"] == "consistent", doc["report"]
    assert doc["base"]["max_order"] == desc["M"] == 17, doc["base"]["max_order"]
    assert max(doc["base"]["grown_orders"]) == 17, doc["base"]["grown_orders"]
