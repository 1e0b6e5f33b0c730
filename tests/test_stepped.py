"""Static stepped calibrations (issue 22, item 5): ``encdesign.diagnose.engine._stepped``."""

import numpy as np
import pytest
from helpers import stepped_sensor_record, validate_diagnosis

from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose.engine import _stepped


def test_approach_direction_forward_fills_the_last_move():
    th = np.array([0.0, 0.0, 1.0, 1.0, 3.0, 2.0, 2.0, 5.0])
    d = _stepped.approach_direction(th)
    np.testing.assert_array_equal(d, [1, 1, 1, 1, 1, -1, -1, 1])
    assert np.all(_stepped.approach_direction(np.zeros(4)) == 1)


def test_a_steady_turn_is_not_stepped():
    t = np.arange(2000) / 1000.0
    th = 2 * np.pi * t + 1e-7 * np.random.default_rng(0).normal(size=t.size)
    assert not _stepped.is_stepped(th, t, np.zeros(t.size, int), 0.1, 0.01)
    rec, _ = stepped_sensor_record(11)
    c = rec.columns
    assert _stepped.is_stepped(c["theta_ref"], c["t"], np.zeros(c["t"].size, int), 0.1, 0.01)


def test_is_stepped_uses_the_callers_settings():
    """The caller's settings reach the segment finder and the steady-row minimum: a steady
    turn of 2,000 rows is a motion record with the defaults, and stepped when the minimum
    asks for more rows than it has or the finder's kept pieces need 60 % of the run."""
    from encdesign.diagnose import FinderSettings

    t = np.arange(2000) / 1000.0
    th = 2 * np.pi * t
    run = np.zeros(t.size, int)
    assert not _stepped.is_stepped(th, t, run, 0.1, 0.01, FinderSettings())
    assert _stepped.is_stepped(th, t, run, 0.1, 0.01, FinderSettings(stepped_max_steady_rows=5000))
    # two pieces (forward, back) of 50 % each: neither is 60 % of the run
    th2 = np.where(t < 1.0, th, 2 * (2 * np.pi) - th)
    assert not _stepped.is_stepped(th2, t, run, 0.1, 0.01, FinderSettings())
    wide = FinderSettings(segment_min_share=0.6, reversal_piece_share=0.6)
    assert _stepped.is_stepped(th2, t, run, 0.1, 0.01, wide)


@pytest.mark.parametrize("seed", [3, 4])
def test_stepped_calibration_names_the_direction_offset_and_no_dynamic_effect(seed):
    rec, _ = stepped_sensor_record(seed, hysteresis_rad=2e-4)
    d = diagnose(rec)
    validate_diagnosis(d.doc)
    assert [e["name"] for e in d.effects] == ["direction_hysteresis"]
    assert "static stepped" in d.doc["sensor"]["record_type"]
    reasons = {c["name"]: c.get("reason", "") for c in d.doc["not_testable"]}
    for name in ("vibration", "thermal_drift", "reading_delay"):
        assert reasons[name] == _stepped.STATIC_REASON


def test_stepped_calibration_clean_one_direction_with_lsb():
    rec, _ = stepped_sensor_record(6, both=False, n_steps=120, lsb_rad=1e-4)
    d = diagnose(rec)
    assert d.verdict in ("consistent", "missing_physics")
    assert [e["name"] for e in d.effects] in ([], ["quantization"])
    assert d.doc["sensor"]["sensor_lattice"]["lsb_rad"] == pytest.approx(1e-4, rel=1e-6)
