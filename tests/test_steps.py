"""The step rule of stage 4 (``engine/_steps.py``, issue 43): the first attempt at every
located step in one pass over the rows, each fit equal to the fits one after another."""

from __future__ import annotations

import dataclasses

import numpy as np

import encdesign  # noqa: F401  (float64)
from tests.helpers import count_passes
from tests.test_fit_fast import _bench_base
from tests.test_stats_pass import _assert_bit_equal


def test_every_located_step_is_tried_in_one_pass(monkeypatch):
    """Three located steps (one of them twice) against a fitted candidate (a line at a held
    frequency beside the held base, chunks of 1024 rows, no Jacobian cache): ``beaten_by_step``
    makes one pass over the rows for all (main: one per step), and the fits of its first
    attempt, each step alone and with the candidate, equal those fits side by side per step
    on one fitter, one step after another (main's order) to the last bit."""
    from encdesign.diagnose.engine import _fit, _stats_pass, _steps
    from encdesign.diagnose.engine._fit import Fitter, make_term
    from encdesign.diagnose.engine._steps import beaten_by_step, frozen, step_term
    from encdesign.diagnose.engine._views import Finding
    from encdesign.diagnose.kinds.multihead._multihead_terms import VIBRATION

    monkeypatch.setattr(_fit, "CACHE_BYTES", 0.0)
    prep, _, held = _bench_base(False)
    rows = np.flatnonzero((prep.run == 1) & prep.keep)
    tau = prep.rows.take("tau", rows)
    sel = np.zeros(prep.ctx.n_runs)
    sel[1] = 1.0
    steps = []
    for i, ch in ((rows.size // 4, [0.0, 1.0, 0.0]), (rows.size // 2, [1.0, 0.0, 0.0])):
        f = Finding("time", {"heads": [1], "runs": [1]}, 0.0, 1, 0.0, detail={"step_time_s": 0})
        steps.append(
            dict(tau_s=float(tau[i]), run=1, channels=np.array(ch), run_sel=sel, finding=f)
        )
    steps.append(dict(steps[0]))  # the same step twice
    line = make_term(VIBRATION, prep, {"frequency_hz": 5.3})

    def fitter() -> Fitter:
        f = Fitter(prep)
        f.chunk = 1024
        assert f.n_chunks() > 1
        return f

    def model(f: Fitter) -> tuple:
        current = f.fit(list(held))
        fr = f.fit([*frozen(current.terms), *frozen([line])])
        return frozen(current.terms), frozen(fr.terms[-1:]), current, fr

    f1 = fitter()
    base, cand, _, _ = model(f1)
    alone: list = []
    for st in steps[:2]:  # main's order: a pass per step
        alone += _stats_pass.drive_many(
            [
                f1.fit_steps([*base, step_term(prep, st)]),
                f1.fit_steps([*base, step_term(prep, st), *cand]),
            ]
        )
    f = fitter()
    base, cand, current, fr = model(f)
    passes = count_passes(monkeypatch)
    cache: dict = {}
    first = _steps._first_fits(f, prep, base, cand, steps, cache)
    assert [p for p in passes if p] == [4]  # two steps, each alone and with the candidate
    keys = [_steps._step_key(st) for st in steps[:2]]
    together = [x for k in keys for x in (cache[k], first[k])]
    _assert_bit_equal(alone, together, 4)
    # the rule itself, where the candidate leaves no step (a criterion no step meets):
    # only the first attempt's fits, one pass (main: one per step)
    prep.settings = dataclasses.replace(prep.settings, bic_min=1e300)
    f = fitter()
    _, _, current, fr = model(f)
    del passes[:]
    assert beaten_by_step(f, prep, current, fr, steps, {}) is None
    assert sum(p > 0 for p in passes) == 1
