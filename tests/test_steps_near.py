"""A located step near a reversal, settled on the model (issue 44, session 24,
``engine/_steps_near.py``): a step on a sensor a few rows after the excluded rows of a
reversal (more than ``FinderSettings.step_change_rows`` kept rows after it, within half a
time-view block) is not a direction offset: ``direction_hysteresis`` is not named for it,
and the step is reported where it is. A direction offset on the same bench is still named.
Generated records, training seeds 7900-7909."""

import numpy as np
import pytest

from encdesign import Recording
from encdesign.diagnose import FinderSettings, diagnose
from encdesign.diagnose._registry import KINDS

RATE_HZ = 200.0
N_ROWS = 1400


def _bench(rng):
    """One run of a sensor against ``theta_ref``: forward ``turns`` turns, then back, at
    ``RATE_HZ``; its own error orders 1-6 (up to 20x the noise), noise 2e-5..2e-4 rad.
    Returns ``(t, theta, error, noise)``."""
    turns = float(rng.uniform(1.5, 3.0))
    t = np.arange(N_ROWS) / RATE_HZ
    half = N_ROWS // 2
    w = turns * 2 * np.pi / (half / RATE_HZ)
    up = np.arange(half) / RATE_HZ * w
    th = np.concatenate([up, up[-1] - np.arange(N_ROWS - half) / RATE_HZ * w])
    th = th + rng.uniform(0, 2 * np.pi)
    noise = float(10 ** rng.uniform(np.log10(2e-5), np.log10(2e-4)))
    err = np.zeros(N_ROWS)
    for m in range(1, 7):
        err += 20 * noise / m * rng.uniform(0.3, 1) * np.sin(m * th + rng.uniform(0, 2 * np.pi))
    return t, th, err, noise


def _record(t, th, y, rng) -> Recording:
    cols = {
        "t": t,
        "run": np.zeros(t.size, int),
        "theta_ref": th + rng.uniform(-np.pi, np.pi),
        "h0": y + rng.uniform(-np.pi, np.pi),
    }
    enc = {
        "head_angles_deg": [0.0],
        "sensor": str(rng.choice(["magnetic", "resolver", "capacitive"])),
        "signal_periods_per_rev": int(rng.choice([1, 2, 7])),
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


def _first_kept_after_reversal(rec: Recording) -> tuple[int, int]:
    """The row of the first kept row after the reversal's excluded rows, and the number of
    kept rows (the finder's own stage 1)."""
    s = FinderSettings()
    kind = KINDS["multihead"]
    kd = kind.data(rec, s)
    prep = kind.prepare(kd, dict(rec.meta), s)
    keep = np.asarray(prep.keep)
    half = N_ROWS // 2
    return half + int(np.flatnonzero(keep[half:])[0]), int(keep.sum())


@pytest.mark.parametrize("seed", [7900, 7901, 7902, 7903, 7904])
def test_a_step_just_after_a_reversal_is_not_a_direction_offset(seed):
    rng = np.random.default_rng([seed, 24])
    t, th, err, noise = _bench(rng)
    y = th + err + rng.normal(0, noise, N_ROWS)
    probe = _record(t, th, y, np.random.default_rng([seed, 1]))
    first, n_kept = _first_kept_after_reversal(probe)
    near = n_kept // 64  # half a time-view block: the coarse "at the reversal"
    s = FinderSettings()
    d = int(rng.integers(s.step_change_rows + 3, near - 1))
    i = first + d
    y[i:] += float(rng.uniform(4, 8)) * noise * rng.choice([-1, 1])
    doc = diagnose(_record(t, th, y, np.random.default_rng([seed, 1]))).doc
    assert "direction_hysteresis" not in [e["name"] for e in doc["effects"]], (d, doc["verdict"])
    steps = [
        u
        for u in doc["unexplained"]
        if u["view"] == "time" and u["where"]["times_s"] and u["detail"].get("shape") == "step"
    ]
    assert steps, doc["verdict"]
    assert any(
        min(u["where"]["times_s"]) - 0.05 <= t[i] <= max(u["where"]["times_s"]) + 0.05
        for u in steps
    )


@pytest.mark.parametrize("seed", [7905, 7906, 7907])
def test_a_direction_offset_on_the_same_bench_is_still_named(seed):
    rng = np.random.default_rng([seed, 24])
    t, th, err, noise = _bench(rng)
    y = th + err + rng.normal(0, noise, N_ROWS)
    om = np.gradient(th, t)
    y = y + float(rng.uniform(4, 8)) * noise * np.sign(om) * rng.choice([-1, 1])
    doc = diagnose(_record(t, th, y, np.random.default_rng([seed, 1]))).doc
    assert "direction_hysteresis" in [e["name"] for e in doc["effects"]], doc["verdict"]
