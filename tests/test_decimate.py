"""Issue 43 (session 32): stage 2 of a long record's reduction, the FIR low-pass and
decimation of the block means (``engine/_decimate.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from encdesign import Recording
from encdesign.diagnose.engine._decimate import MIN_ROWS_OUT, decimate_recording, design
from encdesign.diagnose.engine._reduce import attenuation
from encdesign.diagnose.engine._settings import FinderSettings

ON = FinderSettings()
"""Stage 2 on (the default)."""


def _stage1(cols: dict, B: int, dt: float, f_need: float) -> tuple[Recording, dict]:
    """A record of block means (``cols``) and its stage-1 ``reduced`` entry."""
    enc = {"head_angles_deg": [0.0, 120.0]}
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    info = {
        "applied": True,
        "block_rows": B,
        "dt_s": dt,
        "attenuation_max": 1e-3,
        "f_needed_hz": f_need,
        "shaft_rate_max_rev_s": 1.0,
        "orders_needed": 24,
        "reduced_rows": len(cols["t"]),
    }
    return Recording("multihead", meta, cols), info


def _columns(n: int, step: float, rng, sine_hz: float = 0.0, amp: float = 0.0) -> dict:
    t = np.arange(n) * step
    th = 2 * math.pi * 1.0 * t  # 1 rev/s, unwrapped
    return {
        "t": t,
        "run": np.zeros(n, np.int64),
        "theta_ref": th.copy(),
        "h0": th + rng.normal(0, 1e-6, n) + amp * np.sin(2 * math.pi * sine_hz * t),
        "h1": th + rng.normal(0, 1e-6, n),
    }


def test_the_design_keeps_the_bound_and_is_power_complementary():
    dt, B, f_need = 2e-5, 8, 100.0
    fs = 1 / (B * dt)
    got = design(fs, dt, B, f_need, 20, 1e-3)
    taps = got["taps"]
    assert taps.size % 2 == 1 and np.allclose(taps, taps[::-1], rtol=0, atol=0)
    assert abs(taps.sum() - 1.0) < 1e-12
    assert got["combined_deviation"] <= 1e-3 and got["power_complementary_error"] <= 0.01
    assert got["rate_out_hz"] == fs / 20 and got["stopband_hz"] == fs / 20 - f_need
    # the block and the filter together, exactly at f_needed: within the bound
    H = abs(np.sum(taps * np.exp(-2j * math.pi * f_need / fs * np.arange(taps.size))))
    assert abs((1 - attenuation(f_need, dt, B)) * H - 1) <= 1e-3


def test_white_noise_stays_white_and_a_sinusoid_at_f_needed_keeps_its_amplitude():
    rng = np.random.default_rng(8020)
    dt, B, f_need = 2e-5, 8, 100.0
    step = B * dt
    n = 900_000  # 144 s of block means
    cols = _columns(n, step, rng, f_need, 1e-5)
    rec, info = _stage1(cols, B, dt, f_need)
    out = decimate_recording(rec, info, ON)
    dec = info["decimation"]
    assert dec["applied"] and dec["factor"] == 20 and out.n_rows == info["reduced_rows"]
    assert out.n_rows >= MIN_ROWS_OUT and dec["rows_left_out"] == n - out.n_rows * 20
    assert any(e["name"] == "lines_above_band" for e in info["not_testable"])
    assert info["orders_kept"] >= 24 and info["orders_kept"] * 1.0 <= dec["stopband_hz"]
    # t: the centre row's, exact; the angle: a linear trend passes unchanged
    assert np.all(np.isin(out.columns["t"], cols["t"]))
    assert np.allclose(out.columns["theta_ref"], 2 * math.pi * out.columns["t"], rtol=0, atol=1e-9)
    # h1: white noise of 1e-6 rad plus the shaft: the residual's periodogram is flat
    r = out.columns["h1"] - out.columns["theta_ref"]
    assert np.std(r) * math.sqrt(20) == pytest.approx(1e-6, rel=0.03)
    seg = r[: (r.size // 1024) * 1024].reshape(-1, 1024)
    P = np.mean(np.abs(np.fft.rfft(seg * np.hanning(1024), axis=1)) ** 2, 0)[1:-1]
    third = P.size // 3
    lo, hi = P[:third].mean(), P[-third:].mean()
    assert abs(hi / lo - 1) < 0.05, hi / lo
    # h0: a sinusoid of 1e-5 rad at f_needed keeps its amplitude within the bound
    s = out.columns["h0"] - out.columns["theta_ref"]
    t = out.columns["t"]
    X = np.column_stack([np.sin(2 * math.pi * f_need * t), np.cos(2 * math.pi * f_need * t)])
    a = np.hypot(*np.linalg.lstsq(X, s, rcond=None)[0])
    assert abs(a / 1e-5 - 1) <= 1e-3 + 5e-4  # the bound, and the fit's noise (3e-5)


def test_only_windows_within_one_stretch_on_a_fixed_grid_and_short_records_are_left():
    rng = np.random.default_rng(8021)
    dt, B, f_need = 2e-5, 8, 100.0
    n = 300_000
    cols = _columns(n, B * dt, rng)
    cols["run"][150_000:] = 1
    rec, info = _stage1(cols, B, dt, f_need)
    out = decimate_recording(rec, info, ON)
    dec = info["decimation"]
    assert dec["applied"] and dec["stretches"] == 2
    h = (dec["n_taps"] - 1) // 2
    rows = np.flatnonzero(np.isin(cols["t"], out.columns["t"]))
    assert np.all((rows - h) % dec["factor"] == 0)  # the grid h + k R
    assert not np.any((rows - h < 150_000) & (rows + h >= 150_000))  # no window crosses
    assert np.array_equal(out.columns["run"], cols["run"][rows])
    # too short a record for MIN_ROWS_OUT outputs, and stage 2 off: left as they are
    short, sinfo = _stage1({c: v[:20_000] for c, v in cols.items()}, B, dt, f_need)
    assert decimate_recording(short, sinfo, ON) is short
    assert (
        not sinfo["decimation"]["applied"]
        and "rows would be left" in (sinfo["decimation"]["reason"])
    )
    off = {k: v for k, v in info.items() if k != "decimation"}
    assert decimate_recording(rec, off, FinderSettings(reduce_decimation_max=1)) is rec
    assert "off" in off["decimation"]["reason"]


def test_a_block_too_short_for_half_the_bound_keeps_the_whole_bound():
    """Where the block for half the bound would be a single row, stage 2 cannot follow a
    reduction that is not made: the block takes the whole bound, as without stage 2."""
    from encdesign.diagnose.engine._reduce import plan_for

    s = FinderSettings()
    got = plan_for("multihead", 10**7, 12, False, s, lambda: (2e-5, 26.5))  # 636 Hz
    assert got["applied"] and got["block_rows"] >= 2
    assert got["block_attenuation_max"] == s.reduce_attenuation_max
    off = plan_for(
        "multihead", 10**7, 12, False, FinderSettings(reduce_decimation_max=1), lambda: (2e-5, 26.5)
    )
    assert off["block_rows"] == got["block_rows"]
    on = plan_for("multihead", 10**7, 12, False, s, lambda: (2e-5, 1.8))  # the benchmark's
    assert on["block_attenuation_max"] == 0.5 * s.reduce_attenuation_max


def test_the_noise_of_a_decimated_record_is_taken_above_its_passband():
    """At 3 rows per cycle of the passband's edge second differences see the structure
    below it; the Hann periodogram above the passband sees the noise alone."""
    from encdesign.diagnose.engine._noise import noise_band, noise_sigma

    rng = np.random.default_rng(8021)
    fs, f_pass, n = 300.0, 100.0, 20_000
    t = np.arange(n) / fs
    r = 1e-6 * rng.standard_normal((n, 2))
    r[:, 0] += 3e-5 * np.sin(2 * math.pi * 31.0 * t)  # a line 30x the noise
    r[:, 1] += 3e-5 * np.sin(2 * math.pi * 2.0 * t)  # an order
    seg = np.zeros(n, np.int64)
    seg[n // 2 :] = 1
    sigma, robust = noise_band(r, seg, f_pass, fs)
    assert np.allclose(sigma, 1e-6, rtol=0.03) and np.allclose(robust, 1e-6, rtol=0.05)
    assert noise_sigma(r, seg)[0] > 3e-6  # second differences: the line's
    assert noise_band(r[:40], seg[:40], f_pass, fs) is None  # no segment long enough


def test_split_over_processes_the_shares_are_whole_chunks_and_bit_equal_to_one(monkeypatch):
    """Issue 43: on N processes each filters its chunk_share of the outputs and the shares
    are gathered. Two processes simulated in one: each share computed in turn (the gather
    records it), concatenated, must be the one-process columns bit for bit."""
    import types

    from encdesign.diagnose.engine import _decimate as d

    rng = np.random.default_rng(8023)
    dt, B, f_need = 2e-5, 8, 100.0
    rec, info = _stage1(_columns(400_000, B * dt, rng, sine_hz=30.0, amp=1e-4), B, dt, f_need)
    one = decimate_recording(rec, dict(info), ON)
    n_out = one.n_rows
    assert n_out > 2 * d.OUT_CHUNK and n_out % d.OUT_CHUNK  # 3+ chunks, the last short
    shares, got = [], {}

    def gather(mine, counts):
        got.setdefault("parts", []).append(mine)
        got["counts"] = counts
        return np.zeros((sum(counts), mine.shape[1]))

    monkeypatch.setattr(d, "allgather_concat", gather)
    for p in range(2):
        shares.append(d.chunk_share(n_out, 2, p))
        fake = types.SimpleNamespace(process_count=lambda: 2, process_index=lambda p=p: p)
        monkeypatch.setattr(d, "jax", fake)
        decimate_recording(rec, dict(info), ON)
    assert shares[0] == (0, shares[1][0]) and shares[1][1] == n_out
    assert shares[1][0] % d.OUT_CHUNK == 0 and 0 < shares[1][0] < n_out
    assert got["counts"] == [b - a for a, b in shares]
    both = np.concatenate(got["parts"])
    fir = [k for k in rec.columns if k not in ("t", "run")]
    for j, k in enumerate(fir):
        assert np.array_equal(both[:, j], one.columns[k])  # bit for bit
