"""Drivers on small analytic objectives: statuses, Monte Carlo, DOE, enumeration."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from encdesign import EncdesignInputError
from encdesign.design._drivers import (
    BFGS,
    DRIVERS,
    LBFGSB,
    AbstractGradientSolver,
    DriverStatus,
    Grid,
    LatinHypercube,
    LevenbergMarquardt,
    MonteCarlo,
    OptimisationError,
    doe,
    monte_carlo,
    optimise,
)
from encdesign.design._enumerate import enumerate_designs
from encdesign.design._sampling import build_normals, expected_value, grid_points, latin_hypercube


def rosen(y, a):
    return (1.0 - y[0]) ** 2 + 100.0 * (y[1] - y[0] ** 2) ** 2


def test_bfgs_and_lm_find_rosenbrock_minimum():
    s = optimise(rosen, BFGS(max_steps=500), jnp.array([-1.2, 1.0]))
    assert s.ok and np.allclose(s.value, [1.0, 1.0], atol=1e-6)
    r = optimise(
        lambda y, a: jnp.stack([1.0 - y[0], 10.0 * (y[1] - y[0] ** 2)]),
        LevenbergMarquardt(),
        jnp.array([-1.2, 1.0]),
    )
    assert r.ok and np.allclose(r.value, [1.0, 1.0], atol=1e-8) and r.objective < 1e-16


def test_lbfgsb_keeps_bounds():
    s = optimise(rosen, LBFGSB(), jnp.array([0.0, 0.0]), upper=jnp.array([0.5, 2.0]))
    assert s.value[0] == pytest.approx(0.5) and s.value[1] == pytest.approx(0.25)
    # converged on the bound: an answer (ok), but marked as such, never plain "success"
    assert s.status == "at_bound" and s.ok and s.at_bounds == ("upper[0]",), s.message
    assert s.status is DriverStatus.AT_BOUND and s.status.ok
    # unconstrained BFGS with the same bounds reports the violation instead of hiding it
    b = optimise(rosen, BFGS(), jnp.array([0.0, 0.0]), upper=jnp.array([0.5, 2.0]))
    assert b.status == "bounds_violated" and not b.ok


def test_lbfgsb_compiles_once_per_function():
    traces = []

    def f(y, a):
        if isinstance(y, jax.core.Tracer):
            traces.append(1)
        return jnp.sum((y - a) ** 2)

    s1 = optimise(
        f, LBFGSB(), jnp.array([0.0, 0.0]), jnp.array([1.0, 2.0]), upper=jnp.array([0.5, 3.0])
    )
    n = len(traces)
    # another start, other bounds, other args: the jitted value-and-gradient is reused
    s2 = optimise(
        f, LBFGSB(), jnp.array([0.2, 0.1]), jnp.array([-1.0, 0.5]), lower=jnp.array([-0.5, -1.0])
    )
    assert n >= 1 and len(traces) == n
    assert s1.status == s2.status == "at_bound"  # both converge onto a bound
    np.testing.assert_allclose(s1.value, [0.5, 2.0], atol=1e-6)
    np.testing.assert_allclose(s2.value, [-0.5, 0.5], atol=1e-6)


def test_map_builds_is_independent_of_chunking():
    from encdesign.design._sampling import map_builds

    key = jax.random.key(7)
    ref = build_normals(key, jnp.arange(3, 3 + 203), 5) @ jnp.arange(1.0, 6.0)
    for vector, block in ((1, 7), (4, 4), (8, 512), (8, 20), (64, 64)):
        got = map_builds(
            lambda z: z @ jnp.arange(1.0, 6.0), key, 203, 5, first=3, block=block, vector=vector
        )
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)


def test_failures_come_back_with_a_status():
    s = optimise(lambda y, a: jnp.log(y[0]) + y[0], BFGS(), jnp.array([1.0]))
    assert not s.ok and s.status in ("nonfinite", "failed", "max_steps_reached")
    m = optimise(rosen, BFGS(max_steps=3), jnp.array([-1.2, 1.0]))
    assert m.status == "max_steps_reached"
    with pytest.raises(OptimisationError, match="max_steps_reached"):
        optimise(rosen, BFGS(max_steps=3), jnp.array([-1.2, 1.0]), throw=True)


def test_common_random_numbers_independent_of_chunking():
    k = jax.random.key(5)
    a = build_normals(k, jnp.arange(10), 3)
    b = build_normals(k, jnp.arange(4, 7), 3)
    assert np.array_equal(np.asarray(a[4:7]), np.asarray(b))
    f = lambda th, z: th * z[0] ** 2 + z[1]
    r1 = monte_carlo(f, 2.0, key=k, n=1000, dim=3, chunk_size=7)
    r2 = monte_carlo(f, 2.0, key=k, n=1000, dim=3, chunk_size=1000)
    assert np.array_equal(r1.values, r2.values) and r1.ok


def _sq(th, z):
    return z[0] ** 2 + z[1]


def test_monte_carlo_converges_as_one_over_sqrt_n():
    # E[z0^2 + z1] = 1, var = 3; the spread over independent keys shrinks as 1/sqrt(n)
    spreads = []
    for n in (100, 1600):
        est = [
            monte_carlo(_sq, 0.0, key=jax.random.key(100 + i), n=n, dim=2, chunk_size=n).mean
            for i in range(40)
        ]
        spreads.append(np.std(est))
        assert np.mean(est) == pytest.approx(1.0, abs=4 * math.sqrt(3.0 / n / 40) + 1e-3)
    ratio = spreads[0] / spreads[1]
    assert 2.6 < ratio < 6.0  # sqrt(1600 / 100) = 4
    r = monte_carlo(_sq, 0.0, key=jax.random.key(1), n=1600, dim=2)
    assert r.stderr == pytest.approx(math.sqrt(3.0 / 1600), rel=0.2)


def test_expected_value_gradient_is_smooth_and_matches_fd():
    k = jax.random.key(2)
    f = lambda th, z: jnp.sqrt((th * z[0]) ** 2 + 0.1 + jnp.sin(th) * z[1] ** 2)
    ev = lambda th: expected_value(f, th, key=k, n=500, dim=2, chunk_size=128)
    g = jax.grad(ev)(0.7)
    h = 1e-5
    fd = (ev(0.7 + h) - ev(0.7 - h)) / (2 * h)
    assert float(g) == pytest.approx(float(fd), rel=1e-7)


def test_nonfinite_builds_are_reported():
    r = monte_carlo(lambda th, z: jnp.log(z[0]), 0.0, key=jax.random.key(0), n=50, dim=1)
    assert r.status == "nonfinite" and r.n_nonfinite > 0
    with pytest.raises(OptimisationError):
        monte_carlo(
            lambda th, z: jnp.log(z[0]), 0.0, key=jax.random.key(0), n=50, dim=1, throw=True
        )


def test_grid_and_lhs_find_known_optimum():
    f = lambda x, a: (x[0] - 0.3) ** 2 + 2.0 * (x[1] + 0.2) ** 2
    g = doe(f, grid_points([-1, -1], [1, 1], 21))
    assert g.ok and np.allclose(g.best_point, [0.3, -0.2], atol=1e-12)
    pts = latin_hypercube(jax.random.key(3), [-1, -1], [1, 1], 400)
    # one point per stratum in every dimension
    for d in range(2):
        strata = np.floor((pts[:, d] + 1) / 2 * 400).astype(int)
        assert sorted(strata) == list(range(400))
    best = doe(f, pts).best_point
    assert np.allclose(best, [0.3, -0.2], atol=0.1)
    bad = doe(lambda x, a: jnp.log(x[0]), np.array([[-1.0], [2.0]]))
    assert bad.statuses == ("nonfinite", "success") and bad.best_index == 1


def test_enumeration_finds_discrete_and_continuous_optimum():
    # f(x; n, m) = (x - n)^2 + (n - 2)^2 + 0.5 * |m - 1|: best n = 2, m = 1, x = 2
    def solve(c):
        fn = lambda y, a: (y[0] - a[0]) ** 2 + (a[0] - 2.0) ** 2 + 0.5 * jnp.abs(a[1] - 1.0)
        return optimise(fn, BFGS(), jnp.zeros(1), jnp.array([c["n"], c["m"]], dtype=float))

    r = enumerate_designs(solve, {"n": [1, 2, 3], "m": [0, 1]})
    assert r.ok and r.best_choice == {"n": 2, "m": 1}
    assert r.best_solution.value[0] == pytest.approx(2.0, abs=1e-6)
    assert len(r.choices) == 6


@jax.custom_jvp
def _wrong_gradient(y):
    """``sum((y - 3)^2)`` whose derivative has the wrong sign: every line search fails."""
    return jnp.sum((y - 3.0) ** 2)


@_wrong_gradient.defjvp
def _wrong_gradient_jvp(primals, tangents):
    (y,), (dy,) = primals, tangents
    return _wrong_gradient(y), jnp.sum(-2.0 * (y - 3.0) * dy)


def _bowl(y, uphill):
    """``sum((y - 3)^2)``, its derivative with the wrong sign where ``uphill`` (an argument:
    one compiled solver serves both)."""
    return jnp.where(uphill, _wrong_gradient(y), jnp.sum((y - 3.0) ** 2))


UPHILL, TRUE_GRADIENT = np.asarray(True), np.asarray(False)  # arrays: traced, not static


@pytest.mark.parametrize("solver", [BFGS(max_steps=60), LBFGSB(max_steps=60)], ids=str)
def test_stalled_line_search_is_its_own_status(solver):
    """A line search that never finds a decrease (the gradient points uphill) is reported
    as ``line_search_stalled``, never as success or as a plain step cap (issue 27)."""
    s = optimise(_bowl, solver, jnp.zeros(2), UPHILL)
    assert s.status == "line_search_stalled" and not s.ok, (s.status, s.message)
    with pytest.raises(OptimisationError, match="line_search_stalled"):
        optimise(_bowl, solver, jnp.zeros(2), UPHILL, throw=True)
    # the same function with its true gradient converges; a start at the optimum is a
    # converged answer (no decrease possible), not a stall
    good = optimise(_bowl, solver, jnp.zeros(2), TRUE_GRADIENT)
    assert good.status == "success" and np.allclose(good.value, 3.0, atol=1e-6)
    at_opt = optimise(_bowl, solver, jnp.full(2, 3.0), TRUE_GRADIENT)
    assert at_opt.status == "success", at_opt.message


def test_a_stop_on_a_small_step_with_a_large_gradient_is_stalled():
    """BFGS stops when its steps become small; at a kink (``|y - 3|``) they do while the
    gradient is still +-1, and the quasi-Newton step still predicts a decrease: the stop is
    reported as ``line_search_stalled`` (nothing certifies it), not as success."""
    s = optimise(lambda y, a: jnp.sum(jnp.abs(y - 3.0)), BFGS(max_steps=200), jnp.zeros(2))
    assert s.status == "line_search_stalled" and "quasi-Newton" in s.message, s.message
    smooth = optimise(lambda y, a: jnp.sum((y - 3.0) ** 2), BFGS(), jnp.zeros(2))
    assert smooth.status == "success"


def test_bfgs_and_lm_touching_a_bound_are_marked():
    lm = optimise(lambda y, a: y - 3.0, LevenbergMarquardt(), jnp.zeros(2), upper=3.0)
    assert lm.status == "at_bound" and lm.at_bounds == ("upper[0]", "upper[1]")
    free = optimise(lambda y, a: y - 3.0, LevenbergMarquardt(), jnp.zeros(2), upper=4.0)
    assert free.status == "success" and free.at_bounds == ()


GRADIENT_SOLVERS = [BFGS, LBFGSB, LevenbergMarquardt]


@pytest.mark.parametrize("cls", GRADIENT_SOLVERS, ids=lambda c: c.__name__)
def test_every_gradient_solver_solves_a_bowl_with_its_defaults(cls):
    """The one set of defaults of each solver converges on a shifted bowl; the residual
    form for Levenberg-Marquardt."""
    fn = (lambda y, a: y - a) if cls is LevenbergMarquardt else (lambda y, a: jnp.sum((y - a) ** 2))
    target = jnp.array([0.3, -1.7])
    s = optimise(fn, cls(), jnp.zeros(2), target)
    assert s.status is DriverStatus.SUCCESS and s.ok and s.solver == cls.kind, s.message
    np.testing.assert_allclose(s.value, target, atol=1e-6)


DRIVER_CLASSES = [*GRADIENT_SOLVERS, Grid, LatinHypercube, MonteCarlo]


@pytest.mark.parametrize("cls", DRIVER_CLASSES, ids=lambda c: c.__name__)
def test_driver_settings_are_checked_by_name(cls):
    """Every driver refuses a setting it cannot use in ``__check_init__``, naming its
    class and field; good settings round-trip through ``settings()``."""
    good = {"n_builds": 10} if cls is MonteCarlo else {}
    d = cls(**good)
    assert d.settings()["kind"] == cls.kind
    for name, (number, lo, _hi) in cls.limits.items():
        bad = 0 if number is int and lo >= 1 else -1.0
        if number is int and lo == 2:
            bad = 1
        with pytest.raises(EncdesignInputError, match=rf"{cls.__name__}\.{name}"):
            cls(**{**good, name: bad})
        with pytest.raises(EncdesignInputError, match=rf"{cls.__name__}\.{name}"):
            cls(**{**good, name: True if number is int else "1e-8"})


def test_monte_carlo_refuses_zero_builds_by_name():
    with pytest.raises(EncdesignInputError, match=r"MonteCarlo\.n_builds: 0"):
        MonteCarlo(n_builds=0)
    with pytest.raises(EncdesignInputError, match=r"n_builds"):
        monte_carlo(_sq, 0.0, key=jax.random.key(0), n=0, dim=2)
    r = MonteCarlo(n_builds=64, chunk_size=16).run(_sq, 0.0, key=jax.random.key(0), dim=2)
    same = monte_carlo(_sq, 0.0, key=jax.random.key(0), n=64, dim=2, chunk_size=16)
    assert r.ok and np.array_equal(r.values, same.values)


def test_optimise_refuses_a_solver_name():
    """The string form is gone: a name is refused with the object to use instead."""
    with pytest.raises(EncdesignInputError, match="BFGS"):
        optimise(rosen, "bfgs", jnp.zeros(2))  # type: ignore[arg-type]
    with pytest.raises(EncdesignInputError, match="gradient solver"):
        optimise(rosen, Grid(), jnp.zeros(2))  # type: ignore[arg-type]


def test_statuses_are_one_enumeration_with_a_message_each():
    assert {s.value for s in DriverStatus} >= {"success", "at_bound", "max_steps_reached"}
    assert all(s.message for s in DriverStatus)
    assert [s for s in DriverStatus if s.ok] == [DriverStatus.SUCCESS, DriverStatus.AT_BOUND]
    assert set(DRIVERS) == {"bfgs", "lbfgsb", "lm", "grid", "lhs"}
    assert all(issubclass(DRIVERS[k], AbstractGradientSolver) for k in ("bfgs", "lbfgsb", "lm"))


def test_results_render_in_a_notebook():
    """``_repr_html_`` of every driver result: the status and its key numbers, escaped."""
    s = optimise(_bowl, BFGS(), jnp.zeros(2), TRUE_GRADIENT)
    h = s._repr_html_()
    assert '<span class="badge ok">success</span>' in h and "Solution (bfgs)" in h
    assert f"<td>{s.n_steps}</td>" in h and "[3, 3]" in h  # the steps and the value
    assert f"<td>{s.objective:.8g}</td>" in h
    bad = dataclasses.replace(s, status=DriverStatus.FAILED, message='x < 1 & "<script>"')
    h = bad._repr_html_()
    assert '<span class="badge not-ok">failed</span>' in h
    assert "x &lt; 1 &amp; &quot;&lt;script&gt;&quot;" in h and "<script>" not in h
    assert DriverStatus.FAILED.message in h

    mc = monte_carlo(lambda th, z: th + z[0], 2.0, key=jax.random.key(1), n=400, dim=1)
    h = mc._repr_html_()
    assert '<span class="badge ok">success</span>' in h and "<td>400</td>" in h
    assert f"{mc.mean:.6g} ± {mc.stderr:.3g}" in h and f"{mc.std:.6g}" in h
    assert f"{np.percentile(mc.values, 95):.6g}" in h
    mc_bad = monte_carlo(lambda th, z: jnp.log(z[0]), 0.0, key=jax.random.key(0), n=50, dim=1)
    h = mc_bad._repr_html_()
    assert "not-ok" in h and f"<td>{mc_bad.n_nonfinite}</td>" in h

    g = doe(lambda x, a: (x[0] - 0.3) ** 2, np.array([[0.0], [0.3], [1.0]]))
    h = g._repr_html_()
    assert '<span class="badge ok">success</span>' in h and "<td>1</td>" in h
    assert "[0.3]" in h and f"<td>{g.best_value:.8g}</td>" in h

    def solve(c):
        a = {"<a>": 2.0, "b&": 1.0}[c["tag"]]
        return optimise(lambda y, a: (y[0] - a) ** 2 + a, BFGS(), jnp.zeros(1), a)

    e = enumerate_designs(solve, {"tag": ["<a>", "b&"]})
    h = e._repr_html_()
    assert "<b>best</b> tag = b&amp;" in h and "tag = &lt;a&gt;" in h and "<a>" not in h
    assert h.count('class="badge ok"') == 3  # the result and its two rows
    assert f"{e.solutions[0].objective:.8g}" in h
