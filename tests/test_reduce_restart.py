"""Issue 43 (session 27): the block planned for the base's declared order, and the restart
when the base grows past what it keeps (``engine/_reduce_restart.py``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import reduce_test_record, validate_diagnosis

from encdesign import Recording
from encdesign.diagnose import diagnose
from encdesign.diagnose.engine._reduce import (
    attenuation,
    plan,
    plan_for,
    reduce_recording,
    scan_orders_reached,
)
from encdesign.diagnose.engine._settings import DEFAULT_SETTINGS, FinderSettings

LOW = FinderSettings(reduce_min_rows=1000, reduce_line_hz=20.0)
"""A small record reduced, its block set by the orders (a band of lines below them)."""


def _record(seed: int, n_per_run: int, fs: float, top: int, heads: int = 2) -> Recording:
    """``heads`` heads and ``theta_ref``, 3 runs at 2-3 rev/s sampled at ``fs`` Hz, a disk
    error of orders 1-4 (3 / m urad) and 13-``top`` (1.5 urad each; none for ``top`` < 13),
    0.5 urad noise."""
    rng = np.random.default_rng(seed)
    orders = [*range(1, 5), *range(13, top + 1)]
    amp = {m: 3e-6 / m if m < 5 else 1.5e-6 for m in orders}
    phase = {m: rng.uniform(0, 6) for m in orders}
    return reduce_test_record(rng, n_per_run, fs, heads, amp, phase)


@pytest.mark.parametrize(("dt", "rate"), [(2e-5, 1.8), (5e-5, 2.0), (1e-5, 0.7), (2e-5, 0.1)])
def test_the_block_keeps_the_declared_orders_scan_and_says_which_orders_it_keeps(dt, rate):
    """Planned for the declared order the block keeps the views' scan of twice it and the
    band of lines, and ``orders_kept`` is exactly the highest order within the bound; the
    block for every growth (the plan before session 27) is never longer."""
    s, tol = DEFAULT_SETTINGS, DEFAULT_SETTINGS.reduce_attenuation_max
    mine = plan_for("multihead", 10**7, 12, True, s, lambda: (dt, rate))
    every = plan_for("multihead", 10**7, 12, True, s, lambda: (dt, rate), grown=True)
    assert mine["orders_needed"] == scan_orders_reached(12, False, s) == 24
    assert every["orders_needed"] == scan_orders_reached(12, True, s) == 96
    assert not mine["planned_for_growth"] and every["planned_for_growth"]
    for p in (mine, every):
        B, kept = p["block_rows"], p["orders_kept"]
        assert attenuation(max(p["orders_needed"] * rate, s.reduce_line_hz), dt, B) <= tol
        assert kept >= p["orders_needed"]
        assert attenuation(kept * rate, dt, B) <= tol < attenuation((kept + 1) * rate, dt, B)
        # the longest such block, within the block's share of the bound (half where stage 2,
        # the FIR and decimation of _decimate, follows)
        assert p["block_attenuation_max"] in (tol, 0.5 * tol)
        assert attenuation(p["f_needed_hz"], dt, B) <= p["block_attenuation_max"]
        assert p["block_attenuation_max"] < attenuation(p["f_needed_hz"], dt, B + 1)
    assert mine["block_rows"] >= every["block_rows"]
    fixed = plan_for("multihead", 10**7, 30, False, s, lambda: (dt, rate), grown=True)
    assert fixed["orders_needed"] == 60 and not fixed["planned_for_growth"]  # a user's order


def _same(a: dict, b: dict) -> None:
    """The two diagnoses are the same, number for number (but their times and settings)."""
    assert a["verdict"] == b["verdict"]
    assert [e["name"] for e in a["effects"]] == [e["name"] for e in b["effects"]]
    for key in ("base", "effects", "rms_final", "heldout_rms_final", "noise", "findings_before"):
        assert json.dumps(a[key], sort_keys=True) == json.dumps(b[key], sort_keys=True), key


def test_a_base_grown_past_the_block_restarts_on_the_block_for_every_growth():
    """Orders 13-18 grow the base past order 12; the block planned for order 12 (17 rows at
    50 kHz, 2-3 rev/s) keeps orders up to 24, which the grown base's views would scan past:
    the diagnosis restarts on the block for every growth (4 rows), and is that block's
    diagnosis number for number; a base that does not grow keeps the long block."""
    rec = _record(7970, 30_000, 50_000.0, 18)
    got = diagnose(rec, settings=LOW).doc
    validate_diagnosis(got)
    red = got["reduced"]
    assert red["applied"] and red["planned_for_growth"]
    restart = red["restart"]
    assert restart["block_rows"] > red["block_rows"] >= 2
    assert restart["views_scan_to"] > restart["orders_kept"]
    assert restart["grown_to_order"] > 12 and got["base"]["max_order"] > 12
    assert 2 * got["base"]["max_order"] <= red["orders_kept"]  # every order scanned kept
    assert any("diagnosed again" in n for n in got["notes"])
    info = plan(rec, 12, True, LOW, grown=True)
    want = diagnose(reduce_recording(rec, info), settings=LOW, reduced=info).doc
    assert want["reduced"]["block_rows"] == red["block_rows"]
    _same(got, want)
    plain = diagnose(_record(7970, 30_000, 50_000.0, 0), settings=LOW).doc
    assert plain["reduced"]["applied"] and "restart" not in plain["reduced"]
    assert plain["reduced"]["block_rows"] == restart["block_rows"]
    assert plain["base"]["max_order"] == 12 and plain["verdict"] == "consistent"


def test_a_record_reduced_as_it_was_read_is_read_again_for_the_restart(tmp_path):
    """A Parquet record reduced row group by row group restarts from its file: the same
    diagnosis as the record in memory; one given reduced without its file is refused."""
    from encdesign import write_recording
    from encdesign.diagnose import open_recording

    rec = _record(7971, 30_000, 50_000.0, 18)
    path = tmp_path / "long.toml"
    write_recording(path, "multihead", rec.columns, encoder=rec.encoder, parquet=True)
    red, info = open_recording(path, settings=LOW)
    assert info is not None and not info["planned_for_growth"]
    short = dict(info)
    got = diagnose(red, settings=LOW, reduced=info).doc
    assert "_source" not in got["reduced"] and got["reduced"]["restart"]["block_rows"] > 4
    _same(got, diagnose(rec, settings=LOW).doc)
    short.pop("_source")
    with pytest.raises(Exception, match="without its file"):
        diagnose(red, settings=LOW, reduced=short)
