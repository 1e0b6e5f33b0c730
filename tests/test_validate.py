"""Out-of-sample validation of Monte Carlo optima (issue 27): fresh keys, the paired report,
an in-sample optimum that overfits a few builds, and check-gradients near zero."""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from encdesign import EncdesignInputError
from encdesign.cli import main
from encdesign.design import (
    BFGS,
    check_gradients,
    expected_value,
    fresh_key,
    fresh_seeds,
    monte_carlo,
    optimise,
    paired_comparison,
    parse_problem,
    solve_problem,
)
from encdesign.design._sampling import build_normals

USER_MODULE = '''
import jax.numpy as jnp

import encdesign
from encdesign.design import expected_value


@encdesign.objective_function(
    variables={"a": encdesign.variable("1", lower=-3.0, upper=3.0, start=0.0)},
    outputs=("loss",),
    model={"n_builds": 4},
)
def overfit(x, discrete, model, key):
    """Mean over builds of (a - z)^2, z ~ N(0, 1): the true optimum is a = 0 (the start);
    the optimum over a few builds is their sample mean, which overfits them."""
    return {"loss": expected_value(lambda a, z: (a - z[0]) ** 2, x["a"], key=key,
                                   n=model["n_builds"], dim=1)}


@encdesign.objective_function(
    variables={"a": encdesign.variable("1", lower=-5.0, upper=5.0, start=2.0)},
    outputs=("f",),
)
def flat_at_start(x, discrete, model, key):
    """(a - 2)^2 + 1: both derivatives vanish at the start."""
    return {"f": (x["a"] - 2.0) ** 2 + 1.0}
'''


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    (tmp_path / "val_objectives.py").write_text(USER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    return "val_objectives"


def _value(a, z):
    return (a - z[0]) ** 2


def _train(a, key):
    """The training objective: the mean of :func:`_value` over 4 builds of ``key``."""
    return expected_value(_value, a[0], key=key, n=4, dim=1)


_train_jit = jax.jit(_train)


def test_fresh_keys_are_independent_of_the_training_builds():
    key = jax.random.key(3)
    train = np.asarray(build_normals(key, jnp.arange(256), 2))
    fresh = np.asarray(build_normals(fresh_key(key), jnp.arange(256), 2))
    other = np.asarray(build_normals(fresh_key(key, 1), jnp.arange(256), 2))
    assert not np.any(np.isin(fresh, train)) and not np.any(np.isin(fresh, other))
    s = fresh_seeds(5, 4)
    assert len(set(s)) == 4 and 5 not in s and all(0 <= v < 2**63 for v in s)
    assert fresh_seeds(5, 4) == s  # deterministic


def test_paired_comparison_statistics_and_bad_input():
    rng = np.random.default_rng(11)
    common = rng.normal(size=4000)
    base = 5.0 + common
    chosen = 5.0 + common - 0.01 + 0.01 * rng.normal(size=4000)  # better by 0.01
    c = paired_comparison(chosen, base)
    assert c.win_significant and not c.worse_significant and c.verdict == "win"
    # common random numbers: the difference is far better resolved than either figure
    assert c.difference_stderr < 0.05 * c.chosen_stderr
    np.testing.assert_allclose(c.difference, np.mean(base - chosen), rtol=1e-12)
    # the same designs on independent builds: the 0.01 drowns in the build scatter
    ind = paired_comparison(chosen, 5.0 + rng.normal(size=4000))
    assert not ind.win_significant
    # rms: delta method against the direct estimate
    ms_a, ms_b = base**2, chosen**2
    r = paired_comparison(ms_b, ms_a, reduce="rms")
    np.testing.assert_allclose(r.chosen, math.sqrt(np.mean(ms_b)), rtol=1e-12)
    assert r.win_significant
    d = r.as_dict()
    assert d["win_significant"] is True and d["verdict"] == "win" and d["n"] == 4000
    with pytest.raises(EncdesignInputError):
        paired_comparison([1.0, 2.0], [1.0])
    with pytest.raises(EncdesignInputError):
        paired_comparison([1.0, np.nan], [1.0, 2.0])
    with pytest.raises(EncdesignInputError):
        paired_comparison([1.0, 2.0], [1.0, 2.0], reduce="median")


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_overfit_in_sample_optimum_is_caught_on_fresh_builds(seed):
    """Optimise E[(a - z)^2] over 4 builds: the in-sample optimum (the sample mean of the
    four z) beats the true optimum a = 0 on those builds, always; on fresh builds it cannot
    (its expected excess is a*^2), and the report must not call it a win, and must call it
    a loss once a* is resolved."""
    key = jax.random.key(seed)
    sol = optimise(
        _train, BFGS(rtol=1e-8, atol=1e-12, max_steps=100), jnp.array([0.7]), key
    )  # compiled once
    assert sol.status == "success"
    a_star = float(sol.value[0])
    z4 = np.asarray(build_normals(key, jnp.arange(4), 1))[:, 0]
    np.testing.assert_allclose(a_star, np.mean(z4), atol=1e-6)
    assert float(_train_jit(sol.value, key)) < float(_train_jit(jnp.zeros(1), key))  # in sample
    fk = fresh_key(key)
    chosen = monte_carlo(_value, a_star, key=fk, n=20_000, dim=1).values
    base = monte_carlo(_value, 0.0, key=fk, n=20_000, dim=1).values
    c = paired_comparison(chosen, base)
    assert not c.win_significant
    # E[difference] = -a*^2, stderr ~ 2 |a*| / sqrt(n): resolved when |a*| > 4 / sqrt(n)
    assert abs(a_star) > 0.1  # four builds never give a mean this close to 0 here
    assert c.worse_significant and c.verdict == "loss"
    np.testing.assert_allclose(c.difference, -(a_star**2), atol=5 * c.difference_stderr)

    # the control: a baseline that is truly worse (a = 2) is beaten significantly
    worse = monte_carlo(_value, 2.0, key=fk, n=20_000, dim=1).values
    assert paired_comparison(chosen, worse).win_significant


def test_fresh_replicates_are_one_compiled_program_equal_to_the_old_loop(user_module, monkeypatch):
    """The fresh seed is a traced input: every replicate runs in one compiled program (one
    evaluator built, once, while tracing), with the values of the old per-replicate loop
    (one compilation each) to 1e-12 (issue 27)."""
    from encdesign.design import _solve

    spec = {
        "problem": {"name": "o", "objective": f"{user_module}:overfit", "seed": 5},
        "variables": {"a": {"start": 0.0, "lower": -3.0, "upper": 3.0}},
    }
    p = parse_problem(spec, source="o.toml")
    designs = {"chosen": ({}, {"a": 0.3}), "baseline": ({}, {"a": 0.0})}
    seeds = fresh_seeds(p.seed, 3)
    built = []
    real = _solve._Evaluator.__init__

    def counting(self, *a, **k):
        built.append(1)
        real(self, *a, **k)

    monkeypatch.setattr(_solve._Evaluator, "__init__", counting)
    one = _solve._fresh_rows(p, designs, seeds)
    assert len(built) == 1  # one trace for all replicates and both designs
    loop = _solve._fresh_rows_per_replicate(p, designs, seeds)
    assert len(built) == 1 + len(seeds)
    for label in designs:
        a = np.array([r["loss"] for r in one[label]])
        b = np.array([r["loss"] for r in loop[label]])
        assert len(a) == 3 and len(set(a.tolist())) == 3  # the replicates differ
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=0)


def test_solve_problem_reports_the_fresh_check_and_no_overfit_win(user_module):
    for seed in (0,):
        spec = {
            "problem": {"name": "o", "objective": f"{user_module}:overfit", "seed": seed},
            "variables": {"a": {"start": 0.0, "lower": -3.0, "upper": 3.0}},
        }
        p = parse_problem(spec, source="o.toml")
        res = solve_problem(p, fresh_replicates=4)
        assert res.status == "success"
        assert res.best.objective < res.results[0].objective + 1.0  # solved
        f = res.fresh
        assert f is not None and f["n"] == 4 and f["builds_per_replicate"] == 4
        assert f["total_fresh_builds"] == 16 and len(set(f["fresh_seeds"])) == 4
        assert f["baseline_design"]["inputs"] == {"a": 0.0}
        assert not f["win_significant"]  # the start is the true optimum
        s = res.summary()
        assert s["win_significant"] is False and s["fresh"]["verdict"] in (
            "loss",
            "no significant difference",
        )
    # without Monte Carlo in the objective there is nothing to validate
    spec = {
        "problem": {"name": "f", "objective": f"{user_module}:flat_at_start"},
        "variables": {"a": {"start": 1.0, "lower": -5.0, "upper": 5.0}},
    }
    assert solve_problem(parse_problem(spec, source="f.toml"), fresh_replicates=4).fresh is None


def test_check_gradients_judges_near_zero_derivatives_absolutely(user_module, tmp_path, capsys):
    spec = {
        "problem": {"name": "f", "objective": f"{user_module}:flat_at_start"},
        "variables": {"a": {"start": 2.0, "lower": -5.0, "upper": 5.0}},
    }
    p = parse_problem(spec, source="f.toml")
    (row,) = check_gradients(p)
    assert row.basis == "absolute" and row.ok and abs(row.ad) <= row.atol
    (row,) = check_gradients(p, at={"a": 3.0})  # derivative 2: relative test
    assert row.basis == "relative" and row.ok and row.rel_error < 1e-6
    (row,) = check_gradients(p, at={"a": 2.0 + 1e-9}, atol=1e-12)  # 2e-9 > atol: relative
    assert row.basis == "relative"
    toml = tmp_path / "f.toml"
    toml.write_text(
        f'[problem]\nname = "f"\nobjective = "{user_module}:flat_at_start"\n'
        "[variables.a]\nstart = 2.0\nlower = -5.0\nupper = 5.0\n"
    )
    rc = main(["check-gradients", str(toml), "--json", str(tmp_path / "g.json")])
    out = capsys.readouterr().out
    assert rc == 0 and "absolute test" in out and "1 judged on the absolute tolerance" in out
    assert "rel 1.00e+00" not in out
    g = json.loads((tmp_path / "g.json").read_text())
    assert g["rows"][0]["basis"] == "absolute" and g["all_ok"]
