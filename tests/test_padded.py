"""Whole-record evaluation in bucketed lengths (``engine/_padded``): a second diagnosis of a
record of another length compiles (almost) no XLA program of its own."""

import dataclasses

import numpy as np
from jax._src import compiler
from jax._src.interpreters import pxla
from test_staircase_rival import _record

from encdesign.diagnose import diagnose
from encdesign.diagnose.engine._padded import eval_rows


def test_eval_rows_matches_a_whole_evaluation():
    import jax
    import jax.numpy as jnp

    fn = jax.jit(lambda p, x: {"v": jnp.sin(p * x["t"])[:, None] * x["c"], "s": x["t"] ** 2})
    x = {"t": np.linspace(0.0, 3.0, 9000)}
    c = np.array([1.0, 2.0])
    got = eval_rows(fn, 1.5, x, {"c": c})
    assert got["v"].shape == (9000, 2) and got["s"].shape == (9000,)
    np.testing.assert_allclose(got["v"], np.sin(1.5 * x["t"])[:, None] * c, rtol=1e-14)


def test_a_second_record_length_compiles_few_programs(monkeypatch):
    """The sensor kind's quantization and interpolation terms: main compiled 35 XLA programs
    (one per eager operation on the whole record) for a record 0.83 times as long as one
    already diagnosed; bucketed, it makes one or two (the fitter's, whose chunks are
    bucketed too)."""
    rec, _ = _record(7587, "real")
    d0 = diagnose(rec).doc
    calls = []
    orig = compiler.compile_or_get_cached

    def counted(*a, **k):
        calls.append(1)
        return orig(*a, **k)

    monkeypatch.setattr(compiler, "compile_or_get_cached", counted)
    monkeypatch.setattr(pxla.compiler, "compile_or_get_cached", counted)
    m = int(rec.n_rows * 0.83)
    short = dataclasses.replace(rec, columns={k: v[:m] for k, v in rec.columns.items()})
    d1 = diagnose(short).doc
    assert [e["name"] for e in d1["effects"]] == [e["name"] for e in d0["effects"]]
    assert len(calls) <= 8, len(calls)
