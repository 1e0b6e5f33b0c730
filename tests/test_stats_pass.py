"""Trial fits side by side (issue 43, ``engine/_stats_pass.py``): one pass over the rows
answers a round's requests of several fits, the static block's per-chunk Jacobian computed
once; every fit gets the numbers it gets when the fits run one after another on one
fitter."""

from __future__ import annotations

import numpy as np

import encdesign  # noqa: F401  (float64)
from tests.helpers import count_passes
from tests.test_fit_fast import _bench_base


def _assert_bit_equal(alone, together, n_models: int = 4) -> None:
    """Fits run side by side equal the same fits one after another to the last bit
    (chi-square, held-out chi-square, normal matrix, every term's values), and the
    ``n_models`` fits differ from each other, so the comparison can tell them apart."""
    for a, b in zip(alone, together, strict=True):
        assert a.chi2 == b.chi2 and a.heldout_chi2 == b.heldout_chi2
        np.testing.assert_array_equal(a.A, b.A)
        for ta, tb in zip(a.terms, b.terms):
            for k in ta.values:
                np.testing.assert_array_equal(ta.values[k], tb.values[k])
    assert len({a.chi2 for a in alone}) == n_models


def test_fits_side_by_side_equal_the_fits_one_after_another(monkeypatch):
    """A frozen base with three candidates (a line fitted in frequency from two starts, and
    one at a held frequency: nonlinear and linear fits, rounds of different lengths), no
    cache and chunks of 1024 rows (the shared Jacobians come from the memo, chunk by chunk):
    side by side on one fitter, each fit's values, chi-square, normal matrix and held-out
    chi-square equal the fits one after another on one fitter to the last bit (the later
    fits start from the base's Gram matrices the first one kept), and the memo was read
    (no reference angle: the head mean projected out of every column)."""
    from encdesign.diagnose.engine import _fit, _normal, _stats_pass
    from encdesign.diagnose.engine._fit import Fitter, make_term
    from encdesign.diagnose.engine._steps import frozen
    from encdesign.diagnose.kinds.multihead._multihead_terms import VIBRATION

    monkeypatch.setattr(_fit, "CACHE_BYTES", 0.0)
    monkeypatch.setattr(_normal, "CACHE_BYTES", 0.0)
    prep, _, held = _bench_base(False)
    starts = [{"frequency_hz": 3.7}, {"frequency_hz": 11.2}]
    terms = [make_term(VIBRATION, prep, s) for s in starts]
    terms.append(frozen([make_term(VIBRATION, prep, {"frequency_hz": 5.3})])[0])

    def fitter() -> Fitter:
        f = Fitter(prep)
        f.chunk = 1024  # (the shape test_fit_fast's vibration records compile)
        assert f.n_chunks() > 1
        return f

    f1 = fitter()
    alone = [f1.fit([*held, t], max_steps=6) for t in terms]  # one after another
    hits = []
    get = _stats_pass.ChunkMemo.get

    def counted(self, key):
        got = get(self, key)
        hits.append(got is not None)
        return got

    monkeypatch.setattr(_stats_pass.ChunkMemo, "get", counted)
    f = fitter()
    together = _stats_pass.drive_many([f.fit_steps([*held, t], max_steps=6) for t in terms])
    assert any(hits)
    for a, b in zip(alone, together):
        assert a.chi2 == b.chi2 and a.heldout_chi2 == b.heldout_chi2
        np.testing.assert_array_equal(a.A, b.A)
        for ta, tb in zip(a.terms, b.terms):
            for k in ta.values:
                np.testing.assert_array_equal(ta.values[k], tb.values[k])
    assert alone[0].chi2 != alone[1].chi2  # the fits differ: the test can tell them apart


def test_fits_holding_the_same_free_nonlinear_terms_side_by_side_equal_them_alone(monkeypatch):
    """The located-share rule's four fits (``_spill._kept_fit``: the model, the model with
    the candidate, with a rival, with both; the model's nonlinear parameters free) side by
    side: a round's requests that hold the same free nonlinear terms at the same values read
    their value, processed Jacobian and per-fold Gram products from the memo (the model's at
    its start, once per chunk), two that sum the same static block's Gram matrices (the
    rival's) sum them once, and every fit equals the fits one after another on one fitter
    to the last bit (issue 43, session 23)."""
    from encdesign.diagnose.engine import _fit, _normal, _stats_pass
    from encdesign.diagnose.engine._fit import Fitter, make_term
    from encdesign.diagnose.engine._steps import frozen
    from encdesign.diagnose.kinds.multihead._multihead_terms import VIBRATION

    monkeypatch.setattr(_fit, "CACHE_BYTES", 0.0)
    monkeypatch.setattr(_normal, "CACHE_BYTES", 0.0)
    prep, _, held = _bench_base(False)
    model = [t.copy() for t in held]
    for t in model:  # the base's placements and run zeros free again
        for q in t.cand.params:
            t.free[q.name][...] = bool(q.fit)
    assert any(not q.linear and t.free[q.name].any() for t in model for q in t.cand.params)
    term = make_term(VIBRATION, prep, {"frequency_hz": 3.7})
    other = frozen([make_term(VIBRATION, prep, {"frequency_hz": 5.3})])[0]
    fits = [model, [*model, term], [*model, other], [*model, other, term]]

    def fitter() -> Fitter:
        f = Fitter(prep)
        f.chunk = 1024
        assert f.n_chunks() > 1
        return f

    f1 = fitter()
    alone = [f1.fit(list(ts), max_steps=6) for ts in fits]
    hits: list[str] = []
    get = _stats_pass.ChunkMemo.get

    def counted(self, key):
        got = get(self, key)
        if got is not None:
            hits.append(key[0])
        return got

    monkeypatch.setattr(_stats_pass.ChunkMemo, "get", counted)
    f = fitter()
    together = _stats_pass.drive_many([f.fit_steps(list(ts), max_steps=6) for ts in fits])
    # the free base's Jacobian is factored (issue 43): its dynamic parts and their Gram are
    # shared as features (``parts_dyn``, ``gram_f``) where ``_stats_pass.FEATURE_GRAM`` is on
    dyn = {"parts_dyn", "gram_f"} if _stats_pass.FEATURE_GRAM else {"processed_dyn", "gram_d"}
    assert {"term", "gram_s", *dyn} <= set(hits)
    _assert_bit_equal(alone, together)


def test_a_candidates_screened_starts_side_by_side_equal_them_one_after_another(monkeypatch):
    """A candidate's screened starts (``_starts.screened_starts``: three vibration lines at
    held frequencies on the frozen base, as ``_select._trial_fit`` screens them) beside
    another candidate's full fit (a line with its frequency free), all in the rounds of one
    :func:`drive_many`: every screening fit equals the fits one after another on one fitter
    to the last bit (chi-square, held-out chi-square, normal matrix, values), and the three
    take one pass over the rows together, not one each (issue 43, session 23)."""
    from encdesign.diagnose.engine import _fit, _stats_pass
    from encdesign.diagnose.engine._fit import Fitter, make_term
    from encdesign.diagnose.engine._starts import screened_starts
    from encdesign.diagnose.engine._steps import frozen
    from encdesign.diagnose.kinds.multihead._multihead_terms import VIBRATION

    monkeypatch.setattr(_fit, "CACHE_BYTES", 0.0)
    prep, _, held = _bench_base(False)
    starts = [{"frequency_hz": 3.7}, {"frequency_hz": 11.2}, {"frequency_hz": 5.3}]
    screens = frozen([make_term(VIBRATION, prep, s) for s in starts])
    free = make_term(VIBRATION, prep, {"frequency_hz": 7.9})

    def fitter() -> Fitter:
        f = Fitter(prep)
        f.chunk = 1024
        assert f.n_chunks() > 1
        f.fit(list(held))  # the frozen base's Gram matrices kept, as after the base fit
        return f

    f1 = fitter()
    alone = [f1.fit([*held, t]) for t in screens] + [f1.fit([*held, free], max_steps=6)]
    f = fitter()
    rounds = count_passes(monkeypatch)
    got = _stats_pass.drive_many(
        [screened_starts(f, list(held), screens), f.fit_steps([*held, free], max_steps=6)]
    )
    together = [*got[0], got[1]]
    assert rounds[0] == 4  # the three screens and the free line's first pass, one pass
    _assert_bit_equal(alone, together)


def test_a_fit_beside_the_fit_of_its_leading_block_takes_one_pass(monkeypatch):
    """The step rule's pair (``_steps.beaten_by_step``: the frozen base with a located step,
    and the same with a candidate at its fitted values) side by side in one
    :func:`drive_many`: the second fit's leading block (base and step) is the first fit's
    whole block, whose Gram matrices that fit's pass sums and keeps; one after another the
    second sums only its own columns' products beside them. Side by side it sums those in
    the same pass (:meth:`StatsPass.join`, issue 43, session 28): one pass for both, not two
    (main waited a round), and both fits equal the fits one after another on one fitter to
    the last bit; so do a screen of two more candidates beside the base's own first pass."""
    from encdesign.diagnose.engine import _fit, _stats_pass
    from encdesign.diagnose.engine._fit import Fitter, make_term
    from encdesign.diagnose.engine._steps import frozen, step_term
    from encdesign.diagnose.kinds.multihead._multihead_terms import VIBRATION

    monkeypatch.setattr(_fit, "CACHE_BYTES", 0.0)
    prep, _, held = _bench_base(False)
    rows = np.flatnonzero((prep.run == 1) & prep.keep)
    sel = np.zeros(prep.ctx.n_runs)
    sel[1] = 1.0
    step = dict(
        tau_s=float(prep.rows.take("tau", rows)[rows.size // 3]),
        channels=np.array([0.0, 1.0, 0.0]),
        run_sel=sel,
    )
    lines = frozen([make_term(VIBRATION, prep, {"frequency_hz": f}) for f in (3.7, 5.3)])

    def fitter() -> Fitter:
        f = Fitter(prep)
        f.chunk = 1024
        assert f.n_chunks() > 1
        return f

    pairs = [
        [[*held, step_term(prep, step)], [*held, step_term(prep, step), lines[0]]],
        [list(held), [*held, lines[0]], [*held, lines[1]]],
    ]
    for fits, n_models in zip(pairs, (2, 3)):
        f1 = fitter()
        alone = [f1.fit(list(ts)) for ts in fits]
        rounds: list[int] = []
        run = _stats_pass.run_passes

        def counted(passes, run=run, rounds=rounds):
            rounds.append(sum(s.done is None for s in passes))
            return run(passes)

        monkeypatch.setattr(_stats_pass, "run_passes", counted)
        f = fitter()
        together = _stats_pass.drive_many([f.fit_steps(list(ts)) for ts in fits])
        monkeypatch.setattr(_stats_pass, "run_passes", run)
        assert rounds[0] == n_models  # every fit in the first pass (main: the first alone)
        assert sum(r > 0 for r in rounds) == 1  # linear fits: one pass in all
        _assert_bit_equal(alone, together, n_models)


def test_scaled_columns_keep_the_factored_features_they_multiply_out():
    """One helper makes a chunk's processed columns (``_features.scaled_columns``): the free
    base (factored, issue 43) beside an unfactored vibration line. With ``features``, the
    other columns are those it makes whole to the last bit, and the kept ``Xo Wp`` is the
    factored columns it multiplies out; both equal the fitter's plain Jacobian, sorted,
    projected, whitened and scaled, to rounding. ``eval_term``'s ``compiled`` value is the
    compiled function's even where the term's Jacobian is cached."""
    from encdesign.diagnose.engine._features import Factored, feature_parts, scaled_columns
    from encdesign.diagnose.engine._fit import Fitter, _val_fn, make_term
    from encdesign.diagnose.kinds.multihead._multihead_terms import VIBRATION

    prep, _, held = _bench_base(False)
    model = [t.copy() for t in held]
    for t in model:
        for q in t.cand.params:
            t.free[q.name][...] = bool(q.fit)
    terms = [make_term(VIBRATION, prep, {"frequency_hz": 3.7}), *model]
    f = Fitter(prep)
    a, b, x = next(iter(f.chunks()))
    sc = np.random.default_rng(3).uniform(0.5, 2.0, sum(t.n_free() for t in terms))
    got = [f.eval_term(t, a, b, x, jac=True, whole=False) for t in terms]
    assert [isinstance(J, Factored) for _, J in got] == [False, True]
    order, _ = f._fold_order(a, b)
    pred, whole, *_ = scaled_columns(f, got, order, sc)
    pred_k, out, Xo, Wp, fcols, ocols = scaled_columns(f, got, order, sc, features=True)
    assert fcols.size and ocols.size and sorted([*fcols, *ocols]) == list(range(sc.size))
    np.testing.assert_array_equal(pred_k, pred)
    np.testing.assert_array_equal(out, whole[:, :, ocols])
    XW = np.empty((b - a, prep.n_channels, fcols.size))
    Factored(Xo, Wp).into(XW, Xo)
    np.testing.assert_array_equal(XW, whole[:, :, fcols])
    parts = feature_parts(f, terms, a, b, x, sc)
    assert parts is not None
    np.testing.assert_array_equal(parts[4], out)
    _, J = f.jacobian(terms, a, b, x, order)
    J *= np.sqrt(f.w_ch)[:, None] * sc[None, :]
    np.testing.assert_allclose(whole, J, rtol=1e-9, atol=1e-9 * np.abs(J).max())
    with np.testing.assert_raises(ValueError):  # one factored term kept at most
        scaled_columns(f, [*got, got[1]], order, np.concatenate([sc, sc[1:]]), features=True)

    line = [t.copy() for t in terms[:1]]
    line[0].free["frequency_hz"][...] = False  # linear only: its Jacobian cached
    f.fit(line, max_steps=1)
    assert f._jcache  # (without ``compiled``: ``v0 + J p`` from it)
    v = f.eval_term(line[0], a, b, x, jac=False, compiled=True)[0]
    want = np.asarray(_val_fn(VIBRATION)(dict(line[0].values), x))[: b - a]
    np.testing.assert_array_equal(v, want)
