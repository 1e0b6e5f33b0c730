"""The ``spectrum`` view's peaks without the leakage of a stronger line (engine
``_views_leakage``, issue 43 session 27).

A line far above the noise and off the run's frequency grid leaks into every bin of the
run's periodogram (a rectangular window); the noise makes local maxima in that skirt, and
the view reported them as lines of their own (the benchmark's 10^7-row vibration record:
two extra lines 8-10 bins beside the 31 Hz vibration). A weaker line is now kept only where
it stays above the threshold once the stronger line's fitted leakage is taken out; a true
weak line in the skirt is still found."""

from __future__ import annotations

import numpy as np
import pytest

from encdesign import Recording
from encdesign.diagnose.engine._prepare import prepare
from encdesign.diagnose.engine._settings import FinderSettings
from encdesign.diagnose.engine._views import view_spectrum
from encdesign.diagnose.engine._views_leakage import fit_line
from encdesign.diagnose.engine._views_sums import ViewSums, Whitened
from encdesign.diagnose.kinds.multihead._multihead import multihead_data

RATE_HZ = 1000.0
ROWS = 20000
"""One run of 20 s at 1 kHz: bins of 0.05 Hz."""


def _prep(seed: int):
    """A 4-head record of one run at 1.3 rev/s (its rows only: the residual is set here)."""
    rng = np.random.default_rng(seed)
    t = np.arange(ROWS) / RATE_HZ
    th = 2 * np.pi * 1.3 * t + rng.uniform(0, 6.3)
    alpha = np.array([0.0, 2.1, 4.2, 0.9])
    y = th[:, None] + rng.normal(0, 1e-6, (ROWS, 4))
    cols = {"t": t, "run": np.zeros(ROWS, int), **{f"h{k}": y[:, k] for k in range(4)}}
    enc = {"head_angles_deg": np.degrees(alpha).tolist(), "optical_radius_m": 0.05}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    rec = Recording("multihead", meta, cols)
    return prepare(multihead_data(rec), dict(rec.meta), FinderSettings())


def _lines(prep, seed: int, lines: list[tuple[float, float]]):
    """``view_spectrum`` on a whitened residual of unit white noise plus ``lines``
    (``(frequency Hz, amplitude)``, a random phase per channel), projected as the kind's."""
    rng = np.random.default_rng(seed + 100)
    t = np.arange(ROWS) / RATE_HZ
    e = rng.normal(0.0, 1.0, (ROWS, 4))
    for f, a in lines:
        e += a * np.sin(2 * np.pi * f * t[:, None] + rng.uniform(0, 6.3, 4))
    if prep.kd.project:
        e = e - e.mean(1, keepdims=True)
    prep.sigma = np.ones(4)
    prep.noise_dof = None
    prep.view_sums = ViewSums()
    return view_spectrum(prep, Whitened(e, np.ones(4)))


@pytest.mark.parametrize("seed,delta", [(7973, 0.3), (7974, 0.45), (7975, 0.1)])
def test_a_strong_off_grid_line_is_one_line_not_its_leakage(seed, delta):
    f0 = (620 + delta) * RATE_HZ / ROWS  # 31.0x Hz, delta bins off the grid
    found = _lines(_prep(seed), seed, [(f0, 10.0)])
    freqs = [fr for x in found for fr in x.where["frequencies_hz"]]
    assert len(found) == 1, freqs
    assert abs(freqs[0] - f0) < RATE_HZ / ROWS


@pytest.mark.parametrize("seed,d_bins", [(7976, 40), (7977, 25)])
def test_a_weak_line_in_the_skirt_of_a_strong_one_is_still_found(seed, d_bins):
    f0 = (620 + 0.3) * RATE_HZ / ROWS
    f1 = f0 + d_bins * RATE_HZ / ROWS
    found = _lines(_prep(seed), seed, [(f0, 10.0), (f1, 0.15)])
    freqs = sorted(fr for x in found for fr in x.where["frequencies_hz"])
    assert len(found) == 2, freqs
    assert abs(freqs[0] - f0) < RATE_HZ / ROWS and abs(freqs[1] - f1) < RATE_HZ / ROWS


def test_the_fitted_line_is_the_sinusoid_with_rows_left_out():
    rng = np.random.default_rng(7978)
    m, w = 4096, 2 * np.pi * 123.37 / 4096
    n = np.sort(rng.choice(m, 3900, replace=False))
    coef = rng.normal(0, 1, (2, 3))
    x = np.outer(np.cos(w * n), coef[0]) + np.outer(np.sin(w * n), coef[1])
    # (golden section on a flat maximum: the frequency to about 1e-7 bins)
    assert np.max(np.abs(fit_line(x, n, m, 123) - x)) < 1e-6
