"""A change of the disk's order 1 on part of a turn located where the data put it (issue 44 C,
session 22): in the pause between two runs, at the start of a run, or inside one, on the
recording's own ``t`` with an interval that holds the truth (``order_step`` view with the
base's disk orders projected out, ``kinds/multihead/_order_step_bins.order_step_orders``).

Seeds 7620-7639 are this work's training seeds (``benchmarks/SEEDS.md``)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import WHERE, shift_arcs_record, sweep

from encdesign import Recording
from encdesign.diagnose._dispatch import diagnose
from encdesign.diagnose.engine._located import in_interval, value_in_interval


def shift_record(seed: int) -> tuple[Recording, dict]:
    """``helpers.shift_arcs_record`` of seed ``seed`` (``default_rng([seed, 44, 22])``), the
    change ``WHERE[seed % 3]``."""
    return shift_arcs_record(np.random.default_rng([seed, 44, 22]), WHERE[seed % 3])


SEEDS = list(range(7620, 7640))
"""The training seeds of this work (``benchmarks/SEEDS.md``, session 22)."""

RUN = (7620, 7621, 7622, 7623, 7624, 7625, 7629, 7630, 7636, 7638)
"""The seeds this test runs (CI time, session 30): those main once missed (7620, 7622,
7623, 7629, 7630; 7625, a drop of session 22 since recovered) and one of each change place
and head count the others add (``WHERE`` x 2-4 heads: 7621 run start, 3 heads; 7624 run
start, 4; 7636 run start, 2; 7638 pause, 4), back-and-forth and one-way runs, two and three
runs among them. Left out: 7627 and 7632, where nothing is located (the test asserts
nothing there), and 7626, 7628, 7631, 7633-7635, 7637, 7639, each a place and head count
kept above, located inside their intervals on session 30's main (about 40 s CPU on a cold
cache). The rate over fresh records is ``benchmarks/change_coverage.py``'s.

``make test`` runs three of them (session 31, CI time): ``KEEP``, one of each change place
(7621 run start, 7622 inside a run with two heads, 7623 in the pause); the others are the
``sweep`` tier (``make test-sweeps``)."""

KEEP = (7621, 7622, 7623)


def _first_order_step(doc: dict) -> dict | None:
    """The located time of the strongest ``order_step`` finding of the base residual."""
    for f in doc.get("findings_before") or []:
        if f.get("view") == "order_step" and f.get("located_time"):
            return f["located_time"]
    return None


def _two_heads(seed: int) -> bool:
    return shift_record(seed)[1]["desc"]["H"] == 2


OPEN = pytest.mark.xfail(
    reason="two heads without a reference on part of a turn: open (issue 44 C): the base "
    "fitted before the scan put a later run's angle zero 1.1-3.1 rad from the truth (the "
    "step pulls it; benchmarks/run_zero_pull.py); since session 24 the change is profiled "
    "with the zeros chosen jointly with it (_order_step_zeros), which located 7622; 7620's "
    "zero is unidentified (0.32 turn), 7630 still missed; not run: a non-strict xfail "
    "asserts nothing while it fails (session 26, CI time, as 7630's); run it with --runxfail",
    run=False,
)


NOT_RUN = pytest.mark.xfail(
    reason="two heads without a reference on part of a turn, still missed (issue 44 C, "
    "see 7620's mark); not run: a non-strict xfail asserts nothing while it fails, and this "
    "record's diagnosis is the file's slowest (about 20 s on CI); run it with --runxfail",
    run=False,
)


def _marks(seed: int):
    if not (_two_heads(seed) and seed in (7620, 7630)):
        return ()
    return NOT_RUN if seed == 7630 else OPEN


@pytest.mark.parametrize("seed", sweep([pytest.param(s, marks=_marks(s)) for s in RUN], KEEP))
def test_the_order_change_is_located_where_the_data_put_it(seed):
    """The ``order_step`` view's located change, and every named effect's located time,
    hold the truth in their intervals on the recording's own ``t``. Main put the view's
    outside on 7620, 7622, 7623, 7629 and 7630 (7623: a shift in the pause put 0.8 s into
    run 0; 7629: one in the pause put 1.7 s before run 0's end): the base's disk orders
    and run zeros, fitted before the scan, took part of the step. Session 22's main put
    7623's fitted ``shift_time_s`` a row into run 1, its interval in run 1 alone: the
    profile's smooth step spilled a quarter of the shift on the rows beside the change
    (``_steps._sharp``). Two heads without a reference (one difference channel; 7620,
    7622, 7630) were open: a later run's zero pulled by the shift; session 24's profile
    with the zeros chosen jointly (``_order_step_zeros``) locates 7622; 7620 and 7630 are
    still open."""
    rec, truth = shift_record(seed)
    doc = diagnose(rec).doc
    lt = _first_order_step(doc)
    if lt is not None:  # located (detection is not this test's)
        assert lt["clock"] == "the recording's t", lt
        assert in_interval(lt, truth["t_s"], truth["run"]), (truth, lt, doc["verdict"])
    for e in doc["effects"]:
        for k, p in e["params"].items():
            if isinstance(p, dict) and "interval_s" in p and "run" in p:
                at = {**p, "t_s": p["value"]}
                assert in_interval(at, truth["t_s"], truth["run"]), (e["name"], k, truth, p)


def test_a_shift_in_the_pause_between_runs_is_named_alone_and_located_in_the_pause():
    """Training ``short_arcs.py --set effects --seed 6215`` record 1 (3 heads, two runs of
    0.39 turn, the shift at t = 2.21 s in the 2 s pause between them): main named
    ``eccentricity_shift`` and ``beam_tilt_axial`` and put the shift 0.32 s into run 1, its
    value outside its own interval. Now the shift alone, its interval the pause."""
    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from short_arcs import short_record

    rec, _ = short_record(np.random.default_rng([6215, 44, 1]), "eccentricity_shift")
    doc = diagnose(rec).doc
    assert [e["name"] for e in doc["effects"]] == ["eccentricity_shift"], doc["verdict"]
    p = doc["effects"][0]["params"]["shift_time_s"]
    lt = {**p, "t_s": float(p["value"])}
    t, run = np.asarray(rec.columns["t"]), np.asarray(rec.columns["run"])
    end0, start1 = float(t[run == 0][-1]), float(t[run == 1][0])
    assert in_interval(lt, 2.2053, 0), lt  # the truth, in the pause
    assert in_interval(lt, float(p["value"]), int(p["run"])), lt  # the value, in its interval
    assert p["interval_runs"] == [0, 1], p
    assert p["interval_s"][0] >= end0 - 0.01 and p["interval_s"][1] <= start1 + 0.01, p


def test_a_fitted_time_outside_its_own_interval_becomes_the_profile_best():
    """``_located.value_in_interval``: a fitted time inside its interval is kept; one
    outside becomes the profile's best, the fit's kept beside it."""
    lt = {"t_s": 3.0, "run": 1, "interval_s": [1.7, 3.1], "interval_runs": [0, 1]}
    inside = {"value": 2.0, "run": 0, "se": 0.1, "unit": "s"}
    assert value_in_interval(inside, lt) == inside
    out = value_in_interval({"value": 4.05, "run": 1, "se": 0.1, "unit": "s"}, lt)
    assert (out["value"], out["run"], out["fitted_value"], out["fitted_run"]) == (3.0, 1, 4.05, 1)
    assert in_interval(lt, out["value"], out["run"])


def test_a_step_the_base_nearly_spans_is_deflated_not_left_out():
    """``_multihead_terms._step_kept``: the share of a step's norm squared the base columns
    leave, ``1 - rho^2``; a step the base spans to within ``collinear_refuse`` has its
    evidence deflated by ``kept / kept_min`` (what the base leaves of it would be
    amplified), its likelihood ``_step_gain`` kept; one orthogonal to it keeps its own."""
    from encdesign.diagnose.engine._settings import FinderSettings
    from encdesign.diagnose.kinds.multihead._multihead_terms import (
        _step_deflation,
        _step_gain,
        _step_kept,
    )

    rng = np.random.default_rng(0)
    X = rng.normal(size=(400, 2))
    B = np.concatenate([X + 1e-3 * rng.normal(size=X.shape), rng.normal(size=(400, 3))], 1)
    r = X @ [1.0, -2.0] + rng.normal(size=400)
    SG, SXB, BBi, Br = X.T @ X, X.T @ B, np.linalg.inv(B.T @ B), B.T @ r
    kept_min = 1.0 - FinderSettings().collinear_refuse ** 2
    kept = _step_kept(SG, SXB, BBi)
    assert 0.0 < kept < kept_min
    assert np.isclose(_step_deflation(SG, SXB, BBi, kept_min), kept / kept_min)
    Gp = SG - SXB @ BBi @ SXB.T
    g = X.T @ r - SXB @ BBi @ Br
    assert np.isclose(_step_gain(X.T @ r, SG, SXB, BBi, Br), g @ np.linalg.solve(Gp, g))
    B2 = rng.normal(size=(400, 3))
    B2 -= X @ np.linalg.lstsq(X, B2, rcond=None)[0]  # orthogonal to the step
    SXB2, BBi2, Br2 = X.T @ B2, np.linalg.inv(B2.T @ B2), B2.T @ r
    assert np.isclose(_step_kept(SG, SXB2, BBi2), 1.0)
    assert _step_deflation(SG, SXB2, BBi2, kept_min) == 1.0
    g = X.T @ r
    assert np.isclose(_step_gain(g, SG, SXB2, BBi2, Br2), g @ np.linalg.solve(SG, g))


def test_a_clean_record_of_two_short_runs_has_no_false_order_change():
    """Training ``short_arcs.py --set clean --seed 6334`` record 0 (2 heads, no reference,
    two runs of 0.33 turn, disk orders to 13): with the base's own columns projected out
    (c4a0ea7) a false ``order_step`` change 0.18 s into run 1 (log10 p = -8.4) made it
    ``unexplained``: there the base's run zero and disk orders span the step to within
    ``collinear_refuse``. Now its evidence deflated there (``_step_deflation``), and the
    record is ``consistent``."""
    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from short_arcs import short_record

    rec, _ = short_record(np.random.default_rng([6334, 44, 0]), None)
    doc = diagnose(rec).doc
    assert doc["verdict"] == "consistent", (doc["verdict"], doc.get("findings_before"))


@pytest.mark.parametrize("seed", [7622, 7625, 7630])
def test_the_truth_run_zeros_and_step_fit_the_record_to_its_noise(seed):
    """``helpers.shift_arcs_record``'s ``run_zeros_rad`` are the base's run angle zeros of
    the head-mean shaft angle: the head-projected readings less a constant per run and
    head, the disk orders ``1..M`` at those zeros and the shift at its time leave the noise
    (chi-square per degree of freedom near 1), and a zero moved by a radian does not
    (``benchmarks/run_zero_pull.py``, the diagnosis of the two-head misses)."""
    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    from run_zero_pull import base_chi2

    rec, truth = shift_record(seed)
    z = np.asarray(truth["run_zeros_rad"], float)
    d = truth["desc"]
    dof = d["R"] * d["nr"] * (d["H"] - 1) - d["R"] * (d["H"] - 1) - 2 * d["M"] - 2
    chi = base_chi2(rec, truth, z, step=True)
    assert abs(chi / dof - 1) < 5 * np.sqrt(2 / dof), (chi, dof)
    assert base_chi2(rec, truth, z + 1.0, step=True) > dof + 10 * np.sqrt(2 * dof)
