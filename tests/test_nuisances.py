"""Nuisances of measured benches (issue 22, item 4): ``encdesign.diagnose.engine._nuisances``."""

import numpy as np
import pytest
from helpers import (
    angle_step_record,
    dwell_reversal_record,
    late_stamps_record,
    return_move_record,
    reversal_record,
    steady_start_record,
    sweep,
    validate_diagnosis,
)

from encdesign import Recording
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose.engine import _nuisances


def test_excluded_share_lists_the_reasons_above_a_third():
    ex = [dict(n_rows=300, reason="dwell"), dict(n_rows=100, reason="start-up")]
    w = _nuisances.excluded_share(1000, 580, ex)
    assert w["share"] == pytest.approx(0.42)
    assert list(w["reasons"]) == ["dwell", "start-up", "other (glitches, settling)"]
    assert w["reasons"]["other (glitches, settling)"] == 20
    assert _nuisances.excluded_share(1000, 700, ex) is None
    # the threshold is FinderSettings.excluded_share_warn (the caller's)
    from encdesign.diagnose import FinderSettings

    assert _nuisances.excluded_share(1000, 700, ex, FinderSettings(excluded_share_warn=0.25))
    assert _nuisances.excluded_share(1000, 580, ex, FinderSettings(excluded_share_warn=0.5)) is None


# Each generated nuisance below runs one draw of its generator in ``make test`` (two for the
# return move: its smallest and largest share) and its further draws, the same record
# generator and configuration with other seeds, in the ``sweep`` tier (session 33, CI time).


def _dwell_record(seed: int, dwell_share: float) -> Recording:
    """Two heads and theta_ref: a steady turn, then the shaft at rest for ``dwell_share``."""
    rng = np.random.default_rng(seed)
    n = 1600
    t = np.arange(n) / 200.0
    k = int((1 - dwell_share) * n)
    w = 2 * np.pi * rng.uniform(0.3, 0.8)
    th = np.where(np.arange(n) < k, w * t, w * t[k - 1]) + rng.uniform(0, 6)
    cols = {"t": t, "theta_ref": th}
    for h, a in enumerate((0.0, 2.0)):
        e = 1e-5 * np.sin(th - a + 1.0) + 4e-6 * np.sin(2 * (th - a))
        cols[f"h{h}"] = th + e + rng.normal(0, 5e-7, n) + rng.uniform(-1, 1)
    enc = {"head_angles_deg": [0.0, float(np.degrees(2.0))], "optical_radius_m": 0.02}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


@pytest.mark.parametrize("seed", sweep([21, 22], (21,)))
def test_a_record_mostly_at_rest_is_reported_prominently(seed):
    d = diagnose(_dwell_record(seed, 0.45))
    w = d.doc["excluded_share"]
    assert w is not None and w["share"] > 1 / 3
    assert any("dwell" in r for r in w["reasons"])
    assert d.doc["report"].splitlines()[2].startswith("WARNING: ")
    d = diagnose(_dwell_record(seed, 0.1))
    assert d.doc["excluded_share"] is None


@pytest.mark.parametrize("seed", sweep([31, 32, 33], (31,)))
def test_late_stamps_after_a_logger_gap_are_excluded_as_such(seed):
    rec, late = late_stamps_record(seed)
    doc = diagnose(rec).doc
    assert len(doc["gaps"]) == len(late)
    assert [g.get("late_rows") for g in doc["gaps"]] == late
    reasons = [e["reason"] for e in doc["excluded_segments"]]
    assert reasons == [_nuisances.LATE_STAMPS_REASON] * len(late)
    assert [e["n_rows"] for e in doc["excluded_segments"]] == late
    assert doc["verdict"] == "consistent"


def test_late_stamp_rows_counts_the_leading_short_intervals():
    assert _nuisances.late_stamp_rows(np.array([0.1, 0.1, 1.0, 0.1]), 1.0, 0.5) == 2
    assert _nuisances.late_stamp_rows(np.array([1.0, 0.1]), 1.0, 0.5) == 0
    assert _nuisances.late_stamp_rows(np.array([0.2, 0.2]), 1.0, 0.5) == 2


@pytest.mark.parametrize("seed", sweep([41, 42, 43], (41,)))
def test_a_step_at_a_reversal_is_unexplained_located_not_a_time_drift(seed):
    """No temp_c: thermal_drift is not testable (issue 44 E), so never a stand-in for a
    step at a reversal (no reference: no direction term covers it); the step is reported
    located in time and direction."""
    rec, truth = reversal_record(seed, "reversal_step")
    doc = diagnose(rec).doc
    assert doc["verdict"] == "unexplained", doc["report"]
    assert not doc["effects"]
    assert any(n["name"] == "thermal_drift" for n in doc["not_testable"])
    steps = [u["step_at"] for u in doc["unexplained"] if u.get("step_at")]
    assert steps and steps[0]["heads"] == [1]
    assert steps[0]["at"].startswith("at a reversal (forward to backward)")
    assert abs(steps[0]["t_s"] - truth["t_reversal_s"]) < 0.3
    assert "at a reversal" in doc["report"]
    validate_diagnosis(doc)


@pytest.mark.parametrize("seed", sweep([41, 42], (41,)))
def test_a_slow_drift_across_a_reversal_is_located_not_thermal_drift(seed):
    """Issue 44 E: no temp_c, so a slow drift across a reversal is located (view
    ``drift``, on head 1), never named thermal_drift."""
    rec, _ = reversal_record(seed, "drift")
    doc = diagnose(rec).doc
    assert not doc["effects"], doc["report"]
    drift = [u for u in doc["unexplained"] if u.get("view") == "drift"]
    assert drift and 1 in drift[0]["where"]["heads"], doc["unexplained"][:3]


@pytest.mark.parametrize("seed", sweep([51, 52, 53], (51,)))
def test_a_short_move_back_after_a_dwell_tests_the_direction_offset(seed):
    """Forward, stop, back by a tenth of the forward angle (about 8 % of the rows): the
    move back is kept (``FinderSettings.reversal_piece_share``), so the direction offset
    is tested at the reversal and found with its size."""
    rec, truth = dwell_reversal_record(seed, back=0.1)
    doc = diagnose(rec).doc
    assert [e["name"] for e in doc["effects"]] == ["direction_hysteresis"], doc["report"]
    p = doc["effects"][0]["params"]["hysteresis_rad"]
    assert abs(p["value"] - truth["hysteresis_rad"]) < max(
        4 * p["se"], 0.2 * truth["hysteresis_rad"]
    )


@pytest.mark.parametrize(
    ("seed", "share"), sweep([(201, 0.05), (202, 0.07), (203, 0.09)], ((201, 0.05), (203, 0.09)))
)
def test_a_fast_move_back_before_the_run_is_a_return_move_not_a_reversal(seed, share):
    """A move back into the start position (3x the steady speed, no stop, 5-9 % of the
    rows, the heads shaken while it lasts) comes before any forward motion: it is excluded
    as a return move (``segment_min_share``), not kept as a move back after a stop
    (``reversal_piece_share``), and the record is consistent."""
    doc = diagnose(return_move_record(seed, share)).doc
    ex = doc["excluded_segments"]
    assert ex and ex[0]["t_start_s"] == 0.0 and ex[0]["reason"].startswith("return move"), ex
    assert doc["verdict"] == "consistent", doc["report"]


@pytest.mark.parametrize("seed", sweep([61, 62, 63], (61,)))
def test_a_steady_drive_from_its_first_row_is_no_start_up(seed):
    doc = diagnose(steady_start_record(seed)).doc
    assert doc["excluded_segments"] == [] and doc["verdict"] == "consistent", doc["report"]
    doc = diagnose(steady_start_record(seed, ramp_s=0.6)).doc  # the control: a real ramp
    starts = [e for e in doc["excluded_segments"] if e["reason"].startswith("start-up")]
    assert starts and starts[0]["t_start_s"] < 0.01 and starts[0]["t_end_s"] > 0.3


@pytest.mark.parametrize("seed", sweep([71, 72, 73], (71,)))
def test_steps_recurring_at_one_angle_are_of_the_angle_not_count_jumps(seed):
    rec, truth = angle_step_record(seed)
    doc = diagnose(rec).doc
    assert doc["count_jumps"] == [] and doc["verdict"] == "consistent", doc["report"]
    steps = sorted(doc["angle_steps"], key=lambda s: s["size_rad"], reverse=True)
    assert [s["passes"] >= 4 for s in steps] == [True, True]
    for s, a, sign in zip(steps, truth["angles_rad"], (1, -1)):
        assert abs(np.angle(np.exp(1j * (s["angle_rad"] - a)))) < 0.02
        assert s["size_rad"] == pytest.approx(sign * truth["size_rad"], rel=0.15)
    arc = doc["base"]["terms"]["angle_steps"]["arc_rad"]["value"]
    assert len(arc) == 1 and abs(arc[0]) == pytest.approx(truth["size_rad"], rel=0.05)
    assert "angle step: channel h0" in doc["report"]
    validate_diagnosis(doc)


def test_counts_lost_at_one_angle_every_pass_stay_count_jumps():
    """They recur at one angle but never return: steps in time (angle_step_close)."""
    rec, _ = angle_step_record(71, accumulate=True)
    doc = diagnose(rec).doc
    assert doc["angle_steps"] == [] and len(doc["count_jumps"]) >= 3, doc["report"]
