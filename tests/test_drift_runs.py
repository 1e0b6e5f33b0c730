"""A slow drift over a record of several runs, each with its own zeros: the part of the
drift the per-run constants absorb is not counted as the drift's own size (rule
``plausible_ratio``), so it is named, not refused as an implausible cancellation."""

from __future__ import annotations

import numpy as np
import pytest

from encdesign import Recording
from encdesign.diagnose._dispatch import diagnose
from tests.helpers import sweep

NOISE = 0.5e-6


def _drift_record(seed: int, rate_rad_per_s: float, temp_k_per_s: float = 0.0) -> Recording:
    """4 heads, 4 runs of 3 s at 200 Hz, 2 s apart, per-run zeros of every head and of the
    reference, disk error orders 1-4; each head drifts ``rate * beta_k`` over the global time
    (runs end to end with their gaps): the record is about 5x as long as a run. With
    ``temp_k_per_s`` a ``temp_c`` column rises at that rate over the same time."""
    rng = np.random.default_rng(seed)
    alpha = np.array([0.0, 2.1, 4.2, 0.9])
    beta = np.array([1.0, -0.6, 0.3, -0.8])
    cols: dict[str, list] = {"t": [], "run": [], "theta_ref": [], **{f"h{k}": [] for k in range(4)}}
    for r in range(4):
        t = np.arange(600) / 200.0
        th = 2 * np.pi * (0.6 + 0.4 * r) * t + rng.uniform(0, 6)
        cols["t"].append(t)
        cols["run"].append(np.full(t.size, r))
        cols["theta_ref"].append(th + rng.uniform(-3, 3))
        if temp_k_per_s:
            cols.setdefault("temp_c", []).append(21.0 + temp_k_per_s * (t + 5.0 * r - 10.0))
        for k in range(4):
            e = sum(4e-6 / m * np.sin(m * (th - alpha[k]) + m) for m in range(1, 5))
            e = e + rate_rad_per_s * beta[k] * (t + 5.0 * r - 10.0)
            y = th + e + rng.normal(0, NOISE, t.size) + rng.uniform(-3, 3)
            cols[f"h{k}"].append(y)
    enc = {"optical_radius_m": 0.0254, "head_angles_deg": np.degrees(alpha).tolist()}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, {k: np.concatenate(v) for k, v in cols.items()})


# each test runs one draw of its record in ``make test`` (seed 1) and its other draw in the
# ``sweep`` tier (session 33, CI time)
@pytest.mark.parametrize("seed", sweep([1, 2], (1,)))
def test_drift_over_runs_with_own_zeros_is_named(seed):
    rate = 0.4e-6  # rad/s: 1.2 urad over a run of head 0, 0.5 urad noise
    k_t = 0.05  # K/s: the temperature follows the drift (0.75 K over the record)
    d = diagnose(_drift_record(seed, rate, temp_k_per_s=k_t))
    assert [e["name"] for e in d.effects] == ["thermal_drift"], d.doc["report"]
    got = np.asarray(d.effects[0]["params"]["rate"]["value"]) * k_t
    np.testing.assert_allclose(got, rate * np.array([1.0, -0.6, 0.3, -0.8]), atol=0.15 * rate)


@pytest.mark.parametrize("seed", sweep([1, 4], (1,)))
def test_a_drift_in_time_without_temp_c_is_located_never_thermal_drift(seed):
    """Issue 44 E: without a temp_c column a slow drift is not attributed to temperature:
    thermal_drift is not testable, and the drift is reported located (view ``drift``) on
    the heads that drift most."""
    d = diagnose(_drift_record(seed, 0.4e-6))
    assert d.verdict == "unexplained" and not d.effects, d.doc["report"]
    assert any(n["name"] == "thermal_drift" for n in d.doc["not_testable"])
    drift = [u for u in d.doc["unexplained"] if u.get("view") == "drift"]
    assert drift and 0 in drift[0]["where"]["heads"], d.doc["unexplained"][:3]


def test_no_drift_is_not_named():
    d = diagnose(_drift_record(3, 0.0))
    assert d.verdict == "consistent"
