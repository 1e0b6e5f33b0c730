"""The base order chosen by held-out error (issue 44 E).

A sensor against a stepper's commanded angle, turned one turn (or 1.5) forward, held in a
dwell and turned back, at 140-260 samples per turn: on so few turns the default base order
(12) is often ill-conditioned in the engine's blocked folds (a held-out block's arc is
bridged by orders the other folds cannot pin down) and its held-out RMS is up to several
times its fitted RMS (on ``main``: over 1.5x on 8 of 20 fresh one-turn records). The base
order is then chosen by held-out error among orders 1..12; long records keep the default
order untouched.
"""

import numpy as np
import pytest
from helpers import shared_diagnosis, validate_diagnosis

from encdesign import Recording
from encdesign.diagnose import BaseOrder, Diagnosis, FinderSettings, diagnose


def stepper_sensor_record(seed: int, turns: float = 1.0, hysteresis_noise: float = 0.0):
    """A magnetic sensor against a stepper's commanded angle ``theta_ref``: at rest, ``turns``
    forward at 45-240 deg/s, a dwell of 0.5-2 s, ``turns`` back, at rest (speed ramps of
    0.1 s); 140-260 samples per turn. The sensor's error is one dominant order ``m0``
    (2, 3, 5 or 6) of 2-6 degrees plus every lower order at 0.02-0.1 degree; noise
    0.2-1 mrad; a direction offset ``h d / 2`` with ``h = hysteresis_noise`` noise units
    (``d`` the direction of the last motion, held through the dwell). Returns
    ``(recording, truth)``."""
    rng = np.random.default_rng(seed)
    speed = np.deg2rad(rng.uniform(45.0, 240.0))
    spt = rng.uniform(140.0, 260.0)
    fs = spt * speed / (2 * np.pi)
    noise = 10 ** rng.uniform(-3.7, -3.0)
    T = turns * 2 * np.pi / speed
    plan = [(rng.uniform(0.3, 1.0), 0.0), (T, 1.0), (rng.uniform(0.5, 2.0), 0.0)]
    plan += [(T, -1.0), (0.5, 0.0)]
    v = np.concatenate([np.full(int(d * fs), s * speed) for d, s in plan])
    k = max(1, int(0.1 * fs))
    v = np.convolve(np.pad(v, k, mode="edge"), np.ones(k) / k, mode="same")[k:-k]
    th = np.cumsum(v) / fs + rng.uniform(0, 2 * np.pi)
    m0 = int(rng.choice([2, 3, 5, 6]))
    e = np.deg2rad(rng.uniform(2.0, 6.0)) * np.sin(m0 * th + rng.uniform(0, 2 * np.pi))
    for m in range(1, m0):
        e += np.deg2rad(rng.uniform(0.02, 0.1)) * np.sin(m * th + rng.uniform(0, 2 * np.pi))
    d = np.sign(v) * (np.abs(v) > 1e-9)
    for i in range(1, d.size):
        d[i] = d[i] if d[i] else d[i - 1]
    h = hysteresis_noise * noise
    y = th + e + 0.5 * h * d + rng.normal(0, noise, th.size) + rng.uniform(-1, 1)
    cols = {"t": np.arange(th.size) / fs, "theta_ref": th, "h0": y}
    enc = {"head_angles_deg": [0.0], "sensor": "magnetic"}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), dict(order=m0, hysteresis_rad=h)


RATIO = FinderSettings().base_order_ratio


@pytest.mark.parametrize("turns", [1.0, 1.5])
@pytest.mark.parametrize("seed", range(601, 606))
def test_a_few_turns_get_a_base_order_chosen_by_heldout_error(seed, turns):
    """Clean: consistent, and the base's held-out RMS within ``base_order_ratio`` of its
    fitted RMS (on ``main`` the order-12 base fails that on 3 of the 5 one-turn records
    here, 1.6-3.7x; the 1.5-turn ones pass there too); a lowered order keeps every order of
    the error."""
    rec, truth = stepper_sensor_record(seed, turns)
    d = shared_diagnosis(rec)  # the one-turn ones: also the ratio test's
    doc = d.to_json()
    assert doc["verdict"] == "consistent", doc["report"]
    assert doc["heldout_rms_before"] <= RATIO * doc["rms_before"], doc["report"]
    bo = d.base_order
    assert isinstance(bo, BaseOrder)
    assert bo.start == min(12, doc["base"]["max_order_limit"]) and bo.trial.order == bo.chosen
    if bo.lowered:
        assert bo.heldout_ratio > RATIO
        assert bo.chosen >= truth["order"], doc["report"]
        assert [t.order for t in bo.tried] == list(range(1, bo.start + 1))
        best = min(bo.tried, key=lambda t: t.heldout_chi2)
        assert best.order == bo.chosen
        assert "lowered by held-out error" in doc["report"]
    else:
        assert [t.order for t in bo.tried] == [bo.start] or bo.heldout_ratio > RATIO
    assert "base order: " in doc["report"]
    validate_diagnosis(doc)
    assert Diagnosis.from_json(doc).to_json() == doc


@pytest.mark.parametrize("seed", range(601, 606))
def test_a_direction_offset_on_one_turn_is_named_on_a_well_conditioned_base(seed):
    """One turn forward and back with a direction offset of 6 noise units: named, its size
    right, and the final model's held-out RMS within ``base_order_ratio`` of its fitted RMS
    (on ``main`` the ill-conditioned base leaves it at 1.6-3.9x on 3 of these 5 records)."""
    rec, truth = stepper_sensor_record(seed, 1.0, hysteresis_noise=6.0)
    doc = diagnose(rec).doc
    assert [e["name"] for e in doc["effects"]] == ["direction_hysteresis"], doc["report"]
    p = doc["effects"][0]["params"]["hysteresis_rad"]
    assert abs(p["value"] - truth["hysteresis_rad"]) < max(
        4 * p["se"], 0.2 * truth["hysteresis_rad"]
    )
    assert doc["heldout_rms_final"] <= RATIO * doc["rms_final"], doc["report"]


def test_a_long_record_keeps_the_default_order_untried():
    """Twenty turns at 200 samples per turn: the base is well conditioned, no lower order is
    fitted, and the order is the default one."""
    rng = np.random.default_rng(611)
    n = 4000
    t = np.arange(n) / 400.0
    th = 2 * np.pi * 2.0 * t + 0.4
    e = 3e-3 * np.sin(2 * th + 1.0) + 1e-3 * np.sin(3 * th)
    cols = {"t": t, "theta_ref": th, "h0": th + e + rng.normal(0, 2e-4, n) + 0.3}
    enc = {"head_angles_deg": [0.0], "sensor": "magnetic"}
    rec = Recording(
        "multihead", {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}, cols
    )
    d = diagnose(rec)
    bo = d.base_order
    assert d.verdict == "consistent", d.doc["report"]
    assert bo is not None and not bo.lowered and bo.chosen == bo.start == 12
    assert [t.order for t in bo.tried] == [12] and bo.heldout_ratio < RATIO
    assert d.doc["base"]["max_order"] == 12


def test_the_ratio_setting_decides_whether_orders_are_tried():
    """With ``base_order_ratio`` above any ratio the default order stays (and the base is
    ill-conditioned again); with the default the order is lowered."""
    for seed in range(601, 611):  # the first of these records whose default base is lowered
        rec, _ = stepper_sensor_record(seed, 1.0)
        low = shared_diagnosis(rec)
        if low.base_order.lowered:
            break
    off = diagnose(rec, settings=FinderSettings(base_order_ratio=1e6))
    assert low.base_order.lowered
    assert not off.base_order.lowered and len(off.base_order.tried) == 1
    assert off.doc["base"]["max_order"] >= low.doc["base"]["max_order"]
    assert off.doc["heldout_rms_before"] > RATIO * off.doc["rms_before"]
    # a caller's max_order is kept as given: nothing is chosen
    fixed = diagnose(rec, max_order=8)
    assert fixed.base_order is None and "base_order" not in fixed.doc
    assert fixed.doc["base"]["max_order"] == 8


def sensor_arcs_record(seed: int):
    """A magnetic sensor against ``theta_ref`` over 2-3 runs of 0.35-0.6 turn each, one
    direction (a single pass), each run at its own reference zero and sensor offset; disk
    error orders 1..M (M 3-6) of 10-100x the noise. Returns ``(recording, M)``."""
    rng = np.random.default_rng(seed)
    R, nr = int(rng.integers(2, 4)), int(rng.integers(150, 300))
    turns, rate = rng.uniform(0.35, 0.6), 10 ** rng.uniform(2, 3)
    noise = 10 ** rng.uniform(-6.5, -5)
    M = int(rng.integers(3, 7))
    amp0 = noise * 10 ** rng.uniform(1.0, 2.0)
    amps = [amp0 / m ** rng.uniform(0.5, 1.5) for m in range(1, M + 1)]
    phs = rng.uniform(0, 6.3, M)
    t, th, run, ref = [], [], [], []
    for r in range(R):
        tt = np.arange(nr) / rate
        a = turns * 2 * np.pi * tt / tt[-1] + rng.uniform(0, 6.3)
        t.append(tt + r * (tt[-1] + 2))
        th.append(a)
        run.append(np.full(nr, r))
        ref.append(a + rng.uniform(-3, 3))
    t, th, run, ref = map(np.concatenate, (t, th, run, ref))
    e = sum(amps[m - 1] * np.sin(m * th + phs[m - 1]) for m in range(1, M + 1))
    y = th + e + rng.normal(0, noise, th.size) + rng.uniform(-3, 3, R)[run]
    cols = {"t": t, "run": run, "theta_ref": ref, "h0": y}
    enc = {"head_angles_deg": [0.0], "sensor": "magnetic"}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols), M


@pytest.mark.parametrize("seed", [9])  # 2 too on main and the branch (9 s: left out)
def test_a_single_pass_over_part_of_a_turn_is_not_lowered_by_heldout_error(seed):
    """One rule on part of a turn (session 20): held-out error decides the base's orders
    (the choice here, the growth after it) only where each run's held-out rows lie on angles
    its other folds see. On a single pass a held-out block's arc is seen by no other fold
    and its error measures how the orders extrapolate: on ``main`` it lowered this base
    below the disk's own order (5 -> 4; seed 2: 4 -> 3); the forward-and-back records above
    are still lowered."""
    rec, M = sensor_arcs_record(seed)
    d = diagnose(rec)
    bo = d.base_order
    assert bo is not None and not bo.lowered and "single pass" in bo.reason, d.doc["report"]
    assert d.doc["base"]["max_order"] >= M
    assert [t.order for t in bo.tried] == [bo.start]


def test_folds_see_each_others_arcs_on_a_pass_forward_and_back_only():
    """The predicate of that rule on the engine's own folds: a forward-and-back pass over
    0.4 turn is covered, a single pass over the same arc is not."""
    from encdesign.diagnose.engine._prepare import _fold_blocks, folds_see_each_others_arcs

    n = 600
    fwd = np.linspace(0.0, 0.8 * np.pi, n)
    back = np.concatenate([fwd[: n // 2], fwd[n // 2 - 1 :: -1][: n - n // 2] + 1e-4])
    run, keep = np.zeros(n, int), np.ones(n, bool)
    fold, _ = _fold_blocks(keep, run, FinderSettings().n_folds)
    assert not folds_see_each_others_arcs(fwd, keep, run, fold)
    assert folds_see_each_others_arcs(back * 1.0, keep, run, fold)


@pytest.mark.parametrize("n", [50, 200, 1000])
def test_a_sampled_whole_turn_is_not_part_of_a_turn(n):
    """N rows evenly spaced over one turn span only 2 pi (N - 1) / N of it, yet they cover the
    turn (``magalpha_cal``: 200 rows); 0.9 turn, or a whole turn less two steps, is part of
    one, and a few rows left out inside the turn do not make it part of one."""
    from encdesign.diagnose.engine._prepare import part_turn_span

    run, keep = np.zeros(n, int), np.ones(n, bool)
    turn = 2 * np.pi * np.arange(n) / n
    assert part_turn_span(turn + 0.3, keep, run) is None
    gap = keep.copy()
    gap[n // 3 : n // 3 + n // 10] = False
    assert part_turn_span(turn, gap, run) is None
    assert part_turn_span(turn[: n - 2], keep[: n - 2], run[: n - 2]) is not None
    span = part_turn_span(0.9 * turn, keep, run)
    assert span is not None and abs(span - 0.9 * 2 * np.pi) < 1e-9


def test_the_order_is_chosen_again_beside_a_named_shift():
    """Training ``short_arcs.py --set effects --seed 6684`` record 1 (4 heads, 400 rows, 0.32
    turn forward and back, disk error orders 1-10, the disk shifted on its hub): on the base
    residual the shift dominates held-out error and the choice took order 1, where the
    shift's fit left the disk's orders to a false ``beam_tilt_axial`` (main). Chosen again
    with the shift fitted beside the base, held-out error no longer favours order 1: the
    shift is named alone, and the document says how the order was chosen again."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from short_arcs import short_record

    rec, _ = short_record(np.random.default_rng([6684, 44, 1]), "eccentricity_shift")
    doc = diagnose(rec).doc
    assert [e["name"] for e in doc["effects"]] == ["eccentricity_shift"], doc["report"]
    bo = doc["base_order"]
    again = bo["again"]
    assert again["effects"][0] == "eccentricity_shift", again
    assert [r["order"] for r in again["tried"]] == list(range(1, bo["start"] + 1)), again
    ho = {r["order"]: r["heldout_chi2"] for r in again["tried"]}
    assert bo["chosen"] == again["chosen"] == doc["base"]["max_order"] > 1, bo
    assert ho[again["chosen"]] == min(ho.values()) or again["chosen"] == bo["start"], ho
    assert bo["lowered"] == (bo["chosen"] < bo["start"]), bo
    assert "again beside eccentricity_shift" in doc["report"]
    BaseOrder.from_json(bo)  # the typed entry reads it
    validate_diagnosis(doc)


def test_order_chosen_again_beside_an_effect_held_out_error_refused():
    """Training ``studies/conceal_benchmark.py --kinds sensor,quadrature --seed 6723``
    record 7 (session 38): a capacitive sensor against a reference, 0.8 turn forward and back
    in one run, with a ``direction_hysteresis``. The base alone (order 12) has held-out RMS
    1.38x its fitted RMS, under ``base_order_ratio``; with the direction offset beside it,
    the orders are left for the folds to pin down and held-out chi-square rises by 4351, so
    held-out error refused the offset and main (d5b4fb1) read ``unexplained`` with nothing
    named. The held-out order choice made beside the refused offset lowers the order (8)
    and the offset is named."""
    from encdesign import simulate as cb
    from encdesign.simulate import draw_plan, fix_plan, simulate_plan

    seed, kind = 6723, "sensor"
    rng = np.random.default_rng([seed, sum(map(ord, kind))])  # the benchmark's draws
    recs = []
    for case, k in {"clean": 4, "single": 4}.items():
        for j in range(k):
            plan = draw_plan(rng, kind, case)
            if case == "single" and plan["effects"]:
                pool = cb.SENSOR_EFFECTS
                plan = fix_plan(dict(plan, effects=[pool[(j + 3 * seed) % len(pool)]]), rng)
            recs.append(simulate_plan(rng, plan))
    rec, truth = recs[7]
    assert truth["effects"] == ["direction_hysteresis"]
    d = diagnose(rec).doc
    assert [e["name"] for e in d["effects"]] == ["direction_hysteresis"], d["report"]
    again = d["base_order"]["again"]
    assert again["effects"] == ["direction_hysteresis"] and d["base"]["max_order"] < 12, again
