"""Tolerance budgets on an analytic error model, and the three studies in --quick mode."""

import functools
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from encdesign import EncdesignInputError
from encdesign.cli import main
from encdesign.design._sampling import build_normals
from encdesign.design._tolerance import (
    allocate,
    check_yield,
    contributions,
    pareto_front,
    plot_pareto,
    sweep_scales,
    tolerance_cost,
    yield_stats,
)

NAMES = ("a", "b", "c")
WEIGHT = jnp.array([1.0, 4.0, 0.25])  # how strongly each tolerance drives the error


def _z(seed, n):
    return build_normals(jax.random.key(seed), jnp.arange(n), 3)


@functools.cache
def _z_train() -> jax.Array:
    """The training builds, made on first use (not while pytest collects), eagerly even
    when the first use is inside a trace."""
    with jax.ensure_compile_time_eval():
        return _z(0, 400)


def ms_fn(s, z=None):
    """Mean-square error of each build: sum_i (w_i s_i z_i)^2 (linear error model);
    ``z`` defaults to the training builds."""
    z = _z_train() if z is None else z
    return jnp.sum((WEIGHT * s * z) ** 2, axis=1)


def values_fn(s, z=None):
    return jnp.sqrt(ms_fn(s, z))


def test_contributions_are_exact_variance_shares():
    s = jnp.array([0.3, 0.1, 0.8])
    con = contributions(ms_fn, values_fn, s, NAMES)
    per = np.asarray(jnp.mean((WEIGHT * s * _z_train()) ** 2, axis=0))
    np.testing.assert_allclose(con.variance_share, per / per.sum(), rtol=1e-12)
    assert con.variance_share.sum() == pytest.approx(1.0)
    assert con.order[0] == int(np.argmax(per))
    assert np.all(con.gradient_sensitivity > 0)


def test_sweep_is_monotonic_and_2d_shape():
    s = np.array([0.3, 0.1, 0.8])
    t = sweep_scales(values_fn, s, NAMES, 1.0, [0.5, 1.0, 2.0])
    assert np.all(np.diff(t.yield_) <= 0) and np.all(np.diff(t.percentile) > 0)
    # all tolerances x 2 doubles the linear error's percentile
    assert t.percentile[2] == pytest.approx(2 * t.percentile[1])
    t2 = sweep_scales(
        values_fn,
        s,
        NAMES,
        1.0,
        [0.5, 1.0],
        group_a=["b"],
        group_b=["a", "c"],
        scales_b=[0.5, 1.0, 2.0],
    )
    assert t2.yield_.shape == (2, 3) and len(t2.rows()) == 6
    with pytest.raises(EncdesignInputError, match="unknown tolerance"):
        sweep_scales(values_fn, s, NAMES, 1.0, [1.0], group_a=["zz"])


def test_allocation_meets_target_on_fresh_builds_and_beats_uniform_scaling():
    ref = np.array([0.3, 0.3, 0.3])
    spec, target = 1.0, 0.9
    al = allocate(values_fn, ref, NAMES, spec, target, max_steps=150)
    assert al.ok, al.message
    assert al.train_yield >= target
    fresh = np.asarray(values_fn(jnp.asarray(al.sigmas), _z(77, 20000)))
    chk = check_yield(fresh, spec, target)
    assert chk["meets_target"], chk
    # uniform scaling of the reference to the same training yield costs more
    lo, hi = 1e-3, 10.0
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if yield_stats(values_fn(jnp.asarray(ref * mid)), spec)[0] >= al.train_yield:
            lo = mid
        else:
            hi = mid
    uniform_cost = float(tolerance_cost(ref * lo, ref))
    assert al.cost < 0.95 * uniform_cost
    # the strongly weighted tolerance is held tighter than the weak one
    assert al.sigmas[1] < al.sigmas[0] < al.sigmas[2]


def test_pareto_front_is_monotone_checked_and_warm_started(tmp_path):
    """Cost against yield: each point re-allocated from its neighbour (warm start), the cost
    rising with the target, each point's yield confirmed on fresh builds within its error."""
    ref = np.array([0.3, 0.3, 0.3])
    spec, targets = 1.0, [0.8, 0.9, 0.95, 0.98]
    z_check = _z(78, 20000)
    front = pareto_front(
        values_fn,
        ref,
        NAMES,
        spec,
        targets,
        check_fn=lambda s: values_fn(s, z_check),
        max_steps=150,
    )
    assert front.monotone
    rows = front.rows()
    for r in rows:  # a point that hit its step cap is marked, never reported as success
        assert r["converged"] == (r["status"] == "success")
        assert r["status"] in ("success", "max_steps_reached")
    costs = [r["cost"] for r in rows]
    assert all(b > a for a, b in zip(costs, costs[1:]))  # strictly: a higher yield costs more
    assert rows[0]["warm_start_from_target"] is None
    assert [r["warm_start_from_target"] for r in rows[1:]] == targets[:-1]
    for r in rows:
        assert r["train_yield"] >= r["target_yield"]
        # independent Monte Carlo: meets the target within 2 s.e., and agrees with the
        # training yield within 3 combined standard errors
        assert r["meets_target"], r
        se_train = math.sqrt(r["train_yield"] * (1 - r["train_yield"]) / _z_train().shape[0])
        se = math.hypot(se_train, r["checked_yield_stderr"])
        assert abs(r["checked_yield"] - r["train_yield"]) <= 3 * se + 1e-12, r
    # the warm start is used: a cold allocation at the same target takes more steps to the
    # same cost
    cold = allocate(values_fn, ref, NAMES, spec, targets[-1], max_steps=150)
    assert cold.status in ("success", "max_steps_reached")
    assert rows[-1]["n_steps"] < cold.n_steps
    assert rows[-1]["cost"] == pytest.approx(cold.cost, rel=0.02)
    assert plot_pareto(front, tmp_path, "front.png").stat().st_size > 0
    # an anchor (an allocation already made) is reused as its point on the front
    two = pareto_front(values_fn, ref, NAMES, spec, [0.9], anchor=cold, anchor_target=0.98)
    assert two.allocations[1] is cold and two.warm_from == (0.98, None)
    with pytest.raises(EncdesignInputError, match="yield target"):
        pareto_front(values_fn, ref, NAMES, spec, [0.9, 1.0])


def test_allocator_step_cap_is_reported_not_success():
    """Too few BFGS steps for the last penalty round: the allocation comes back marked
    ``max_steps_reached`` (scaled to its goal, usable, but never "success"), and its point
    on a front says it did not converge (issue 27)."""
    ref = np.array([0.3, 0.3, 0.3])
    spec, target = 1.0, 0.9
    capped = allocate(values_fn, ref, NAMES, spec, target, max_steps=3)
    assert capped.status == "max_steps_reached" and not capped.ok
    assert "step cap" in capped.message and "3 of 3 steps" in capped.message
    assert capped.n_steps == 3 * 3  # every round took all its steps
    assert capped.train_yield >= target  # still scaled to the goal
    with pytest.raises(Exception, match="max_steps_reached"):
        allocate(values_fn, ref, NAMES, spec, target, max_steps=3, throw=True)
    z_check = _z(79, 4000)
    front = pareto_front(
        values_fn, ref, NAMES, spec, [0.9], check_fn=lambda s: values_fn(s, z_check), max_steps=3
    )
    (row,) = front.rows()
    assert row["status"] == "max_steps_reached" and row["converged"] is False
    assert not front.ok
    # a capped point is still checked on fresh builds, against the reference on the same
    fr = row["fresh_vs_reference"]
    assert fr["n"] == 4000 and fr["figure"] == "failure fraction"
    assert {"chosen", "baseline", "difference", "difference_stderr", "win_significant"} <= set(fr)
    # enough steps: converged, and the row says so
    ok = pareto_front(
        values_fn, ref, NAMES, spec, [0.9], check_fn=lambda s: values_fn(s, z_check), max_steps=150
    )
    assert ok.rows()[0]["converged"] is True


def test_infeasible_targets_are_refused():
    with pytest.raises(EncdesignInputError, match="infeasible yield target"):
        allocate(values_fn, np.ones(3), NAMES, 1.0, 1.0)


def test_reference_head_opt_quick(tmp_path):
    out = tmp_path / "rho.json"
    rc = main(
        [
            "study",
            "run",
            "reference-head-opt",
            "--quick",
            "--no-plots",
            "--out",
            str(tmp_path),
            "--json",
            str(out),
            *("--builds", "4", "--grid-step-deg", "0.5", "--max-order", "8"),
            *("--fresh-builds", "200"),  # smaller than quick: CI time
        ]
    )
    assert rc == 0
    d = json.loads(out.read_text())
    assert [e["layout"] for e in d["layouts"]] == ["2+1", "3+1", "4+1"]
    assert d["fresh_builds"] == 200
    for e in d["layouts"]:
        step = e["grid_step_deg"]
        assert abs(e["reference_angle_deg"] - e["grid_best_angle_deg"]) <= step
        assert e["sensitivity"] <= e["grid_best_sensitivity"] * (1 + 1e-12)
        # out of sample against the tolerance-free optimum, on the same fresh builds
        fr = e["fresh"]
        assert fr["n"] == 200 and fr["chosen"] == e["sensitivity_fresh"]
        assert fr["baseline"] == e["baseline_sensitivity_fresh"]
        assert e["sensitivity_fresh_stderr"] > 0 and e["baseline_sensitivity_fresh_stderr"] > 0
        assert e["win_significant"] == (fr["z"] > 2) == d["win_significant"][e["layout"]]
        assert abs(e["baseline_angle_deg"] - e["grid_best_angle_deg"]) < 10 * step


def test_tolerance_budget_quick(tmp_path):
    out = tmp_path / "tb.json"
    rc = main(
        [
            "study",
            "run",
            "tolerance-budget",
            "--quick",
            "--no-plots",
            "--out",
            str(tmp_path),
            "--json",
            str(out),
        ]
    )
    assert rc == 0
    d = json.loads(out.read_text())
    assert d["target_yield"] == 0.99
    assert d["checked_yield"] + 2 * d["checked_yield_stderr"] >= d["target_yield"]
    assert sum(d["contributions"].values()) == pytest.approx(1.0, abs=1e-9)
    assert set(d["tolerances"]) == set(d["contributions"])
    assert all(v > 0 for v in d["tolerances"].values())
    # Sobol indices beside the shares (issue 14): one per tolerance, noise not sampled
    assert set(d["sobol_first"]) == set(d["contributions"]) == set(d["sobol_total"])
    assert d["sobol_first"]["noise"] is None
    for n, v in d["sobol_first"].items():
        if v is not None:
            assert v <= d["sobol_total"][n] + 0.1  # first <= total up to estimator noise
    # Pareto front of cost against yield target (issue 14 item 6), warm-started
    front = d["pareto"]
    assert [r["target_yield"] for r in front] == [0.95, 0.99]
    assert d["pareto_monotone"]
    for r in front:  # a capped point is marked as such, never reported as success
        assert r["converged"] == (r["status"] == "success")
        assert r["status"] in ("success", "max_steps_reached")
    assert d["allocation_converged"] == (d["allocation_status"] == "success")
    fr = d["fresh_vs_reference"]
    assert fr["n"] == d["n_check"] and isinstance(fr["win_significant"], bool)
    assert front[0]["cost"] < front[1]["cost"] == pytest.approx(d["cost"])
    assert [r["warm_start_from_target"] for r in front] == [0.99, None]
    for r in front:
        assert r["checked_yield"] + 2 * r["checked_yield_stderr"] >= r["target_yield"], r


def test_pole_sensor_opt_quick(tmp_path):
    out = tmp_path / "ps.json"
    rc = main(
        [
            "study",
            "run",
            "pole-sensor-opt",
            "--quick",
            "--no-plots",
            "--out",
            str(tmp_path),
            "--json",
            str(out),
            *("--starts", "1", "--fresh-builds", "4"),  # smaller than quick: CI time
        ]
    )
    assert rc == 0
    d = json.loads(out.read_text())
    best = d["best"]
    # seed 001: the pole count should not be a multiple of the sensor count
    assert not best["pole_multiple_of_sensors"]
    assert best["residual_mean_rad"] == min(r["residual_mean_rad"] for r in d["table"])
    # second stage (issue 14 item 2): moving-sensor azimuths optimised from random layouts
    opt = {(r["pole_pairs"], r["n_sensors"]): r for r in d["optimised"]}
    assert set(opt) == {(5, 3), (6, 3)}
    for r in opt.values():
        assert r["status"] in ("success", "max_steps_reached")
        assert r["residual_mean_rad"] < 0.1 * r["residual_start_rad"]
        # the optimiser finds the equally spaced layout by itself (starts are random)
        assert r["max_gap_deviation_from_equal_deg"] < 1.0, r["moving_gaps_deg"]
    # ... and the pole-count rule from the optimised residuals, not from the enumeration
    assert d["rule_from_optimiser"]["3"]["holds"]
    assert opt[(6, 3)]["residual_mean_rad"] > 2 * opt[(5, 3)]["residual_mean_rad"]
    assert not d["best_optimised"]["pole_multiple_of_sensors"]
    # out of sample: the optimiser's layout against equally spaced sensors, same disks
    fc = d["fresh_check"]
    assert (fc["pole_pairs"], fc["n_sensors"]) == (
        d["best_optimised"]["pole_pairs"],
        d["best_optimised"]["n_sensors"],
    )
    assert fc["n_fresh_builds"] == 4 and fc["comparison"]["n"] == 4
    assert fc["residual_fresh_stderr_rad"] > 0 and fc["baseline_residual_fresh_stderr_rad"] > 0
    assert d["win_significant"] == fc["win_significant"] == (fc["comparison"]["z"] > 2)
    g = d["gradient_check"]
    assert g["max_rel_error"] < 1e-3
    assert max(abs(v) for v in g["grad_fixed_per_rad"]) < 1e-6 * max(
        abs(v) for v in g["grad_moving_per_rad"]
    )


@jax.custom_jvp
def _uphill_values(s):
    """:func:`values_fn` whose derivative has the wrong sign: the allocator's line search
    cannot find a decrease."""
    return values_fn(s)


@_uphill_values.defjvp
def _uphill_values_jvp(primals, tangents):
    (s,), (ds,) = primals, tangents
    v, dv = jax.jvp(values_fn, (s,), (ds,))
    return v, -dv


def test_allocator_stalled_line_search_is_reported_not_success():
    """A stalled line search in a penalty round ends the allocation with status
    ``line_search_stalled`` (not success, not scaled), and its front row says so (issue 27)."""
    ref = np.array([0.3, 0.3, 0.3])
    a = allocate(_uphill_values, ref, NAMES, 1.0, 0.9, max_steps=60)
    assert a.status == "line_search_stalled" and not a.ok, (a.status, a.message)
    front = pareto_front(_uphill_values, ref, NAMES, 1.0, [0.9], max_steps=60)
    (row,) = front.rows()
    assert row["status"] == "line_search_stalled" and row["converged"] is False
