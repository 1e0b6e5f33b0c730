"""The fitter's shortcuts against what they replace: the base term's hand-written Jacobian
against ``jax.jacfwd``, and :meth:`Fitter.column_chi2` (one added column by an update of the
held model's normal equations) against a refit per column."""

from __future__ import annotations

import copy
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import encdesign  # noqa: F401  (float64)
from encdesign.diagnose.kinds.multihead._multihead import _base_candidate
from tests.helpers import sweep


def _random_runs(rng: np.random.Generator, n: int, R: int) -> jax.Array:
    """One-hot run membership (``n`` rows by ``R`` runs) drawn at random: the hand
    Jacobians' test records."""
    oh = np.zeros((n, R))
    oh[np.arange(n), rng.integers(0, R, n)] = 1.0
    return jnp.asarray(oh)


@pytest.mark.parametrize("C,R,M", [(4, 4, 12), (1, 3, 4)])
def test_base_hand_jacobian_equals_jacfwd(C, R, M):
    rng = np.random.default_rng(C * 100 + R * 10 + M)
    n = 300
    x = {
        "run_onehot": _random_runs(rng, n, R),
        "theta_raw": jnp.asarray(rng.uniform(0, 40, n)),
        "alpha": jnp.asarray(rng.uniform(0, 6, C)),
    }
    cand = _base_candidate(C, R, M)
    p = {q.name: jnp.asarray(rng.normal(0, 1e-3, q.resolved_shape(C, R))) for q in cand.params}
    assert cand.valjac is not None
    v, J = jax.jit(cand.valjac)(p, x)  # (compiled: op by op, the test took 3x as long)
    Jf = jax.jit(jax.jacfwd(cand.fn))(p, x)
    f = np.asarray(jax.jit(cand.fn)(p, x))
    # issue 43: its value by Horner's rule (Candidate.value) equals fn to the rounding of
    # m phi (fn's own: |m phi| eps per order); the hand-written Jacobian's value is that one
    size = float(jnp.sum(jnp.abs(p["fourier_cos_rad"]) + jnp.abs(p["fourier_sin_rad"])))
    assert cand.value is not None
    fv = np.asarray(jax.jit(cand.value)(p, x))
    dv = np.abs(fv - f)
    assert 0.0 < np.max(dv) <= 40 * M * 4e-16 * size
    np.testing.assert_array_equal(np.asarray(v), fv)
    # its order columns by powers of exp(i phi): to the same rounding of m phi per order
    # (unit columns), the slope's (placements, run offsets) to that times sum m |a_m|
    slope = float(
        jnp.sum(
            jnp.arange(1, M + 1) * (jnp.abs(p["fourier_cos_rad"]) + jnp.abs(p["fourier_sin_rad"]))
        )
    )
    tol = {"fourier_cos_rad": 1.0, "fourier_sin_rad": 1.0, "offset_rad": 0.0}
    assert set(J) == set(Jf)
    for k in Jf:
        assert J[k].shape == Jf[k].shape, k
        atol = 40 * M * 4e-16 * tol.get(k, slope) + 1e-17
        np.testing.assert_allclose(np.asarray(J[k]), np.asarray(Jf[k]), rtol=0, atol=atol)


@functools.lru_cache(maxsize=2)
def _fitted(ref: bool) -> tuple:
    """The 1,500-row 3-head bench prepared and its base fitted, once per module."""
    from encdesign.diagnose.engine._fit import Fitter, make_term
    from encdesign.diagnose.engine._prepare import prepare
    from encdesign.diagnose.engine._steps import frozen
    from encdesign.diagnose.kinds.multihead._multihead import multihead_base, multihead_data
    from tests.test_engine import _bench

    rec = _bench(1500, 3, ref)
    prep = prepare(multihead_data(rec), dict(rec.meta))
    (cand, start), *_ = multihead_base(prep, 4)[0]
    base = Fitter(prep).fit([make_term(cand, prep, start)])
    return prep, cand, tuple(frozen(base.terms))


def _bench_base(ref: bool) -> tuple:
    """``(prep, cand, held)`` of :func:`_fitted`: copies (a test may give ``prep`` other
    observations), the base term's nonlinear parameters held."""
    prep, cand, held = _fitted(ref)
    return copy.copy(prep), cand, [t.copy() for t in held]


@pytest.mark.parametrize("ref", [True, False])
def test_column_chi2_equals_a_refit_per_column(ref):
    """A step scanned over rows (the located-step refinement): the chi-square of held base +
    one step column, for every row, equals the fit of that model; without a reference the
    head mean is projected out of the columns too."""
    from encdesign.diagnose.engine._fit import Fitter
    from encdesign.diagnose.engine._steps import step_term

    prep, _, held = _bench_base(ref)
    fitter = Fitter(prep)
    rows = np.flatnonzero((prep.run == 1) & prep.keep)
    tau = prep.rows.take("tau", rows)
    ch = np.array([0.0, 1.0, 0.0])
    sel = np.zeros(prep.ctx.n_runs)
    sel[1] = 1.0
    idx = np.linspace(2, rows.size - 2, 9).astype(int)
    steps = [step_term(prep, dict(tau_s=float(tau[i]), channels=ch, run_sel=sel)) for i in idx]
    got = fitter.column_chi2(held, steps)
    want = np.array([fitter.fit([*held, s]).chi2 for s in steps])
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert np.ptp(want) > 1e-6 * want.max()  # the rows differ: the test can tell them apart
    assert int(np.argmin(got)) == int(np.argmin(want))


@pytest.mark.parametrize("ref", [True, False])
def test_column_chi2_of_a_term_of_two_sizes_equals_a_refit(ref):
    """A located time's profile with the term's own sizes refitted at each time (issue 44
    C, session 22): an eccentricity shift at held times, its two sizes free, beside the
    held base; :meth:`Fitter.column_chi2` equals the fit of each model."""
    from encdesign.diagnose.engine._fit import Fitter, make_term
    from encdesign.diagnose.kinds.multihead._multihead_terms import ECCENTRICITY_SHIFT

    prep, _, held = _bench_base(ref)
    fitter = Fitter(prep)
    tau = np.asarray(prep.rows["tau"], float)
    times = np.linspace(tau.min(), tau.max(), 9)[1:-1]
    terms = []
    for t in times:
        tm = make_term(ECCENTRICITY_SHIFT, prep, {"shift_time_s": t})
        tm.free["shift_time_s"][...] = False
        terms.append(tm)
    assert all(tm.n_free() == 2 for tm in terms)
    got = fitter.column_chi2(held, terms)
    want = np.array([fitter.fit([*held, tm]).chi2 for tm in terms])
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert np.ptp(want) > 1e-6 * want.max()


def _vibration_record(seed: int):
    """Three heads, two runs of 500 rows at 200 Hz, disk errors of orders 1-4 and a 23 Hz
    vibration at 4x the 0.5 urad noise (a nonlinear candidate: its fit takes several
    passes), per-run zeros and a reference angle."""
    rng = np.random.default_rng(seed)
    alpha = np.array([0.0, 2.2, 4.1])
    n, R = 500, 2
    t = np.tile(np.arange(n) / 200.0, R)
    run = np.repeat(np.arange(R), n)
    th = 2 * np.pi * (1.0 + 0.5 * run) * t + rng.uniform(0, 6, R)[run]
    err = sum(
        4e-6 / m * np.sin(m * (th[:, None] - alpha[None, :]) + rng.uniform(0, 6))
        for m in range(1, 5)
    )
    err = err + 2e-6 * np.sin(2 * np.pi * 23.0 * t[:, None] + rng.uniform(0, 6, (R, 3))[run])
    read = th[:, None] + err + rng.normal(0, 5e-7, (t.size, 3)) + rng.uniform(-3, 3, (R, 3))[run]
    cols = {"t": t, "run": run, "theta_ref": th, **{f"h{k}": read[:, k] for k in range(3)}}
    meta = {
        "format": "encdesign-recording/1",
        "kind": "multihead",
        "encoder": {"head_angles_deg": np.degrees(alpha).tolist()},
    }
    return encdesign.Recording("multihead", meta, cols)


# ``make test`` runs seed 4; 19, another draw of the same vibration record, is the ``sweep``
# tier (session 33, CI time)
@pytest.mark.parametrize("seed", sweep([4, 19], (4,)))
def test_the_caches_change_no_bit_of_a_diagnosis(monkeypatch, seed):
    """Every chunk recomputed (no cache: the static prediction is the one made with the
    Jacobian, column_chi2's residual too) against the default cache: the same document."""
    from encdesign.diagnose import diagnose
    from encdesign.diagnose.engine import _fit, _normal

    def doc(cache_bytes: float) -> dict:
        monkeypatch.setattr(_fit, "CACHE_BYTES", cache_bytes)
        monkeypatch.setattr(_normal, "CACHE_BYTES", cache_bytes)
        d = diagnose(_vibration_record(seed))
        skip = ("time_s", "timings_s", "timings_cpu_s", "report")
        return {k: v for k, v in d.doc.items() if k not in skip}

    cached, uncached = doc(_fit.CACHE_BYTES), doc(0.0)
    assert [e["name"] for e in cached["effects"]] == ["vibration"]
    assert uncached == cached


@pytest.mark.parametrize("ref", [True, False])
def test_accumulated_stats_equal_a_pass_over_the_rows(ref):
    """Issue 43: a static block's statistics at other linear values, from the normal
    equations summed in the last pass (:mod:`engine._normal`), equal those of a pass over
    the rows (a fresh fitter, nothing cached); new observations or held values make a pass."""
    from encdesign.diagnose.engine._fit import Fitter

    prep, cand, held = _bench_base(ref)
    fitter = Fitter(prep)
    fitter.stats(held)  # one pass: sums the normal equations at these values
    rng = np.random.default_rng(7)
    moved = [t.copy() for t in held]
    for q in cand.params:
        m = moved[0].free[q.name]
        moved[0].values[q.name][m] += rng.normal(0, 1e-6, int(m.sum()))
    calls = []
    orig = fitter.chunks
    fitter.chunks = lambda *a: calls.append(a) or orig(*a)  # type: ignore[method-assign]
    got = fitter.stats(moved)
    assert not calls  # no pass over the rows
    want = Fitter(prep).stats(moved)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-9 * np.abs(w).max())
    assert abs(want[2].sum() - fitter.stats(held)[2].sum()) > 1e-3 * want[2].sum()  # it moved
    prep.y = prep.y + 1e-7  # other observations: a pass
    fitter.stats(moved)
    assert calls


def test_block_gram_cache_equals_a_fresh_pass():
    """Issue 43: a static block that starts with one whose Gram matrices are kept (the model
    and a candidate start) sums only the new columns' products, the model's processed
    Jacobian not remade; its statistics, and those of its accumulated normal equations at
    other values, equal a fresh fitter's pass. A longer block's Gram leaves its leading
    block's own."""
    from encdesign.diagnose.engine._fit import Fitter
    from encdesign.diagnose.engine._steps import step_term

    prep, _, held = _bench_base(True)
    tau = prep.rows.take("tau", np.flatnonzero(prep.run == 1))
    sel = np.zeros(prep.ctx.n_runs)
    sel[1] = 1.0
    steps = [
        step_term(prep, dict(tau_s=float(tau[i]), channels=np.ones(3), run_sel=sel))
        for i in (300, 900)
    ]
    fitter = Fitter(prep)
    fitter.stats(held)  # the model's Gram matrices and processed Jacobians kept
    made = []
    orig = fitter._processed
    fitter._processed = lambda ts, *a: made.append(list(ts)) or orig(ts, *a)  # type: ignore
    rng = np.random.default_rng(11)
    for st in steps:
        block = [*held, st]
        assert fitter.blocks.longest_prefix(block) == 1
        got = fitter.stats(block)
        assert made and all(len(ts) == 1 and ts[0] is st for ts in made)  # its columns only
        moved = [t.copy() for t in block]
        moved[-1].values["size"][...] = rng.normal(0, 1e-6)
        moved[0].values["offset_rad"][...] += rng.normal(0, 1e-7)
        made.clear()
        again = fitter.stats(moved)  # the accumulated normal equations: no pass
        assert not made
        for g, w in zip(got, Fitter(prep).stats(block)):
            np.testing.assert_allclose(g, w, rtol=1e-10, atol=1e-12 * np.abs(w).max())
        for g, w in zip(again, Fitter(prep).stats(moved)):  # (as the test above)
            np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-9 * np.abs(w).max())
    fresh = Fitter(prep)
    fresh.stats([*held, steps[0]])  # the whole block's Gram: the model's is its leading square
    want = Fitter(prep)
    want.stats(held)
    got_g, want_g = fresh.gram(held), want.gram(held)
    assert got_g is not None and want_g is not None
    for g, w in zip(got_g, want_g):
        np.testing.assert_allclose(g, w, rtol=1e-12, atol=0)


def test_linear_valjac_equals_the_linear_columns_of_jacfwd():
    """Issue 43: a linear-only term's Jacobian over its linear parameters alone
    (``linear_valjac``, no nonlinear tangents) against the full ``jacfwd``'s linear columns,
    for catalog candidates (:data:`CHECKED`; a hand-written Jacobian where the candidate has
    one), at a probe's nonlinear values (the detection bounds' terms)."""
    from encdesign.diagnose.engine._fit import Fitter
    from encdesign.diagnose.engine._normal import linear_valjac
    from encdesign.diagnose.kinds.multihead._multihead import multihead_candidates

    prep, _, _ = _bench_base(True)
    ctx = prep.ctx
    C, R = prep.n_channels, ctx.n_runs
    rng = np.random.default_rng(5700)
    fitter = Fitter(prep)
    fitter.chunk = 200
    _, _, x = next(fitter.chunks())
    checked = 0
    for cand in multihead_candidates(ctx):
        if cand.name not in CHECKED:
            continue
        probes = cand.probes(ctx) if cand.probes is not None else ()
        for vals in [dict(pr.values) for pr in probes[:1]] or [{}]:
            p = {}
            for q in cand.params:
                shape = q.resolved_shape(C, R)
                v = vals.get(q.name) if not q.linear else None
                v = rng.normal(0, 1e-3, shape) if v is None else np.broadcast_to(v, shape)
                p[q.name] = jnp.asarray(v, dtype=jnp.float64)
            v, J = linear_valjac(cand)(p, x)
            vf, Jf = jax.jit(functools.partial(_full_valjac, cand.fn))(p, x)
            atol = 1e-12 * max(float(np.max(np.abs(vf))), 1e-300)
            np.testing.assert_allclose(np.asarray(v), np.asarray(vf), rtol=0, atol=atol)
            assert set(J) == {q.name for q in cand.params if q.linear}, cand.name
            for k in J:
                ref = np.asarray(Jf[k])
                tol = 1e-12 * max(float(np.max(np.abs(ref))), 1e-300)
                np.testing.assert_allclose(np.asarray(J[k]), ref, rtol=0, atol=tol)
            checked += 1
    assert checked == len(CHECKED)


def _full_valjac(fn, p, x):
    return fn(p, x), jax.jacfwd(fn)(p, x)


CHECKED = ("thermal_drift", "vibration", "interpolation_error")
"""Candidates whose linear-only Jacobian is checked (``interpolation_error``'s written by
hand; a few seconds of compiling: the others are covered by
``test_the_caches_change_no_bit_of_a_diagnosis``)."""


def test_vibration_hand_jacobian_equals_jacfwd():
    """Issue 43: the ``vibration`` term's hand-written value and Jacobian against
    ``jax.jacfwd`` of its ``fn`` (the amplitudes' columns exactly, the frequency's to
    rounding)."""
    from encdesign.diagnose.kinds.multihead._multihead_terms import VIBRATION

    rng = np.random.default_rng(7150)
    n, C, R = 200, 3, 2
    x = {
        "run_onehot": _random_runs(rng, n, R),
        "t": jnp.asarray(np.sort(rng.uniform(0, 20, n))),
        "reading": jnp.zeros((n, C)),
    }
    p = {q.name: jnp.asarray(rng.normal(0, 1e-6, q.resolved_shape(C, R))) for q in VIBRATION.params}
    p["frequency_hz"] = jnp.asarray(31.3)
    assert VIBRATION.valjac is not None
    v, J = jax.jit(VIBRATION.valjac)(p, x)
    Jf = jax.jit(jax.jacfwd(VIBRATION.fn))(p, x)
    np.testing.assert_array_equal(np.asarray(v), np.asarray(jax.jit(VIBRATION.fn)(p, x)))
    assert set(J) == set(Jf)
    for k in Jf:
        assert J[k].shape == Jf[k].shape, k
        scale = float(np.max(np.abs(np.asarray(Jf[k])))) or 1.0
        np.testing.assert_allclose(np.asarray(J[k]), np.asarray(Jf[k]), rtol=0, atol=1e-14 * scale)
    for k in ("cos_rad", "sin_rad"):
        np.testing.assert_array_equal(np.asarray(J[k]), np.asarray(Jf[k]))


@pytest.mark.parametrize("name", ["bearing_wobble", "eccentricity_shift"])
def test_wobble_and_shift_hand_jacobians_equal_jacfwd(name):
    """Issue 43: the hand-written values and Jacobians of ``bearing_wobble`` and
    ``eccentricity_shift`` against ``jax.jacfwd`` of their ``fn`` (values to 1e-15 relative,
    every column to 1e-14 relative: compiled apart, the arguments of the sines fuse
    differently), with the shift inside the record (its column not all zero)."""
    from encdesign.diagnose.kinds.multihead import _multihead_terms as mt

    cand = {"bearing_wobble": mt.BEARING_WOBBLE, "eccentricity_shift": mt.ECCENTRICITY_SHIFT}[name]
    rng = np.random.default_rng(7442)
    n, C, R = 300, 4, 2
    x = {
        "run_onehot": _random_runs(rng, n, R),
        "theta": jnp.asarray(np.sort(rng.uniform(0, 300, n))),
        "tau": jnp.asarray(np.sort(rng.uniform(0, 20, n))),
        "alpha": jnp.asarray([0.0, 1.5, 3.1, 4.7]),
        "radius_m": jnp.asarray(0.03),
        "step_width_s": jnp.asarray(0.05),
        "reading": jnp.zeros((n, C)),
    }
    p = {q.name: jnp.asarray(rng.normal(0, 1e-6, q.resolved_shape(C, R))) for q in cand.params}
    p["frequency_ratio"] = jnp.asarray(0.437)
    p["shift_time_s"] = jnp.asarray(9.99)
    p = {q.name: p[q.name] for q in cand.params}
    assert cand.valjac is not None
    v, J = jax.jit(cand.valjac)(p, x)
    Jf = jax.jit(jax.jacfwd(cand.fn))(p, x)
    want = np.asarray(jax.jit(cand.fn)(p, x))  # (compiled apart: fused to rounding)
    np.testing.assert_allclose(np.asarray(v), want, rtol=0, atol=1e-15 * np.max(np.abs(want)))
    assert set(J) == set(Jf)
    for q in cand.params:
        a, b = np.asarray(J[q.name]), np.asarray(Jf[q.name])
        assert a.shape == b.shape, q.name
        scale = float(np.max(np.abs(b)))
        assert scale > 0, q.name
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-14 * scale)


def test_equivalent_columns_keep_the_same_ones_whatever_the_rounding():
    """A design with a common offset beside per-run offsets (equal runs) and a repeated
    column: which columns the fit keeps follows their order (the first of tied pivots,
    ``_normal.PIVOT_TIE``), however its sums are rounded (other summation orders, 1e-15
    relative noise); LAPACK's pivoting alone kept 5 different sets on these draws."""
    from encdesign.diagnose.engine._normal import solve_determined

    n_per, R = 40, 3
    t = np.arange(R * n_per) * 0.013
    run = np.repeat(np.arange(R), n_per)
    offsets = [(run == r).astype(float) for r in range(R)]
    c, s = np.cos(2.1 * t), np.sin(2.1 * t)
    X = np.column_stack([np.ones(t.size), *offsets, c, s, c])
    g = X.T @ np.random.default_rng(7453).normal(size=t.size)
    kept = set()
    for k in range(40):
        rng = np.random.default_rng([7453, k])
        rows = rng.permutation(t.size)
        A = X[rows].T @ X[rows]
        E = rng.normal(size=A.shape)
        A = A * (1.0 + 1e-15 * (E + E.T) / 2)
        kept.add(tuple(solve_determined(A, g, 0.0)[1].tolist()))
    # the common offset and the first two runs' offsets, the first cos, the sin
    assert kept == {(0, 1, 2, 4, 5)}
