"""Issue 43: long records diagnosed on block means (``engine/_reduce.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import reduce_test_record, validate_diagnosis

from encdesign import Recording
from encdesign.diagnose import diagnose
from encdesign.diagnose.engine._reduce import plan, reduce_recording
from encdesign.diagnose.engine._settings import FinderSettings

LOW = FinderSettings(reduce_min_rows=1000)
"""The threshold lowered so a small record is reduced."""


def _record(seed: int, n_per_run: int, fs: float, heads: int = 2, vib: float = 0.0) -> Recording:
    """``heads`` heads and ``theta_ref``, 3 runs at 2-3 rev/s sampled at ``fs`` Hz,
    disk errors of orders 1-4, 0.5 urad noise, a ``vib`` rad 31 Hz vibration."""
    amp = {m: 3e-6 / m for m in range(1, 5)}
    phase = {m: float(m) for m in range(1, 5)}
    return reduce_test_record(np.random.default_rng(seed), n_per_run, fs, heads, amp, phase, vib)


def test_short_records_are_untouched():
    rec = _record(0, 2000, 1000.0)
    info = plan(rec, 12, True, FinderSettings())
    assert not info["applied"] and "reduce_min_rows" in info["reason"]


def test_block_is_the_longest_within_the_bound_and_never_crosses_a_run():
    rec = _record(1, 30_000, 20_000.0)
    info = plan(rec, 6, False, LOW)
    assert info["applied"]
    B, dt, f = info["block_rows"], info["dt_s"], info["f_needed_hz"]
    assert dt == pytest.approx(5e-5)
    assert info["shaft_rate_max_rev_s"] == pytest.approx(3.0, rel=1e-3)

    def atten(b: int) -> float:  # the mean of b samples of a sinusoid of f Hz
        k = np.arange(b)
        return 1.0 - abs(np.mean(np.exp(2j * math.pi * f * dt * k)))

    assert atten(B) <= LOW.reduce_attenuation_max < atten(B + 1)
    red = reduce_recording(rec, info)
    n_blocks = 3 * (30_000 // B)
    assert red.n_rows == info["reduced_rows"] == n_blocks
    assert info["rows_left_out"] == 3 * (30_000 % B)
    # each block: the mean of B rows of one run
    h = rec.columns["h1"][30_000 : 30_000 + B].mean()
    assert red.columns["h1"][30_000 // B] == pytest.approx(h, rel=0, abs=1e-12)
    assert np.array_equal(np.unique(red.columns["run"]), [0, 1, 2])
    assert np.all(np.diff(red.columns["run"]) >= 0)
    assert red.encoder.get("signal_periods_per_rev") is None  # orders L, 2L: not testable


def test_a_gap_or_a_reversal_ends_a_block():
    rec = _record(2, 20_000, 20_000.0)
    t = rec.columns["t"].copy()
    t[5_000:20_000] += 0.01  # a gap in run 0
    ref = rec.columns["theta_ref"].copy()
    cols = dict(rec.columns, t=t, theta_ref=ref)
    # a reversal in run 1 at row 30,000: the shaft and the heads turn back
    for c in ("theta_ref", "h0", "h1"):
        v = np.asarray(cols[c], float).copy()
        v[30_000:40_000] = 2 * v[30_000] - v[30_000:40_000]
        cols[c] = v
    rec = Recording("multihead", rec.meta, cols)
    info = plan(rec, 6, False, LOW)
    assert info["applied"]
    reduce_recording(rec, info)
    assert info["stretches"] == 3 + 2


def _within_se(a_terms: dict, b_terms: dict) -> None:
    for name, terms in a_terms.items():
        for p, v in terms.items():
            if not isinstance(v, dict) or v.get("se") is None:
                continue
            a, b = np.asarray(v["value"], float), np.asarray(b_terms[name][p]["value"], float)
            z = np.abs(a - b) / np.asarray(v["se"], float)
            assert np.all(z <= 1.0), (name, p, float(np.max(z)))


@pytest.mark.parametrize("vib", [0.0, 2e-6])
def test_reduced_verdict_and_parameters_agree_with_the_unreduced(vib):
    """Within the bound (blocks of 4 rows) every base parameter and the vibration's agree
    within one standard error (measured: at most 0.39 and 0.05); blocks of 49 rows
    (``reduce_attenuation_max`` = 0.1) move a base parameter by 3.6."""
    rec = _record(3, 12_000, 20_000.0, vib=vib)
    full = diagnose(rec, max_order=6).doc
    red = diagnose(rec, max_order=6, settings=LOW).doc
    validate_diagnosis(red)
    assert not full["reduced"]["applied"] and red["reduced"]["applied"]
    assert red["reduced"]["block_rows"] >= 4
    assert red["verdict"] == full["verdict"] == ("missing_physics" if vib else "consistent")
    assert [e["name"] for e in red["effects"]] == [e["name"] for e in full["effects"]]
    assert any(e["name"] == "interpolation_error" for e in red["not_testable"])
    _within_se(full["base"]["terms"], red["base"]["terms"])
    _within_se(full["base"]["terms_with_effects"], red["base"]["terms_with_effects"])
    for e, f in zip(full["effects"], red["effects"]):
        _within_se({e["name"]: e["params"]}, {f["name"]: f["params"]})


def test_a_parquet_record_is_reduced_row_group_by_row_group(tmp_path):
    """Streamed (row groups of 7,000 rows, stretches carried across them) and in memory
    the blocks are the same; a bad cell is still named by row group and column."""
    from encdesign import write_recording
    from encdesign.diagnose import open_recording
    from encdesign.io._parquet import write_parquet_table

    rec = _record(4, 20_000, 20_000.0)
    path = tmp_path / "long.toml"
    back = write_recording(path, "multihead", rec.columns, encoder=rec.encoder, parquet=True)
    data = path.parent / back.meta["data"]
    with open(data, "wb") as fh:
        write_parquet_table(fh, rec.columns, row_group_rows=7_000)
    red, info = open_recording(path, max_order=6, settings=LOW)
    assert info is not None and info["streamed_row_groups"] == 9
    mem_info = plan(rec, 6, False, LOW)
    mem = reduce_recording(rec, mem_info)
    assert info["block_rows"] == mem_info["block_rows"] >= 2
    assert info["reduced_rows"] == mem.n_rows and info["stretches"] == mem_info["stretches"]
    for c in rec.columns:
        assert np.allclose(red.columns[c], mem.columns[c], rtol=0, atol=1e-12), c
    assert open_recording(path, max_order=6)[1] is None  # short: loaded whole
    bad = dict(rec.columns, h1=rec.columns["h1"].copy())
    bad["h1"][15_000] = np.inf
    with open(data, "wb") as fh:
        write_parquet_table(fh, bad, row_group_rows=7_000)
    with pytest.raises(Exception, match=r"row group 2.*h1"):
        open_recording(path, max_order=6, settings=LOW)


def _split_reduce(cols: dict, sizes: list[int], P: int, B: int, flags) -> tuple[dict, int]:
    """The streamed reduction of ``cols`` in row groups of ``sizes`` rows on ``P``
    processes, each process's share (``_reduce_stream._Share``) run here in turn and their
    edges and reduced rows handed over as the collectives would."""
    from encdesign._distributed import split_range
    from encdesign.diagnose.engine._reduce_stream import _Share

    off = np.concatenate([[0], np.cumsum(sizes)])
    types = {h: v.dtype.type for h, v in cols.items()}
    shares, edges = [], []
    for p in range(P):
        g0, g1 = split_range(len(sizes), P, p)
        sh = _Share(types, B, int(off[g0]), int(off[g1]))
        edges.append(
            sh.run(
                lambda g: {h: v[off[g] : off[g + 1]] for h, v in cols.items()},
                range(g0, g1),
                off,
                flags,
            )
        )
        shares.append(sh)
    for p, sh in enumerate(shares):
        sh.finish(edges[:p], flags)
    out = {h: np.concatenate([sh.take(h) for sh in shares]) for h in cols}
    return out, sum(sh.n_starts for sh in shares)


def test_a_split_record_is_reduced_to_the_same_blocks_bit_for_bit():
    """Row groups of any size (some shorter than a block; fewer groups than processes) split
    over 1-5 processes give the blocks of the whole record, bit for bit: a run change, a
    gap, a reversal and a jump over half a turn sit at and next to the groups' and the
    processes' boundaries."""
    from encdesign.diagnose.engine._reduce import block_means, full_blocks, stretch_starts

    rng = np.random.default_rng(4700)
    rec = _record(4701, 3_000, 20_000.0)
    cols = {h: np.asarray(v).copy() for h, v in rec.columns.items()}
    n, dt = rec.n_rows, 5e-5
    cols["t"][4_000:6_000] += 0.01  # a gap in run 1 (rows 3,000-5,999)
    for c in ("theta_ref", "h0", "h1"):  # two reversals in run 1
        for at in (3_500, 4_600):
            cols[c][at:] = 2 * cols[c][at] - cols[c][at:]
    cols["h1"][7_000:] += 4.0  # a jump of a reading over half a turn in run 2
    flags = lambda c: stretch_starts(c, ["h0", "h1", "theta_ref"], c["theta_ref"], dt)  # noqa: E731
    for B in (3, 7):
        st = flags(cols)
        full = full_blocks(st[: n // B * B], B)
        ref = {h: block_means(v[: n // B * B], B, full, h == "run") for h, v in cols.items()}
        assert int(st.sum()) == 3 + 1 + 2 + 1
        splits = []
        for trial in range(4):
            cuts = np.sort(rng.choice(np.arange(1, n), size=12 + trial, replace=False))
            near = np.flatnonzero(st)[1:, None] + np.arange(-2, 2)[None, :]  # around each
            cuts = np.unique(np.concatenate([cuts, near[trial::4].ravel()]))
            splits.append(np.diff(np.concatenate([[0], cuts, [n]])).tolist())
        splits += [[n], [1, 2, n - 3]]  # more processes than row groups: some have none
        for trial, sizes in enumerate(splits):
            for P in (1, 2, 3, 5):
                got, starts = _split_reduce(cols, sizes, P, B, flags)
                assert starts == int(st.sum()), (B, trial, P)
                for h in cols:
                    assert got[h].dtype == ref[h].dtype
                    assert np.array_equal(got[h], ref[h]), (B, trial, P, h)
