"""The located-change-point coverage benchmark (issue 44 C, ``benchmarks/change_points.py``):
its truth and interval rules, and one quick record end to end (the benchmark itself is not
in the test suite: it runs many diagnoses). Seed 7872 is a training seed
(``benchmarks/SEEDS.md``)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest


def _cp():
    sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
    import change_points

    return change_points


def test_a_change_between_runs_is_covered_only_by_an_interval_that_spans_it():
    """SDS: the change lies between run ``k - 1`` and run ``k``; an interval from the row of
    run ``r0`` to that of run ``r1`` covers it when ``r0 < k <= r1`` (an interval that
    starts at run ``k``'s own row lies after it). A time inside a run: on the record's own
    clock, with runs."""
    cp = _cp()
    lt = {"interval_s": [1.0, 3.0], "interval_runs": [4, 6]}
    assert [cp.covered(lt, {"t_s": None, "run": k}) for k in (3, 4, 5, 6, 7)] == [
        False,
        False,
        True,
        True,
        False,
    ]
    lt = {"interval_s": [2.0, 0.5], "interval_runs": [0, 1]}
    assert cp.covered(lt, {"t_s": 2.5, "run": 0}) and cp.covered(lt, {"t_s": 0.4, "run": 1})
    assert not cp.covered(lt, {"t_s": 1.9, "run": 0}) and not cp.covered(lt, {"t_s": 0.6, "run": 1})


def test_wilson_interval_and_step_chi2():
    """The Wilson 95 % interval of 41 / 50 is 0.69-0.90 (session 23's figure); a step of
    size ``d`` splitting ``a`` and ``b`` rows takes out ``d^2 a b / (a + b)``."""
    cp = _cp()
    lo, hi = cp.wilson(41, 50)
    assert lo == pytest.approx(0.6920, abs=1e-3) and hi == pytest.approx(0.9023, abs=1e-3)
    assert cp.wilson(0, 0) is None and cp.wilson(5, 5)[1] == pytest.approx(1.0)
    after = np.arange(100) >= 25
    assert cp.step_chi2(after, 2.0, 3) == pytest.approx(3 * 4.0 * 25 * 75 / 100)
    assert math.isfinite(cp.step_chi2(np.zeros(5, bool), 1.0))


def test_one_record_end_to_end():
    """A quadrature capture with an amplitude step: located on its own clock, every located
    time scored, the located time's interval holds the truth, the summary counts it."""
    cp = _cp()
    r = cp.run_record(7872, "quad_amp_step", 0)
    assert r["located"], r
    assert all(set(x) >= {"what", "covered", "interval_s", "interval_runs"} for x in r["located"])
    assert any(x["what"].endswith(".time") and x["covered"] for x in r["located"]), r
    s = cp.summarize([r])
    assert s["all"]["records"] == 1 and s["quad_amp_step"]["located_records"] == 1
    assert s["all"]["strongest"]["covered"] >= 1
