"""The diagnosis's time per stage: exclusive sums that add up, and the engine's stages."""

from __future__ import annotations

import numpy as np
import pytest

from encdesign import Recording
from encdesign.diagnose import diagnose
from encdesign.diagnose.engine import _timing
from encdesign.diagnose.engine._timing import stage, timing
from tests.helpers import validate_diagnosis


class _Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_nested_stages_are_exclusive_and_add_up(monkeypatch):
    clock = _Clock()
    monkeypatch.setattr(_timing.time, "perf_counter", clock)
    monkeypatch.setattr(_timing.time, "process_time", lambda: clock.now / 2)
    with timing() as timer:
        with stage("a"):
            clock.now += 1.0
            with stage("b"):
                clock.now += 2.0
                with stage("a"):  # a stage re-entered inside another: charged to itself
                    clock.now += 0.5
            clock.now += 4.0
        clock.now += 8.0  # outside every stage: not charged
        with stage("c"):
            clock.now += 16.0
    assert timer.totals == {"a": 5.5, "b": 2.0, "c": 16.0}
    assert timer.cpu_totals == {"a": 2.75, "b": 1.0, "c": 8.0}


def test_no_timer_no_cost_and_an_exception_leaves_the_stack(monkeypatch):
    clock = _Clock()
    monkeypatch.setattr(_timing.time, "perf_counter", clock)
    with stage("x"):  # no active timer: nothing recorded, nothing raised
        clock.now += 1.0
    with timing() as timer:
        with pytest.raises(ValueError), stage("x"):
            clock.now += 3.0
            raise ValueError("boom")
        with stage("y"):
            clock.now += 1.0
    assert timer.totals == {"x": 3.0, "y": 1.0}
    with timing() as inner:
        pass
    assert inner.totals == {} and inner is not timer


def _record(seed: int) -> Recording:
    rng = np.random.default_rng(seed)
    alpha = np.array([0.0, 2.0, 4.3])
    n, R = 600, 2
    t = np.tile(np.arange(n) / 200.0, R)
    run = np.repeat(np.arange(R), n)
    th = 2 * np.pi * (1.0 + 0.6 * run) * t + rng.uniform(0, 6, R)[run]
    err = sum(
        4e-6 / m * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6))
        for m in range(1, 5)
    )
    read = th[:, None] + err + rng.normal(0, 5e-7, (t.size, 3)) + rng.uniform(-3, 3, (R, 3))[run]
    cols = {"t": t, "run": run, "theta_ref": th, **{f"h{k}": read[:, k] for k in range(3)}}
    enc = {"head_angles_deg": np.degrees(alpha).tolist()}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


@pytest.mark.parametrize("seed", [2, 13])
def test_diagnosis_reports_its_stages(seed):
    d = diagnose(_record(seed))
    validate_diagnosis(d.doc)
    tm = d.doc["timings_s"]
    assert set(d.doc["timings_cpu_s"]) == set(tm)
    assert {"data", "prepare", "base_fit", "views", "heldout", "select", "report"} <= set(tm)
    assert all(v >= 0.0 for v in tm.values())
    assert tm["base_fit"] > 0.0 and tm["views"] > 0.0
    total = sum(tm.values())
    assert total <= d.doc["time_s"] + 1e-9
    # outside the stages: the progress bar's set-up and the calls between stages only (the
    # margin is for a loaded machine, where a process can wait anywhere)
    assert total >= 0.5 * d.doc["time_s"]
