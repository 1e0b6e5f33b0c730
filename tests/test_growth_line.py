"""The base's order growth beside a signal-period line (engine ``_growth_line``, issue 44).

Sparse multihead records without a reference (three runs of 133 rows forward and back,
about 4 samples per turn): a base kept at order 12 below a disk's orders 13-18 leaks into
the ``line_phase`` view, a few percent of what the views located. The orders the growth
would add are fitted jointly with the line's columns; the line is not significant beside
them, so the base grows and the record is ``consistent`` (on main the line vetoed the
growth: the orders were reported unexplained, or an ``interpolation_error`` was named). A
real ``interpolation_error`` line stays significant beside those orders: the veto holds and
the effect is named."""

from __future__ import annotations

import numpy as np
import pytest

from encdesign import Recording
from encdesign.diagnose._dispatch import diagnose
from tests.helpers import sweep

NOISE = 2.3e-7
"""The heads' white noise (rad)."""


def _sparse_record(seed: int, M: int | None = None, interp: float = 0.0) -> Recording:
    """A multihead record without ``theta_ref``: 3-5 heads, 3 runs of 133 evenly spaced rows
    at 150-400 Hz, each forward then back over 20-60 turns (speed 1, 1.3, 1.6 times), disk
    error orders 1..M (M 13-18 drawn unless given) of 10-300x the noise falling as
    1/m^0.5..1/m^1.5, per-run head zeros, a 4096-line grating; ``interp``: an
    interpolation error ``interp * NOISE * sin(L reading + phase)`` on every head (rad)."""
    rng = np.random.default_rng(seed)
    H = int(rng.integers(3, 6))
    R, nr, L = 3, 133, 4096
    turns = float(rng.uniform(20, 60))
    rate = float(rng.uniform(150, 400))
    if M is None:
        M = int(rng.integers(13, 19))
    ts, ths, runs = [], [], []
    for r in range(R):
        t = np.arange(nr) / rate
        sp = turns * 2 * np.pi / t[-1] * (1 + 0.3 * r)
        h = nr // 2
        th = np.where(np.arange(nr) < h, sp * t, sp * t[h] - sp * (t - t[h]))
        ths.append(th + rng.uniform(0, 6.3))
        ts.append(t + r * (t[-1] + 5))
        runs.append(np.full(nr, r))
    t, th, run = np.concatenate(ts), np.concatenate(ths), np.concatenate(runs)
    alpha = np.concatenate([[0.0], np.sort(rng.uniform(0.2, 6.1, H - 1))])
    err = np.zeros((t.size, H))
    amp0 = NOISE * 10 ** rng.uniform(1.0, 2.5)
    for m in range(1, M + 1):
        a = amp0 / m ** rng.uniform(0.5, 1.5)
        ph = rng.uniform(0, 6.3)
        for k in range(H):
            err[:, k] += a * np.sin(m * (th - alpha[k]) + ph)
    y = th[:, None] + err + rng.normal(0, NOISE, err.shape)
    for r in range(R):
        y[run == r] += rng.integers(-3, 4, H) * 2 * np.pi + rng.uniform(-3, 3, H)
    if interp:
        y = y + interp * NOISE * np.sin(L * y + rng.uniform(0, 6.3))
    cols = {"t": t, "run": run, **{f"h{k}": y[:, k] for k in range(H)}}
    enc = {
        "head_angles_deg": [float(np.degrees(a)) for a in alpha],
        "optical_radius_m": 0.05,
        "grating_lines": L,
    }
    meta = {"format": "encdesign-recording/1", "kind": "multihead", "encoder": enc}
    return Recording("multihead", meta, cols)


@pytest.mark.parametrize("seed", [7723, 7726])
def test_leaked_line_no_longer_keeps_the_base_below_the_disk_orders(seed):
    # (training seeds 7720-7729: on main 7723 (orders 1-14) `unexplained` at orders 13-14,
    # 7726 (orders 1-18) a false `interpolation_error`; 7720 and 7729 (orders 1-13): see
    # the test below)
    d = diagnose(_sparse_record(seed)).doc
    assert d["verdict"] == "consistent", d["report"]
    g = d["base"]["growth_line"]
    assert g["grows"] and not g["line_significant"], g
    assert d["base"]["max_order"] >= 14, d["base"]["max_order"]


# ``make test`` runs the control on 7721; 7723, another draw of the same configuration (disk
# orders 1-10, the line at 20x the noise), is the ``sweep`` tier (session 33, CI time)
@pytest.mark.parametrize("seed", sweep([7721, 7723], (7721,)))
def test_a_real_interpolation_line_still_vetoes_the_growth(seed):
    # (disk orders 1-10, an interpolation error at 20x the noise: the line stays
    # significant beside the orders 13-24 it aliases onto; named, the base stays at 12)
    d = diagnose(_sparse_record(seed, M=10, interp=20.0)).doc
    assert [e["name"] for e in d["effects"]] == ["interpolation_error"], d["report"]
    g = d["base"].get("growth_line")  # (main has no joint test: the line alone vetoed)
    assert g is None or (g["line_significant"] and not g["grows"]), g
    assert d["base"]["max_order"] == 12, d["base"]["max_order"]


@pytest.mark.parametrize("seed,M", [(7720, None), (7729, None), (7777, 13), (7777, 15)])
def test_grown_base_restarts_its_run_zeros_from_the_kind_start(seed, M):
    # (engine ``_growth_start``, session 23: orders 13-15 missing from a base of order 12 alias
    # onto a low order's phase in one run and not in another, so a run's angle zero starts,
    # and the fit stays, up to 2.2 rad off; the growth continued from there leaves 60 % of
    # what the views located and is undone: on main 7720 / 7729 `unexplained`, 7777 a false
    # `vibration`, the base 3.5-6.6x the noise. The grown base is now fitted from the kind's
    # own start at the grown order too, the lower chi-square kept. Training seeds
    # 7764-7779 at M = 13 and 15: main 15/16 and 15/16 consistent, 16/16 here)
    d = diagnose(_sparse_record(seed, M=M)).doc
    assert d["verdict"] == "consistent", d["report"]
    assert d["base"]["max_order"] >= (M or 13), d["base"]["max_order"]
    assert d["base"].get("grown_from_start"), d["base"].get("grown_orders")
    assert d["goodness_of_fit_base"]["variance_ratio"] < 1.5, d["goodness_of_fit_base"]


def test_the_line_is_tested_beside_the_base_own_orders_too():
    """Training ``finder_variations.py --set high --seed 6713`` record 5 (session 37: 4 heads
    with a reference, 400 rows in 2 runs at 44 Hz over 34 turns, about 6 samples per turn,
    disk orders 1-17, clean). The missing orders alias onto the base's own (1-12), whose
    fitted coefficients hold part of them; beside the added orders 13-24 alone the line kept
    a chi-square of 59.5 (threshold 21.5), the growth was vetoed and a false ``vibration``
    named (main f1eba4d). Beside the base's own orders too it keeps 0.7: the base grows and
    the record is ``consistent``."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from finder_variations import clean_record

    rec, desc = clean_record(np.random.default_rng([6713, 5]), 13, 21)
    d = diagnose(rec).doc
    assert d["verdict"] == "consistent", d["report"]
    g = d["base"]["growth_line"]
    assert g["grows"] and not g["line_significant"], g
    assert g["held_orders"] == list(range(1, 13)), g
    assert d["base"]["max_order"] >= desc["M"] == 17, d["base"]["max_order"]
